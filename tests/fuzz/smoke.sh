#!/usr/bin/env bash
# Short fuzz run for CI: builds the libFuzzer targets with clang in build/fuzz, runs each on its
# committed corpus (and kept crashers) for SECONDS_PER_TARGET seconds (default 10), one process,
# and fails on any crash, leak, timeout (FUZZ_TIMEOUT, default 3 s per input) or out-of-memory.
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
failed=0
summary=()
for name in "${FUZZ_TARGETS[@]}"; do
    mkdir -p "$scratch/$name" "$FUZZ_BUILD/artifacts"
    inputs=("$scratch/$name" "$FUZZ_DIR/corpus/$name")
    if [[ -d "$FUZZ_DIR/regressions/$name" ]]; then
        inputs+=("$FUZZ_DIR/regressions/$name")
    fi
    log="$FUZZ_BUILD/smoke-$name.log"
    rc=0
    # shellcheck disable=SC2046
    "$FUZZ_BUILD/tests/fuzz/proxima_fuzz_$name" $(fuzz_options "$name") -seed=1 \
        -max_total_time="$seconds" -artifact_prefix="$FUZZ_BUILD/artifacts/$name-" \
        "${inputs[@]}" >"$log" 2>&1 || rc=$?
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
