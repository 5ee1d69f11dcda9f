#include "proxima/culling/bvh.hpp"

#include <algorithm>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include "proxima/culling/bvh_build.hpp"

namespace proxima {

namespace {
// Builds: ranges at least this large split their two halves into parallel tasks; triangle boxes
// are computed in parallel chunks of this many.
constexpr std::uint32_t PARALLEL_RANGE = 4096;
}  // namespace

void Bvh::compute_triangle_boxes(std::span<const Vec3> vertices, const MeshTopology& topology) {
    const auto& tris = topology.triangles();
    m_tri_boxes.resize(tris.size());
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, tris.size(), PARALLEL_RANGE), [&](const auto& range) {
            for (auto t = range.begin(); t != range.end(); ++t) {
                m_tri_boxes[t] =
                    triangle_box(vertices[tris[t][0]], vertices[tris[t][1]], vertices[tris[t][2]]);
            }
        });
}

namespace {

double half_area(const Aabb& b) {
    const Vec3 e = b.extent();
    return e.x * e.y + e.y * e.z + e.z * e.x;
}

// A triangle being placed: its box centre beside its index, so that the median partitions and the
// centre bounds of every level read one contiguous run instead of looking each centre up through
// the slot order (the build is on the self query's path after a large deformation).
struct Item {
    Vec3 centre;
    std::uint32_t index;
};

struct Builder {
    std::vector<Bvh::Node>& nodes;
    std::vector<Item> items;  // in slot order once built (Bvh::order())

    // Nodes of the subtree over `count` triangles: every split is at the middle slot, so the
    // layout depends on the count alone.
    static std::uint32_t subtree_nodes(std::uint32_t count) {
        return count <= Bvh::LEAF_SIZE
                   ? 1
                   : 1 + subtree_nodes(count / 2) + subtree_nodes(count - count / 2);
    }

    // Node `index` over slots [begin, end), its subtree at the following indices (pre-order:
    // left child index + 1, right child after the left subtree); boxes are set afterwards
    // (Bvh::set_boxes). Recursion depth is log2(n / LEAF_SIZE) because every split is at the
    // median: safe.
    void build(std::uint32_t index, std::uint32_t begin, std::uint32_t end) {
        Bvh::Node& node = nodes[index];
        const auto count = end - begin;
        if (count <= Bvh::LEAF_SIZE) {
            node.first = begin;
            node.count = count;
            return;
        }
        Aabb cbox;
        for (auto i = begin; i < end; ++i) {
            cbox.extend(items[i].centre);
        }
        // Median split on the longest axis of the centre bounds (bvh_build::longest_axis):
        // balanced trees keep refitted boxes reasonably tight under deformation, and coincident
        // centres still split. Equal coordinates are left as std::nth_element leaves them:
        // deterministic for a given input.
        const int axis = bvh_build::longest_axis(cbox);
        const auto mid = begin + count / 2;
        std::nth_element(
            items.begin() + begin, items.begin() + mid, items.begin() + end,
            [axis](const Item& a, const Item& b) { return a.centre[axis] < b.centre[axis]; });
        const auto right = index + 1 + subtree_nodes(mid - begin);
        node.first = right;
        node.count = 0;
        // The halves touch disjoint slots and nodes, and each half's split depends on its own
        // slots only: the same tree whichever runs first, on any number of threads.
        if (count >= PARALLEL_RANGE) {
            tbb::parallel_invoke([&] { build(index + 1, begin, mid); },
                                 [&] { build(right, mid, end); });
        } else {
            build(index + 1, begin, mid);
            build(right, mid, end);
        }
    }
};

}  // namespace

bool Bvh::degraded() const {
    // Not a number (no area at all, e.g. every triangle a point) compares false: no rebuild.
    return m_looseness > REBUILD_GROWTH * m_built_looseness;
}

void Bvh::build(std::span<const Vec3> vertices, const MeshTopology& topology) {
    compute_triangle_boxes(vertices, topology);
    const auto n = static_cast<std::uint32_t>(m_tri_boxes.size());
    m_order.resize(n);
    m_nodes.clear();
    if (n == 0) {
        m_built_looseness = m_looseness = 0.0;
        return;
    }
    m_nodes.assign(Builder::subtree_nodes(n), Node{});
    Builder b{m_nodes, std::vector<Item>(n)};
    tbb::parallel_for(tbb::blocked_range<std::uint32_t>(0, n, PARALLEL_RANGE),
                      [&](const auto& range) {
                          for (auto t = range.begin(); t != range.end(); ++t) {
                              b.items[t] = {m_tri_boxes[t].center(), t};
                          }
                      });
    b.build(0, 0, n);
    for (std::uint32_t s = 0; s < n; ++s) {
        m_order[s] = b.items[s].index;
    }
    set_boxes();
    m_built_looseness = m_looseness;
}

void Bvh::refit(std::span<const Vec3> vertices, const MeshTopology& topology) {
    compute_triangle_boxes(vertices, topology);
    set_boxes();
}

void Bvh::set_boxes() {
    // The looseness's two sums in the same sweep: every triangle is in exactly one leaf.
    double node_area = 0.0;
    double triangle_area = 0.0;
    for (auto i = m_nodes.size(); i-- > 0;) {
        Node& node = m_nodes[i];
        Aabb box;
        if (node.leaf()) {
            for (auto k = node.first; k < node.first + node.count; ++k) {
                const Aabb& t = m_tri_boxes[m_order[k]];
                box.extend(t);
                triangle_area += half_area(t);
            }
        } else {
            box = m_nodes[i + 1].box;
            box.extend(m_nodes[node.first].box);
        }
        node.box = box;
        node_area += half_area(box);
    }
    m_looseness = node_area / triangle_area;
}

}  // namespace proxima
