#!/usr/bin/env bash
# Same-run comparison of the real frames' self distance (issue #14): builds proxima_bench of an old
# commit (default d8a348f, the issue's "today's main") in a git worktree under
# build/baseline-<commit>/, then runs the old and this tree's proxima_bench on the same scenes,
# interleaved (old first in odd rounds, new first in even ones), and prints per scene the medians
# over the rounds: old ms, new warm ms, new cold ms, old/new ratios and the issue's goals.
#
#   tests/bench/baseline.sh [--commit C] [--rounds N] [--reps N] [--frames N] [--scenes a,b,...]
#                           [--data DIR] [--ccd]
#
# --ccd compares full-frame CCD instead (item 2 of the issue): proxima_ccd_frames_bench of both
# trees on the five real frame pairs, --reps runs each (median), and prints per scene old and new
# total seconds, their ratio, the issue's goal and whether the 4x and the goal are met, with the
# contacts each found (d8a348f's tois sat on a coarse grid, so old and new pair sets may differ).
#
# Real frame pairs (--reps steps each) and the seed's procedural scenes bowl and breaking
# (--frames frames, their per-frame self column) are compared; cloth-ball names both a real and a
# procedural scene, only its real frames are reported.
#
# Run from the repository root after building this tree's proxima_bench
# (cmake --build build/release --target proxima_bench). The old tree is built with the same
# release preset (ccache is used when CMAKE_CXX_COMPILER_LAUNCHER says so).
set -euo pipefail

commit=d8a348f
rounds=3
reps=5
frames=4
data=/work/shared/data
scenes=
ccd=0
while [[ $# -gt 0 ]]; do
    case "$1" in
        --commit) commit="$2"; shift 2 ;;
        --rounds) rounds="$2"; shift 2 ;;
        --reps) reps="$2"; shift 2 ;;
        --scenes) scenes="$2"; shift 2 ;;
        --frames) frames="$2"; shift 2 ;;
        --data) data="$2"; shift 2 ;;
        --ccd) ccd=1; shift ;;
        -h|--help) sed -n 2,23p "$0"; exit 0 ;;
        *) echo "unknown argument: $1" >&2; exit 2 ;;
    esac
done

target=proxima_bench
default_scenes=n-body-simulation,cloth-ball,rod-twist,armadillo-rollers,cloth-funnel,bowl,breaking
if ((ccd)); then
    target=proxima_ccd_frames_bench
    default_scenes=armadillo-rollers,cloth-ball,cloth-funnel,n-body-simulation,rod-twist
fi
scenes=${scenes:-$default_scenes}
root=$(git rev-parse --show-toplevel)
cd "$root"
new_bench=build/release/tests/bench/$target
[[ -x $new_bench ]] || { echo "build $new_bench first" >&2; exit 1; }
full=$(git rev-parse --short "$commit")
base=build/baseline-$full
if [[ ! -d $base/src ]]; then
    mkdir -p "$base"
    git worktree add --detach "$base/src" "$full" >&2
fi
(cd "$base/src" && cmake --preset release >/dev/null &&
    cmake --build build/release -j2 --target "$target" >&2)
old_bench=$base/src/build/release/tests/bench/$target

out=$base/runs-$target
rm -rf "$out"
mkdir -p "$out"
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
echo "start: $(date -u +%FT%TZ), load $(cut -d' ' -f1-3 /proc/loadavg)"
for ((r = 1; r <= rounds; ++r)); do
    order=(old new)
    ((r % 2 == 0)) && order=(new old)
    for which in "${order[@]}"; do
        bench=$old_bench
        [[ $which == new ]] && bench=$new_bench
        echo "round $r: $which (load $(cut -d' ' -f1 /proc/loadavg))" >&2
        args=(--scenes "$scenes" --reps "$reps" --data "$data")
        ((ccd)) || args+=(--frames "$frames")
        "$bench" "${args[@]}" >"$out/$which-$r.txt" 2>/dev/null
    done
done
echo "end: $(date -u +%FT%TZ), load $(cut -d' ' -f1-3 /proc/loadavg)"

if ((ccd)); then
    /usr/bin/python3 - "$out" "$rounds" "$full" <<'EOF'
import pathlib, statistics, sys

out, rounds, commit = pathlib.Path(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
GOALS = {"cloth-ball": 1.0, "n-body-simulation": 0.9, "rod-twist": 0.5, "armadillo-rollers": 0.45}

def table(path):
    """scene -> (total s, contacts, triangle pairs), from the bench's table (named columns)."""
    rows, header = {}, None
    for line in path.read_text().splitlines():
        f = line.split()
        if f and f[0] == "scene":
            header = f
            continue
        if header and len(f) == len(header):
            rows[f[0]] = (float(f[header.index("total-s")]), int(f[header.index("contacts")]),
                          int(f[header.index("tri-pairs")]))
    return rows

old = [table(out / f"old-{r}.txt") for r in range(1, rounds + 1)]
new = [table(out / f"new-{r}.txt") for r in range(1, rounds + 1)]
print(f"\nfull-frame CCD, total seconds, median over {rounds} interleaved rounds "
      f"(each a median of its runs), old = {commit}")
cols = ["scene", "old s", "new s", "old/new", "ratios per round", "goal s", "4x met", "goal met",
        "old contacts", "new contacts", "old tri-pairs", "new tri-pairs"]
print("| " + " | ".join(cols) + " |")
print("|" + "---|" * len(cols))
for scene in new[0]:
    o = [t[scene][0] for t in old]
    n = [t[scene][0] for t in new]
    om, nm = statistics.median(o), statistics.median(n)
    goal = GOALS.get(scene)
    per = ", ".join(f"{a / b:.2f}" for a, b in zip(o, n))
    print(f"| {scene} | {om:.3f} | {nm:.3f} | {om / nm:.2f} | {per} | {goal or '-'} | "
          f"{'yes' if om / nm >= 4 else 'no'} | "
          f"{'-' if goal is None else ('yes' if nm <= goal else 'no')} | "
          f"{old[0][scene][1]:,} | {new[0][scene][1]:,} | {old[0][scene][2]:,} | "
          f"{new[0][scene][2]:,} |")
EOF
    exit 0
fi

/usr/bin/python3 - "$out" "$rounds" "$full" <<'EOF'
import pathlib, statistics, sys

out, rounds, commit = pathlib.Path(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
GOALS = {"cloth-ball": 100, "n-body": 25, "rod-twist": 30, "armadillo-rollers": 15,
         "cloth-funnel": 10, "bowl": 3.5, "breaking": 6}

def self_table(path):
    """scene -> (self ms, exact tests, cold ms, cold exact tests, warm != cold, floor ms)"""
    rows, on, header = {}, False, None
    for line in path.read_text().splitlines():
        if line.startswith("Real frames: self distance"):
            on = True
            continue
        if on and header is None:
            header = line.split()
            continue
        if on:
            if not line.strip() or line.startswith(" "):
                break
            f = line.split()
            f = [x.replace(",", "") for x in f]
            if "warm" in header:
                # scene triangles warm exact cold exact cold/warm pairs floor warm/floor goal met diff
                rows[f[0]] = (float(f[2]), float(f[3]), float(f[4]), float(f[5]), int(f[-1]),
                              float(f[8]))
            else:  # scene triangles self exact goal met
                rows[f[0]] = (float(f[2]), float(f[3]), None, None, 0, None)
    # Seed scenes: the procedural table's per-frame self column (every frame is warm in the new
    # engine; there is no cold column for them).
    on, header = False, None
    for line in path.read_text().splitlines():
        if line.startswith("Procedural scenes: separation + self"):
            on = True
            continue
        if on and header is None:
            header = line.split()
            continue
        if on:
            if not line.strip() or line.startswith(" "):
                break
            f = line.split()
            if f[0] in ("bowl", "breaking"):
                ms, exact = float(f[header.index("self")]), float(f[header.index("exact")])
                rows[f[0]] = (ms, exact, None, None, 0, None)
    return rows

old = [self_table(out / f"old-{r}.txt") for r in range(1, rounds + 1)]
new = [self_table(out / f"new-{r}.txt") for r in range(1, rounds + 1)]
print(f"\nself distance per frame, median over {rounds} interleaved rounds "
      f"(each a median of its steps), old = {commit}")
cols = ["scene", "old ms", "new warm ms", "new cold ms", "old/warm", "old/cold",
        "ratios per round (old/warm)", "old tests", "warm tests", "cold tests", "floor ms",
        "warm/floor", "goal ms",
        "4x met", "goal met", "warm!=cold"]
print("| " + " | ".join(cols) + " |")
print("|" + "---|" * len(cols))
for scene in old[0]:
    o = [t[scene][0] for t in old]
    w = [t[scene][0] for t in new]
    c = [t[scene][2] for t in new]
    om, wm = statistics.median(o), statistics.median(w)
    cm = statistics.median(c) if None not in c else float("nan")
    per = ", ".join(f"{a / b:.2f}" for a, b in zip(o, w))
    goal = GOALS.get(scene)
    diff = sum(t[scene][4] for t in new)
    fl = [t[scene][5] for t in new]
    fm = statistics.median(fl) if None not in fl else float("nan")
    ct = [t[scene][3] for t in new]
    ctm = statistics.median(ct) if None not in ct else float("nan")
    print(f"| {scene} | {om:.1f} | {wm:.1f} | {cm:.1f} | {om / wm:.2f} | {om / cm:.2f} | {per} | "
          f"{statistics.median(t[scene][1] for t in old):,.0f} | "
          f"{statistics.median(t[scene][1] for t in new):,.0f} | "
          f"{ctm:,.0f} | {fm:.1f} | {wm / fm:.1f} | {goal} | "
          f"{'yes' if om / wm >= 4 else 'no'} | {'yes' if goal and wm <= goal else 'no'} | "
          f"{diff} |")
EOF
