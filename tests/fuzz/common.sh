# Shared by smoke.sh and run.sh: configure and build the libFuzzer targets in build/fuzz with
# clang. Only the fuzz targets and what they link are built (the engine, the protos and the few
# daemon sources the request target needs), everything with ASan + UBSan and libFuzzer's coverage
# instrumentation. -O2 without NDEBUG: the engine's assertions stay on, they are checks too.

FUZZ_TARGETS=(ccd_queries mesh mesh_obj request frames)
FUZZ_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
FUZZ_BUILD="${FUZZ_BUILD:-$FUZZ_ROOT/build/fuzz}"
FUZZ_DIR="$FUZZ_ROOT/tests/fuzz"
# Leaks inside Debian's (uninstrumented) assimp are suppressed; see lsan.supp.
export LSAN_OPTIONS="suppressions=$FUZZ_DIR/lsan.supp${LSAN_OPTIONS:+:$LSAN_OPTIONS}"
# A 16 MiB quarantine instead of 256: each execution frees what it allocated, and recycling that
# memory instead of faulting in fresh pages makes the assimp targets 2.6 times faster. A
# use-after-free within the last 16 MiB freed (every execution here frees far less) is still
# caught.
export ASAN_OPTIONS="quarantine_size_mb=16${ASAN_OPTIONS:+:$ASAN_OPTIONS}"

# FUZZ_NO_BUILD=1 skips the build when the binaries exist: several run.sh on one build directory
# (one per target) must not run ninja at the same time.
fuzz_build() {
    if [[ -n "${FUZZ_NO_BUILD:-}" ]]; then
        local name
        for name in "$@"; do
            [[ -x "$FUZZ_BUILD/tests/fuzz/proxima_fuzz_$name" ]] || {
                echo "FUZZ_NO_BUILD: $FUZZ_BUILD/tests/fuzz/proxima_fuzz_$name is not built" >&2
                return 1
            }
        done
        return 0
    fi
    local targets=()
    local name
    for name in "$@"; do
        targets+=("proxima_fuzz_$name")
    done
    local launcher=()
    if command -v ccache >/dev/null; then
        launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)  # CI's reruns rebuild from the cache
    fi
    if [[ ! -f "$FUZZ_BUILD/build.ninja" ]]; then
        cmake -S "$FUZZ_ROOT" -B "$FUZZ_BUILD" -G Ninja "${launcher[@]}" \
            -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=Release \
            -DCMAKE_CXX_FLAGS_RELEASE="-O2 -gline-tables-only" \
            -DCMAKE_CXX_FLAGS="-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer" \
            -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=address,undefined" \
            -DPROXIMA_BUILD_FUZZERS=ON -DPROXIMA_BUILD_TESTS=OFF -DPROXIMA_BUILD_BENCHMARKS=OFF \
            >"$FUZZ_BUILD.configure.log" 2>&1 || {
            cat "$FUZZ_BUILD.configure.log" >&2
            return 1
        }
    fi
    cmake --build "$FUZZ_BUILD" -j "${FUZZ_BUILD_JOBS:-2}" --target "${targets[@]}"
}

# libFuzzer's options shared by every run: inputs up to 4 KiB (every seed fits, and small inputs
# keep executions fast), 2 GiB of RSS at most. An input slower than 1 s is reported in the log
# ("Slowest unit") and is a finding once it is slow when run alone; the hard limit that stops the
# run is FUZZ_TIMEOUT seconds (default 3): the timer counts wall-clock time, and on a loaded
# machine a reniced process can wait seconds for a core (the long runs behind
# docs/reliability.md used 30).
fuzz_options() {
    local name="$1"
    local options=(-max_len=4096 "-timeout=${FUZZ_TIMEOUT:-3}" -report_slow_units=1
        -rss_limit_mb=2048 -print_final_stats=1)
    if [[ "$name" == mesh* ]]; then
        # assimp leaks on most malformed files (lsan.supp), and each leak makes libFuzzer run a
        # full leak check: ~100 times slower. Leaks of these targets are checked by the replay
        # (LeakSanitizer at exit, in the ASan build) instead.
        options+=(-detect_leaks=0)
    fi
    if [[ "$name" == frames && "${FUZZ_TIMEOUT:-3}" -lt 20 ]]; then
        # CCD checks its deadline every 64 elementary tests, and a degenerate (coplanar, crossing)
        # test uses its whole work bound: under ASan on a loaded machine a frame can overrun its
        # 100 ms deadline by seconds (docs/reliability.md, "Open findings"). Slow units are still
        # reported from 1 s.
        options+=(-timeout=20)
    fi
    if [[ -f "$FUZZ_DIR/dict/$name.dict" ]]; then
        options+=("-dict=$FUZZ_DIR/dict/$name.dict")
    fi
    echo "${options[@]}"
}
