// The self traversal's leaf rows (proxima/culling/leaf_rows.hpp): the dispatched copy (AVX2 where
// the processor has it) and the portable one keep exactly the triangles that share no vertex with
// the row's triangle, whose box distance is below their threshold and whose diagonal extents do
// not keep them that far apart, as box_squared_distance, share_vertex and diagonals_far say, on
// random rows with touching, overlapping and tied boxes; and whatever the diagonals drop is at
// least the threshold away by the exact triangle distance.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <random>
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
    const double err = dop_error(2.0);
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
        ASSERT_EQ(leaf_row_portable(slots, first, n, row, row_threshold, threshold, err), expected)
            << "round " << round;
        ASSERT_EQ(leaf_row(slots, first, n, row, row_threshold, threshold, err), expected)
            << "round " << round;

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
}

}  // namespace
}  // namespace proxima::detail
