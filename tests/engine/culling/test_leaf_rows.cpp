// The self traversal's leaf rows (proxima/culling/leaf_rows.hpp): the dispatched copy (AVX2 where
// the processor has it) and the portable one keep exactly the triangles that share no vertex with
// the row's triangle, whose box distance is below their threshold and whose diagonal extents do
// not keep them that far apart, as box_squared_distance, share_vertex and diagonals_far say, on
// random rows with touching, overlapping and tied boxes; and whatever the diagonals drop is at
// least the threshold away by the exact triangle distance.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <type_traits>
#include <vector>

#include "proxima/culling/leaf_rows.hpp"
#include "proxima/distance/primitives.hpp"

namespace proxima::detail {
namespace {

TEST(LeafRows, DispatchedAndPortableKeepWhatTheScalarTestsKeep) {
    std::mt19937_64 rng(20261127);
    constexpr std::size_t N = 64;
    // Corners on a coarse grid, so that many boxes touch, overlap or share a distance exactly and
    // diagonal gaps tie with thresholds.
    std::uniform_int_distribution<int> corner(0, 6);
    std::uniform_int_distribution<std::uint32_t> vertex(0, 11);  // few ids: many shared
    std::uniform_int_distribution<int> offset(0, 2);
    auto random_point = [&] {
        return Vec3{0.25 * corner(rng), 0.25 * corner(rng), 0.25 * corner(rng)};
    };
    // A small triangle: corners within two grid steps of a random point.
    auto near_point = [&](const Vec3& base) {
        return Vec3{base.x + 0.25 * offset(rng), base.y + 0.25 * offset(rng),
                    base.z + 0.25 * offset(rng)};
    };
    std::vector<Triangle> tris(N);
    std::vector<Aabb> boxes(N);
    std::vector<TriangleIndices> ids(N);
    std::vector<DiagonalExtents> diagonals(N);
    LeafSlots slots;
    slots.resize(N);
    for (std::size_t k = 0; k < N; ++k) {
        const Vec3 base = random_point();
        tris[k] = {near_point(base), near_point(base), near_point(base)};
        boxes[k] = triangle_box(tris[k][0], tris[k][1], tris[k][2]);
        ids[k] = {vertex(rng), vertex(rng), vertex(rng)};
        diagonals[k] = DiagonalExtents::of(tris[k][0], tris[k][1], tris[k][2]);
        slots.set(k, boxes[k], ids[k], diagonals[k]);
    }
    slots.round_to_float(0, N);
    const double err = dop_error(2.0);
    const float row_err = float_dop_error(2.0);
    // A pair the diagonals keep apart is at least sqrt(th) apart by the exact distance (which
    // rounds: relatively 1e-12 below).
    auto exactly_apart = [&](const Triangle& x, const Triangle& y, double th) {
        return triangle_triangle(x, y).squared_distance >= th * (1.0 - 1e-12);
    };
    std::uniform_int_distribution<std::uint32_t> count(1, 32);
    std::uniform_int_distribution<std::uint32_t> slot(0, N - 1);
    std::uniform_int_distribution<int> threshold_step(0, 12);
    int kept = 0;
    int dropped_adjacent = 0;
    int dropped_box = 0;
    int dropped_diagonal = 0;
    int rows_dropped_diagonal = 0;
    int extra_kept = 0;
    for (int round = 0; round < 20000; ++round) {
        const std::uint32_t n = count(rng);
        const std::uint32_t first = std::uniform_int_distribution<std::uint32_t>(0, N - n)(rng);
        const std::uint32_t row = slot(rng);
        double threshold[32] = {};
        for (std::uint32_t q = 0; q < n; ++q) {
            // Squared distances on this grid are multiples of 1/16: thresholds on it make ties.
            threshold[q] = threshold_step(rng) / 16.0;
        }
        // The row's own threshold: below every column's half the time, the larger the rest.
        const double row_threshold = round % 2 == 0 ? -1.0 : threshold_step(rng) / 16.0;
        unsigned expected = 0;
        for (std::uint32_t q = 0; q < n; ++q) {
            const auto k = first + q;
            const double th = std::max(row_threshold, threshold[q]);
            if (share_vertex(ids[row], ids[k])) {
                ++dropped_adjacent;
            } else if (!(box_squared_distance(boxes[row], boxes[k]) < th)) {
                ++dropped_box;
            } else if (diagonals_far(diagonals[row], diagonals[k], err, th)) {
                ++dropped_diagonal;
                ASSERT_TRUE(exactly_apart(tris[row], tris[k], th)) << "round " << round;
            } else {
                expected |= 1U << q;
                ++kept;
            }
        }
        // The single-precision row: the portable and dispatched copies agree, keep every slot
        // the double-precision tests keep and drop no vertex-disjoint slot that is closer than
        // sqrt(th) by the exact distance.
        float row_threshold_f[40] = {};
        for (std::uint32_t q = 0; q < n; ++q) {
            row_threshold_f[q] = float_threshold(threshold[q]);
        }
        const unsigned got = leaf_row(slots, first, n, row, float_threshold(row_threshold),
                                      row_threshold_f, row_err);
        ASSERT_EQ(leaf_row_portable(slots, first, n, row, float_threshold(row_threshold),
                                    row_threshold_f, row_err),
                  got)
            << "round " << round;
        ASSERT_EQ(got & expected, expected) << "round " << round;
        for (std::uint32_t q = 0; q < n; ++q) {
            const auto k = first + q;
            if ((got & (1U << q)) == 0 && !share_vertex(ids[row], ids[k])) {
                ASSERT_TRUE(
                    exactly_apart(tris[row], tris[k], std::max(row_threshold, threshold[q])))
                    << "round " << round;
            }
        }
        extra_kept += std::popcount(got & ~expected);

        // leaf_rows_near: the slots first..first+n as the rows, against another group of slots
        // (its box and diagonal extents the union of its triangles').
        const std::uint32_t m = count(rng);
        const std::uint32_t other = std::uniform_int_distribution<std::uint32_t>(0, N - m)(rng);
        Aabb box = boxes[other];
        DiagonalExtents group = diagonals[other];
        for (std::uint32_t k = other; k < other + m; ++k) {
            box.extend(boxes[k]);
            group.extend(diagonals[k]);
        }
        unsigned near = 0;
        for (std::uint32_t p = 0; p < n; ++p) {
            const auto k = first + p;
            const double th = std::max(threshold[p], row_threshold);
            if (!(box_squared_distance(boxes[k], box) < th)) {
                continue;
            }
            if (diagonals_far(group, diagonals[k], err, th)) {
                ++rows_dropped_diagonal;
                for (std::uint32_t o = other; o < other + m; ++o) {
                    ASSERT_TRUE(exactly_apart(tris[k], tris[o], th)) << "round " << round;
                }
                continue;
            }
            near |= 1U << p;
        }
        ASSERT_EQ(
            leaf_rows_near_portable(slots, first, n, box, group, threshold, row_threshold, err),
            near)
            << "round " << round;
        ASSERT_EQ(leaf_rows_near(slots, first, n, box, group, threshold, row_threshold, err), near)
            << "round " << round;
    }
    // Each outcome is exercised, often.
    EXPECT_GT(kept, 5000);
    EXPECT_GT(dropped_adjacent, 5000);
    EXPECT_GT(dropped_box, 5000);
    EXPECT_GT(dropped_diagonal, 1000);
    EXPECT_GT(rows_dropped_diagonal, 1000);
    // The margins keep exact ties on the grid (a box distance equal to the threshold): a few
    // more than the double-precision tests, not many.
    EXPECT_LT(extra_kept, kept / 4);
}

// The single-precision copies are rounded outward: float_below(x) <= x <= float_above(x) and
// float_threshold(th) >= th + 1e-36 for every magnitude (subnormal, tiny, huge, past the floats),
// and round_to_float (four at a time with AVX2 where the processor has it) gives the scalar
// values bit for bit, whatever the range's start and length. Fails with a margin below the
// conversion's rounding, a clamp on the wrong side or a lane out of place.
TEST(LeafRows, SinglePrecisionCopiesHoldTheDoubles) {
    std::mt19937_64 rng(20261129);
    std::uniform_real_distribution<double> mantissa(-1.0, 1.0);
    std::uniform_int_distribution<int> exponent(-160, 140);
    std::vector<double> xs = {0.0,
                              -0.0,
                              1e-44,
                              -1e-44,
                              1e-46,
                              1e-300,
                              -1e-300,
                              1e300,
                              -1e300,
                              static_cast<double>(std::numeric_limits<float>::max()),
                              -static_cast<double>(std::numeric_limits<float>::max()),
                              static_cast<double>(std::numeric_limits<float>::denorm_min())};
    for (int i = 0; i < 20000; ++i) {
        xs.push_back(std::ldexp(mantissa(rng), exponent(rng)));
    }
    for (const double x : xs) {
        ASSERT_LE(static_cast<double>(float_below(x)), x) << x;
        ASSERT_GE(static_cast<double>(float_above(x)), x) << x;
        ASSERT_FALSE(std::isnan(float_below(x)));
        if (x >= 0.0) {
            ASSERT_GE(static_cast<double>(float_threshold(x)), x + 1e-37) << x;
        }
    }
    EXPECT_EQ(float_threshold(2e30), std::numeric_limits<float>::infinity());
    EXPECT_EQ(float_below(1e300), std::numeric_limits<float>::max());
    EXPECT_EQ(float_above(-1e300), -std::numeric_limits<float>::max());

    const std::size_t n = 203;
    LeafSlots slots;
    slots.resize(n);
    for (std::size_t k = 0; k < n; ++k) {
        auto x = [&](std::size_t j) { return xs[(k * 14 + j) % xs.size()]; };
        const Aabb box{{x(0), x(1), x(2)}, {x(3), x(4), x(5)}};
        DiagonalExtents d;
        for (int i = 0; i < DiagonalExtents::N; ++i) {
            d.lo[i] = x(6 + static_cast<std::size_t>(i));
            d.hi[i] = x(10 + static_cast<std::size_t>(i));
        }
        slots.set(k, box, TriangleIndices{0, 1, 2}, d);
    }
    // Consecutive ranges of every length 0-9 (so starts at every residue), then the rest.
    std::size_t begin = 0;
    for (std::size_t len = 0; len < 10; ++len) {
        slots.round_to_float(begin, begin + len);
        begin += len;
    }
    slots.round_to_float(begin, n);
    auto bits = [](float f) { return std::bit_cast<std::uint32_t>(f); };
    for (std::size_t k = 0; k < n; ++k) {
        ASSERT_EQ(bits(slots.flox[k]), bits(float_below(slots.lox[k]))) << k;
        ASSERT_EQ(bits(slots.floy[k]), bits(float_below(slots.loy[k]))) << k;
        ASSERT_EQ(bits(slots.floz[k]), bits(float_below(slots.loz[k]))) << k;
        ASSERT_EQ(bits(slots.fhix[k]), bits(float_above(slots.hix[k]))) << k;
        ASSERT_EQ(bits(slots.fhiy[k]), bits(float_above(slots.hiy[k]))) << k;
        ASSERT_EQ(bits(slots.fhiz[k]), bits(float_above(slots.hiz[k]))) << k;
        for (int i = 0; i < DiagonalExtents::N; ++i) {
            ASSERT_EQ(bits(slots.fdlo[i][k]), bits(float_below(slots.dlo[i][k]))) << k;
            ASSERT_EQ(bits(slots.fdhi[i][k]), bits(float_above(slots.dhi[i][k]))) << k;
        }
    }
}

// leaf_thresholds (the traversal's per-leaf thresholds, four at a time where AVX2 runs) gives
// exactly traversal_threshold_sq and float_threshold of each bound, in the order of idx, and
// their largest; bounds from 0 and subnormals to past the floats and infinity, every n 0-32.
TEST(LeafRows, LeafThresholdsAreTheScalarThresholdsBitForBit) {
    std::mt19937_64 rng(20261129);
    std::uniform_real_distribution<double> mantissa(0.0, 1.0);
    std::uniform_int_distribution<int> exponent(-1074, 1023);
    const std::size_t m = 4096;
    std::vector<std::atomic<double>> bounds(m);
    const double specials[] = {0.0,
                               std::numeric_limits<double>::infinity(),
                               std::numeric_limits<double>::denorm_min(),
                               1e-300,
                               1e30,
                               1e30 * (1.0 - 1e-9),
                               static_cast<double>(std::numeric_limits<float>::max()),
                               std::numeric_limits<double>::max()};
    for (std::size_t k = 0; k < m; ++k) {
        const double b =
            k < std::size(specials) ? specials[k] : std::ldexp(mantissa(rng), exponent(rng));
        bounds[k].store(b, std::memory_order_relaxed);
    }
    std::uniform_int_distribution<std::uint32_t> pick(0, m - 1);
    auto bits = [](auto x) {
        return std::bit_cast<std::conditional_t<sizeof(x) == 8, std::uint64_t, std::uint32_t>>(x);
    };
    std::size_t finite_floats = 0;
    std::size_t infinite_floats = 0;
    for (const double slack : {0.0, 1e-300, 3.3e-15, 2.2e-12, 1e-6}) {
        for (int round = 0; round < 200; ++round) {
            for (std::uint32_t n = 0; n <= 32; ++n) {
                std::uint32_t idx[32];
                for (std::uint32_t q = 0; q < n; ++q) {
                    idx[q] = round == 0 && q < std::size(specials) ? q : pick(rng);
                }
                double out[32];
                float out_f[32];
                double ref[32];
                float ref_f[32];
                const double largest = leaf_thresholds(bounds.data(), idx, n, slack, out, out_f);
                const double ref_largest =
                    leaf_thresholds_portable(bounds.data(), idx, n, slack, ref, ref_f);
                ASSERT_EQ(bits(largest), bits(ref_largest)) << n;
                double expect_largest = 0.0;
                for (std::uint32_t q = 0; q < n; ++q) {
                    const double th = traversal_threshold_sq(bounds[idx[q]].load(), slack);
                    ASSERT_EQ(bits(out[q]), bits(th)) << n << " " << q;
                    ASSERT_EQ(bits(ref[q]), bits(th)) << n << " " << q;
                    ASSERT_EQ(bits(out_f[q]), bits(float_threshold(th))) << n << " " << q;
                    ASSERT_EQ(bits(ref_f[q]), bits(out_f[q])) << n << " " << q;
                    expect_largest = std::max(expect_largest, th);
                    (std::isinf(out_f[q]) ? infinite_floats : finite_floats) += 1;
                }
                ASSERT_EQ(bits(largest), bits(expect_largest)) << n;
            }
        }
    }
    // Both sides of float_threshold's cut at 1e30 were met.
    EXPECT_GT(finite_floats, 1000U);
    EXPECT_GT(infinite_floats, 1000U);
}

}  // namespace
}  // namespace proxima::detail
