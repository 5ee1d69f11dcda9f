#!/usr/bin/env python3
"""Redraws every plot in docs/plots from the JSON data files committed next to this script: one
PNG per JSON file, named after it (dvd_resolution.json -> dvd_resolution.png). Python 3 standard
library and gnuplot (Debian gnuplot-nox, installed by deploy/setup.sh; its pngcairo terminal).

    python3 docs/plots/plot_all.py                      # redraw docs/plots/*.png in place
    python3 docs/plots/plot_all.py --out /tmp/plots     # the same PNGs into another folder

Each JSON file is recognised by its shape, and a file of no known shape is an error (so every
data file here has a plot):

  - proxima_dvd_bench --json FILE (tests/bench/dvd_bench.cpp): "tool": "proxima_dvd_bench".
    Per scene and query, time per frame (DVD kernel and total per Voronoi backend, the BVH
    culler's total as a dashed line) and exact triangle tests, against the grid cell size.
    dvd_resolution.json is the run of docs/benchmarks.md ("Discrete-Voronoi culling"), converted
    once from its CSV (--csv writes the same rows); a new run is
        ./build/release/tests/bench/proxima_dvd_bench --no-gpu --frames 3 \\
            --cells 0.125,0.25,0.5,1 --scenes skirt,cloth-ball,bowl,ramps,breaking \\
            --json docs/plots/dvd_resolution.json
  - proxima load --json (docs/load.md): a ghz-style report with a "timeline". Latency per second
    (p50-p90 and p90-p99 bands, p50, max), throughput per call kind and errors, and the daemons'
    RSS and CPU from the Prometheus samples. load-example.json is a 10 s run against a proximad
    on an 8K-triangle generated plant (the set-up of tests/cli/test_load_cli.py), on the shared,
    loaded 2-core AMD EPYC development VM:
        proxima generate plant --triangles 8K --dir /tmp/plant --quiet
        proxima import --store /tmp/models/plant --quiet /tmp/plant/scene.json
        proximad --listen 127.0.0.1:0 --metrics-listen 127.0.0.1:0 --models /tmp/models &
        proxima load --server ADDR --duration 10s --warmup 2s \\
            --clients sim=2,review=2,verify=1 --scene bowl,breaking --episode-frames 8 \\
            --queries separation,collisions,ccd --edit-every 3 \\
            --metrics http://METRICS_ADDR/metrics --json --quiet > docs/plots/load-example.json

snapshot-demo.png (the README's offscreen snapshot: an 8K-triangle generated plant, colliding
triangles red) is not drawn from JSON but rendered by proxima itself, locally (no daemon), from the
repository root (llvmpipe here; another renderer may write other bytes):
    build/release/clients/proxima generate plant --triangles 8K --dir /tmp/plant --quiet
    build/release/clients/proxima snapshot /tmp/plant/meshes/bay-0000/*.ply \
        --out docs/plots/snapshot-demo.png

Environment: GNUPLOT names the gnuplot program (default: gnuplot on PATH).
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))

# The colours of one Voronoi backend's curves (kernel, total) in order of appearance.
PALETTE = ["#1f78b4", "#33a02c", "#6a3d9a", "#ff7f00"]
# Call kinds of proxima load in its order (clients/cli/load_command.cpp, KIND_NAMES).
LOAD_KINDS = ["sim_scene", "sim_frame", "pair_scene", "pair_frame", "review_join", "review_pose",
              "review_edit", "verify_model", "play_scene", "play_frame"]
KIND_COLOURS = ["#a6761d", "#1f78b4", "#b2df8a", "#33a02c", "#999999", "#ff7f00", "#6a3d9a",
                "#e31a1c", "#fb9a99", "#cab2d6"]


def gp_string(s):
    """A gnuplot double-quoted string."""
    return '"' + str(s).replace("\\", "\\\\").replace('"', '\\"') + '"'


def number(v):
    """A gnuplot data-file value: NaN for null."""
    return "NaN" if v is None else repr(float(v))


def dvd_plot(doc, png, tmp):
    """Two panels per (scene, query): time per frame and exact tests against the cell size."""
    rows = doc["rows"]
    panels, bvh, series = [], {}, {}
    for r in rows:
        key = (r["scene"], r["query"])
        if key not in panels:
            panels.append(key)
        if r["culler"] == "bvh":
            bvh[key] = r
            continue
        series.setdefault(key, {}).setdefault(r["culler"], []).append(r)
    cullers = []
    for per in series.values():
        for c in per:
            if c not in cullers:
                cullers.append(c)
    files = {}
    for key, per in series.items():
        for culler, pts in per.items():
            path = os.path.join(tmp, f"dvd-{len(files)}.dat")
            with open(path, "w") as f:
                for r in sorted(pts, key=lambda r: (r["cell"] is None, r["cell"] or 0)):
                    if r["cell"] is None:
                        continue
                    f.write(" ".join(number(r[k]) for k in ("cell", "dvd_ms", "exact_tests",
                                                             "total_ms")) + "\n")
            files[key + (culler,)] = path
    width, row_height = 1500, 330
    facts = [f"device {doc.get('device', '?')}"]
    if doc.get("cpu"):
        facts.append(doc["cpu"])
    if doc.get("frames"):
        facts.append(f"medians over frames 1..{doc['frames'] - 1}")
    lines = [
        f"set terminal pngcairo size {width},{row_height * len(panels) + 60} font 'sans,10' "
        "noenhanced",
        f"set output {gp_string(png)}",
        f"set multiplot layout {len(panels)},2 title "
        + gp_string("proxima_dvd_bench: discrete-Voronoi culling vs grid cell size ("
                    + "; ".join(facts) + ")") + " font 'sans,13'",
        "set logscale xy",
        "set grid",
        "set xlabel 'cell (scene units)'",
        # Keys outside the plot area, just right of it, in a fixed margin so the panels line up.
        "set key at graph 1.03, graph 1 left top vertical Left reverse samplen 2 spacing 1.1",
        "set lmargin 11",
        "set rmargin 27",
        "set format y '%g'",
    ]
    for key in panels:
        scene, query = key
        b = bvh.get(key)
        tris = (b or next(iter(series.get(key, {}).values()), [{}])[0]).get("triangles")
        cells = [r["cell"] for per in series.get(key, {}).values() for r in per
                 if r["cell"] is not None and r["cell"] > 0]
        lo, hi = (min(cells) / 1.5, max(cells) * 1.5) if cells else (1e-3, 1.0)
        lines.append(f"set xrange [{lo!r}:{hi!r}]")
        lines.append("set xtics (" + ", ".join(f"'{c:.3g}' {c!r}" for c in sorted(set(cells)))
                     + ")")
        # The BVH culler's figures as dashed lines across the panel (they have no cell size).
        ref = os.path.join(tmp, f"bvh-{panels.index(key)}.dat")
        with open(ref, "w") as f:
            for x in (lo, hi):
                f.write(f"{x!r} {number(b and b.get('total_ms'))} "
                        f"{number(b and b.get('exact_tests'))}\n")
        label = f"{scene}" + (f" ({tris} triangles)" if tris else "") + f", {query}"
        lines.append(f"set title {gp_string(label + ': time per frame')}")
        lines.append("set ylabel 'ms'")
        lines.append("set yrange [*:*]")
        plot = []
        for i, culler in enumerate(cullers):
            path = files.get(key + (culler,))
            if path is None:
                continue
            colour = PALETTE[i % len(PALETTE)]
            plot.append(f"{gp_string(path)} using 1:2 with linespoints pt 7 ps 0.6 lw 2 "
                        f"lc rgb '{colour}' title {gp_string(culler + ' DVD kernel')}")
            plot.append(f"{gp_string(path)} using 1:4 with linespoints pt 5 ps 0.6 lw 2 dt 3 "
                        f"lc rgb '{colour}' title {gp_string(culler + ' total')}")
        if b and b.get("total_ms") is not None:
            plot.append(f"{gp_string(ref)} using 1:2 with lines dt 2 lw 2 lc rgb 'black' "
                        "title 'bvh culler total'")
        lines.append("plot " + ", ".join(plot))
        lines.append(f"set title {gp_string(label + ': exact triangle tests')}")
        lines.append("set ylabel 'exact tests'")
        # A log axis has no 0: a configuration with no exact tests is drawn on the bottom edge.
        tests = [r["exact_tests"] for per in series.get(key, {}).values() for r in per
                 if r["exact_tests"] is not None]
        if b and b.get("exact_tests") is not None:
            tests.append(b["exact_tests"])
        positive = [t for t in tests if t > 0]
        floor = 10 ** math.floor(math.log10(min(positive) / 2)) if positive else 1
        has_zero = any(t == 0 for t in tests)
        lines.append(f"set yrange [{floor!r}:*]" if has_zero else "set yrange [*:*]")
        plot = []
        for i, culler in enumerate(cullers):
            path = files.get(key + (culler,))
            if path is None:
                continue
            colour = PALETTE[i % len(PALETTE)]
            plot.append(f"{gp_string(path)} using 1:($3 > 0 ? $3 : NaN) with linespoints pt 7 "
                        f"ps 0.6 lw 2 lc rgb '{colour}' title {gp_string(culler)}")
            if has_zero:
                plot.append(f"{gp_string(path)} using 1:($3 == 0 ? {floor!r} : NaN) with points "
                            f"pt 9 ps 1.4 lc rgb '{colour}' title {gp_string(culler + ': 0 tests')}")
        if b and b.get("exact_tests") is not None:
            plot.append(f"{gp_string(ref)} using 1:3 with lines dt 2 lw 2 lc rgb 'black' "
                        "title 'bvh culler'")
        lines.append("plot " + ", ".join(plot))
    lines.append("unset multiplot")
    return lines


def load_plot(doc, png, tmp):
    """Latency, throughput and (with metric samples) the daemons' RSS and CPU over time."""
    calls = os.path.join(tmp, "calls.dat")
    kinds = [k for k in LOAD_KINDS if k in doc.get("kinds", {})]
    with open(calls, "w") as f:
        for s in doc["timeline"]:
            if not s.get("count"):
                continue
            values = [s["second"] + 0.5, s["count"], s.get("error_count", 0)]
            values += [None if s.get(p) is None else s[p] * 1e-6 for p in ("p50", "p90", "p99",
                                                                          "max")]
            values += [s.get("kinds", {}).get(k, 0) for k in kinds]
            f.write(" ".join(number(v) for v in values) + "\n")
    metrics = os.path.join(tmp, "metrics.dat")
    have_metrics = False
    with open(metrics, "w") as f:
        for e in doc.get("metrics", {}).get("endpoints", []):
            last = None
            for s in e.get("samples", []):
                if s.get("rss_bytes") is None or s.get("cpu_seconds") is None:
                    continue
                if last is not None and s["t"] > last[0]:
                    cpu = 100.0 * (s["cpu_seconds"] - last[1]) / (s["t"] - last[0])
                    f.write(f"{s['t']!r} {s['rss_bytes'] / 2**20!r} {cpu!r}\n")
                    have_metrics = True
                last = (s["t"], s["cpu_seconds"])
            f.write("\n\n")
    clients = ", ".join(f"{n} {k}" for k, n in sorted(doc.get("clients", {}).items()) if n)
    servers = ", ".join(doc.get("servers", [])) or "?"
    title = f"proxima load: {clients} clients against {servers}, {doc.get('date', '')}"
    lines = [
        f"set terminal pngcairo size 1100,{900 if have_metrics else 640} font 'sans,10' "
        "noenhanced",
        f"set output {gp_string(png)}",
        f"set multiplot layout {3 if have_metrics else 2},1 title {gp_string(title)}",
        "set grid",
        "set key outside right top vertical Left reverse samplen 2",
        "set xlabel 'seconds'",
        f"set xrange [0:{float(doc['duration_seconds'])!r}]",
        "set lmargin 11",
        "set rmargin 24",
        f"set arrow from {float(doc.get('warmup_seconds', 0))!r}, graph 0 to "
        f"{float(doc.get('warmup_seconds', 0))!r}, graph 1 nohead dt 2 lc rgb 'gray'",
        "set ylabel 'latency (ms)'",
        "set logscale y",
        "set title 'latency per second, all calls (dashed line: end of warm-up)'",
        f"plot {gp_string(calls)} using 1:4:5 with filledcurves lc rgb '#a6cee3' "
        "title 'p50-p90', '' using 1:5:6 with filledcurves lc rgb '#fdbf6f' title 'p90-p99', "
        "'' using 1:4 with lines lw 2 lc rgb '#1f78b4' title 'p50', '' using 1:7 with points "
        "pt 7 ps 0.6 lc rgb '#e31a1c' title 'max'",
        "unset logscale y",
        "set ylabel 'calls/s'",
        "set title 'throughput per call kind'",
    ]
    plot = [f"{gp_string(calls)} using 1:2 with linespoints lw 2 lc rgb 'black' "
            "title 'all calls'", "'' using 1:3 with impulses lw 3 lc rgb 'red' title 'errors'"]
    plot += [f"'' using 1:{8 + i} with linespoints pt 7 ps 0.5 lw 1.5 "
             f"lc rgb '{KIND_COLOURS[LOAD_KINDS.index(k)]}' title '{k}'"
             for i, k in enumerate(kinds)]
    lines.append("plot " + ", ".join(plot))
    if have_metrics:
        lines += [
            "set ylabel 'RSS (MiB)'",
            "set y2label 'CPU (% of a core)'",
            "set y2tics",
            "set title 'daemon (Prometheus samples)'",
            f"plot {gp_string(metrics)} using 1:2 with linespoints lw 2 title 'RSS', '' using "
            "1:3 axes x1y2 with linespoints lw 2 title 'CPU'",
        ]
    lines.append("unset multiplot")
    return lines


def plotter(doc):
    """The function that draws this JSON document, or None for a shape this script does not know."""
    if isinstance(doc, dict) and doc.get("tool") == "proxima_dvd_bench" and "rows" in doc:
        return dvd_plot
    if isinstance(doc, dict) and "timeline" in doc and "duration_seconds" in doc:
        return load_plot
    return None


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default=HERE, help="folder of the JSON files (default: %(default)s)")
    parser.add_argument("--out", default=None, help="folder for the PNGs (default: --data)")
    args = parser.parse_args(argv)
    out = args.out or args.data
    gnuplot = os.environ.get("GNUPLOT", "gnuplot")
    if shutil.which(gnuplot) is None:
        print(f"plot_all.py: {gnuplot} not found (Debian: apt-get install gnuplot-nox)",
              file=sys.stderr)
        return 1
    names = sorted(n for n in os.listdir(args.data) if n.endswith(".json"))
    if not names:
        print(f"plot_all.py: no JSON files in {args.data}", file=sys.stderr)
        return 1
    os.makedirs(out, exist_ok=True)
    failed = 0
    for name in names:
        path = os.path.join(args.data, name)
        try:
            with open(path) as f:
                doc = json.load(f)
        except (OSError, ValueError) as e:
            print(f"plot_all.py: {path}: {e}", file=sys.stderr)
            failed += 1
            continue
        draw = plotter(doc)
        if draw is None:
            print(f"plot_all.py: {path}: not a JSON document this script knows how to plot",
                  file=sys.stderr)
            failed += 1
            continue
        png = os.path.join(out, name[:-len(".json")] + ".png")
        with tempfile.TemporaryDirectory(prefix="proxima-plots-") as tmp:
            script = os.path.join(tmp, "plot.gp")
            with open(script, "w") as f:
                f.write("\n".join(draw(doc, png, tmp)) + "\n")
            p = subprocess.run([gnuplot, script], capture_output=True, text=True)
        if p.returncode != 0 or not os.path.exists(png):
            print(f"plot_all.py: gnuplot could not draw {png}: {p.stderr.strip()}",
                  file=sys.stderr)
            failed += 1
            continue
        print(f"wrote {png}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
