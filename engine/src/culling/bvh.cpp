#include "proxima/culling/bvh.hpp"

#include <algorithm>
#include <numeric>

#include "proxima/culling/bvh_build.hpp"

namespace proxima {

void Bvh::compute_triangle_boxes(std::span<const Vec3> vertices, const MeshTopology& topology) {
    const auto& tris = topology.triangles();
    m_tri_boxes.resize(tris.size());
    for (std::size_t t = 0; t < tris.size(); ++t) {
        m_tri_boxes[t] =
            triangle_box(vertices[tris[t][0]], vertices[tris[t][1]], vertices[tris[t][2]]);
    }
}

namespace {

struct Builder {
    std::vector<Bvh::Node>& nodes;
    std::vector<std::uint32_t>& order;
    const std::vector<Aabb>& boxes;
    std::vector<Vec3> centers;

    // Recursion depth is log2(n / LEAF_SIZE) because every split is at the median: safe.
    std::uint32_t build(std::uint32_t begin, std::uint32_t end) {
        const auto index = static_cast<std::uint32_t>(nodes.size());
        nodes.emplace_back();
        Aabb box;
        Aabb cbox;
        for (auto i = begin; i < end; ++i) {
            box.extend(boxes[order[i]]);
            cbox.extend(centers[order[i]]);
        }
        nodes[index].box = box;
        const auto count = end - begin;
        if (count <= Bvh::LEAF_SIZE) {
            nodes[index].first = begin;
            nodes[index].count = count;
            return index;
        }
        // Median split on the longest axis of the centre bounds: balanced trees keep refitted
        // boxes reasonably tight under deformation, and coincident centres still split.
        const auto mid = bvh_build::split_at_median<bvh_build::Ties::unordered>(
            order, begin, end, cbox, [&](std::uint32_t t) -> const Vec3& { return centers[t]; });
        build(begin, mid);  // left child is index + 1
        const auto right = build(mid, end);
        nodes[index].first = right;
        nodes[index].count = 0;
        return index;
    }
};

}  // namespace

void Bvh::build(std::span<const Vec3> vertices, const MeshTopology& topology) {
    compute_triangle_boxes(vertices, topology);
    const auto n = static_cast<std::uint32_t>(m_tri_boxes.size());
    m_order.resize(n);
    std::iota(m_order.begin(), m_order.end(), 0u);
    m_nodes.clear();
    if (n == 0) {
        return;
    }
    m_nodes.reserve(2 * ((n + LEAF_SIZE - 1) / LEAF_SIZE) + 1);
    Builder b{m_nodes, m_order, m_tri_boxes, {}};
    b.centers.resize(n);
    for (std::uint32_t t = 0; t < n; ++t) {
        b.centers[t] = m_tri_boxes[t].center();
    }
    b.build(0, n);
}

void Bvh::refit(std::span<const Vec3> vertices, const MeshTopology& topology) {
    compute_triangle_boxes(vertices, topology);
    for (auto i = m_nodes.size(); i-- > 0;) {
        Node& node = m_nodes[i];
        Aabb box;
        if (node.leaf()) {
            for (auto k = node.first; k < node.first + node.count; ++k) {
                box.extend(m_tri_boxes[m_order[k]]);
            }
        } else {
            box = m_nodes[i + 1].box;
            box.extend(m_nodes[node.first].box);
        }
        node.box = box;
    }
}

}  // namespace proxima
