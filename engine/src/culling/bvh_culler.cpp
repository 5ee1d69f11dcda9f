// BVH culler: one AABB hierarchy per object, refitted when only positions change. Pairs are
// culled by box distance against the current best widened by the rounding slack, so rounding in
// the box arithmetic can never drop a pair whose computed distance would be the answer.
#include <algorithm>
#include <bit>
#include <cmath>
#include <unordered_map>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "culling/cullers.hpp"
#include "overwrite_array.hpp"
#include "proxima/culling/leaf_rows.hpp"
#include "proxima/distance/bounds.hpp"

namespace proxima::detail {

namespace {
// A node pair is culled when its box distance reaches `threshold_sq`, the current best widened by
// the rounding slack (cull_threshold_sq): rounding can then never drop a pair whose computed
// distance is the answer, nor one tied with it.
bool culled(double box_sq, double threshold_sq) {
    return box_sq >= threshold_sq;
}

double pair_slack(const Scene& scene, std::size_t a, std::size_t b) {
    return rounding_slack(std::max(coordinate_scale(scene[a].box), coordinate_scale(scene[b].box)));
}

double center_gap(const Aabb& a, const Aabb& b) {
    return squared_norm(a.center() - b.center());
}

// The self traversal's leaf: a subtree of at most this many triangles (see self_pairs); a
// multiple of 4 (leaf_rows_near's lanes; leaf_row's eight read at most 7 entries past a row's end,
// inside ty_row), at most 32 (their bit masks). 8 before the leaf rows had
// diagonal extents; with them 16-32 measured 5-10 % faster than 8 (4 slower), 24 the fastest on
// rod-twist and the fewest instructions on armadillo-rollers (docs/benchmarks.md).
constexpr std::uint32_t SELF_LEAF = 24;
static_assert(SELF_LEAF % 4 == 0 && SELF_LEAF <= 32);

double node_size(const Bvh::Node& n) {
    const Vec3 e = n.box.extent();
    return e.x + e.y + e.z;
}
}  // namespace

void BvhCuller::prepare(const Scene& scene) {
    if (m_scene == &scene && m_generation == scene.generation()) {
        return;
    }
    std::unordered_map<ObjectId, Entry> old;
    old.reserve(m_entries.size());
    for (auto& e : m_entries) {
        old.emplace(e.id, std::move(e));
    }
    std::vector<Entry> next(scene.size());
    std::vector<char> reuse(scene.size(), 0);
    for (std::size_t i = 0; i < scene.size(); ++i) {
        const auto& obj = scene[i];
        auto it = old.find(obj.id);
        if (it != old.end() && it->second.topology_version == obj.topology_version) {
            next[i] = std::move(it->second);
            reuse[i] = 1;
        }
        next[i].id = obj.id;
        next[i].topology_version = obj.topology_version;
    }
    tbb::parallel_for(std::size_t{0}, scene.size(), [&](std::size_t i) {
        const auto& obj = scene[i];
        if (reuse[i] != 0) {
            next[i].bvh.refit(obj.vertices, *obj.topology);
        } else {
            next[i].bvh.build(obj.vertices, *obj.topology);
        }
    });
    m_entries = std::move(next);
    m_scene = &scene;
    m_generation = scene.generation();
}

Status BvhCuller::refine_self(const Scene& scene, std::size_t a,
                              std::vector<std::uint32_t>& partner) {
    partner.clear();
    // A refit keeps the grouping of the last build. After a large deformation (parts that were
    // close then have moved apart) its boxes are loose, and the self traversal, which opens
    // every node pair near each triangle, pays for it: there a new tree costs less than it
    // saves (docs/algorithms.md, "Refit or rebuild"). The other queries' traversals are short and
    // keep the refitted tree.
    Bvh& bvh = m_entries[a].bvh;
    if (bvh.degraded()) {
        bvh.build(scene[a].vertices, *scene[a].topology);
    }
    return {};
}

void BvhCuller::nearest_between(const Scene& scene, std::size_t a, std::size_t b, double& bound_sq,
                                PairVisitor visit) const {
    const Bvh& ba = m_entries[a].bvh;
    const Bvh& bb = m_entries[b].bvh;
    const auto& na = ba.nodes();
    const auto& nb = bb.nodes();
    const auto& boxes_a = ba.triangle_boxes();
    const auto& boxes_b = bb.triangle_boxes();
    struct Item {
        std::uint32_t i, j;
        double d;
    };
    CullThreshold th(bound_sq, pair_slack(scene, a, b));
    std::vector<Item> stack;
    stack.reserve(64);
    const double d0 = box_squared_distance(na[0].box, nb[0].box);
    if (culled(d0, th.get())) {
        return;
    }
    stack.push_back({0, 0, d0});
    while (!stack.empty()) {
        const Item it = stack.back();
        stack.pop_back();
        if (culled(it.d, th.get())) {
            continue;
        }
        const auto& x = na[it.i];
        const auto& y = nb[it.j];
        if (x.leaf() && y.leaf()) {
            for (auto p = x.first; p < x.first + x.count; ++p) {
                const auto ta = ba.order()[p];
                if (culled(box_squared_distance(boxes_a[ta], y.box), th.get())) {
                    continue;
                }
                for (auto q = y.first; q < y.first + y.count; ++q) {
                    const auto tb = bb.order()[q];
                    if (!culled(box_squared_distance(boxes_a[ta], boxes_b[tb]), th.get())) {
                        visit(ta, tb);
                    }
                }
            }
            continue;
        }
        // Descend the larger node (or the only inner one); visit the nearer child first by
        // pushing it last.
        const bool split_a = !x.leaf() && (y.leaf() || node_size(x) >= node_size(y));
        Item c1, c2;
        if (split_a) {
            c1 = {it.i + 1, it.j, box_squared_distance(na[it.i + 1].box, y.box)};
            c2 = {x.first, it.j, box_squared_distance(na[x.first].box, y.box)};
        } else {
            c1 = {it.i, it.j + 1, box_squared_distance(x.box, nb[it.j + 1].box)};
            c2 = {it.i, y.first, box_squared_distance(x.box, nb[y.first].box)};
        }
        // Overlapping boxes all have distance 0: among them, nearer centres are the likelier
        // contact, so they go first (the order only affects speed, never the answer's value).
        if (c1.d > c2.d ||
            (c1.d == c2.d && c1.d == 0.0 &&
             center_gap(na[c1.i].box, nb[c1.j].box) > center_gap(na[c2.i].box, nb[c2.j].box))) {
            std::swap(c1, c2);
        }
        if (!culled(c2.d, th.get())) {
            stack.push_back(c2);
        }
        if (!culled(c1.d, th.get())) {
            stack.push_back(c1);
        }
    }
}

namespace {

using NodePair = std::pair<std::uint32_t, std::uint32_t>;

// One step of a dual traversal of hierarchies `a` and `b` (`same`: one object against itself).
// A leaf pair goes to `leaves(x, y, same_node)`; child pairs that `near(i, j)` accepts are pushed
// on `next`. Within one hierarchy (X, X) expands to (L, L), (R, R) and (L, R), so each unordered
// node pair is visited once; otherwise the larger node is split.
template <class Leaves, class Near>
void dual_step(const Bvh& a, const Bvh& b, bool same, NodePair pair, std::vector<NodePair>& next,
               Leaves&& leaves, Near&& near) {
    const auto [i, j] = pair;
    const auto& x = a.nodes()[i];
    const auto& y = b.nodes()[j];
    auto push = [&](std::uint32_t p, std::uint32_t q) {
        if (near(p, q)) {
            next.emplace_back(p, q);
        }
    };
    if (same && i == j) {
        if (x.leaf()) {
            leaves(x, x, true);
            return;
        }
        next.emplace_back(i + 1, i + 1);
        next.emplace_back(x.first, x.first);
        push(i + 1, x.first);
        return;
    }
    if (x.leaf() && y.leaf()) {
        leaves(x, y, false);
        return;
    }
    if (!x.leaf() && (y.leaf() || node_size(x) >= node_size(y))) {
        push(i + 1, j);
        push(x.first, j);
    } else {
        push(i, j + 1);
        push(i, y.first);
    }
}

// Runs `step(pair, next, slot)` from the root pair: breadth-first (slot 0) until `fan_out` node
// pairs are pending, then each pending pair depth-first in parallel (slot 1 + its index), so that
// every core gets independent subtrees. `slots(n)` is told the number of slots before the parallel
// part starts.
template <class Step, class Slots>
void parallel_dual_traversal(std::size_t fan_out, Step&& step, Slots&& slots) {
    std::vector<NodePair> frontier{{0, 0}};
    std::vector<NodePair> next;
    while (!frontier.empty() && frontier.size() < fan_out) {
        next.clear();
        for (const auto& pair : frontier) {
            step(pair, next, std::size_t{0});
        }
        frontier.swap(next);
    }
    slots(frontier.size() + 1);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, frontier.size(), 4),
                      [&](const auto& range) {
                          std::vector<NodePair> stack;
                          for (auto k = range.begin(); k != range.end(); ++k) {
                              stack.assign(1, frontier[k]);
                              while (!stack.empty()) {
                                  const NodePair pair = stack.back();
                                  stack.pop_back();
                                  step(pair, stack, k + 1);
                              }
                          }
                      });
}

}  // namespace

// Intra-object nearest search. A node pair is culled when its box distance reaches the larger of
// the two nodes' thresholds, where a node's threshold comes from the largest bound in its subtree
// (computed once at the start; bounds only shrink, so it stays valid); a triangle pair when its
// box distance reaches the larger of the two triangles' current thresholds.
void BvhCuller::self_pairs(const Scene& scene, std::size_t a, BoundLookup bound_sq,
                           PairVisitor visit) const {
    const Bvh& bvh = m_entries[a].bvh;
    const auto& nodes = bvh.nodes();
    const auto& boxes = bvh.triangle_boxes();
    const auto& order = bvh.order();
    const auto& tris = scene[a].topology->triangles();
    const double slack = pair_slack(scene, a, a);
    auto threshold_of = [&](std::uint32_t t) { return cull_threshold_sq(bound_sq(t), slack); };
    // Triangles still without a finite bound (no seed: e.g. no non-adjacent 2-ring triangle, or
    // one whose seeds all went to others) would make every ancestor's threshold infinite below,
    // so the dual traversal would pair each of their leaves with every leaf of the object: on an
    // object of many disjoint components that is almost all of the work. Each gets a nearest-first
    // search of the hierarchy with its own bound instead, which tightens as it goes; these visits
    // only add candidates, the dual traversal below still proposes every pair it needs.
    std::vector<std::uint32_t> unbounded;
    for (std::uint32_t t = 0; t < static_cast<std::uint32_t>(tris.size()); ++t) {
        if (!std::isfinite(bound_sq(t))) {
            unbounded.push_back(t);
        }
    }
    if (!unbounded.empty() && !nodes.empty()) {
        tbb::parallel_for(
            tbb::blocked_range<std::size_t>(0, unbounded.size(), 16), [&](const auto& range) {
                std::vector<std::pair<double, std::uint32_t>> stack;
                for (auto k = range.begin(); k != range.end(); ++k) {
                    const std::uint32_t t = unbounded[k];
                    const Aabb& bt = boxes[t];
                    stack.assign(1, {box_squared_distance(bt, nodes[0].box), 0u});
                    while (!stack.empty()) {
                        const auto [d, i] = stack.back();
                        stack.pop_back();
                        if (d >= threshold_of(t)) {
                            continue;
                        }
                        const auto& n = nodes[i];
                        if (n.leaf()) {
                            for (auto q = n.first; q < n.first + n.count; ++q) {
                                const auto u = order[q];
                                if (u == t || share_vertex(tris[t], tris[u])) {
                                    continue;
                                }
                                if (box_squared_distance(bt, boxes[u]) < threshold_of(t)) {
                                    visit(std::min(t, u), std::max(t, u));
                                }
                            }
                            continue;
                        }
                        std::pair<double, std::uint32_t> c1{
                            box_squared_distance(bt, nodes[i + 1].box), i + 1};
                        std::pair<double, std::uint32_t> c2{
                            box_squared_distance(bt, nodes[n.first].box), n.first};
                        if (c1.first < c2.first) {
                            std::swap(c1, c2);  // the nearer child is pushed last
                        }
                        stack.push_back(c1);
                        stack.push_back(c2);
                    }
                }
            });
    }
    // The traversal below reads thresholds for every triangle of every leaf pair it opens (about
    // 80 per triangle on the real frames): traversal_threshold_sq needs no square root, and a
    // larger threshold only proposes more pairs (the visitor applies the exact one), never fewer.
    auto reach = [&](double bound) { return traversal_threshold_sq(bound, slack); };
    // The triangles in slot order (order()) as structure of arrays: boxes, vertex ids and
    // diagonal extents, what the leaf rows read (leaf_row), one contiguous run per leaf.
    const auto& vertices = scene[a].vertices;
    const double dop_err = dop_error(coordinate_scale(scene[a].box));
    const float row_dop_err = float_dop_error(coordinate_scale(scene[a].box));
    LeafSlots rows;
    rows.resize(order.size());
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, order.size(), 4096), [&](const auto& range) {
            for (auto s = range.begin(); s != range.end(); ++s) {
                const auto t = order[s];
                const auto& v = tris[t];
                rows.set(s, boxes[t], v,
                         DiagonalExtents::of(vertices[v[0]], vertices[v[1]], vertices[v[2]]));
            }
            rows.round_to_float(range.begin(), range.end());
        });
    // Each node's run of slots (a subtree's triangles are contiguous in order()), bottom-up
    // (children have larger indices than their parent), its largest bound and its triangles'
    // diagonal extents (with its box, a 14-DOP of the subtree).
    // The traversal treats a subtree of at most SELF_LEAF triangles as one leaf: measured on the
    // real frames, a leaf pair costs less than the node pairs that would split it.
    // Every entry is set below before any is read, so the arrays are left unset (80 bytes a node
    // were zero-filled per query, on one thread while the other waited).
    OverwriteArray<std::uint32_t> run_first(nodes.size());
    OverwriteArray<std::uint32_t> run_count(nodes.size());
    OverwriteArray<double> node_threshold(nodes.size());
    OverwriteArray<DiagonalExtents> node_diagonals(nodes.size());
    for (auto i = nodes.size(); i-- > 0;) {
        const auto& n = nodes[i];
        if (n.leaf()) {
            double m = 0.0;
            DiagonalExtents d = rows.diagonals(n.first);
            for (auto k = n.first; k < n.first + n.count; ++k) {
                m = std::max(m, bound_sq(order[k]));
                d.extend(rows.diagonals(k));
            }
            node_threshold[i] = reach(m);
            node_diagonals[i] = d;
            run_first[i] = n.first;
            run_count[i] = n.count;
        } else {
            node_threshold[i] = std::max(node_threshold[i + 1], node_threshold[n.first]);
            node_diagonals[i] = node_diagonals[i + 1];
            node_diagonals[i].extend(node_diagonals[n.first]);
            run_first[i] = std::min(run_first[i + 1], run_first[n.first]);
            run_count[i] = run_count[i + 1] + run_count[n.first];
        }
    }
    auto leaf = [&](std::uint32_t i) { return run_count[i] <= SELF_LEAF; };
    auto leaves = [&](std::uint32_t i, std::uint32_t j) {
        const bool same_node = i == j;
        const std::uint32_t* sx = &order[run_first[i]];
        const std::uint32_t* sy = &order[run_first[j]];
        const std::uint32_t nx = run_count[i];
        const std::uint32_t ny = run_count[j];
        // A stopped query ends the traversal here (the lookups below do not check).
        if (bound_sq.stopped()) {
            return;
        }
        // Each triangle's threshold (read once per leaf pair: bounds shrink as the traversal
        // goes, reach() four at a time: leaf_thresholds), and in single precision for leaf_row
        // (float_threshold); ty_row has 2 * SELF_LEAF entries so that a row from any q0 may read
        // a multiple of 8 (SELF_LEAF is one).
        double ty[SELF_LEAF] = {};
        float ty_row[2 * SELF_LEAF] = {};
        double tx[SELF_LEAF] = {};
        float tx_row[SELF_LEAF] = {};
        const double ty_max = leaf_thresholds(bound_sq.bounds(), sy, ny, slack, ty, ty_row);
        // The rows that can keep anything: those whose box and diagonal extents come within the
        // larger threshold of the other leaf's (which hold each of its triangles'); within one
        // leaf every row.
        unsigned live = static_cast<unsigned>((std::uint64_t{1} << nx) - 1U);
        if (!same_node) {
            leaf_thresholds(bound_sq.bounds(), sx, nx, slack, tx, tx_row);
            live = leaf_rows_near(rows, run_first[i], nx, nodes[j].box, node_diagonals[j], tx,
                                  ty_max, dop_err);
        }
        for (; live != 0; live &= live - 1) {
            const auto p = static_cast<std::uint32_t>(std::countr_zero(live));
            const std::uint32_t st = sx[p];
            // The row's non-adjacent triangles whose boxes and diagonal extents come within the
            // larger threshold.
            const std::uint32_t q0 = same_node ? p + 1 : 0;
            if (q0 >= ny) {
                continue;
            }
            const float tt = same_node ? ty_row[p] : tx_row[p];
            for (unsigned pass = leaf_row(rows, run_first[j] + q0, ny - q0, run_first[i] + p, tt,
                                          ty_row + q0, row_dop_err);
                 pass != 0; pass &= pass - 1) {
                const std::uint32_t su =
                    sy[q0 + static_cast<std::uint32_t>(std::countr_zero(pass))];
                visit(std::min(st, su), std::max(st, su));
            }
        }
    };
    // A node pair is opened when neither its boxes nor its diagonal extents keep it the larger
    // of its two thresholds apart (the diagonals only looked at where the boxes do not).
    auto near = [&](std::uint32_t i, std::uint32_t j) {
        const double th = std::max(node_threshold[i], node_threshold[j]);
        return box_squared_distance(nodes[i].box, nodes[j].box) < th &&
               !diagonals_far(node_diagonals[i], node_diagonals[j], dop_err, th);
    };
    // dual_step's expansion with the leaves above: (X, X) gives (L, L), (R, R) and (L, R), so
    // each unordered node pair is met once; otherwise the larger node is split.
    auto step = [&](NodePair pair, std::vector<NodePair>& next, std::size_t) {
        const auto [i, j] = pair;
        const auto& x = nodes[i];
        const auto& y = nodes[j];
        auto push = [&](std::uint32_t p, std::uint32_t q) {
            if (near(p, q)) {
                next.emplace_back(p, q);
            }
        };
        const bool lx = leaf(i);
        const bool ly = leaf(j);
        if (i == j) {
            if (lx) {
                leaves(i, i);
                return;
            }
            next.emplace_back(i + 1, i + 1);
            next.emplace_back(x.first, x.first);
            push(i + 1, x.first);
            return;
        }
        if (lx && ly) {
            leaves(i, j);
            return;
        }
        if (!lx && (ly || node_size(x) >= node_size(y))) {
            push(i + 1, j);
            push(x.first, j);
        } else {
            push(i, j + 1);
            push(i, y.first);
        }
    };
    parallel_dual_traversal(512, step, [](std::size_t) {});
}

// Every triangle pair whose boxes come within the radius (widened by the rounding slack); for one
// object against itself, non-adjacent pairs with ta < tb.
void BvhCuller::pairs_within(const Scene& scene, std::size_t a, std::size_t b, double radius,
                             std::vector<TrianglePair>& out) const {
    const Bvh& ba = m_entries[a].bvh;
    const Bvh& bb = m_entries[b].bvh;
    const bool same = a == b;
    const auto& tris = scene[a].topology->triangles();
    const double threshold_sq = cull_threshold_sq(radius * radius, pair_slack(scene, a, b));
    if (!same && box_squared_distance(ba.nodes()[0].box, bb.nodes()[0].box) > threshold_sq) {
        return;
    }
    std::vector<std::vector<TrianglePair>> parts;
    auto near = [&](std::uint32_t i, std::uint32_t j) {
        return box_squared_distance(ba.nodes()[i].box, bb.nodes()[j].box) <= threshold_sq;
    };
    auto step = [&](NodePair pair, std::vector<NodePair>& next, std::size_t slot) {
        auto& sink = slot == 0 ? out : parts[slot];
        auto emit = [&](std::uint32_t ta, std::uint32_t tb) {
            if (same) {
                if (ta == tb || share_vertex(tris[ta], tris[tb])) {
                    return;
                }
                if (ta > tb) {
                    std::swap(ta, tb);
                }
            }
            if (box_squared_distance(ba.triangle_boxes()[ta], bb.triangle_boxes()[tb]) <=
                threshold_sq) {
                sink.emplace_back(ta, tb);
            }
        };
        auto leaves = [&](const Bvh::Node& x, const Bvh::Node& y, bool same_node) {
            for (auto p = x.first; p < x.first + x.count; ++p) {
                for (auto q = same_node ? p + 1 : y.first; q < y.first + y.count; ++q) {
                    emit(ba.order()[p], bb.order()[q]);
                }
            }
        };
        dual_step(ba, bb, same, pair, next, leaves, near);
    };
    parallel_dual_traversal(256, step, [&](std::size_t n) { parts.resize(n); });
    for (std::size_t k = 1; k < parts.size(); ++k) {
        out.insert(out.end(), parts[k].begin(), parts[k].end());
    }
}

}  // namespace proxima::detail
