// LazyBvh and closest_pair (lazy_bvh.hpp).
#include "proxima/massive/lazy_bvh.hpp"

#include <algorithm>
#include <cmath>
#include <tuple>

#include "proxima/culling/bvh_build.hpp"
#include "proxima/distance/bounds.hpp"

namespace proxima::massive {

// ---------------------------------------------------------------------------------------------
// LazyBvh

LazyBvh::LazyBvh(std::span<const Vec3> vertices, std::span<const TriangleIndices> triangles,
                 std::atomic<std::int64_t>* bytes, std::span<const std::uint32_t> source,
                 std::uint32_t leaf_size)
    : m_vertices(vertices),
      m_triangles(triangles),
      m_source(source),
      m_leaf_size(std::max<std::uint32_t>(1, leaf_size)),
      m_order(triangles.size()),
      m_bytes(bytes) {
    for (std::uint32_t t = 0; t < m_order.size(); ++t) {
        m_order[t] = t;
    }
    // A binary tree with leaves of >= 1 triangle has < 2n nodes: the block table is sized once, so
    // readers never see it reallocate.
    const std::size_t max_nodes = std::max<std::size_t>(1, 2 * triangles.size());
    m_blocks.resize((max_nodes + BLOCK - 1) / BLOCK + 1);
    const std::uint32_t r = allocate_two();  // nodes 0 (root) and 1 (spare, keeps pairs aligned)
    Node& root = mutable_node(r);
    root.first = 0;
    root.count = static_cast<std::uint32_t>(triangles.size());
    set_box(root);
    if (m_bytes != nullptr) {
        m_bytes->fetch_add(static_cast<std::int64_t>(m_order.size() * sizeof(std::uint32_t) +
                                                     m_blocks.size() * sizeof(m_blocks[0])),
                           std::memory_order_relaxed);
    }
}

std::uint32_t LazyBvh::expand_above(std::uint32_t count) {
    const std::uint32_t before = nodes_built();
    std::vector<const Node*> stack{&root()};
    while (!stack.empty()) {
        const Node* n = stack.back();
        stack.pop_back();
        if (leaf(*n) || n->count <= count) {
            continue;
        }
        auto [l, r] = children(*n);
        stack.push_back(l);
        stack.push_back(r);
    }
    return nodes_built() - before;
}

std::uint64_t LazyBvh::memory_bytes() const {
    std::uint64_t blocks = 0;
    for (const auto& b : m_blocks) {
        blocks += b ? BLOCK * sizeof(Node) : 0;
    }
    return blocks + m_order.size() * sizeof(std::uint32_t) +
           m_blocks.size() * sizeof(std::unique_ptr<Node[]>);
}

std::uint32_t LazyBvh::allocate_two() {
    const std::uint32_t i = m_count.load(std::memory_order_relaxed);
    for (std::uint32_t k = i; k < i + 2; ++k) {
        auto& block = m_blocks[k / BLOCK];
        if (!block) {
            block = std::make_unique<Node[]>(BLOCK);
            if (m_bytes != nullptr) {
                m_bytes->fetch_add(static_cast<std::int64_t>(BLOCK * sizeof(Node)),
                                   std::memory_order_relaxed);
            }
        }
    }
    m_count.store(i + 2, std::memory_order_relaxed);
    return i;
}

void LazyBvh::set_box(Node& n) {
    Aabb box;
    std::uint32_t min_source = UINT32_MAX;
    for (std::uint32_t s = n.first; s < n.first + n.count; ++s) {
        const std::uint32_t t = m_order[s];
        min_source = std::min(min_source, m_source.empty() ? t : m_source[t]);
        const auto& tri = m_triangles[t];
        box.extend(m_vertices[tri[0]]);
        box.extend(m_vertices[tri[1]]);
        box.extend(m_vertices[tri[2]]);
    }
    n.box = box;
    n.min_source = min_source;
}

std::pair<const LazyBvh::Node*, const LazyBvh::Node*> LazyBvh::children(const Node& n) {
    std::uint32_t left = n.left.load(std::memory_order_acquire);
    if (left == NONE) {
        std::lock_guard lock(m_mutex);
        left = n.left.load(std::memory_order_relaxed);
        if (left == NONE) {
            // Split at the median of triangle centres along the longest axis of the centres'
            // box (ties by triangle index: deterministic whatever thread expands first).
            Aabb centres;
            auto centre = [&](std::uint32_t t) {
                const auto& tri = m_triangles[t];
                return (m_vertices[tri[0]] + m_vertices[tri[1]] + m_vertices[tri[2]]) / 3.0;
            };
            for (std::uint32_t s = n.first; s < n.first + n.count; ++s) {
                centres.extend(centre(m_order[s]));
            }
            const std::uint32_t half =
                bvh_build::split_at_median(m_order, n.first, n.first + n.count, centres, centre) -
                n.first;
            left = allocate_two();
            Node& l = mutable_node(left);
            Node& r = mutable_node(left + 1);
            l.first = n.first;
            l.count = half;
            r.first = n.first + half;
            r.count = n.count - half;
            set_box(l);
            set_box(r);
            const_cast<Node&>(n).left.store(left, std::memory_order_release);
        }
    }
    return {&node(left), &node(left + 1)};
}

// ---------------------------------------------------------------------------------------------
// closest_pair: dual traversal, nearer child pairs first, tied pairs never pruned.

namespace {

// The box of a node of `t`: its own, or under the avatar's pose the box of its mapped box
// (centre mapped, half-extent through |A|), grown by a few ulps of the result so rounding never
// makes it smaller than the posed triangles it holds.
Aabb node_box(const TreeRef& t, const LazyBvh::Node& n) {
    if (t.pose == nullptr) {
        return n.box;
    }
    const auto& m = t.pose->m;
    const Vec3 c = t.pose->apply(n.box.center());
    const Vec3 h = 0.5 * n.box.extent();
    Vec3 e{std::abs(m[0]) * h.x + std::abs(m[1]) * h.y + std::abs(m[2]) * h.z,
           std::abs(m[4]) * h.x + std::abs(m[5]) * h.y + std::abs(m[6]) * h.z,
           std::abs(m[8]) * h.x + std::abs(m[9]) * h.y + std::abs(m[10]) * h.z};
    const double scale = std::max({std::abs(c.x), std::abs(c.y), std::abs(c.z), e.x, e.y, e.z});
    const double grow = 1e-14 * scale;
    e = e + Vec3{grow, grow, grow};
    return {c - e, c + e};
}

Triangle tree_corners(const TreeRef& t, std::uint32_t tri) {
    if (t.posed == nullptr) {
        return t.bvh->corners(tri);
    }
    const auto& idx = t.bvh->indices(tri);
    return {t.posed[idx[0]], t.posed[idx[1]], t.posed[idx[2]]};
}

struct PairSearch {
    TreeRef a;
    TreeRef b;
    double bound_sq;  // accept pairs with squared distance <= this
    double slack;
    bool ties_b_first;
    PairHit hit;

    std::uint32_t source(const TreeRef& t, std::uint32_t tri) const {
        return t.source != nullptr ? (*t.source)[tri] : tri;
    }
    double threshold() const {
        const double best = hit.found ? std::min(hit.squared_distance, bound_sq) : bound_sq;
        return cull_threshold_sq(best, slack);
    }
    void leaves(const LazyBvh::Node& na, const LazyBvh::Node& nb) {
        for (std::uint32_t i = na.first; i < na.first + na.count; ++i) {
            const std::uint32_t ta = a.bvh->triangle(i);
            const Triangle x = tree_corners(a, ta);
            for (std::uint32_t j = nb.first; j < nb.first + nb.count; ++j) {
                const std::uint32_t tb = b.bvh->triangle(j);
                const Triangle y = tree_corners(b, tb);
                // The triangles' boxes first (a lower bound up to rounding, which the widened
                // threshold covers): a pair beyond it can be neither closer nor tied.
                const double t = threshold();
                if (std::isfinite(t)) {
                    if (box_squared_distance(triangle_box(x[0], x[1], x[2]),
                                             triangle_box(y[0], y[1], y[2])) > t) {
                        continue;
                    }
                    // Then the separating-plane and centroid-axis bounds (each accounts for its
                    // own rounding): tight where boxes are loose, small triangles facing each
                    // other from afar.
                    const double lb = triangle_lower_bound(x, y, slack);
                    if (lb * lb > t) {
                        continue;
                    }
                }
                ++hit.exact_tests;
                const auto cp = triangle_triangle(x, y);
                if (cp.squared_distance > bound_sq) {
                    continue;
                }
                const std::uint32_t sa = source(a, ta);
                const std::uint32_t sb = source(b, tb);
                bool better = !hit.found || cp.squared_distance < hit.squared_distance;
                if (hit.found && cp.squared_distance == hit.squared_distance) {
                    better = ties_b_first
                                 ? std::tie(sb, sa) < std::tie(hit.triangle_b, hit.triangle_a)
                                 : std::tie(sa, sb) < std::tie(hit.triangle_a, hit.triangle_b);
                }
                if (better) {
                    hit.found = true;
                    hit.squared_distance = cp.squared_distance;
                    hit.triangle_a = sa;
                    hit.triangle_b = sb;
                    hit.local_a = ta;
                    hit.local_b = tb;
                    hit.point_a = cp.point_a;
                    hit.point_b = cp.point_b;
                }
            }
        }
    }
    // With a best distance of 0 nothing is strictly closer: only a tied pair of smaller indices
    // (in the tie order) could still win, and a subtree pair whose smallest indices are not
    // smaller cannot hold one.
    bool cannot_beat_tie(const LazyBvh::Node& na, const LazyBvh::Node& nb) const {
        if (!hit.found || hit.squared_distance != 0.0) {
            return false;
        }
        const auto [first, second, best_first, best_second] =
            ties_b_first ? std::tuple{nb.min_source, na.min_source, hit.triangle_b, hit.triangle_a}
                         : std::tuple{na.min_source, nb.min_source, hit.triangle_a, hit.triangle_b};
        return first > best_first || (first == best_first && second >= best_second);
    }
    // Whether child (d1, s1) goes before child (d0, s0): the nearer box first; between equally
    // near ones (overlapping boxes, distance 0: contacts), the one with the smaller triangle
    // index, so the tie a search at distance 0 must find (the smallest indices) comes early and
    // cannot_beat_tie prunes the rest. Only the order of the visits: every pair that could win
    // or tie is still visited, so the answer is the same.
    static bool first_is_second(double d1, std::uint32_t s1, double d0, std::uint32_t s0) {
        return d1 < d0 || (d1 == d0 && s1 < s0);
    }
    void visit(const LazyBvh::Node& na, const Aabb& ba, const LazyBvh::Node& nb, const Aabb& bb) {
        if (box_squared_distance(ba, bb) > threshold() || cannot_beat_tie(na, nb)) {
            return;
        }
        const bool la = a.bvh->leaf(na);
        const bool lb = b.bvh->leaf(nb);
        if (la && lb) {
            leaves(na, nb);
            return;
        }
        // Descend the larger node (by triangle count), nearer child first.
        if (lb || (!la && na.count >= nb.count)) {
            auto [c0, c1] = a.bvh->children(na);
            Aabb b0 = node_box(a, *c0);
            Aabb b1 = node_box(a, *c1);
            if (first_is_second(box_squared_distance(b1, bb), c1->min_source,
                                box_squared_distance(b0, bb), c0->min_source)) {
                std::swap(c0, c1);
                std::swap(b0, b1);
            }
            visit(*c0, b0, nb, bb);
            visit(*c1, b1, nb, bb);
        } else {
            auto [c0, c1] = b.bvh->children(nb);
            Aabb b0 = node_box(b, *c0);
            Aabb b1 = node_box(b, *c1);
            if (first_is_second(box_squared_distance(ba, b1), c1->min_source,
                                box_squared_distance(ba, b0), c0->min_source)) {
                std::swap(c0, c1);
                std::swap(b0, b1);
            }
            visit(na, ba, *c0, b0);
            visit(na, ba, *c1, b1);
        }
    }
};

}  // namespace

PairHit closest_pair(TreeRef a, TreeRef b, double bound_sq, double slack, bool ties_b_first) {
    PairSearch s{a, b, bound_sq, slack, ties_b_first, {}};
    if (a.bvh->root().count > 0 && b.bvh->root().count > 0) {
        s.visit(a.bvh->root(), node_box(a, a.bvh->root()), b.bvh->root(),
                node_box(b, b.bvh->root()));
    }
    return s.hit;
}

// ---------------------------------------------------------------------------------------------
// GeometryCache

}  // namespace proxima::massive
