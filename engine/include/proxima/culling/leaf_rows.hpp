#pragma once
// One row of the self traversal's leaf pairs (engine/src/culling/bvh_culler.cpp): one triangle
// against up to 32 triangles of a leaf, each kept when it shares no vertex with the triangle, its
// box comes closer than its threshold and the two triangles' extents along four diagonal
// directions do not already keep them that far apart (a 14-DOP, see diagonals_far), tested in
// single precision on outward-rounded copies (leaf_row). On x86-64 a copy compiled for AVX2 (eight
// triangles at a time; leaf_rows_near four, in double precision) runs where the processor has it,
// checked once at run time; it computes every distance and gap with the same IEEE operations in
// the same order as the portable copy (no fused multiply-add), so both keep the same triangles
// (tests/engine/culling/test_leaf_rows.cpp).

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>

#include "proxima/distance/bounds.hpp"
#include "proxima/geometry/vec3.hpp"
#include "proxima/mesh/mesh.hpp"

namespace proxima::detail {

// A triangle's (or a group's) extents along the four body diagonals (1, 1, 1), (1, 1, -1),
// (1, -1, 1) and (-1, 1, 1), unnormalised (each of length sqrt(3)): with the box's three axes, a
// 14-DOP. Diagonal i of a point is projection(p, i), two additions (no fused multiply-add).
// (The six face diagonals too, a 26-DOP, dropped another 21-35 % of the candidate pairs on the
// real frames but cost more than they saved: docs/benchmarks.md.)
struct DiagonalExtents {
    static constexpr int N = 4;
    double lo[N];
    double hi[N];

    static double projection(const Vec3& p, int i) {
        switch (i) {
            case 0:
                return (p.x + p.y) + p.z;
            case 1:
                return (p.x + p.y) - p.z;
            case 2:
                return (p.x - p.y) + p.z;
            default:
                return (p.y - p.x) + p.z;
        }
    }
    static DiagonalExtents of(const Vec3& a, const Vec3& b, const Vec3& c) {
        DiagonalExtents e;
        for (int i = 0; i < N; ++i) {
            const double pa = projection(a, i);
            const double pb = projection(b, i);
            const double pc = projection(c, i);
            e.lo[i] = std::min(std::min(pa, pb), pc);
            e.hi[i] = std::max(std::max(pa, pb), pc);
        }
        return e;
    }
    void extend(const DiagonalExtents& o) {
        for (int i = 0; i < N; ++i) {
            lo[i] = std::min(lo[i], o.lo[i]);
            hi[i] = std::max(hi[i], o.hi[i]);
        }
    }
};

// The absolute rounding allowance of a diagonal gap for coordinates of magnitude at most `scale`
// (coordinate_scale of the object's box): a projection adds three coordinates with two roundings
// of at most one ulp of 3 * scale, so the difference of two is off by at most 4
// ulps of 3 * scale (and rounds once more, relatively); this allows 32 ulps.
inline double dop_error(double scale) {
    return 32.0 * 3.0 * scale * 2.220446049250313e-16;
}

// Whether a and b's extents along one diagonal keep every point of one at least
// sqrt(threshold_sq) from every point of the other. A gap g along a direction of length sqrt(3)
// keeps them (g - dop_error) / sqrt(3) apart, so: the largest gap g with g - dop_error > 0 and
// (g - dop_error)^2 >= 3 threshold_sq. The threshold carries the relative and absolute slack of
// cull_threshold_sq, far above the rounding of the square and the product. Per diagonal the gap
// is the larger of b.lo - a.hi and a.lo - b.hi, and the largest is taken pairwise in a fixed order
// (the larger of x and y as x > y ? x : y, as _mm256_max_pd): the AVX2 lanes of leaf_row compute
// the same values.
inline bool diagonals_far(const DiagonalExtents& a, const DiagonalExtents& b, double dop_error,
                          double threshold_sq) {
    auto larger = [](double x, double y) { return x > y ? x : y; };
    double g[DiagonalExtents::N];
    for (int i = 0; i < DiagonalExtents::N; ++i) {
        g[i] = larger(b.lo[i] - a.hi[i], a.lo[i] - b.hi[i]);
    }
    const double h = larger(larger(g[0], g[1]), larger(g[2], g[3])) - dop_error;
    return h > 0.0 && h * h >= 3.0 * threshold_sq;
}

// A float at most x and a float at least x (x not NaN), branch-free: x moved outward by 2^-22 of
// its magnitude and 1e-44, more than the conversion's rounding (2^-24 relatively, 2^-150
// absolutely among subnormals), and kept within the finite floats on the inner side. The row
// test's single-precision copies of boxes and extents are rounded so, outward: they hold the
// doubles.
inline float float_below(double x) {
    return static_cast<float>(std::min(x - (std::fabs(x) * 0x1p-22 + 1e-44),
                                       static_cast<double>(std::numeric_limits<float>::max())));
}
inline float float_above(double x) {
    return static_cast<float>(std::max(x + (std::fabs(x) * 0x1p-22 + 1e-44),
                                       -static_cast<double>(std::numeric_limits<float>::max())));
}

// A squared threshold for leaf_row: a float at least th + 1e-37 for th >= 0 (th moved up by 2^-22
// of itself and 1e-36, then rounded: so that the single-precision test's absolute rounding near
// underflow stays below the margin), infinite above 1e30 (so that its squares never overflow
// against a finite one).
inline float float_threshold(double th) {
    const double y = th + (std::fabs(th) * 0x1p-22 + 1e-36);
    return y > 1e30 ? std::numeric_limits<float>::infinity() : static_cast<float>(y);
}

// leaf_row's diagonal allowance for coordinates of magnitude at most `scale`: dop_error plus the
// single-precision rounding of a gap (extents of magnitude at most 3 * scale, so gaps at most
// 6 * scale, each subtraction off by at most 2^-24 of that; this allows 2^-21).
inline float float_dop_error(double scale) {
    return float_above(dop_error(scale) + 6.0 * scale * 0x1p-21);
}

// Triangles' boxes, vertex ids and diagonal extents as structure of arrays, in the order the
// caller chooses (the traversal's slot order), with PAD readable entries past the last (zero).
// resize leaves the first n entries unset: the caller sets every slot before reading any (a
// zero fill of the 17 arrays was 2 % of rod-twist's self query).
struct LeafSlots {
    static constexpr std::size_t PAD = 8;
    std::unique_ptr<double[]> lox, loy, loz, hix, hiy, hiz;
    std::unique_ptr<std::uint32_t[]> v0, v1, v2;
    std::array<std::unique_ptr<double[]>, DiagonalExtents::N> dlo, dhi;
    // The same boxes and extents in single precision, rounded outward (leaf_row's).
    std::unique_ptr<float[]> flox, floy, floz, fhix, fhiy, fhiz;
    std::array<std::unique_ptr<float[]>, DiagonalExtents::N> fdlo, fdhi;

    void resize(std::size_t n);
    // Fills the single-precision copies of slots [begin, end) from the doubles set there.
    void round_to_float(std::size_t begin, std::size_t end);
    void set(std::size_t k, const Aabb& box, const TriangleIndices& v,
             const DiagonalExtents& diagonals) {
        lox[k] = box.lo.x;
        loy[k] = box.lo.y;
        loz[k] = box.lo.z;
        hix[k] = box.hi.x;
        hiy[k] = box.hi.y;
        hiz[k] = box.hi.z;
        v0[k] = v[0];
        v1[k] = v[1];
        v2[k] = v[2];
        for (int i = 0; i < DiagonalExtents::N; ++i) {
            dlo[i][k] = diagonals.lo[i];
            dhi[i][k] = diagonals.hi[i];
        }
    }
    DiagonalExtents diagonals(std::size_t k) const {
        DiagonalExtents e;
        for (int i = 0; i < DiagonalExtents::N; ++i) {
            e.lo[i] = dlo[i][k];
            e.hi[i] = dhi[i][k];
        }
        return e;
    }
};

// Bit q (q < n <= 32) is set for slot first + q unless it shares a vertex with the row's triangle
// (slot `row`) or a single-precision test on the outward-rounded copies shows the two triangles at
// least sqrt(th) apart, th = max(row_threshold_sq, threshold_sq[q]) (float_threshold of the
// doubles): its box distance, or its diagonal gaps less float_dop_error (diagonals_far's test),
// each with a relative margin of 2^-18 against rounding. Every slot the double-precision test
// keeps (share_vertex, box_squared_distance < th, diagonals_far) is kept: the single-precision
// distances and gaps are at most the double ones up to those margins (docs/algorithms.md,
// "Leaf rows in single precision"); a few more may be.
// threshold_sq must have n rounded up to a multiple of 8 readable entries (those from n on are
// ignored).
unsigned leaf_row(const LeafSlots& slots, std::uint32_t first, std::uint32_t n, std::uint32_t row,
                  float row_threshold_sq, const float* threshold_sq, float dop_error);
// The baseline x86-64 copy, whatever the processor: the same operations (tests compare the two).
unsigned leaf_row_portable(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                           std::uint32_t row, float row_threshold_sq, const float* threshold_sq,
                           float dop_error);

// The traversal's thresholds of a leaf's n triangles (n <= 32), whose bounds are
// bounds[idx[0..n)] (relaxed loads, as BoundLookup): out[q] = traversal_threshold_sq(bound, slack)
// and out_f[q] = float_threshold(out[q]), leaf_row's single-precision copy. Returns the largest
// out[q] (0 when n = 0). The AVX2 copy computes four at a time with the same operations.
double leaf_thresholds(const std::atomic<double>* bounds, const std::uint32_t* idx, std::uint32_t n,
                       double slack, double* out, float* out_f);
double leaf_thresholds_portable(const std::atomic<double>* bounds, const std::uint32_t* idx,
                                std::uint32_t n, double slack, double* out, float* out_f);

// The rows of a leaf that can keep anything against another leaf of box `box` and diagonal
// extents `diagonals`: bit p (p < n <= 32) is set when box_squared_distance(slot first + p's box,
// box) < th and not diagonals_far(diagonals, slot first + p's diagonals, dop_error, th), where
// th = max(threshold_sq[p], other_sq). threshold_sq must have n rounded up to a multiple of 4
// readable entries. A
// row left out would keep nothing: `box` and `diagonals` hold each of the other leaf's triangles',
// whose box distances and diagonal gaps are at least these (the same IEEE operations on larger or
// equal gaps).
unsigned leaf_rows_near(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                        const Aabb& box, const DiagonalExtents& diagonals,
                        const double* threshold_sq, double other_sq, double dop_error);
unsigned leaf_rows_near_portable(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                                 const Aabb& box, const DiagonalExtents& diagonals,
                                 const double* threshold_sq, double other_sq, double dop_error);

}  // namespace proxima::detail
