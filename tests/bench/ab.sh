#!/usr/bin/env bash
# Interleaved A/B of two or more proxima_bench binaries on the real frames' warm self distance
# (issue #14): each round runs every binary once, in the order given, with
# `--scenes SCENES --reps 7 --threads THREADS`, and the script prints per scene and binary the
# smallest and the median of the rounds' warm medians (ms). For comparing a patch against its
# base on this noisy 2-core VM: build each variant's proxima_bench and copy it aside first, e.g.
#
#   cmake --build build/release --target proxima_bench
#   cp build/release/tests/bench/proxima_bench /tmp/bench_new
#   tests/bench/ab.sh 5 rod-twist,armadillo-rollers 2 /tmp/bench_old /tmp/bench_new
#
# baseline.sh does the same for a whole commit (building it in a worktree) with more columns.
#
#   tests/bench/ab.sh ROUNDS SCENES THREADS BENCH...   [DATA defaults to /work/shared/data]
set -euo pipefail

if [ $# -lt 4 ]; then
    sed -n '2,14p' "$0" >&2
    exit 2
fi
rounds=$1
scenes=$2
threads=$3
shift 3
data=${DATA:-/work/shared/data}

for _ in $(seq "$rounds"); do
    for bench in "$@"; do
        "$bench" --scenes "$scenes" --reps 7 --threads "$threads" --data "$data" 2>&1 |
            grep -A6 "self distance (every" |
            grep -E "^(armadillo|cloth|n-body|rod)" |
            awk -v b="$bench" '{print b, $1, $3}'
    done
done | python3 -c '
import collections, statistics, sys
d = collections.defaultdict(list)
for line in sys.stdin:
    bench, scene, warm = line.split()
    d[(scene, bench)].append(float(warm))
for (scene, bench) in sorted(d):
    v = d[(scene, bench)]
    print("%s %s min %.2f med %.2f n %d" % (scene, bench, min(v), statistics.median(v), len(v)))
'
