# Shared by smoke.sh and run.sh: configure and build the libFuzzer targets with clang. Only the
# fuzz targets and what they link are built (the engine, the protos and the few daemon sources the
# request target needs). -O2 without NDEBUG: the engine's assertions stay on, they are checks too.
#
# Two flavours (FUZZ_FLAVOR):
# - asan (default), in build/fuzz: ASan + UBSan and libFuzzer's coverage instrumentation
#   everywhere. CI's smoke run and every target's long runs use it.
# - fast, in build/fuzz-fast: edge coverage only (no ASan/UBSan, no comparison tracing), and none
#   in the exact CCD solver (engine/src/ccd/, listed in coverage-ignore.txt; fuzz_ccd_queries
#   fuzzes it under ASan). For fuzz_frames, whose executions are real queries. Crashes, aborts
#   (assertions, the targets' own checks), hangs and out-of-memory are still found; memory errors
#   that do not crash are not, so the working corpus is replayed under ASan afterwards (run.sh
#   does; docs/reliability.md has the measured rates).

FUZZ_TARGETS=(ccd_queries mesh mesh_obj md2 request frames)
FUZZ_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
FUZZ_FLAVOR="${FUZZ_FLAVOR:-asan}"
case "$FUZZ_FLAVOR" in
asan) FUZZ_BUILD="${FUZZ_BUILD:-$FUZZ_ROOT/build/fuzz}" ;;
fast) FUZZ_BUILD="${FUZZ_BUILD:-$FUZZ_ROOT/build/fuzz-fast}" ;;
*)
    echo "FUZZ_FLAVOR must be asan or fast, not '$FUZZ_FLAVOR'" >&2
    exit 2
    ;;
esac
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
    local cxx_flags="-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer"
    local link_flags="-fsanitize=address,undefined"
    if [[ "$FUZZ_FLAVOR" == fast ]]; then
        cxx_flags="-fsanitize=fuzzer-no-link -fno-sanitize-coverage=trace-cmp -fsanitize-coverage-ignorelist=$FUZZ_DIR/coverage-ignore.txt -fno-omit-frame-pointer"
        link_flags=""
    fi
    if [[ ! -f "$FUZZ_BUILD/build.ninja" ]]; then
        cmake -S "$FUZZ_ROOT" -B "$FUZZ_BUILD" -G Ninja "${launcher[@]}" \
            -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=Release \
            -DCMAKE_CXX_FLAGS_RELEASE="-O2 -gline-tables-only" \
            -DCMAKE_CXX_FLAGS="$cxx_flags" \
            -DCMAKE_EXE_LINKER_FLAGS="$link_flags" \
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
    if [[ "$name" == mesh ]]; then
        # assimp (STL) leaks on malformed files (lsan.supp), and each leak makes libFuzzer run a
        # full leak check: ~100 times slower. Leaks of this target are checked by the replay
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
