#pragma once
// The lazily built hierarchy of a resident piece (seed 001 §5.2) and the exact closest-pair search
// between two of them, which the static verification and the avatar queries run on pieces in the
// cache (cache.hpp).

#include <atomic>
#include <cstdint>
#include <limits>
#include <memory>
#include <mutex>
#include <span>
#include <utility>
#include <vector>

#include "proxima/distance/primitives.hpp"
#include "proxima/massive/model.hpp"
#include "proxima/mesh/mesh.hpp"

namespace proxima::massive {

// An AABB tree over a piece's triangles whose children are built the first time a traversal
// visits them (§5.2): a query that touches a small region of a large piece builds only the nodes
// on its way. Thread-safe: several traversals may expand the same tree at once (expansion takes a
// lock; reading built nodes does not).
class LazyBvh {
  public:
    static constexpr std::uint32_t LEAF_SIZE = 4;
    static constexpr std::uint32_t NONE = 0;  // `left` of a node not expanded yet (or a leaf)

    struct Node {
        Aabb box;
        std::uint32_t first = 0;  // range of order()
        std::uint32_t count = 0;
        // Smallest reported (source) triangle index below: lets a search whose best distance is
        // 0 skip subtrees that cannot hold a smaller tied pair.
        std::uint32_t min_source = 0;
        std::atomic<std::uint32_t> left{NONE};  // right child is left + 1
    };

    // `bytes` (optional) is credited with the memory of every node built; `source` (optional)
    // maps triangles to the indices results report (identity when empty); nodes of at most
    // `leaf_size` (>= 1) triangles are leaves. An avatar's tree uses 1: its few, large triangles
    // (a box's faces) grouped in fours have boxes as big as the avatar itself, so every object
    // triangle inside the avatar's volume would be a candidate of every leaf.
    LazyBvh(std::span<const Vec3> vertices, std::span<const TriangleIndices> triangles,
            std::atomic<std::int64_t>* bytes = nullptr, std::span<const std::uint32_t> source = {},
            std::uint32_t leaf_size = LEAF_SIZE);
    LazyBvh(const LazyBvh&) = delete;
    LazyBvh& operator=(const LazyBvh&) = delete;

    const Node& root() const { return node(0); }
    bool leaf(const Node& n) const { return n.count <= m_leaf_size; }
    const Node& node(std::uint32_t i) const { return m_blocks[i / BLOCK][i % BLOCK]; }
    // The children of an inner node, built on first call.
    std::pair<const Node*, const Node*> children(const Node& n);
    std::uint32_t triangle(std::uint32_t slot) const { return m_order[slot]; }
    const TriangleIndices& indices(std::uint32_t t) const { return m_triangles[t]; }
    Triangle corners(std::uint32_t t) const {
        const auto& tri = m_triangles[t];
        return {m_vertices[tri[0]], m_vertices[tri[1]], m_vertices[tri[2]]};
    }
    // Builds every node holding more than `count` triangles (the prefetch thread's head start);
    // returns how many nodes the tree gained meanwhile (its own and any concurrent traversal's).
    std::uint32_t expand_above(std::uint32_t count);
    std::uint32_t nodes_built() const { return m_count.load(std::memory_order_relaxed); }
    std::uint64_t memory_bytes() const;

  private:
    // Nodes are allocated (and charged to `bytes`) in blocks of this many: small enough that a
    // tree built only near the queries is charged little more than the nodes it holds.
    static constexpr std::uint32_t BLOCK = 128;
    Node& mutable_node(std::uint32_t i) { return m_blocks[i / BLOCK][i % BLOCK]; }
    std::uint32_t allocate_two();  // under m_mutex
    void set_box(Node& n);

    std::span<const Vec3> m_vertices;
    std::span<const TriangleIndices> m_triangles;
    std::span<const std::uint32_t> m_source;
    std::uint32_t m_leaf_size;
    std::vector<std::uint32_t> m_order;
    std::vector<std::unique_ptr<Node[]>> m_blocks;  // sized for the worst case up front
    std::atomic<std::uint32_t> m_count{0};
    std::mutex m_mutex;
    std::atomic<std::int64_t>* m_bytes;
};

// Closest pair between two resident trees among pairs at most sqrt(bound_sq) apart. Ties in
// distance go to the smaller (source triangle of a, source triangle of b): every tied pair is
// visited (thresholds are widened), so the answer does not depend on traversal order. `a` is the
// first argument of every exact test (callers put the lower object index first, so the computed
// distances equal the in-memory engine's bit for bit).
struct PairHit {
    bool found = false;
    double squared_distance = std::numeric_limits<double>::infinity();
    std::uint32_t triangle_a = 0;  // source triangle indices (object numbering)
    std::uint32_t triangle_b = 0;
    std::uint32_t local_a = 0;  // the same triangles as indices of the trees
    std::uint32_t local_b = 0;
    Vec3 point_a;
    Vec3 point_b;
    std::uint64_t exact_tests = 0;
};
struct TreeRef {
    LazyBvh* bvh;
    const std::vector<std::uint32_t>* source = nullptr;  // tree triangle -> reported; null: same
    // A rigid avatar: the tree is built once on its own coordinates and searched under `pose`
    // (node boxes mapped conservatively, exact tests on `posed`, the posed vertices, indexed
    // like the tree's).
    const Affine* pose = nullptr;
    const Vec3* posed = nullptr;
};
// `ties_b_first`: break ties by (triangle_b, triangle_a) instead (the engine's separation order
// when b is the object asking).
PairHit closest_pair(TreeRef a, TreeRef b, double bound_sq, double slack,
                     bool ties_b_first = false);

}  // namespace proxima::massive
