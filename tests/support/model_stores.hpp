#pragma once
// Helpers of the massive-model tests that write their own small stores (test_region.cpp,
// tests/integration/test_massive_daemon.cpp): a box mesh and a store written from objects.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "proxima/massive/store.hpp"

namespace proxima::test {

// The closed box [lo, hi]: 8 vertices (vertex k takes hi.x if bit 0 of k is set, hi.y bit 1,
// hi.z bit 2), 12 triangles.
inline TriangleMesh box_mesh(Vec3 lo, Vec3 hi) {
    TriangleMesh m;
    for (int k = 0; k < 8; ++k) {
        m.vertices.push_back({k & 1 ? hi.x : lo.x, k & 2 ? hi.y : lo.y, k & 4 ? hi.z : lo.z});
    }
    m.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                   {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
    return m;
}

// Writes `objects` as the store in `dir` (fatal failures on any error); the tests want pieces,
// so at least one object must be split.
inline void write_model_store(const std::string& dir,
                              const std::vector<massive::ModelObject>& objects,
                              const massive::StoreOptions& options) {
    auto writer = massive::StoreWriter::create(dir, options);
    ASSERT_TRUE(writer.ok()) << writer.status().to_string();
    for (const auto& o : objects) {
        ASSERT_TRUE((*writer)->add(o).ok()) << o.name;
    }
    auto summary = (*writer)->commit();
    ASSERT_TRUE(summary.ok()) << summary.status().to_string();
    ASSERT_GT(summary->split_objects, 0u) << "the test wants objects split into pieces";
}

}  // namespace proxima::test
