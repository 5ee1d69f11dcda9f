// The self traversal's leaf rows (proxima/culling/leaf_rows.hpp): the dispatched copy (AVX2 where
// the processor has it) and the portable one keep exactly the triangles that share no vertex with
// the row's triangle and whose box distance is below their threshold, as box_squared_distance and
// share_vertex say, on random rows with touching, overlapping and tied boxes.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <random>
#include <vector>

#include "proxima/culling/leaf_rows.hpp"

namespace proxima::detail {
namespace {

TEST(LeafRows, DispatchedAndPortableKeepWhatTheScalarTestsKeep) {
    std::mt19937_64 rng(20261127);
    constexpr std::size_t N = 64;
    // Boxes on a coarse grid of corners so that many touch, overlap or share a distance exactly.
    std::uniform_int_distribution<int> corner(0, 6);
    std::uniform_int_distribution<std::uint32_t> vertex(0, 11);  // few ids: many shared
    auto random_box = [&] {
        Aabb b;
        b.extend(Vec3{0.25 * corner(rng), 0.25 * corner(rng), 0.25 * corner(rng)});
        b.extend(Vec3{0.25 * corner(rng), 0.25 * corner(rng), 0.25 * corner(rng)});
        return b;
    };
    std::vector<Aabb> boxes(N);
    std::vector<TriangleIndices> ids(N);
    LeafSlots slots;
    slots.resize(N);
    for (std::size_t k = 0; k < N; ++k) {
        boxes[k] = random_box();
        ids[k] = {vertex(rng), vertex(rng), vertex(rng)};
        slots.set(k, boxes[k], ids[k]);
    }
    std::uniform_int_distribution<std::uint32_t> count(1, 8);
    std::uniform_int_distribution<int> threshold_step(0, 12);
    int kept = 0;
    int dropped_adjacent = 0;
    int dropped_far = 0;
    for (int row = 0; row < 20000; ++row) {
        const std::uint32_t n = count(rng);
        const std::uint32_t first = std::uniform_int_distribution<std::uint32_t>(0, N - n)(rng);
        const Aabb box = random_box();
        const TriangleIndices v{vertex(rng), vertex(rng), vertex(rng)};
        double threshold[8] = {};
        for (std::uint32_t q = 0; q < n; ++q) {
            // Squared distances on this grid are multiples of 1/16: thresholds on it make ties.
            threshold[q] = threshold_step(rng) / 16.0;
        }
        // The row's own threshold: below every column's half the time, the larger the rest.
        const double row_threshold = row % 2 == 0 ? -1.0 : threshold_step(rng) / 16.0;
        unsigned expected = 0;
        unsigned near = 0;
        for (std::uint32_t q = 0; q < n; ++q) {
            const auto k = first + q;
            // leaf_rows_near, with the slots as the rows and `box` as the other leaf's box.
            if (box_squared_distance(boxes[k], box) < std::max(threshold[q], row_threshold)) {
                near |= 1U << q;
            }
            if (share_vertex(v, ids[k])) {
                ++dropped_adjacent;
            } else if (box_squared_distance(box, boxes[k]) <
                       std::max(row_threshold, threshold[q])) {
                expected |= 1U << q;
                ++kept;
            } else {
                ++dropped_far;
            }
        }
        ASSERT_EQ(leaf_row_portable(slots, first, n, box, v, row_threshold, threshold), expected)
            << "row " << row;
        ASSERT_EQ(leaf_row(slots, first, n, box, v, row_threshold, threshold), expected)
            << "row " << row;
        ASSERT_EQ(leaf_rows_near_portable(slots, first, n, box, threshold, row_threshold), near)
            << "row " << row;
        ASSERT_EQ(leaf_rows_near(slots, first, n, box, threshold, row_threshold), near)
            << "row " << row;
    }
    // Each outcome is exercised, often.
    EXPECT_GT(kept, 5000);
    EXPECT_GT(dropped_adjacent, 5000);
    EXPECT_GT(dropped_far, 5000);
}

}  // namespace
}  // namespace proxima::detail
