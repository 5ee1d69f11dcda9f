#pragma once
// Whether the processor runs AVX2, for the engine's hot loops that have a second copy compiled
// for it (the CCD solver and prefilter, engine/src/ccd/elementary.cpp; the self traversal's leaf
// rows, engine/src/culling/leaf_rows.cpp). Debian's packages are baseline x86-64, so the engine
// never requires AVX2: each copy computes the same IEEE operations in the same order (those files
// are compiled with -ffp-contract=off) and the dispatch only chooses the faster one.

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define PROXIMA_X86_64_DISPATCH 1
#endif

namespace proxima::detail {

#ifdef PROXIMA_X86_64_DISPATCH
// Read once, on the first call (thread-safe; one value for the whole program).
inline bool cpu_has_avx2() {
    static const bool HAS_AVX2 = [] {
        __builtin_cpu_init();
        return __builtin_cpu_supports("avx2") != 0;
    }();
    return HAS_AVX2;
}
#endif

}  // namespace proxima::detail
