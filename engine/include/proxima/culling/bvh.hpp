#pragma once
// Axis-aligned bounding-box hierarchy over the triangles of one object. Built top-down once per
// topology; when only vertex positions change it is *refitted* bottom-up (same tree, new boxes),
// which is O(n) and keeps every box conservative, so culling stays exact. A refit cannot regroup
// triangles: after a large deformation (parts that were close at the build moved apart) its
// boxes are loose, and `degraded()` says when a rebuild is due (BvhCuller::refine_self).

#include <cstdint>
#include <span>
#include <vector>

#include "proxima/geometry/vec3.hpp"
#include "proxima/mesh/mesh.hpp"

namespace proxima {

class Bvh {
  public:
    // Nodes are stored in depth-first pre-order: a node's left child is the next node and its
    // right child is `right`; children always have larger indices than their parent, so a reverse
    // sweep refits bottom-up. A leaf (count > 0) holds triangles order()[first, first + count),
    // and every node's subtree holds one contiguous run of order() (the left child's run first).
    struct Node {
        Aabb box;
        std::uint32_t first = 0;  // leaf: first slot in order(); inner: index of the right child
        std::uint32_t count = 0;  // 0 for inner nodes
        bool leaf() const { return count != 0; }
    };
    static constexpr std::uint32_t LEAF_SIZE = 4;

    // A refitted tree whose boxes have grown this much against the triangles' own boxes since the
    // last build is rebuilt (see degraded()). 1.3 until the self traversal culled with diagonal
    // extents and larger leaves; since then armadillo-rollers' armadillo (1.58-1.90 after a step)
    // answers faster from its refitted tree than rebuilt (docs/benchmarks.md).
    static constexpr double REBUILD_GROWTH = 2.0;

    // Top-down median splits; the two halves of a large range are built in parallel (the same
    // tree as one thread builds).
    void build(std::span<const Vec3> vertices, const MeshTopology& topology);
    void refit(std::span<const Vec3> vertices, const MeshTopology& topology);
    // True when the boxes are loose: the nodes' total surface area, relative to the triangles'
    // boxes' total, is more than REBUILD_GROWTH times what it was right after the last build.
    // A rebuild then gives the same culling answers (every tree is conservative), only faster.
    bool degraded() const;

    bool empty() const { return m_nodes.empty(); }
    const std::vector<Node>& nodes() const { return m_nodes; }
    const std::vector<std::uint32_t>& order() const { return m_order; }
    // Box of each triangle (by triangle index) at the last build/refit.
    const std::vector<Aabb>& triangle_boxes() const { return m_tri_boxes; }

  private:
    void compute_triangle_boxes(std::span<const Vec3> vertices, const MeshTopology& topology);
    // Every node's box from its triangles' boxes, bottom-up, and m_looseness.
    void set_boxes();
    // The looseness: the sum of every node's box area over the sum of the triangle boxes' areas
    // (half surface areas), right after the last build and after the last build or refit.
    double m_built_looseness = 0.0;
    double m_looseness = 0.0;
    std::vector<Node> m_nodes;
    std::vector<std::uint32_t> m_order;
    std::vector<Aabb> m_tri_boxes;
};

}  // namespace proxima
