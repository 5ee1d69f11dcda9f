#pragma once
// Elementary continuous collision tests (seed 000 §3.2, §5.3): a vertex against a triangle and an
// edge against an edge, every vertex moving linearly from its position at t = 0 to its position at
// t = 1. The tests are conservative: they never miss a contact, and a reported time of impact is
// never later than the true earliest one (the argument is in docs/algorithms.md).

#include <array>
#include <cstdint>
#include <optional>
#include <string_view>

#include "proxima/geometry/vec3.hpp"

namespace proxima::ccd {

enum class CcdKind { vertex_face, edge_edge };

// "vf" or "ee".
const char* ccd_kind_name(CcdKind kind);

struct ElementaryOptions {
    // Report contact when the primitives come within this distance (>= 0); 0 is touching.
    double min_distance = 0.0;
    // Precision of the time of impact, and the size below which a region of (t, u, v) that still
    // may hold a root is reported as contact rather than refined further.
    double tolerance = 1e-6;
    // Precision of the time of impact, as a fraction of the step (>= 0): a region is accepted as
    // a contact only once its time interval is at most this wide (or at the width floor), so the
    // toi is at most this much earlier than the earliest time at which the primitives come within
    // min_distance + tolerance, and never later than the earliest contact. Without it a pair
    // that stays inside that band (a resting contact) was reported at the start of whatever time
    // interval first fit the band: a coarse grid (multiples of 1/64-1/128 of the step on real
    // cloth frames).
    double toi_tolerance = 1e-6;
    // Work bound: at most this many regions are examined per test. When it is reached the test
    // reports contact at the earliest time it could not exclude (conservative, flagged `capped`).
    // Each region costs the same bounded work (about 50-90 ns on a 2-core EPYC dev box), so the
    // default keeps the worst test near 4 ms. Of the public benchmark's 7,279 queries two reach
    // it (parallel edges sliding along each other, erleben-cube-cliff-edges, edge-edge); the
    // hardest of the others needs 799.
    std::uint32_t max_boxes = 50'000;
    // Also exclude a region when F . w misses the band for one of a few fixed directions w (the
    // in-plane normals of the primitives' sides; docs/algorithms.md, "Direction exclusion").
    // It only skips regions in which no region would ever be accepted, so every answer that does
    // not reach max_boxes is the same bit for bit with it off; fewer regions are examined, so a
    // test that reached max_boxes without it may now finish. Off: for comparisons.
    bool direction_exclusion = true;
};

struct ElementaryResult {
    bool hit = false;         // the primitives may touch in [0, 1]; never false when they do
    double toi = 1.0;         // when hit: a time in [0, 1] no later than the earliest contact
    bool capped = false;      // the work bound was reached (hit is then true)
    std::uint32_t boxes = 0;  // regions examined
};

// The eight points in the order of the public CCD benchmark (Wang et al. 2021):
//   vertex_face: v_t0, f0_t0, f1_t0, f2_t0, v_t1, f0_t1, f1_t1, f2_t1
//   edge_edge:   ea0_t0, ea1_t0, eb0_t0, eb1_t0, ea0_t1, ea1_t1, eb0_t1, eb1_t1
using CcdPoints = std::array<Vec3, 8>;

ElementaryResult vertex_face(const CcdPoints& points, const ElementaryOptions& options = {});
ElementaryResult edge_edge(const CcdPoints& points, const ElementaryOptions& options = {});
ElementaryResult elementary(CcdKind kind, const CcdPoints& points,
                            const ElementaryOptions& options = {});

// A cheap conservative prefilter for the tests above (docs/algorithms.md, "CCD prefilter"): true
// only when it proves that at every t in [0, 1] every point of the first primitive is farther than
// d + tol (d = min_distance, tol = tolerance) from every point of the second in the max norm, with
// every floating-point rounding bounded: along a coordinate axis or a fixed direction (the vertex
// beyond one side of the triangle, the edges apart), or from the plane of the triangle / the
// common normal of the edges as the primitives move (a distance-aware form of Tang et al. 2010's
// coplanarity filter). Then `elementary` with the same options reports no hit, except possibly a
// `capped` one (its work bound reached on a pair that a larger bound would reject). False (no
// decision) for non-finite coordinates, coordinates of magnitude above 2^200 or all below 2^-300,
// a NaN min_distance or max_boxes = 0. Cost: a few dozen dot and cross products, against the
// solver's hundreds of nanoseconds or more.
bool elementary_prefilter_rejects(CcdKind kind, const CcdPoints& points,
                                  const ElementaryOptions& options = {});

// --- Internals exposed for tests (the rounding-error bound is checked against exact arithmetic).

// `elementary` compiled for baseline x86-64 only. On an x86-64 processor with AVX2, `elementary`
// runs a copy of the solver compiled for AVX2 (chosen at run time), which must give the same
// answer bit for bit (hit, toi, capped and boxes); this is the reference it is tested against.
ElementaryResult elementary_portable(CcdKind kind, const CcdPoints& points,
                                     const ElementaryOptions& options = {});
// The same for `elementary_prefilter_rejects`.
bool elementary_prefilter_rejects_portable(CcdKind kind, const CcdPoints& points,
                                           const ElementaryOptions& options = {});

// A region of the (t, u, v) domain: {t0, t1, u0, u1, v0, v1}.
using CcdRegion = std::array<double, 6>;

// The values of F at the 8 corners of a region, computed exactly as the solver computes them,
// with the solver's per-axis bound on |computed - exact|, where "exact" is F evaluated in exact
// arithmetic on the exact (e.g. rational) coordinates that `points` round to within 1 ulp.
//   vertex_face: F(t, u, v) = p(t) - a(t) - u (b(t) - a(t)) - v (c(t) - a(t))
//   edge_edge:   F(t, u, v) = a0(t) + u (a1(t) - a0(t)) - b0(t) - v (b1(t) - b0(t))
// with x(t) = (1 - t) x_t0 + t x_t1. Corner c is (t, u, v) = (t[c >> 2], u[(c >> 1) & 1],
// v[c & 1]). Preconditions: finite coordinates of magnitude <= 2^1000; region bounds in [0, 1]
// and multiples of 2^-52 (the solver's bisection points are multiples of 2^-50). `valid` is false
// otherwise.
struct CcdCornerValues {
    bool valid = false;
    std::array<std::array<double, 8>, 3> values{};  // [axis][corner]
    std::array<double, 3> error_bound{};            // [axis]
};
CcdCornerValues elementary_corner_values(CcdKind kind, const CcdPoints& points,
                                         const CcdRegion& region);

}  // namespace proxima::ccd
