#!/usr/bin/env bash
# Plots the discrete-Voronoi resolution sweep (seed 000 Fig. 14): for each scene and query of a
# proxima_dvd_bench CSV, the DVD (kernel) time and the total query time, and the exact tests,
# against the grid cell size, per backend, with the BVH culler's total time and exact tests as
# reference lines. Needs gnuplot (Debian gnuplot-nox).
#
#   ./build/release/tests/bench/proxima_dvd_bench --cells 0.25,0.5,1,2,4 --csv /tmp/dvd.csv
#   bash docs/plots/plot_dvd.sh /tmp/dvd.csv docs/plots/dvd_resolution.png
set -euo pipefail
csv="$1"
out="$2"
command -v gnuplot >/dev/null || { echo "plot_dvd.sh: gnuplot not found (apt-get install gnuplot-nox)" >&2; exit 1; }
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

# One data file per (scene, query, culler): cell, dvd_ms, exact_tests, total_ms, sorted by cell.
python3 - "$csv" "$tmp" <<'PY'
import csv, sys, collections
rows = list(csv.DictReader(open(sys.argv[1])))
series = collections.defaultdict(list)
bvh = {}
for r in rows:
    key = (r["scene"], r["query"])
    if r["culler"] == "bvh":
        bvh[key] = (r["exact_tests"], r["total_ms"])
        continue
    series[key + (r["culler"],)].append(
        (float(r["cell"]), float(r["dvd_ms"]), float(r["exact_tests"]), float(r["total_ms"])))
panels = sorted({k[:2] for k in series})
with open(sys.argv[2] + "/panels", "w") as p:
    for scene, query in panels:
        tests, ms = bvh.get((scene, query), ("NaN", "NaN"))
        p.write(f"{scene} {query} {tests} {ms}\n")
for (scene, query, culler), pts in series.items():
    with open(f"{sys.argv[2]}/{scene}.{query}.{culler}.dat", "w") as f:
        for c, d, e, t in sorted(set(pts)):
            f.write(f"{c} {d} {e} {t}\n")
PY

n=$(wc -l < "$tmp/panels")
{
  echo "set terminal pngcairo size 1400,$((360 * n)) font ',10'"
  echo "set output '$out'"
  echo "set multiplot layout $n,2"
  echo "set logscale x; set grid; set key top right"
  while read -r scene query bvh bvh_ms; do
    echo "set title '$scene, $query: time per frame vs cell size'; set xlabel 'cell (scene units)'; set ylabel 'ms'; set logscale y"
    plot="plot"
    for f in "$tmp/$scene.$query".*.dat; do
      c="${f##*.$query.}"; c="${c%.dat}"
      plot="$plot '$f' using 1:2 with linespoints title '$c DVD kernel', '$f' using 1:4 with linespoints title '$c total',"
    done
    echo "$plot $bvh_ms with lines dashtype 2 title 'bvh culler total'"
    echo "set title '$scene, $query: exact tests vs cell size'; set ylabel 'exact tests'"
    plot="plot"
    for f in "$tmp/$scene.$query".*.dat; do
      c="${f##*.$query.}"; c="${c%.dat}"
      plot="$plot '$f' using 1:3 with linespoints title '$c',"
    done
    echo "$plot $bvh with lines dashtype 2 title 'bvh culler'"
  done < "$tmp/panels"
  echo "unset multiplot"
} > "$tmp/plot.gp"
gnuplot "$tmp/plot.gp"
echo "wrote $out"
