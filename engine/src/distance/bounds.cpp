#include "proxima/distance/bounds.hpp"

#include <algorithm>
#include <cmath>

#include "cpu_features.hpp"

#ifdef PROXIMA_X86_64_DISPATCH
#include <immintrin.h>
#endif

namespace proxima {

namespace {

PlaneFrame plane_frame(const Triangle& p) {
    const Vec3 e1 = p[1] - p[0];
    const Vec3 e2 = p[2] - p[0];
    const Vec3 n = cross(e1, e2);
    const double nn = norm(n);
    const double l1l2 = norm(e1) * norm(e2);
    // The unit normal's rounding error grows like eps * |e1||e2| / |n|: past 1e6 (a sliver) the
    // bound is not worth its error term.
    if (!(nn > 1e-6 * l1l2)) {
        return {n, 0.0, l1l2};
    }
    return {n, nn, l1l2};
}

// Signed distances of q's vertices to p's plane are linear over q, so the smallest absolute value
// among them, when all share a sign, bounds every point of q away from the plane and so from p.
double one_side(const Triangle& p, const PlaneFrame& f, const Triangle& q) {
    if (!(f.nn > 0.0)) {
        return 0.0;
    }
    const Vec3& n = f.n;
    const double nn = f.nn;
    const double s0 = dot(n, q[0] - p[0]);
    const double s1 = dot(n, q[1] - p[0]);
    const double s2 = dot(n, q[2] - p[0]);
    double m;
    if (s0 > 0.0 && s1 > 0.0 && s2 > 0.0) {
        m = std::min({s0, s1, s2});
    } else if (s0 < 0.0 && s1 < 0.0 && s2 < 0.0) {
        m = -std::max({s0, s1, s2});
    } else {
        return 0.0;
    }
    // One square root of the largest square: the same value as the largest norm (sqrt is
    // monotone and correctly rounded).
    const double reach = std::sqrt(std::max(
        {squared_norm(q[0] - p[0]), squared_norm(q[1] - p[0]), squared_norm(q[2] - p[0])}));
    // Error of m / nn: the normal's direction error (eps * l1l2 / nn, times a small constant) times
    // the lever arm, plus the dot product's own rounding.
    const double err = 64.0 * std::numeric_limits<double>::epsilon() * (f.l1l2 / nn + 1.0) * reach;
    return m / nn - err;
}

}  // namespace

namespace {

double l1_norm(const Vec3& d) {
    return std::abs(d.x) + std::abs(d.y) + std::abs(d.z);
}

Vec3 centroid_of(const Triangle& a) {
    return (a[0] + a[1] + a[2]) / 3.0;
}

// axis_lower_bound with the two centroids given.
double axis_bound(const Triangle& a, const Vec3& ca, const Triangle& b, const Vec3& cb,
                  double slack) {
    const Vec3 axis = cb - ca;
    const double len = norm(axis);
    if (!(len > 0.0)) {
        return 0.0;
    }
    // Projections relative to a's centroid keep the magnitudes (and so the rounding) small.
    const double a_max =
        std::max({dot(axis, a[0] - ca), dot(axis, a[1] - ca), dot(axis, a[2] - ca)});
    const double b_min =
        std::min({dot(axis, b[0] - ca), dot(axis, b[1] - ca), dot(axis, b[2] - ca)});
    const double gap = (b_min - a_max) / len;
    if (!(gap > 0.0)) {
        return 0.0;
    }
    // Any unit direction gives a valid bound, so the axis's own rounding costs nothing; what is
    // left is the rounding of the differences and dot products, relative to the extent involved.
    // One square root of the largest square: the same value as the largest norm (sqrt is
    // monotone and correctly rounded).
    double reach_sq = 0.0;
    for (const auto& p : a) {
        reach_sq = std::max(reach_sq, squared_norm(p - ca));
    }
    for (const auto& p : b) {
        reach_sq = std::max(reach_sq, squared_norm(p - ca));
    }
    const double reach = std::sqrt(reach_sq);
    const double lb = gap - 64.0 * std::numeric_limits<double>::epsilon() * reach - slack;
    return lb > 0.0 ? lb : 0.0;
}

}  // namespace

double axis_lower_bound(const Triangle& a, const Triangle& b, double slack) {
    return axis_bound(a, centroid_of(a), b, centroid_of(b), slack);
}

EdgeFrame edge_frame(const Triangle& a) {
    // Any direction gives a valid bound (the projections' gap), so the rounding of the normal,
    // of the in-plane directions and of their normalisation costs nothing; a's own extent along
    // each is taken from all three corners, not assumed zero at the edge.
    EdgeFrame f;
    f.plane = plane_frame(a);
    f.centroid = centroid_of(a);
    f.reach = std::max(l1_norm(a[1] - a[0]), l1_norm(a[2] - a[0]));
    const Vec3& n = f.plane.n;
    for (int i = 0; i < 3; ++i) {
        const Vec3& p = a[i];
        const Vec3& q = a[i == 2 ? 0 : i + 1];
        const Vec3& r = a[i == 0 ? 2 : i - 1];
        const Vec3 m = cross(q - p, n);
        const double len = norm(m);
        if (!(len > 0.0)) {
            f.normal[i] = Vec3{0.0, 0.0, 0.0};
            f.extent[i] = 0.0;  // b's gap along a zero direction is 0: never positive
            continue;
        }
        f.normal[i] = (1.0 / len) * m;
        f.extent[i] = std::max({0.0, dot(f.normal[i], q - p), dot(f.normal[i], r - p)});
    }
    return f;
}

namespace detail {

// The gap between b and the outside of a's edges, along a's in-plane edge normals.
double edge_side_portable(const Triangle& a, const EdgeFrame& fa, const Triangle& b) {
    double best = 0.0;
    for (int i = 0; i < 3; ++i) {
        const Vec3& m = fa.normal[i];
        const Vec3& p = a[i];
        const double floor = std::max(best, 0.0) + fa.extent[i];
        // b's lowest corner must clear a's extent (and the best gap so far): stop at the first
        // corner that does not.
        const double d0 = dot(m, b[0] - p);
        if (!(d0 > floor)) {
            continue;
        }
        const double d1 = dot(m, b[1] - p);
        if (!(d1 > floor)) {
            continue;
        }
        const double d2 = dot(m, b[2] - p);
        if (!(d2 > floor)) {
            continue;
        }
        best = std::min({d0, d1, d2}) - fa.extent[i];
    }
    return best;
}

#ifdef PROXIMA_X86_64_DISPATCH
namespace {

// edge_side with b's three corners in lanes 0-2 (lane 3 repeats corner 0, which changes neither
// "all corners clear" nor the minimum): per edge one vector of the three projections, the same
// operations in the same order (this file is compiled with -ffp-contract=off), so the same value.
// Whether b clears an edge is close to a coin toss on the self query's candidates: one branch per
// edge instead of one per corner.
__attribute__((target("avx2"))) double edge_side_avx2(const Triangle& a, const EdgeFrame& fa,
                                                      const Triangle& b) {
    const __m256d bx = _mm256_set_pd(b[0].x, b[2].x, b[1].x, b[0].x);
    const __m256d by = _mm256_set_pd(b[0].y, b[2].y, b[1].y, b[0].y);
    const __m256d bz = _mm256_set_pd(b[0].z, b[2].z, b[1].z, b[0].z);
    double best = 0.0;
    for (int i = 0; i < 3; ++i) {
        const Vec3& m = fa.normal[i];
        const Vec3& p = a[i];
        const double floor = std::max(best, 0.0) + fa.extent[i];
        // dot(m, b - p) for the three corners.
        const __m256d d = _mm256_add_pd(
            _mm256_add_pd(
                _mm256_mul_pd(_mm256_set1_pd(m.x), _mm256_sub_pd(bx, _mm256_set1_pd(p.x))),
                _mm256_mul_pd(_mm256_set1_pd(m.y), _mm256_sub_pd(by, _mm256_set1_pd(p.y)))),
            _mm256_mul_pd(_mm256_set1_pd(m.z), _mm256_sub_pd(bz, _mm256_set1_pd(p.z))));
        if (_mm256_movemask_pd(_mm256_cmp_pd(d, _mm256_set1_pd(floor), _CMP_GT_OQ)) != 0xF) {
            continue;
        }
        // All above the floor, so none is NaN: the minimum of the lanes is std::min's.
        __m128d low = _mm_min_pd(_mm256_castpd256_pd128(d), _mm256_extractf128_pd(d, 1));
        low = _mm_min_sd(low, _mm_unpackhi_pd(low, low));
        best = _mm_cvtsd_f64(low) - fa.extent[i];
    }
    return best;
}

// Read once at start-up (a call before this, from another file's static initializer, takes the
// portable copy: the same values).
const bool HAS_AVX2 = cpu_has_avx2();

}  // namespace
#endif

double edge_side(const Triangle& a, const EdgeFrame& fa, const Triangle& b) {
#ifdef PROXIMA_X86_64_DISPATCH
    if (HAS_AVX2) {
        return edge_side_avx2(a, fa, b);
    }
#endif
    return edge_side_portable(a, fa, b);
}

}  // namespace detail

namespace {

// An upper bound on the largest distance from a's first corner to a corner of either triangle
// (the largest L1 distance: no square root): the lever arm of the rounding of edge_side's
// projections. From the frames' own reaches and one difference (the triangle inequality), not
// from all six corners: a little larger at most, which only widens the error term.
double reach_from(const Triangle& a, const EdgeFrame& fa, const Triangle& b, const EdgeFrame& fb) {
    return std::max(fa.reach, l1_norm(b[0] - a[0]) + fb.reach);
}

// A gap along a direction of length 1 (edge_side) less its rounding and the slack, or 0. Same
// error model as axis_lower_bound: differences and dot products relative to the extent involved
// (`reach`, reach_from), and a direction of length 1 within a few ulps.
double gap_bound(double gap, double reach, double slack) {
    const double lb = gap - 64.0 * std::numeric_limits<double>::epsilon() * reach - slack;
    return lb > 0.0 ? lb : 0.0;
}

// reach_from where edge_side found a positive gap `side` (the only case its rounding matters),
// else 0.
double side_reach(double side, const Triangle& a, const EdgeFrame& fa, const Triangle& b,
                  const EdgeFrame& fb) {
    return side > 0.0 ? reach_from(a, fa, b, fb) : 0.0;
}

// The edge bound from both sides' gaps (`ab` = edge_side(a, fa, b), `ba` the other way) and their
// lever arms: where a's edge normals point away from b the gap is negative, so only edges facing b
// count; the larger gap, with its own triangle's lever arm.
double edge_bound_from(double ab, double reach_a, double ba, double reach_b, double slack) {
    if (!(std::max(ab, ba) > 0.0)) {
        return 0.0;
    }
    return ab >= ba ? gap_bound(ab, reach_a, slack) : gap_bound(ba, reach_b, slack);
}

// One triangle's plane gap h and edge gap g together: every point of b is at least h from a's
// plane (all of b on one side) and at least g beyond one of a's edges in the plane's directions,
// and the two are orthogonal, so b is at least sqrt(h^2 + g^2) from a. `h` is one_side's value
// (its error already subtracted); `gap` and `reach` are edge_side's and its lever arm, whose
// error term is doubled here for the edge normals' small component along the plane normal (the
// orthogonality is exact only for exact directions). The square root and squares round by a few
// ulps: 16 more off, relatively. 0 unless both gaps are positive.
double pythagoras(double h, double gap, double reach) {
    const double g = gap - 128.0 * std::numeric_limits<double>::epsilon() * reach;
    if (!(h > 0.0) || !(gap > 0.0) || !(g > 0.0)) {
        return 0.0;
    }
    return std::sqrt(h * h + g * g) * (1.0 - 16.0 * std::numeric_limits<double>::epsilon());
}

// The plane-and-edge bound from both triangles' plane gaps (one_side) and edge gaps.
double plane_edge_from(double ha, double ab, double reach_a, double hb, double ba, double reach_b,
                       double slack) {
    const double lb = std::max(pythagoras(ha, ab, reach_a), pythagoras(hb, ba, reach_b)) - slack;
    return lb > 0.0 ? lb : 0.0;
}

}  // namespace

double edge_lower_bound(const Triangle& a, const EdgeFrame& fa, const Triangle& b,
                        const EdgeFrame& fb, double slack) {
    const double ab = detail::edge_side(a, fa, b);
    const double ba = detail::edge_side(b, fb, a);
    return edge_bound_from(ab, side_reach(ab, a, fa, b, fb), ba, side_reach(ba, b, fb, a, fa),
                           slack);
}

double edge_lower_bound(const Triangle& a, const Triangle& b, double slack) {
    return edge_lower_bound(a, edge_frame(a), b, edge_frame(b), slack);
}

double plane_edge_lower_bound(const Triangle& a, const Triangle& b, double slack) {
    const EdgeFrame fa = edge_frame(a);
    const EdgeFrame fb = edge_frame(b);
    const double ab = detail::edge_side(a, fa, b);
    const double ba = detail::edge_side(b, fb, a);
    return plane_edge_from(one_side(a, fa.plane, b), ab, side_reach(ab, a, fa, b, fb),
                           one_side(b, fb.plane, a), ba, side_reach(ba, b, fb, a, fa), slack);
}

double lower_bound_until(const Triangle& a, const EdgeFrame& fa, const Triangle& b,
                         const EdgeFrame& fb, double slack, double threshold_sq) {
    // Most pruning per instruction first (docs/benchmarks.md, "In-plane edge bound"): with its
    // per-triangle frames the edge bound is the cheapest and alone prunes 44-68 % of the self
    // search's candidates on cloth-ball and rod-twist; the plane bound most of the rest; then
    // the two together (a triangle above another's plane and beside its edges, as in a fold).
    // Its first side (a's edges) alone, when it already reaches the threshold, spares the
    // second. Each step's value is that of the bound of the same name. The centroid-axis bound
    // is not tried after them: it pruned 1-3 % of the pairs that got that far (0.2-0.6 % of all
    // calls) and cost more than the exact tests it spared (docs/benchmarks.md, "Ideal seeds, and
    // the axis stage dropped").
    const double ab = detail::edge_side(a, fa, b);
    const double reach_a = side_reach(ab, a, fa, b, fb);
    if (ab > 0.0) {
        const double lb_a = gap_bound(ab, reach_a, slack);
        if (lb_a > 0.0 && lb_a * lb_a >= threshold_sq) {
            return lb_a;
        }
    }
    const double ba = detail::edge_side(b, fb, a);
    const double reach_b = side_reach(ba, b, fb, a, fa);
    double lb = edge_bound_from(ab, reach_a, ba, reach_b, slack);
    if (lb * lb >= threshold_sq) {
        return lb;
    }
    const double ha = one_side(a, fa.plane, b);
    const double hb = one_side(b, fb.plane, a);
    lb = std::max(lb, std::max(0.0, std::max(ha, hb) - slack));
    if (lb * lb >= threshold_sq) {
        return lb;
    }
    return std::max(lb, plane_edge_from(ha, ab, reach_a, hb, ba, reach_b, slack));
}

double lower_bound_until(const Triangle& a, const Triangle& b, double slack, double threshold_sq) {
    return lower_bound_until(a, edge_frame(a), b, edge_frame(b), slack, threshold_sq);
}

double plane_lower_bound(const Triangle& a, const Triangle& b, double slack) {
    const double lb =
        std::max(one_side(a, plane_frame(a), b), one_side(b, plane_frame(b), a)) - slack;
    return lb > 0.0 ? lb : 0.0;
}

double plane_lower_bound(const Triangle& a, const EdgeFrame& fa, const Triangle& b,
                         const EdgeFrame& fb, double slack) {
    const double lb = std::max(one_side(a, fa.plane, b), one_side(b, fb.plane, a)) - slack;
    return lb > 0.0 ? lb : 0.0;
}

}  // namespace proxima
