#!/usr/bin/env bash
# Long fuzz runs. Builds build/fuzz if needed, then fuzzes TARGET for SECONDS with JOBS processes
# (default 1) on a working corpus in build/fuzz/corpus/TARGET (kept between runs, seeded with the
# committed corpus and crashers), and appends one line per process to build/fuzz/totals.tsv:
#
#   utc-date  target  seconds-run  executions  exec/s  cov  ft  corpus-units  exit-status
#
# so totals over many runs are sums of column 4 (`bash tests/fuzz/run.sh --totals`). Crashers land
# in build/fuzz/artifacts/; keep each one in tests/fuzz/regressions/TARGET/ once it is fixed.
#
#   bash tests/fuzz/run.sh TARGET SECONDS [JOBS]   # TARGET: ccd_queries, mesh, mesh_obj, md2, request or frames
#   FUZZ_FLAVOR=fast bash tests/fuzz/run.sh ...    # without ASan, in build/fuzz-fast (common.sh);
#                                                  # its working corpus is replayed under ASan after
#   bash tests/fuzz/run.sh --totals                # executions per target, summed over runs
#   bash tests/fuzz/run.sh --merge TARGET          # minimize the working corpus into
#                                                  # tests/fuzz/corpus/TARGET (-merge=1)
set -euo pipefail
# shellcheck source=common.sh
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
totals="$FUZZ_BUILD/totals.tsv"

if [[ "${1:-}" == "--totals" ]]; then
    [[ -f "$totals" ]] || { echo "no runs recorded in $totals" >&2; exit 1; }
    awk -F'\t' '{ e[$2] += $4; s[$2] += $3; if ($9 != 0) bad[$2]++ }
        END { for (t in e) printf "%-12s %12d executions in %7d s (%.0f exec/s)%s\n", t, e[t], s[t],
              s[t] ? e[t] / s[t] : 0, bad[t] ? ", " bad[t] " runs failed" : "" }' "$totals" | sort
    exit 0
fi

if [[ "${1:-}" == "--merge" ]]; then
    name="${2:?usage: run.sh --merge TARGET}"
    fuzz_build "$name"
    work="$FUZZ_BUILD/corpus/$name"
    merged=$(mktemp -d)
    # Only inputs that add coverage survive, smallest first; the result replaces the committed
    # corpus (the hand-made seeds are kept: they document the formats).
    "$FUZZ_BUILD/tests/fuzz/proxima_fuzz_$name" -merge=1 $(fuzz_options "$name") "$merged" \
        "$FUZZ_DIR/corpus/$name" "$work"
    find "$FUZZ_DIR/corpus/$name" -type f ! -name 'seed-*' -delete
    for f in "$merged"/*; do
        dup=0
        for s in "$FUZZ_DIR/corpus/$name"/seed-*; do
            if cmp -s "$f" "$s"; then
                dup=1
                break
            fi
        done
        # libFuzzer names units by their SHA-1.
        [[ $dup -eq 1 ]] || cp "$f" "$FUZZ_DIR/corpus/$name/"
    done
    rm -rf "$merged"
    echo "corpus/$name: $(find "$FUZZ_DIR/corpus/$name" -type f | wc -l) files," \
        "$(du -sh "$FUZZ_DIR/corpus/$name" | cut -f1)"
    exit 0
fi

name="${1:?usage: run.sh TARGET SECONDS [JOBS]}"
seconds="${2:?usage: run.sh TARGET SECONDS [JOBS]}"
jobs="${3:-1}"
fuzz_build "$name"
work="$FUZZ_BUILD/corpus/$name"
logs="$FUZZ_BUILD/logs/$name-$(date -u +%Y%m%dT%H%M%S)"
mkdir -p "$work" "$logs" "$FUZZ_BUILD/artifacts"
inputs=("$work" "$FUZZ_DIR/corpus/$name")
[[ -d "$FUZZ_DIR/regressions/$name" ]] && inputs+=("$FUZZ_DIR/regressions/$name")

rc=0
started=$(date +%s)
cd "$logs"  # -jobs writes fuzz-N.log into the current directory
if [[ "$jobs" -gt 1 ]]; then
    # shellcheck disable=SC2046
    "$FUZZ_BUILD/tests/fuzz/proxima_fuzz_$name" $(fuzz_options "$name") -max_total_time="$seconds" \
        -jobs="$jobs" -workers="$jobs" -artifact_prefix="$FUZZ_BUILD/artifacts/$name-" \
        "${inputs[@]}" >"$logs/main.log" 2>&1 || rc=$?
else
    # shellcheck disable=SC2046
    "$FUZZ_BUILD/tests/fuzz/proxima_fuzz_$name" $(fuzz_options "$name") -max_total_time="$seconds" \
        -artifact_prefix="$FUZZ_BUILD/artifacts/$name-" \
        "${inputs[@]}" >"$logs/fuzz-0.log" 2>&1 || rc=$?
fi
elapsed=$(($(date +%s) - started))
for log in "$logs"/fuzz-*.log; do
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
    rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
    cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | cut -d' ' -f2)
    ft=$(grep -o 'ft: [0-9]*' "$log" | tail -1 | cut -d' ' -f2)
    units=$(find "$work" -type f | wc -l)
    printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$(date -u +%FT%TZ)" "$name" "$elapsed" \
        "${execs:-0}" "${rate:-0}" "${cov:-0}" "${ft:-0}" "$units" "$rc" | tee -a "$totals"
done
if [[ $rc -ne 0 ]]; then
    echo "fuzzing $name failed (exit $rc): see $logs and $FUZZ_BUILD/artifacts/" >&2
fi
# The fast flavour has no ASan: replay its working corpus (every input that added coverage) with
# the ASan + UBSan build, so that a memory error on those inputs is still found.
asan_binary="$FUZZ_ROOT/build/fuzz/tests/fuzz/proxima_fuzz_$name"
if [[ "$FUZZ_FLAVOR" == fast ]]; then
    if [[ -x "$asan_binary" ]]; then
        replay=0
        # shellcheck disable=SC2046
        "$asan_binary" $(fuzz_options "$name") -runs=0 "$work" >"$logs/asan-replay.log" 2>&1 ||
            replay=$?
        echo "ASan replay of $(find "$work" -type f | wc -l) inputs of $work: exit $replay" \
            "($logs/asan-replay.log)"
        [[ $replay -eq 0 ]] || rc=$replay
    else
        echo "no ASan build ($asan_binary): the working corpus was not replayed under ASan" >&2
    fi
fi
exit $rc
