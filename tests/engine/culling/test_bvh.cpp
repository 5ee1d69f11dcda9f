// The object hierarchy (proxima/culling/bvh.hpp): a build covers every triangle once with boxes
// that hold their triangles, splits each node at the median of its longest centre axis, gives the
// same tree on one thread as on many, and `degraded()` tells a refit that has kept the grouping
// of a very different shape from one that has only jittered.

#include <gtest/gtest.h>

#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "proxima/culling/bvh.hpp"
#include "proxima/culling/bvh_build.hpp"

namespace proxima {
namespace {

// An nx x ny grid of quads, two triangles each; `place(i, j)` gives vertex (i, j)'s position.
struct Grid {
    std::vector<Vec3> vertices;
    std::vector<TriangleIndices> triangles;
};

template <class Place>
Grid grid(int nx, int ny, Place&& place) {
    Grid g;
    for (int j = 0; j <= ny; ++j) {
        for (int i = 0; i <= nx; ++i) {
            g.vertices.push_back(place(i, j));
        }
    }
    auto id = [&](int i, int j) { return static_cast<std::uint32_t>(j * (nx + 1) + i); };
    for (int j = 0; j < ny; ++j) {
        for (int i = 0; i < nx; ++i) {
            g.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
            g.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
        }
    }
    return g;
}

// A wavy sheet: large enough (20,000 triangles) that the build splits in parallel.
constexpr int NX = 100;
constexpr int NY = 100;
Vec3 wavy(int i, int j) {
    const double u = static_cast<double>(i) / NX;
    const double v = static_cast<double>(j) / NY;
    return {u, v, 0.1 * std::sin(7.0 * u) * std::cos(5.0 * v)};
}

bool contains(const Aabb& outer, const Aabb& inner) {
    return outer.lo.x <= inner.lo.x && outer.lo.y <= inner.lo.y && outer.lo.z <= inner.lo.z &&
           outer.hi.x >= inner.hi.x && outer.hi.y >= inner.hi.y && outer.hi.z >= inner.hi.z;
}

// Checks node i's subtree over slots [first, first + count) and returns the index after it.
std::uint32_t check_subtree(const Bvh& bvh, std::uint32_t i, std::uint32_t first,
                            std::uint32_t count) {
    const auto& nodes = bvh.nodes();
    const auto& order = bvh.order();
    const auto& boxes = bvh.triangle_boxes();
    EXPECT_LT(i, nodes.size());
    const Bvh::Node& n = nodes[i];
    Aabb held;
    Aabb centres;
    for (auto k = first; k < first + count; ++k) {
        held.extend(boxes[order[k]]);
        centres.extend(boxes[order[k]].center());
    }
    EXPECT_EQ(n.box.lo, held.lo) << "node " << i;
    EXPECT_EQ(n.box.hi, held.hi) << "node " << i;
    if (count <= Bvh::LEAF_SIZE) {
        EXPECT_TRUE(n.leaf()) << "node " << i;
        EXPECT_EQ(n.first, first);
        EXPECT_EQ(n.count, count);
        return i + 1;
    }
    EXPECT_FALSE(n.leaf()) << "node " << i;
    // The median split: the left half is the first count / 2 slots, and along the longest axis
    // of the centres no left centre lies beyond a right one.
    const std::uint32_t left = count / 2;
    const int axis = bvh_build::longest_axis(centres);
    double left_max = -INFINITY;
    double right_min = INFINITY;
    for (auto k = first; k < first + count; ++k) {
        const double c = boxes[order[k]].center()[axis];
        if (k < first + left) {
            left_max = std::max(left_max, c);
        } else {
            right_min = std::min(right_min, c);
        }
    }
    EXPECT_LE(left_max, right_min) << "node " << i;
    const std::uint32_t right = check_subtree(bvh, i + 1, first, left);
    EXPECT_EQ(n.first, right) << "node " << i;
    return check_subtree(bvh, right, first + left, count - left);
}

TEST(Bvh, BuildCoversEveryTriangleOnceWithBoxesThatHoldThem) {
    const Grid g = grid(NX, NY, wavy);
    const MeshTopology topology(g.triangles, g.vertices.size());
    Bvh bvh;
    bvh.build(g.vertices, topology);
    const auto n = static_cast<std::uint32_t>(g.triangles.size());
    std::vector<std::uint32_t> sorted = bvh.order();
    std::sort(sorted.begin(), sorted.end());
    for (std::uint32_t t = 0; t < n; ++t) {
        ASSERT_EQ(sorted[t], t);
        const auto& v = g.triangles[t];
        EXPECT_TRUE(contains(bvh.triangle_boxes()[t],
                             triangle_box(g.vertices[v[0]], g.vertices[v[1]], g.vertices[v[2]])));
    }
    EXPECT_EQ(check_subtree(bvh, 0, 0, n), bvh.nodes().size());
    EXPECT_FALSE(bvh.degraded());
}

TEST(Bvh, SameTreeOnOneThreadAndOnMany) {
    const Grid g = grid(NX, NY, wavy);
    const MeshTopology topology(g.triangles, g.vertices.size());
    Bvh one;
    tbb::task_arena(1).execute([&] { one.build(g.vertices, topology); });
    for (int threads : {2, 4}) {
        Bvh many;
        tbb::task_arena(threads).execute([&] { many.build(g.vertices, topology); });
        ASSERT_EQ(many.order(), one.order()) << threads << " threads";
        ASSERT_EQ(many.nodes().size(), one.nodes().size());
        for (std::size_t i = 0; i < one.nodes().size(); ++i) {
            EXPECT_EQ(many.nodes()[i].box.lo, one.nodes()[i].box.lo);
            EXPECT_EQ(many.nodes()[i].box.hi, one.nodes()[i].box.hi);
            EXPECT_EQ(many.nodes()[i].first, one.nodes()[i].first);
            EXPECT_EQ(many.nodes()[i].count, one.nodes()[i].count);
        }
    }
}

TEST(Bvh, DegradedWhenARefitKeepsTheGroupingOfAVeryDifferentShape) {
    // Built on the sheet rolled up tightly (its columns far closer together than its rows), then
    // refitted to the flat sheet: the build grouped whole columns, which are now long.
    const Grid rolled = grid(NX, NY, [](int i, int j) {
        const double a = 6.0 * static_cast<double>(i) / NX;
        const double r = 0.02 + 0.002 * a;
        return Vec3{r * std::cos(a), static_cast<double>(j) / NY, r * std::sin(a)};
    });
    const Grid flat = grid(NX, NY, wavy);
    const MeshTopology topology(flat.triangles, flat.vertices.size());
    Bvh bvh;
    bvh.build(rolled.vertices, topology);
    EXPECT_FALSE(bvh.degraded());
    bvh.refit(flat.vertices, topology);
    EXPECT_TRUE(bvh.degraded());
    // A rebuild at the new shape is tight again, and stays so under a jitter much smaller than
    // a triangle.
    bvh.build(flat.vertices, topology);
    EXPECT_FALSE(bvh.degraded());
    std::mt19937_64 rng(20261129);
    std::uniform_real_distribution<double> jitter(-1e-4, 1e-4);
    std::vector<Vec3> moved = flat.vertices;
    for (auto& p : moved) {
        p = p + Vec3{jitter(rng), jitter(rng), jitter(rng)};
    }
    bvh.refit(moved, topology);
    EXPECT_FALSE(bvh.degraded());
}

}  // namespace
}  // namespace proxima
