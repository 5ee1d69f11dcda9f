#!/usr/bin/python3
"""Same-run comparison of `proxima ccd-queries` with Tight-Inclusion at equal toi precision
(issue #14 item 3). A benchmark, not a test: not run by CI.

  python3 tests/bench/ti_compare.py [--rounds 3] [--sim-per-kind 2000] [--json OUT.json]

1. Builds the peer with ../shared/peers/tight-inclusion/build.sh into build/ti-compare/peer/
   (Debian libeigen3-dev libspdlog-dev libfmt-dev libgmp-dev; nothing is vendored) and compiles
   tests/bench/ti_toi_driver.cpp against its objects: the same ticcd calls, settings and timing as
   the peer's own driver ti_queries, plus each query's toi and time. ti_queries itself runs once
   on the handcrafted files as a cross-check of the answers.
2. Queries: the public handcrafted sets (../shared/data/ccd-queries, with ground truth) and
   "simulation" sets made from the five real frame pairs of ../shared/data/frames: the contacts
   `proxima ccd --local --split-components` reports there (up to --sim-per-kind vertex-face and
   edge-edge ones per scene, evenly spaced), written in the benchmark format (exact rationals of
   the frames' doubles, no truth column) under build/ti-compare/inputs/.
3. Runs ours (`proxima ccd-queries --json --tolerance 1e-6 --toi-tolerance 1e-6 FILE`) and the
   peer (tolerance 1e-6) on every file, interleaved: per file, ours then the peer in even rounds
   and the peer then ours in odd ones; times are medians over the rounds. Both time each CCD call
   with std::chrono::steady_clock after every file is read.
4. Compares answer by answer and prints a table per group (handcrafted / simulation, vf / ee).
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from fractions import Fraction
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCENES = {
    "armadillo-rollers": ("326.ply", "327.ply"),
    "cloth-ball": ("cloth_ball92.ply", "cloth_ball93.ply"),
    "cloth-funnel": ("227.ply", "228.ply"),
    "n-body-simulation": ("balls16_18.ply", "balls16_19.ply"),
    "rod-twist": ("3036.ply", "3037.ply"),
}
PLY_TYPES = {"float": "f4", "float32": "f4", "double": "f8", "float64": "f8", "char": "i1",
             "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
             "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4",
             "uint32": "u4"}


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def build_peer(work, peer_dir, rebuild):
    driver = work / "ti_toi_driver"
    peer = work / "peer"
    if rebuild or not (peer / "ti_queries").exists():
        subprocess.run(["sh", str(peer_dir / "build.sh"), str(peer)], check=True)
    src = ROOT / "tests/bench/ti_toi_driver.cpp"
    if rebuild or not driver.exists() or driver.stat().st_mtime < src.stat().st_mtime:
        flags = ["-O3", "-DNDEBUG", "-DNOMINMAX", f"-I{peer}/src", f"-I{peer}/shim",
                 "-I/usr/include/eigen3", "-DSPDLOG_SHARED_LIB", "-DSPDLOG_COMPILED_LIB",
                 "-DSPDLOG_FMT_EXTERNAL"]
        objs = [str(peer / "obj" / f"{n}.o")
                for n in ("avx", "ccd", "interval", "interval_root_finder", "logger")]
        subprocess.run(["g++", "-std=c++20", *flags, str(src), *objs, "-o", str(driver),
                        "-lgmp", "-lspdlog", "-lfmt", "-pthread"], check=True)
    return peer / "ti_queries", driver


def read_benchmark_csv(path):
    """[(truth or None, [24 Fractions])] from the public benchmark format."""
    rows = []
    for line in Path(path).read_text().splitlines():
        f = [x.strip() for x in line.split(",")]
        if f == [""]:
            continue
        rows.append(f)
    queries = []
    for i in range(0, len(rows), 8):
        coords = []
        for r in rows[i:i + 8]:
            coords += [Fraction(int(r[2 * k]), int(r[2 * k + 1])) for k in range(3)]
        truth = int(rows[i][6]) != 0 if len(rows[i]) == 7 else None
        queries.append((truth, coords))
    return queries


def write_driver_input(queries, path):
    # float(Fraction) is correctly rounded (ties to even), as proxima's reader and ti_queries.
    with open(path, "w") as out:
        for truth, coords in queries:
            t = -1 if truth is None else int(truth)
            out.write(f"{t} " + " ".join(float(c).hex() for c in coords) + "\n")


def read_ply_vertices(path):
    import numpy as np
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" in header:
        order = "<"
    elif "format binary_big_endian 1.0" in header:
        order = ">"
    else:
        raise SystemExit(f"{path}: only binary PLY is read here")
    count, props, in_vertex = 0, [], False
    for h in header:  # vertices come first in these files
        if h.startswith("element face") and count == 0:
            raise SystemExit(f"{path}: faces before vertices")
        w = h.split()
        if w[:2] == ["element", "vertex"]:
            count, in_vertex = int(w[2]), True
        elif w[:1] == ["element"]:
            in_vertex = False
        elif w[:1] == ["property"] and in_vertex:
            props.append((w[2], order + PLY_TYPES[w[1]]))
    v = np.frombuffer(data, dtype=np.dtype(props), count=count, offset=end)
    return np.stack([v["x"].astype("f8"), v["y"].astype("f8"), v["z"].astype("f8")], axis=1)


def make_sim_queries(proxima, frames, inputs, per_kind):
    """The contacts `proxima ccd` finds on each real frame pair, as benchmark files."""
    made = []
    for scene, (f0, f1) in SCENES.items():
        p0, p1 = frames / scene / f0, frames / scene / f1
        if not p0.exists():
            log(f"skip {scene}: {p0} absent")
            continue
        out_json = inputs / f"{scene}.ccd.json"
        if not out_json.exists():
            log(f"proxima ccd on {scene} ...")
            r = subprocess.run([str(proxima), "ccd", "--local", "--split-components", "--json",
                                str(p0), str(p1)], check=True, capture_output=True, text=True)
            out_json.write_text(r.stdout)
        pairs = json.loads(out_json.read_text())["pairs"]
        x0, x1 = read_ply_vertices(p0), read_ply_vertices(p1)
        for kind, folder in (("vf", "vertex-face"), ("ee", "edge-edge")):
            mine = [p for p in pairs if p["kind"] == kind]
            if not mine:
                continue
            step = max(1, len(mine) / per_kind)
            chosen = [mine[int(i * step)] for i in range(min(per_kind, len(mine)))]
            d = inputs / "sim" / scene / folder
            d.mkdir(parents=True, exist_ok=True)
            csv = d / "data.csv"
            queries = []
            with open(csv, "w") as out:
                for p in chosen:
                    ids = p["vertices"] + p["other_vertices"]  # vf: v, f0, f1, f2; ee: a0 a1 b0 b1
                    pts = [x0[i] for i in ids] + [x1[i] for i in ids]
                    coords = []
                    for pt in pts:
                        row = []
                        for c in pt:
                            n, q = float(c).as_integer_ratio()
                            row += [str(n), str(q)]
                            coords.append(Fraction(n, q))
                        out.write(",".join(row) + "\n")
                    queries.append((None, coords))
            write_driver_input(queries, csv.with_suffix(".ti.txt"))
            made.append(("simulation", kind, f"{scene}/{folder}", csv, len(mine)))
    return made


def hand_files(data, inputs):
    made = []
    for csv in sorted((data / "ccd-queries").glob("*/*/*.csv")):
        folder = csv.parent.name
        kind = {"vertex-face": "vf", "edge-edge": "ee"}[folder]
        rel = csv.relative_to(data / "ccd-queries")
        txt = inputs / "hand" / str(rel).replace("/", "__")
        txt = txt.with_suffix(".ti.txt")
        if not txt.exists():
            txt.parent.mkdir(parents=True, exist_ok=True)
            write_driver_input(read_benchmark_csv(csv), txt)
        made.append(("handcrafted", kind, str(rel), csv, None))
    return made


def run_ours(proxima, kind, csv, toi_tol):
    r = subprocess.run([str(proxima), "ccd-queries", "--json", "--kind", kind, "--tolerance",
                        "1e-6", "--toi-tolerance", repr(toi_tol), str(csv)],
                       check=True, capture_output=True, text=True)
    return json.loads(r.stdout)


def exact_earliest(coords, kind, limit, eps=Fraction(1, 2**20), before=None):
    """An exact lower bound on the earliest contact of the query (its coordinates rounded to
    doubles, as both tools see them): boxes of (t, u, v) in order of t are excluded when the 8
    corner values of F (trilinear, so they bound it over the box) lie on one side of 0 on an axis,
    or those of F . w for w the primitives' normal gu x gv at the box's middle time or an in-plane
    normal of a side (any w: F . w != 0 implies F != 0), all in exact rationals. Time is split
    first unless u or v is 8x wider. With `before`, only [0, before] is searched (the root box
    ends there) and the search returns ("from", before) once every box is excluded: no contact
    before it. Returns ("none", None) when every box is excluded (no contact at all),
    ("from", t0) when the earliest box that survives to width eps starts at t0 (no contact before
    t0), or ("unknown", None) past `limit` boxes."""
    import heapq
    p = [[Fraction(float(c)) for c in coords[3 * r:3 * r + 3]] for r in range(8)]

    def f(t, u, v):
        at = [[p[j][i] + (p[j + 4][i] - p[j][i]) * t for i in range(3)] for j in range(4)]
        if kind == "ee":
            return [at[0][i] + (at[1][i] - at[0][i]) * u - at[2][i] - (at[3][i] - at[2][i]) * v
                    for i in range(3)]
        return [at[0][i] - at[1][i] - (at[2][i] - at[1][i]) * u - (at[3][i] - at[1][i]) * v
                for i in range(3)]

    def excluded(b):
        t0, t1, u0, u1, v0, v1 = b
        if kind == "vf" and u0 + v0 > 1:
            return True
        vals = [f(t, u, v) for t in (t0, t1) for u in (u0, u1) for v in (v0, v1)]
        if any(min(x[a] for x in vals) > 0 or max(x[a] for x in vals) < 0 for a in range(3)):
            return True
        # F = g0 - u gu - v gv: gu, gv at the middle time, from F's own differences.
        tm = (t0 + t1) / 2
        f00, f10, f01 = f(tm, zero, zero), f(tm, one, zero), f(tm, zero, one)
        gu = [f00[i] - f10[i] for i in range(3)]
        gv = [f00[i] - f01[i] for i in range(3)]
        n = cross(gu, gv)
        dirs = [n, cross(n, gu), cross(n, gv)]
        if kind == "vf":
            dirs.append(cross(n, [gv[i] - gu[i] for i in range(3)]))
        for w in dirs:
            if any(w):
                d = [x[0] * w[0] + x[1] * w[1] + x[2] * w[2] for x in vals]
                if min(d) > 0 or max(d) < 0:
                    return True
        return False

    def cross(x, y):
        return [x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]]

    zero, one = Fraction(0), Fraction(1)
    end = one if before is None else min(one, before)
    heap, n = [(zero, 0, (zero, end, zero, one, zero, one))], 0
    for _ in range(limit):
        if not heap:
            return ("none", None) if before is None else ("from", before)
        _, _, b = heapq.heappop(heap)
        if excluded(b):
            continue
        w = [b[1] - b[0], b[3] - b[2], b[5] - b[4]]
        if max(w) <= eps:
            return "from", b[0]
        d = 0 if 8 * w[0] >= max(w[1], w[2]) else (1 if w[1] >= w[2] else 2)
        m = (b[2 * d] + b[2 * d + 1]) / 2
        for lo, hi in ((b[2 * d], m), (m, b[2 * d + 1])):
            x = list(b)
            x[2 * d], x[2 * d + 1] = lo, hi
            n += 1
            heapq.heappush(heap, (x[0], n, tuple(x)))
    return "unknown", None


def percentile(xs, p):
    if not xs:
        return float("nan")
    xs = sorted(xs)
    k = min(len(xs) - 1, max(0, int(round(p / 100 * (len(xs) - 1)))))
    return xs[k]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--sim-per-kind", type=int, default=2000)
    ap.add_argument("--toi-tolerance", type=float, default=1e-6)
    ap.add_argument("--proxima", default=str(ROOT / "build/release/clients/proxima"))
    ap.add_argument("--data", default=str(ROOT.parent / "shared/data"))
    ap.add_argument("--peer", default=str(ROOT.parent / "shared/peers/tight-inclusion"))
    ap.add_argument("--work", default=str(ROOT / "build/ti-compare"))
    ap.add_argument("--no-sim", action="store_true")
    ap.add_argument("--exact-limit", type=int, default=3000,
                    help="boxes per query for the exact check (Python rationals: ~0.5 ms a box)")
    ap.add_argument("--rebuild", action="store_true")
    ap.add_argument("--json", help="write every per-file, per-round figure here")
    a = ap.parse_args()

    work, data = Path(a.work), Path(a.data)
    inputs = work / "inputs"
    inputs.mkdir(parents=True, exist_ok=True)
    ti_queries, driver = build_peer(work, Path(a.peer), a.rebuild)
    proxima = Path(a.proxima)

    files = hand_files(data, inputs)
    if not a.no_sim:
        files += make_sim_queries(proxima, data / "frames", inputs, a.sim_per_kind)

    def driver_input(group, csv):
        if group == "handcrafted":
            rel = csv.relative_to(data / "ccd-queries")
            return (inputs / "hand" / str(rel).replace("/", "__")).with_suffix(".ti.txt")
        return csv.with_suffix(".ti.txt")

    # Cross-check: the peer's own driver gives the same answers as ours on the handcrafted files.
    for kind in ("vf", "ee"):
        mine = [f for f in files if f[0] == "handcrafted" and f[1] == kind]
        r = subprocess.run([str(ti_queries), "--kind", kind, "--results",
                            *[str(f[3]) for f in mine]], check=True, capture_output=True,
                           text=True)
        ref = json.loads(r.stdout)["results"]
        got = []
        for f in mine:
            lines = subprocess.run([str(driver), "--kind", kind, str(driver_input(f[0], f[3]))],
                                   check=True, capture_output=True, text=True).stdout.split("\n")
            got += [ln.split()[0] == "1" for ln in lines if ln]
        if got != ref:
            raise SystemExit(f"ti_toi_driver and ti_queries disagree on the {kind} answers")
    log("cross-check: ti_toi_driver answers = ti_queries answers on the handcrafted files")

    per_file = {f[2]: {"ours_s": [], "ours_worst": [], "peer_s": [], "peer_worst": [],
                       "peer_q": []} for f in files}
    answers = {}
    loads = []
    t_start = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    for rnd in range(a.rounds):
        loads.append(os.getloadavg()[0])
        log(f"round {rnd + 1}/{a.rounds} (1-min load {loads[-1]:.2f})")
        for idx, (group, kind, name, csv, _) in enumerate(files):
            def ours():
                j = run_ours(proxima, kind, csv, a.toi_tolerance)
                per_file[name]["ours_s"].append(j["seconds"])
                per_file[name]["ours_worst"].append(j["worst_seconds"])
                prev = answers.setdefault(name, {}).get("ours")
                cur = (j["results"], j["tois"])
                if prev is not None and prev != cur:
                    raise SystemExit(f"{name}: our answers changed between rounds")
                answers[name]["ours"] = cur
                answers[name]["capped"] = j["capped_tests"]

            def peer():
                out = subprocess.run([str(driver), "--kind", kind,
                                      str(driver_input(group, csv))], check=True,
                                     capture_output=True, text=True).stdout
                rows = [ln.split() for ln in out.splitlines() if ln]
                secs = [float(r[2]) for r in rows]
                per_file[name]["peer_s"].append(sum(secs))
                w = max(range(len(secs)), key=lambda i: secs[i]) if secs else 0
                per_file[name]["peer_worst"].append(secs[w] if secs else 0.0)
                per_file[name]["peer_q"].append(w)
                cur = ([r[0] == "1" for r in rows], [float.fromhex(r[1]) for r in rows],
                       sum(float(r[3]) > 1e-6 for r in rows))
                prev = answers.setdefault(name, {}).get("peer")
                if prev is not None and prev[:2] != cur[:2]:
                    raise SystemExit(f"{name}: the peer's answers changed between rounds")
                answers[name]["peer"] = cur

            for step in ((ours, peer) if (rnd + idx) % 2 == 0 else (peer, ours)):
                step()
    loads.append(os.getloadavg()[0])
    t_end = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())

    # Where ours is later than the peer's toi at tolerance 1e-6, run the peer again on those
    # queries with finer tolerances: its toi is never later than the true earliest contact and
    # rises towards it as the tolerance shrinks, so ours later than the peer's converged toi
    # would be ours later than the truth (a bug).
    conv_tols = (1e-9, 1e-12)
    converged = {}  # name -> {index: (toi at each tolerance, max_itr reached at the finest)}
    for group, kind, name, csv, _ in files:
        (oh, ot), (ph, pt, _) = answers[name]["ours"], answers[name]["peer"]
        later = [i for i in range(len(oh)) if oh[i] and ph[i] and ot[i] > pt[i]]
        if not later:
            continue
        lines = driver_input(group, csv).read_text().splitlines()
        sub = work / "later.ti.txt"
        sub.write_text("".join(lines[i] + "\n" for i in later))
        tois, itr = {i: [] for i in later}, {}
        for tol in conv_tols:
            out = subprocess.run([str(driver), "--kind", kind, str(sub), repr(tol)], check=True,
                                 capture_output=True, text=True).stdout.split("\n")
            for i, ln in zip(later, [x for x in out if x]):
                r = ln.split()
                tois[i].append(float.fromhex(r[1]) if r[0] == "1" else None)
                itr[i] = float(r[3]) > tol
        converged[name] = {i: (tois[i], itr[i]) for i in later}

    truth = {}
    for group, kind, name, csv, _ in files:
        if group == "handcrafted":
            truth[name] = [t for t, _ in read_benchmark_csv(csv)]

    groups = [("handcrafted", "vf"), ("handcrafted", "ee"), ("simulation", "vf"),
              ("simulation", "ee")]
    summary, parsed = [], {}
    for g in groups + [("all", None)]:
        mine = [f for f in files if (g[0] == "all" or (f[0] == g[0] and f[1] == g[1]))]
        if not mine:
            continue
        s = {"group": g[0], "kind": g[1] or "vf+ee", "queries": 0, "colliding": 0,
             "ours_fn": 0, "ours_fp": 0, "peer_fn": 0, "peer_fp": 0, "hits_ours": 0,
             "hits_peer": 0, "ours_only": 0, "peer_only": 0, "capped": 0, "peer_max_itr": 0,
             "both_hit": 0, "conv_checked": 0, "conv_max_itr": 0, "conv_miss": 0,
             "conv_rise_max": 0.0, "conv_later_max": float("-inf"), "conv_later_count": 0,
             "conv_later_examples": [], "exact_ok": 0, "exact_unsure": 0,
             "has_truth": all(f[0] == "handcrafted" for f in mine)}
        diffs = []  # toi_ours - toi_peer where both report contact
        worst_examples = []
        for group, kind, name, csv, _ in mine:
            (ours_hit, ours_toi), (peer_hit, peer_toi, max_itr) = \
                answers[name]["ours"], answers[name]["peer"]
            s["queries"] += len(ours_hit)
            s["capped"] += answers[name]["capped"]
            s["peer_max_itr"] += max_itr
            tr = truth.get(name)
            for i, (oh, ph) in enumerate(zip(ours_hit, peer_hit)):
                s["hits_ours"] += oh
                s["hits_peer"] += ph
                s["ours_only"] += oh and not ph
                s["peer_only"] += ph and not oh
                if tr is not None and tr[i] is not None:
                    s["colliding"] += tr[i]
                    s["ours_fn"] += tr[i] and not oh
                    s["ours_fp"] += oh and not tr[i]
                    s["peer_fn"] += tr[i] and not ph
                    s["peer_fp"] += ph and not tr[i]
                if oh and ph:
                    d = ours_toi[i] - peer_toi[i]
                    diffs.append(d)
                    worst_examples.append((d, name, i, ours_toi[i], peer_toi[i]))
            for i, (ts, reached) in converged.get(name, {}).items():
                fine = ts[-1]
                s["conv_checked"] += 1
                s["conv_max_itr"] += reached
                if fine is None:
                    s["conv_miss"] += 1
                    continue
                s["conv_rise_max"] = max(s["conv_rise_max"], fine - peer_toi[i])
                s["conv_later_max"] = max(s["conv_later_max"], ours_toi[i] - fine)
                s["conv_later_count"] += ours_toi[i] > fine
                if ours_toi[i] > fine:
                    if name not in parsed:
                        parsed[name] = read_benchmark_csv(csv)
                    coords = parsed[name][i][1]
                    verdict, t0 = exact_earliest(coords, kind, a.exact_limit,
                                                 eps=Fraction(1, 2**40),
                                                 before=Fraction(ours_toi[i]))
                    ok = verdict == "none" or (verdict == "from" and t0 >= ours_toi[i])
                    s["exact_ok" if ok else "exact_unsure"] += 1
                    s["conv_later_examples"].append(
                        {"file": name, "index": i, "ours": ours_toi[i], "peer_1e-6": peer_toi[i],
                         "peer_finer": ts, "truth": truth[name][i] if name in truth else None,
                         "exact": verdict, "no_contact_before": None if t0 is None else float(t0)})
        s["both_hit"] = len(diffs)
        absd = [abs(d) for d in diffs]
        s["toi_absdiff_max"] = max(absd) if absd else None
        s["toi_absdiff_p99"] = percentile(absd, 99) if absd else None
        s["toi_absdiff_median"] = percentile(absd, 50) if absd else None
        s["ours_later_max"] = max(diffs) if diffs else None
        s["ours_later_count"] = sum(d > 0 for d in diffs)
        s["ours_later_1e6_count"] = sum(d > 1e-6 for d in diffs)
        s["ours_earlier_1e6_count"] = sum(d < -1e-6 for d in diffs)
        worst_examples.sort(reverse=True)
        s["latest_examples"] = [
            {"file": n, "index": i, "ours": o, "peer": p} for d, n, i, o, p in
            worst_examples[:5] if d > 0]
        # times: medians over the rounds of the group sums; worst: median over rounds of the
        # group's worst query, and the largest seen in any round.
        ours_tot = [sum(per_file[f[2]]["ours_s"][r] for f in mine) for r in range(a.rounds)]
        peer_tot = [sum(per_file[f[2]]["peer_s"][r] for f in mine) for r in range(a.rounds)]
        ours_w = [max(per_file[f[2]]["ours_worst"][r] for f in mine) for r in range(a.rounds)]
        peer_w = [max(per_file[f[2]]["peer_worst"][r] for f in mine) for r in range(a.rounds)]
        s["ours_s"] = statistics.median(ours_tot)
        s["peer_s"] = statistics.median(peer_tot)
        s["ours_s_rounds"], s["peer_s_rounds"] = ours_tot, peer_tot
        s["ratio"] = s["peer_s"] / s["ours_s"] if s["ours_s"] > 0 else None
        s["ours_worst_s"] = statistics.median(ours_w)
        s["ours_worst_s_max"] = max(ours_w)
        s["peer_worst_s"] = statistics.median(peer_w)
        s["peer_worst_s_max"] = max(peer_w)
        wf = max(mine, key=lambda f: statistics.median(per_file[f[2]]["ours_worst"]))
        s["ours_worst_file"] = wf[2]
        pf = max(mine, key=lambda f: statistics.median(per_file[f[2]]["peer_worst"]))
        s["peer_worst_query"] = {"file": pf[2], "index": per_file[pf[2]]["peer_q"][-1]}
        summary.append(s)

    print(f"Same-run CCD comparison, {t_start} .. {t_end}, {a.rounds} rounds, interleaved per "
          f"file; 1-minute load at each round's start and the end: "
          + ", ".join(f"{x:.2f}" for x in loads))
    print("ours: proxima ccd-queries --tolerance 1e-6 --toi-tolerance "
          f"{a.toi_tolerance:g}; peer: Tight-Inclusion {(Path(a.peer) / 'upstream/COMMIT').read_text().strip()[:12]} "
          "tolerance 1e-6, BFS, max_itr 1e6, double")
    hdr = ("group", "kind", "queries", "colliding", "FN ours/peer", "FP ours/peer",
           "hits ours/peer (only ours/only peer)", "capped / peer max_itr", "ours s", "peer s",
           "peer/ours", "worst ms ours (max)", "worst ms peer (max)", "both hit",
           "|dtoi| max", "|dtoi| p99", "ours later: max, count > 0, > 1e-6",
           "ours earlier > 1e-6")
    print("| " + " | ".join(hdr) + " |")
    print("|" + "---|" * len(hdr))

    def num(x, fmt):
        return "–" if x is None else format(x, fmt)

    for s in summary:
        t = s["has_truth"]
        row = (s["group"], s["kind"], f"{s['queries']:,}",
               f"{s['colliding']:,}" if t else "–",
               f"{s['ours_fn']} / {s['peer_fn']}" if t else "–",
               f"{s['ours_fp']} / {s['peer_fp']}" if t else "–",
               f"{s['hits_ours']:,} / {s['hits_peer']:,} ({s['ours_only']} / {s['peer_only']})",
               f"{s['capped']} / {s['peer_max_itr']}",
               f"{s['ours_s']:.3f}", f"{s['peer_s']:.3f}", num(s["ratio"], ".0f") + "×",
               f"{s['ours_worst_s'] * 1e3:.2f} ({s['ours_worst_s_max'] * 1e3:.2f})",
               f"{s['peer_worst_s'] * 1e3:.2f} ({s['peer_worst_s_max'] * 1e3:.2f})",
               f"{s['both_hit']:,}", num(s["toi_absdiff_max"], ".2e"),
               num(s["toi_absdiff_p99"], ".2e"),
               f"{num(s['ours_later_max'], '.2e')}, {s['ours_later_count']}, "
               f"{s['ours_later_1e6_count']}", str(s["ours_earlier_1e6_count"]))
        print("| " + " | ".join(row) + " |")
    for s in summary:
        print(f"{s['group']} {s['kind']}: our worst file {s['ours_worst_file']}; the peer's "
              f"worst query {s['peer_worst_query']['file']} #{s['peer_worst_query']['index']}; "
              f"ours s per round {[round(x, 4) for x in s['ours_s_rounds']]}, peer "
              f"{[round(x, 3) for x in s['peer_s_rounds']]}")
        for e in s["latest_examples"]:
            print(f"  ours later: {e['file']} #{e['index']}: ours {e['ours']!r} peer {e['peer']!r}")
        print(f"  queries where ours > the peer's toi, rerun with the peer at tolerance "
              f"{', '.join(f'{t:g}' for t in conv_tols)}: {s['conv_checked']} (max_itr reached at "
              f"the finest: {s['conv_max_itr']}, no hit: {s['conv_miss']}); the peer's toi rose by "
              f"up to {s['conv_rise_max']:.3e}; ours later than the peer at "
              f"{conv_tols[-1]:g}: {s['conv_later_count']} (max "
              f"{s['conv_later_max'] if s['conv_checked'] else float('nan'):.3e})")
        print(f"  of those, exact rational check (tests/bench/ti_compare.py exact_earliest): "
              f"{s['exact_ok']} ours proven no later than the earliest contact (no contact "
              f"in [0, ours)), {s['exact_unsure']} not proven")
        for e in [x for x in s["conv_later_examples"]
                  if not (x["exact"] == "none" or (x["exact"] == "from" and
                                                   x["no_contact_before"] >= x["ours"]))][:10]:
            print(f"  NOT PROVEN: {e}")
        for e in s["conv_later_examples"][:5]:
            print(f"  ours later than converged: {e}")
    if a.json:
        Path(a.json).write_text(json.dumps({"summary": summary, "per_file": per_file,
                                            "loads": loads, "start": t_start, "end": t_end},
                                           indent=1))


if __name__ == "__main__":
    main()
