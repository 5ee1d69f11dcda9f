#!/usr/bin/env bash
# Short fuzz run for CI: builds the libFuzzer targets with clang in build/fuzz, runs each on its
# committed corpus (and kept crashers) for SECONDS_PER_TARGET seconds (default 10), one process
# each, as many at once as there are CPUs, and fails on any crash, leak, timeout (FUZZ_TIMEOUT,
# default 3 s per input) or out-of-memory.
# New inputs go to a scratch directory, never into the repository. Prints the executions done per
# target and the time taken.
#
#   bash tests/fuzz/smoke.sh [SECONDS_PER_TARGET]
#
# Long runs: tests/fuzz/run.sh; the targets and totals: docs/reliability.md ("Fuzzing").
set -euo pipefail
seconds="${1:-10}"
# shellcheck source=common.sh
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

start=$(date +%s)
fuzz_build "${FUZZ_TARGETS[@]}"
built=$(date +%s)

scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
mkdir -p "$FUZZ_BUILD/artifacts"

# One target's run; its exit status goes to $scratch/NAME.rc.
run_target() {
    local name="$1"
    mkdir -p "$scratch/$name"
    local inputs=("$scratch/$name" "$FUZZ_DIR/corpus/$name")
    if [[ -d "$FUZZ_DIR/regressions/$name" ]]; then
        inputs+=("$FUZZ_DIR/regressions/$name")
    fi
    local rc=0
    # shellcheck disable=SC2046
    "$FUZZ_BUILD/tests/fuzz/proxima_fuzz_$name" $(fuzz_options "$name") -seed=1 \
        -max_total_time="$seconds" -artifact_prefix="$FUZZ_BUILD/artifacts/$name-" \
        "${inputs[@]}" >"$FUZZ_BUILD/smoke-$name.log" 2>&1 || rc=$?
    echo "$rc" >"$scratch/$name.rc"
}

# As many targets at once as there are CPUs (each libFuzzer run is one process on one core, so
# each still gets its $seconds of a whole core), then the results in FUZZ_TARGETS order.
parallel=$(nproc)
running=0
for name in "${FUZZ_TARGETS[@]}"; do
    run_target "$name" &
    running=$((running + 1))
    if [[ $running -ge $parallel ]]; then
        wait -n || true
        running=$((running - 1))
    fi
done
wait

failed=0
summary=()
for name in "${FUZZ_TARGETS[@]}"; do
    log="$FUZZ_BUILD/smoke-$name.log"
    rc=$(cat "$scratch/$name.rc" 2>/dev/null || echo 1)
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
    rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
    if [[ $rc -ne 0 ]]; then
        failed=1
        echo "fuzz smoke: $name FAILED (exit $rc); its log, $log, ends:" >&2
        tail -40 "$log" >&2
        echo "the input is under $FUZZ_BUILD/artifacts/$name-*; reproduce with:" >&2
        echo "  $FUZZ_BUILD/tests/fuzz/proxima_fuzz_$name FILE" >&2
    fi
    summary+=("$(printf '%-12s %10s executions %8s exec/s  %s' "$name" "${execs:-?}" "${rate:-?}" \
        "$([[ $rc -eq 0 ]] && echo ok || echo FAILED)")")
done
end=$(date +%s)
printf 'fuzz smoke (%s s per target):\n' "$seconds"
printf '  %s\n' "${summary[@]}"
printf 'build %d s, runs %d s, total %d s\n' $((built - start)) $((end - built)) $((end - start))
exit $failed
