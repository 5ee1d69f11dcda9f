#pragma once
// Whether the processor runs AVX2, for the engine's hot loops that have a second copy compiled
// for it (the CCD solver and prefilter, engine/src/ccd/elementary.cpp; the self traversal's leaf
// rows, engine/src/culling/leaf_rows.cpp; the self query's frames and edge gap,
// engine/src/distance/edge_frames.cpp and bounds.cpp; the exact distance's edge pairs,
// engine/src/distance/edge_pairs.cpp; the plane-side filter on three corners,
// engine/src/geometry/predicates.cpp). Debian's packages are baseline x86-64, so the engine
// never requires AVX2: each copy computes the same IEEE operations in the same order (those files
// are compiled with -ffp-contract=off) and the dispatch only chooses the faster one.

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define PROXIMA_X86_64_DISPATCH 1
#endif

namespace proxima::detail {

#ifdef PROXIMA_X86_64_DISPATCH
// Each caller reads it once at start-up into a constant of its own file (a check per call would
// cost its hot loop; a call from another file's static initializer before that reads false and
// takes the portable copy: the same answers).
inline bool cpu_has_avx2() {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") != 0;
}
#endif

}  // namespace proxima::detail
