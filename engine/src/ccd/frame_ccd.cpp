// Full-frame CCD (seed 000 §3.2, §5.3): boxes, one hierarchy per object over its triangles'
// boxes, object pairs culled by their boxes (sort and sweep, as Stage I), dual traversal between
// objects and self traversal within an object, then the elementary vf / ee tests on the distinct
// primitive pairs whose boxes still meet.
//
// Why the culling never drops a pair the elementary test would report, rounding included. With
// the prefilter off (CcdRequest::prefilter = false, for checks) the result equals testing every
// primitive pair with the elementary tests (points 1-3); with it on (the default) it equals that
// less pairs that the elementary test could only report `capped` and that provably never come
// within min_distance + tolerance (points 2' and 4). A pair that truly touches (within d) has its
// two swept boxes within d of each other, so either way this covers every contact; the point of
// the argument is that it also covers the elementary tests' conservative false positives.
// 1. What an elementary hit implies. elementary.cpp reports a hit only once its root region
//    [0,1]^3 of (t, u, v) has passed its inclusion test: on every axis k, [min_k - e_k, max_k +
//    e_k] meets [-d, d], where min_k / max_k are over the computed values of F at the region's 8
//    corners, each within e_k = M_k 2^-47 of the exact value (M_k the largest |coordinate| on
//    axis k of the 8 points, so e_k <= 2^-47 s with s below) and d is min_distance. (Its other
//    hits, for a NaN d, a non-finite coordinate or max_boxes = 0, are reported unexamined:
//    continuous_collisions rejects all three as invalid_argument.)
//    F is  p(t) - [a(t) + u (b(t) - a(t)) + v (c(t) - a(t))]  for vf and
//    a0(t) + u (a1(t) - a0(t)) - b0(t) - v (b1(t) - b0(t))  for ee, every point moving linearly.
//    At a corner, t, u, v lie in {0, 1}, so the exact value is x - y with x in the swept box X of
//    the first primitive and y in the swept box Y of
//      - ee: the other edge (an endpoint at time t, and x(t) lies in the box of x(0), x(1));
//      - vf: the *parallelogram* a, b, c, b + c - a of the triangle, not the triangle itself: the
//        corner (u, v) = (1, 1) is evaluated. We therefore bound each triangle by the swept box of
//        its parallelogram (the box of the 8 points a, b, c, b + c - a at t = 0 and t = 1). That
//        box contains the triangle's swept box, so it also bounds its vertices and edges.
//    Hence on every axis  X.lo - Y.hi - e <= min_k  and  max_k <= X.hi - Y.lo + e, and the
//    inclusion test gives  X.lo - Y.hi <= d + 2e  and  Y.lo - X.hi <= d + 2e: the two boxes meet
//    once one of them is grown by d + 2e on every side. (Coordinates beyond 2^1000 are scaled by
//    2^-64 in elementary.cpp together with d: the same statement in scaled units.)
// 2. Our boxes with the prefilter off: each box is a swept box (FrameBox holds it twice, for both
//    frames, so that "apart at both frames" below is "apart"). Box corners are exact copies of
//    input coordinates (min / max round nothing),
//    except the fourth parallelogram corner b + c - a, computed with an error below 2 ulp(3 s),
//    where s is the largest coordinate magnitude in the scene (both frames). Two boxes are
//    declared apart only when fl(X.lo - g) > Y.hi on some axis (or the mirror), with
//        g = d (1 + 1e-9) + 1e-12 s      (computed; its own rounding is covered by the margins).
//    fl(X.lo - g) > Y.hi implies X.lo - Y.hi > g - ulp(s + g) > d + 2e + 2 ulp(3 s), since
//    2e <= 2^-46 s < 1.5e-14 s is far below the 1e-12 s margin. So a pair we drop has boxes more
//    than d + 2e apart on some axis: the elementary test would reject it at its root region. Every
//    containment used by the hierarchy (triangle box >= vertex and edge boxes, node box
//    >= children) is exact, so a pair of primitives whose boxes meet is always reached.
// 2'. Our boxes with the prefilter on (and every coordinate at most 2^200 in magnitude): per frame,
//    the box of the vertex, the edge's two vertices or the triangle's three corners at t = 0 and
//    the box of the same points at t = 1 (no parallelogram corner: no computed coordinate). Two are
//    declared apart only when on some axis one lies beyond the other at both frames, on the same
//    side: fl(X.lo - g) > Y.hi at t = 0 and at t = 1 (or the mirror), with
//        g = (d + tol + 2^-44 s)(1 + 2^-40) + 2^-50 s + 2^-1000   (tol the elementary tolerance).
//    fl(X.lo - g) > Y.hi implies X.lo - Y.hi > g - 2^-53 (s + g) >= d + tol + 2^-44 s, the factor
//    and 2^-50 s covering that rounding and g's own. Then every difference x_k - y_k of a point of
//    the first primitive and one of the second exceeds d + tol + 2^-44 s at t = 0 and at t = 1,
//    hence at every t (it is linear in t), and so does F_k, a convex combination of such
//    differences at each t: this is the prefilter's axis filter (elementary.cpp) with s >= the
//    pair's M, so the elementary test can report the pair only capped and point 4 applies. (The
//    2^-1000 covers the solver's absolute underflow term, 2^-1059.) Moving together, two
//    primitives in resting contact have far-apart swept boxes only when the motion is small;
//    per-frame boxes are apart whenever the primitives are, at both frames, by more than g: on the
//    real frame pairs 1.8-7.4x fewer triangle pairs than the parallelogram's swept boxes.
//    Containment is exact as in point 2, so a pair whose boxes are not apart is always reached.
// 3. Deduplication loses nothing: a vertex is tested from the smallest triangle that has it as a
//    corner (its owner), an edge from the smallest triangle that has it as a side. The vf pair
//    (v, f) is tested when the triangle pair (owner(v), f) is a candidate, which it is whenever
//    v's box meets f's box (owner(v)'s box contains v's); the same for ee with both owners.
//    Within an object, owner(v) == f means v is a corner of f, and both edges owned by one
//    triangle share a vertex: exactly the excluded pairs.
// 4. The prefilter (elementary_prefilter_rejects, argued in elementary.cpp) runs on each pair
//    that survives the boxes, before the elementary test: it rejects a pair only when the
//    elementary test would report no hit or a capped one on a pair that provably never comes
//    within min_distance + tolerance (CcdRequest::prefilter = false turns it off, for checks).
//    So the result is what testing every primitive pair reports, less such capped pairs (those
//    the boxes of point 2' drop included).

#include "proxima/ccd/frame_ccd.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <map>
#include <numeric>
#include <string>
#include <tuple>
#include <utility>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/parallel_sort.h>
#include <tbb/task_arena.h>

namespace proxima::ccd {

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

constexpr std::uint32_t NONE = ~0u;

// The boxes of a set of moving points at the two frames: at[0] holds them at t = 0, at[1] at
// t = 1 (with the prefilter off, both are the swept box; see point 2 at the top).
struct FrameBox {
    Aabb at[2];
    void extend(const FrameBox& b) {
        at[0].extend(b.at[0]);
        at[1].extend(b.at[1]);
    }
    Aabb swept() const {
        Aabb b = at[0];
        b.extend(at[1]);
        return b;
    }
};

// Whether a and b may come within g of each other: false when on some axis one lies beyond the
// other by more than g at both frames, on the same side (see the argument at the top).
inline bool near(const FrameBox& a, const FrameBox& b, double g) {
    for (int k = 0; k < 3; ++k) {
        if ((a.at[0].lo[k] - g > b.at[0].hi[k] && a.at[1].lo[k] - g > b.at[1].hi[k]) ||
            (b.at[0].lo[k] - g > a.at[0].hi[k] && b.at[1].lo[k] - g > a.at[1].hi[k])) {
            return false;
        }
    }
    return true;
}

// A hierarchy over boxes (one per triangle), nodes in depth-first pre-order: the left child of an
// inner node is the next node. Subtree triangles are order[begin, end).
class SweptBvh {
  public:
    struct Node {
        FrameBox box;
        std::uint32_t begin = 0;
        std::uint32_t end = 0;
        std::uint32_t right = 0;  // 0 for leaves (node 0 is the root, never a right child)
        bool leaf() const { return right == 0; }
        std::uint32_t size() const { return end - begin; }
    };
    static constexpr std::uint32_t LEAF_SIZE = 4;

    void build(const std::vector<FrameBox>& boxes) {
        const auto n = static_cast<std::uint32_t>(boxes.size());
        m_order.resize(n);
        std::iota(m_order.begin(), m_order.end(), 0u);
        m_centers.resize(n);
        tbb::parallel_for(std::uint32_t{0}, n,
                          [&](std::uint32_t t) { m_centers[t] = boxes[t].swept().center(); });
        m_nodes.assign(n > 0 ? node_count(n) : 0, Node{});
        if (n > 0) {
            build(boxes, 0, n, 0);
        }
        m_centers = {};
    }
    const std::vector<Node>& nodes() const { return m_nodes; }
    const std::vector<std::uint32_t>& order() const { return m_order; }

  private:
    // Nodes of the subtree over m triangles (the split below halves m, rounding down on the left).
    static std::uint32_t node_count(std::uint32_t m) {
        return m <= LEAF_SIZE ? 1 : 1 + node_count(m / 2) + node_count(m - m / 2);
    }

    // Median split on the longest axis of the centre bounds; depth is log2(n / LEAF_SIZE). Node
    // `index` and its subtree: the left child is index + 1 and the right one follows the left
    // subtree, so the layout does not depend on the order of construction and large subtrees are
    // built in parallel.
    void build(const std::vector<FrameBox>& boxes, std::uint32_t begin, std::uint32_t end,
               std::uint32_t index) {
        FrameBox box;
        Aabb cbox;
        for (auto i = begin; i < end; ++i) {
            box.extend(boxes[m_order[i]]);
            cbox.extend(m_centers[m_order[i]]);
        }
        m_nodes[index].box = box;
        m_nodes[index].begin = begin;
        m_nodes[index].end = end;
        if (end - begin <= LEAF_SIZE) {
            return;
        }
        const Vec3 ext = cbox.extent();
        const int axis = ext.x >= ext.y && ext.x >= ext.z ? 0 : (ext.y >= ext.z ? 1 : 2);
        const auto mid = begin + (end - begin) / 2;
        std::nth_element(m_order.begin() + begin, m_order.begin() + mid, m_order.begin() + end,
                         [&](std::uint32_t a, std::uint32_t b) {
                             return std::tie(m_centers[a][axis], a) <
                                    std::tie(m_centers[b][axis], b);
                         });
        const auto right = index + 1 + node_count(mid - begin);
        m_nodes[index].right = right;
        constexpr std::uint32_t PARALLEL_BELOW = 8192;  // smaller subtrees: one task
        if (end - begin > PARALLEL_BELOW) {
            tbb::parallel_invoke([&] { build(boxes, begin, mid, index + 1); },
                                 [&] { build(boxes, mid, end, right); });
        } else {
            build(boxes, begin, mid, index + 1);
            build(boxes, mid, end, right);
        }
    }

    std::vector<Node> m_nodes;
    std::vector<std::uint32_t> m_order;
    std::vector<Vec3> m_centers;
};

// Per object: edges, ownership, swept boxes and the hierarchy.
struct ObjectData {
    const SceneObject* object = nullptr;
    const std::vector<Vec3>* p1 = nullptr;
    std::vector<std::array<std::uint32_t, 2>> edges;
    std::vector<std::array<std::uint32_t, 3>> tri_edges;  // side k = (corner k, corner k+1)
    // Bits 0-2: the triangle owns corner k; bits 3-5: it owns side k.
    std::vector<std::uint8_t> owns;
    std::vector<FrameBox> vertex_box;  // boxes of each vertex
    std::vector<FrameBox> edge_box;    // of each edge
    std::vector<FrameBox> face_box;  // of each triangle (its parallelogram's swept box when loose)
    FrameBox box;                    // of all face boxes
    SweptBvh bvh;
};

std::uint32_t edge_index(const std::vector<std::array<std::uint32_t, 2>>& edges, std::uint32_t a,
                         std::uint32_t b) {
    if (a == b) {
        return NONE;
    }
    const std::array<std::uint32_t, 2> key{std::min(a, b), std::max(a, b)};
    auto it = std::lower_bound(edges.begin(), edges.end(), key);
    return static_cast<std::uint32_t>(it - edges.begin());
}

void prepare(ObjectData& d, bool tight) {
    const auto& obj = *d.object;
    const auto& topo = *obj.topology;
    const auto& p0 = obj.vertices;
    const auto& p1 = *d.p1;
    const auto nt = static_cast<std::uint32_t>(topo.triangle_count());
    d.edges = mesh_edges(topo);
    d.tri_edges.resize(nt);
    tbb::parallel_for(std::uint32_t{0}, nt, [&](std::uint32_t t) {
        const auto& tri = topo.triangle(t);
        for (int k = 0; k < 3; ++k) {
            d.tri_edges[t][k] = edge_index(d.edges, tri[k], tri[(k + 1) % 3]);
        }
    });
    // Owners: the smallest triangle with the vertex as a corner, the edge as a side.
    d.owns.assign(nt, 0);
    std::vector<std::uint8_t> vertex_owned(p0.size(), 0);
    std::vector<std::uint8_t> edge_owned(d.edges.size(), 0);
    for (std::uint32_t t = 0; t < nt; ++t) {
        const auto& tri = topo.triangle(t);
        for (int k = 0; k < 3; ++k) {
            if (vertex_owned[tri[k]] == 0) {
                vertex_owned[tri[k]] = 1;
                d.owns[t] |= static_cast<std::uint8_t>(1u << k);
            }
            const auto e = d.tri_edges[t][k];
            if (e != NONE && edge_owned[e] == 0) {
                edge_owned[e] = 1;
                d.owns[t] |= static_cast<std::uint8_t>(8u << k);
            }
        }
    }
    d.vertex_box.resize(p0.size());
    tbb::parallel_for(std::size_t{0}, p0.size(), [&](std::size_t v) {
        if (tight) {
            d.vertex_box[v] = {Aabb{p0[v], p0[v]}, Aabb{p1[v], p1[v]}};
        } else {
            const Aabb b{cwise_min(p0[v], p1[v]), cwise_max(p0[v], p1[v])};
            d.vertex_box[v] = {b, b};
        }
    });
    d.edge_box.resize(d.edges.size());
    tbb::parallel_for(std::size_t{0}, d.edges.size(), [&](std::size_t e) {
        FrameBox b = d.vertex_box[d.edges[e][0]];
        b.extend(d.vertex_box[d.edges[e][1]]);
        d.edge_box[e] = b;
    });
    d.face_box.resize(nt);
    tbb::parallel_for(std::uint32_t{0}, nt, [&](std::uint32_t t) {
        const auto& tri = topo.triangle(t);
        FrameBox b = d.vertex_box[tri[0]];
        b.extend(d.vertex_box[tri[1]]);
        b.extend(d.vertex_box[tri[2]]);
        if (!tight) {
            b.at[0].extend(p0[tri[1]] + p0[tri[2]] - p0[tri[0]]);
            b.at[0].extend(p1[tri[1]] + p1[tri[2]] - p1[tri[0]]);
            b.at[1] = b.at[0];
        }
        d.face_box[t] = b;
    });
    d.box = FrameBox{};
    for (const auto& b : d.face_box) {
        d.box.extend(b);
    }
    d.bvh.build(d.face_box);
}

struct Candidate {
    std::uint32_t object;
    std::uint32_t primitive;
    std::uint32_t other;
    std::uint32_t other_primitive;
    CcdKind kind;
};

// A unit of broad-phase work: the triangle pairs of one node (a == b, na == nb: pairs within the
// subtree) or of two nodes (pairs across them).
struct Job {
    std::uint32_t a;
    std::uint32_t na;
    std::uint32_t b;
    std::uint32_t nb;
};

CcdPoints points_of(const std::vector<ObjectData>& objects, const Candidate& c);

// The primitive pairs of one job, each through the prefilter as it is found (while its triangles'
// data is in cache, and without storing the pairs that the prefilter rejects, 65-98 % of them on
// the real frame pairs): the pairs the prefilter keeps go to `out`.
struct Traversal {
    const std::vector<ObjectData>& objects;
    double gap;
    const CcdRequest& request;
    std::vector<Candidate>& out;
    std::uint64_t triangle_pairs = 0;
    std::uint64_t prefilter_rejects = 0;

    void emit(const Candidate& c) {
        if (request.prefilter &&
            elementary_prefilter_rejects(c.kind, points_of(objects, c), request.elementary)) {
            ++prefilter_rejects;
            return;
        }
        out.push_back(c);
    }

    // Between objects a != b: triangles ta of a and tb of b.
    void pair_between(std::uint32_t a, std::uint32_t ta, std::uint32_t b, std::uint32_t tb) {
        const auto& A = objects[a];
        const auto& B = objects[b];
        if (!near(A.face_box[ta], B.face_box[tb], gap)) {
            return;
        }
        ++triangle_pairs;
        const auto& tri_a = A.object->triangle(ta);
        const auto& tri_b = B.object->triangle(tb);
        const auto own_a = A.owns[ta];
        const auto own_b = B.owns[tb];
        for (int k = 0; k < 3; ++k) {
            if ((own_a & (1u << k)) != 0 && near(A.vertex_box[tri_a[k]], B.face_box[tb], gap)) {
                emit({a, tri_a[k], b, tb, CcdKind::vertex_face});
            }
            if ((own_b & (1u << k)) != 0 && near(B.vertex_box[tri_b[k]], A.face_box[ta], gap)) {
                emit({b, tri_b[k], a, ta, CcdKind::vertex_face});
            }
        }
        for (int i = 0; i < 3; ++i) {
            if ((own_a & (8u << i)) == 0) {
                continue;
            }
            const auto ea = A.tri_edges[ta][i];
            for (int j = 0; j < 3; ++j) {
                if ((own_b & (8u << j)) == 0) {
                    continue;
                }
                const auto eb = B.tri_edges[tb][j];
                if (near(A.edge_box[ea], B.edge_box[eb], gap)) {
                    emit({a, ea, b, eb, CcdKind::edge_edge});
                }
            }
        }
    }

    // Within object o: triangles t != u.
    void pair_within(std::uint32_t o, std::uint32_t t, std::uint32_t u) {
        const auto& O = objects[o];
        if (!near(O.face_box[t], O.face_box[u], gap)) {
            return;
        }
        ++triangle_pairs;
        const auto& tri_t = O.object->triangle(t);
        const auto& tri_u = O.object->triangle(u);
        const auto own_t = O.owns[t];
        const auto own_u = O.owns[u];
        auto corner_of = [](std::uint32_t v, const TriangleIndices& tri) {
            return v == tri[0] || v == tri[1] || v == tri[2];
        };
        for (int k = 0; k < 3; ++k) {
            if ((own_t & (1u << k)) != 0 && !corner_of(tri_t[k], tri_u) &&
                near(O.vertex_box[tri_t[k]], O.face_box[u], gap)) {
                emit({o, tri_t[k], o, u, CcdKind::vertex_face});
            }
            if ((own_u & (1u << k)) != 0 && !corner_of(tri_u[k], tri_t) &&
                near(O.vertex_box[tri_u[k]], O.face_box[t], gap)) {
                emit({o, tri_u[k], o, t, CcdKind::vertex_face});
            }
        }
        for (int i = 0; i < 3; ++i) {
            if ((own_t & (8u << i)) == 0) {
                continue;
            }
            const auto e1 = O.tri_edges[t][i];
            const auto& v1 = O.edges[e1];
            for (int j = 0; j < 3; ++j) {
                if ((own_u & (8u << j)) == 0) {
                    continue;
                }
                const auto e2 = O.tri_edges[u][j];
                const auto& v2 = O.edges[e2];
                if (v1[0] == v2[0] || v1[0] == v2[1] || v1[1] == v2[0] || v1[1] == v2[1]) {
                    continue;
                }
                if (near(O.edge_box[e1], O.edge_box[e2], gap)) {
                    emit({o, std::min(e1, e2), o, std::max(e1, e2), CcdKind::edge_edge});
                }
            }
        }
    }

    void within_node(std::uint32_t o, std::uint32_t n) {
        const auto& bvh = objects[o].bvh;
        const auto& node = bvh.nodes()[n];
        if (node.leaf()) {
            const auto& order = bvh.order();
            for (auto i = node.begin; i < node.end; ++i) {
                for (auto j = i + 1; j < node.end; ++j) {
                    pair_within(o, std::min(order[i], order[j]), std::max(order[i], order[j]));
                }
            }
            return;
        }
        within_node(o, n + 1);
        within_node(o, node.right);
        across(o, n + 1, o, node.right);
    }

    void across(std::uint32_t a, std::uint32_t na, std::uint32_t b, std::uint32_t nb) {
        const auto& A = objects[a].bvh;
        const auto& B = objects[b].bvh;
        const auto& x = A.nodes()[na];
        const auto& y = B.nodes()[nb];
        if (!near(x.box, y.box, gap)) {
            return;
        }
        if (x.leaf() && y.leaf()) {
            for (auto i = x.begin; i < x.end; ++i) {
                for (auto j = y.begin; j < y.end; ++j) {
                    const auto t = A.order()[i];
                    const auto u = B.order()[j];
                    if (a != b) {
                        pair_between(a, t, b, u);
                    } else {
                        pair_within(a, std::min(t, u), std::max(t, u));
                    }
                }
            }
            return;
        }
        if (y.leaf() || (!x.leaf() && x.size() >= y.size())) {
            across(a, na + 1, b, nb);
            across(a, x.right, b, nb);
        } else {
            across(a, na, b, nb + 1);
            across(a, na, b, y.right);
        }
    }

    void run(const Job& job) {
        if (job.a == job.b && job.na == job.nb) {
            within_node(job.a, job.na);
        } else {
            across(job.a, job.na, job.b, job.nb);
        }
    }
};

// Splits the broad phase into jobs of at most about JOB_TRIANGLES triangles on each side, so that
// the parallel loop balances; the split itself is serial and cheap (a few levels of each tree).
constexpr std::uint32_t JOB_TRIANGLES = 256;

void split_job(const std::vector<ObjectData>& objects, double gap, const Job& job,
               std::vector<Job>& jobs) {
    const auto& A = objects[job.a].bvh.nodes();
    const auto& B = objects[job.b].bvh.nodes();
    const auto& x = A[job.na];
    const auto& y = B[job.nb];
    if (job.a == job.b && job.na == job.nb) {
        if (x.leaf() || x.size() <= JOB_TRIANGLES) {
            jobs.push_back(job);
            return;
        }
        split_job(objects, gap, {job.a, job.na + 1, job.a, job.na + 1}, jobs);
        split_job(objects, gap, {job.a, x.right, job.a, x.right}, jobs);
        split_job(objects, gap, {job.a, job.na + 1, job.a, x.right}, jobs);
        return;
    }
    if (!near(x.box, y.box, gap)) {
        return;
    }
    if ((x.leaf() || x.size() <= JOB_TRIANGLES) && (y.leaf() || y.size() <= JOB_TRIANGLES)) {
        jobs.push_back(job);
        return;
    }
    if (y.leaf() || (!x.leaf() && x.size() >= y.size())) {
        split_job(objects, gap, {job.a, job.na + 1, job.b, job.nb}, jobs);
        split_job(objects, gap, {job.a, x.right, job.b, job.nb}, jobs);
    } else {
        split_job(objects, gap, {job.a, job.na, job.b, job.nb + 1}, jobs);
        split_job(objects, gap, {job.a, job.na, job.b, y.right}, jobs);
    }
}

CcdPoints points_of(const std::vector<ObjectData>& objects, const Candidate& c) {
    const auto& A = objects[c.object];
    const auto& B = objects[c.other];
    const auto& a0 = A.object->vertices;
    const auto& a1 = *A.p1;
    const auto& b0 = B.object->vertices;
    const auto& b1 = *B.p1;
    if (c.kind == CcdKind::vertex_face) {
        const auto v = c.primitive;
        const auto& f = B.object->triangle(c.other_primitive);
        return {a0[v], b0[f[0]], b0[f[1]], b0[f[2]], a1[v], b1[f[0]], b1[f[1]], b1[f[2]]};
    }
    const auto& ea = A.edges[c.primitive];
    const auto& eb = B.edges[c.other_primitive];
    return {a0[ea[0]], a0[ea[1]], b0[eb[0]], b0[eb[1]], a1[ea[0]], a1[ea[1]], b1[eb[0]], b1[eb[1]]};
}

Status validate(const Scene& scene, std::span<const std::vector<Vec3>> positions_t1,
                const CcdRequest& request) {
    const auto& opt = request.elementary;
    if (!std::isfinite(opt.min_distance) || opt.min_distance < 0.0) {
        return invalid_argument("ccd: min_distance must be finite and >= 0 (got " +
                                std::to_string(opt.min_distance) + ")");
    }
    if (!std::isfinite(opt.tolerance) || opt.tolerance <= 0.0) {
        return invalid_argument("ccd: tolerance must be finite and > 0 (got " +
                                std::to_string(opt.tolerance) + ")");
    }
    if (!std::isfinite(opt.toi_tolerance) || opt.toi_tolerance < 0.0 || opt.toi_tolerance > 1.0) {
        return invalid_argument(
            "ccd: toi_tolerance must be in [0, 1] (a fraction of the step; got " +
            std::to_string(opt.toi_tolerance) + ")");
    }
    if (opt.max_boxes == 0) {
        // The elementary tests would report every pair (capped at t = 0) without examining it.
        return invalid_argument("ccd: max_boxes must be at least 1");
    }
    if (positions_t1.size() != scene.size()) {
        return invalid_argument("ccd: " + std::to_string(positions_t1.size()) +
                                " position sets at t = 1 for " + std::to_string(scene.size()) +
                                " objects (one per object, in scene order)");
    }
    for (std::size_t i = 0; i < scene.size(); ++i) {
        const auto& obj = scene[i];
        const std::string what = "ccd: object " + std::to_string(i) +
                                 (obj.name.empty() ? std::string() : " '" + obj.name + "'") +
                                 " at t = 1";
        if (Status s = validate_positions(positions_t1[i], obj.vertices.size(), what); !s.ok()) {
            return invalid_argument(s.message());
        }
    }
    return {};
}

std::uint64_t brute_force_count(const std::vector<ObjectData>& objects, const CcdRequest& req) {
    std::uint64_t total = 0;
    // Vertices used by some triangle (the others are no primitive), per object.
    std::vector<std::uint64_t> used(objects.size(), 0);
    for (std::size_t i = 0; i < objects.size(); ++i) {
        const auto& topo = *objects[i].object->topology;
        const auto nt = topo.triangle_count();
        const auto ne = objects[i].edges.size();
        std::vector<std::uint64_t> edge_degree(topo.vertex_count(), 0);
        for (const auto& e : objects[i].edges) {
            ++edge_degree[e[0]];
            ++edge_degree[e[1]];
        }
        std::uint64_t excluded_vf = 0;
        std::uint64_t excluded_ee = 0;
        for (std::uint32_t v = 0; v < topo.vertex_count(); ++v) {
            const auto deg = topo.vertex_triangles(v).size();
            used[i] += deg > 0 ? 1 : 0;
            excluded_vf += deg;
            excluded_ee += edge_degree[v] > 1 ? edge_degree[v] * (edge_degree[v] - 1) / 2 : 0;
        }
        if (req.self) {
            total += used[i] * nt - excluded_vf;
            total += (ne > 1 ? ne * (ne - 1) / 2 : 0) - excluded_ee;
        }
    }
    if (req.between_objects) {
        for (std::size_t i = 0; i < objects.size(); ++i) {
            for (std::size_t j = i + 1; j < objects.size(); ++j) {
                total += used[i] * objects[j].face_box.size() +
                         used[j] * objects[i].face_box.size() +
                         objects[i].edges.size() * objects[j].edges.size();
            }
        }
    }
    return total;
}

// The caller's cancellation, latched: once a check sees it, every later check returns at once.
class Stopper {
  public:
    explicit Stopper(const CancelToken* cancel) : m_cancel(cancel) {}

    bool should_stop() {
        if (m_stopped.load(std::memory_order_relaxed)) {
            return true;
        }
        if (m_cancel != nullptr && m_cancel->should_stop()) {
            m_stopped.store(true, std::memory_order_relaxed);
            return true;
        }
        return false;
    }

    // Only after should_stop() returned true (m_cancel is then set).
    Status status() const { return stop_status(*m_cancel, "ccd"); }

  private:
    const CancelToken* m_cancel;
    std::atomic<bool> m_stopped{false};
};

// Broad phase, part 1: per-object swept boxes and hierarchies. Returns the largest coordinate
// magnitude at t0 and t1.
double prepare_objects(const Scene& scene, std::span<const std::vector<Vec3>> positions_t1,
                       std::vector<ObjectData>& objects) {
    const auto n = static_cast<std::uint32_t>(objects.size());
    double scale = 0.0;
    for (std::uint32_t i = 0; i < n; ++i) {
        objects[i].object = &scene[i];
        objects[i].p1 = &positions_t1[i];
        for (const auto& p : scene[i].vertices) {
            scale = std::max({scale, std::abs(p.x), std::abs(p.y), std::abs(p.z)});
        }
        for (const auto& p : positions_t1[i]) {
            scale = std::max({scale, std::abs(p.x), std::abs(p.y), std::abs(p.z)});
        }
    }
    return scale;
}

// Object pairs (a < b, sorted) whose swept boxes come within `gap` (sort and sweep along x).
std::vector<std::pair<std::uint32_t, std::uint32_t>> near_object_pairs(
    const std::vector<ObjectData>& objects, double gap) {
    const auto n = static_cast<std::uint32_t>(objects.size());
    std::vector<std::uint32_t> by_x(n);
    std::iota(by_x.begin(), by_x.end(), 0u);
    std::vector<Aabb> swept(n);
    for (std::uint32_t i = 0; i < n; ++i) {
        swept[i] = objects[i].box.swept();
    }
    std::sort(by_x.begin(), by_x.end(), [&](std::uint32_t a, std::uint32_t b) {
        return std::tie(swept[a].lo.x, a) < std::tie(swept[b].lo.x, b);
    });
    std::vector<std::pair<std::uint32_t, std::uint32_t>> object_pairs;
    for (std::uint32_t k = 0; k < n; ++k) {
        const auto& bi = swept[by_x[k]];
        for (auto l = k + 1; l < n; ++l) {
            const auto& bj = swept[by_x[l]];
            if (bj.lo.x - gap > bi.hi.x) {
                // Sorted by lo.x: every later box starts further right, beyond at both frames.
                break;
            }
            if (near(objects[by_x[k]].box, objects[by_x[l]].box, gap)) {
                object_pairs.emplace_back(std::min(by_x[k], by_x[l]), std::max(by_x[k], by_x[l]));
            }
        }
    }
    std::sort(object_pairs.begin(), object_pairs.end());
    return object_pairs;
}

// Broad phase, part 2: the root jobs (each object with itself when `self`, then the object pairs
// whose swept boxes meet), split into jobs over node pairs.
std::vector<Job> broad_phase_jobs(const std::vector<ObjectData>& objects, double gap,
                                  const CcdRequest& request, CcdStats& stats) {
    const auto n = static_cast<std::uint32_t>(objects.size());
    std::vector<Job> roots;
    if (request.self) {
        for (std::uint32_t i = 0; i < n; ++i) {
            roots.push_back({i, 0, i, 0});
        }
    }
    if (request.between_objects) {
        const auto object_pairs = near_object_pairs(objects, gap);
        stats.object_pairs_tested = object_pairs.size();
        for (const auto& [a, b] : object_pairs) {
            roots.push_back({a, 0, b, 0});
        }
    }
    std::vector<Job> jobs;
    for (const auto& r : roots) {
        split_job(objects, gap, r, jobs);
    }
    return jobs;
}

// Broad phase, part 3, and narrow phase, fused: one parallel loop over the jobs; each job
// traverses its node pair, puts every primitive pair through the prefilter as it is found
// (Traversal::emit), then runs the elementary tests on the pairs the prefilter kept. Only one
// job's kept pairs are stored per thread (the rejected ones are never stored), and no thread
// waits for another before the end (earlier, batches of jobs collected their candidates and
// tested them in two parallel loops, with a barrier after each). The hits go to per-thread
// lists, in no particular order.
class FusedRunner {
  public:
    FusedRunner(const std::vector<ObjectData>& objects, double gap, const std::vector<Job>& jobs,
                const CcdRequest& request, Stopper& stopper)
        : m_objects(objects), m_gap(gap), m_jobs(jobs), m_request(request), m_stopper(stopper) {}

    // False when stopped (the caller's stopper then says why). The loop's wall time goes to the
    // broad and the narrow phase in proportion to the CPU time each part took in it.
    bool run(CcdStats& stats) {
        const auto start = Clock::now();
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, m_jobs.size(), 1),
                          [&](const tbb::blocked_range<std::size_t>& range) {
                              auto& local = m_local.local();
                              for (auto j = range.begin(); j < range.end(); ++j) {
                                  if (m_stopper.should_stop()) {
                                      return;
                                  }
                                  run_job(m_jobs[j], local);
                              }
                          });
        if (m_stopper.should_stop()) {
            return false;
        }
        const double wall = seconds_since(start);
        double traversal = 0.0;
        double tests = 0.0;
        for (const auto& local : m_local) {
            stats.candidate_pairs += local.triangle_pairs;
            stats.prefilter_rejects += local.prefilter_rejects;
            stats.elementary_tests += local.tests;
            traversal += local.traversal_seconds;
            tests += local.test_seconds;
        }
        const double share = traversal + tests > 0.0 ? traversal / (traversal + tests) : 1.0;
        stats.broad_phase_seconds += wall * share;
        stats.narrow_phase_seconds += wall * (1.0 - share);
        return true;
    }

    // Every thread's hits, appended to `out`.
    void take_hits(std::vector<CcdPair>& out) {
        for (auto& local : m_local) {
            out.insert(out.end(), local.hits.begin(), local.hits.end());
            local.hits = {};
        }
    }

  private:
    struct Local {
        std::vector<Candidate> kept;  // one job's pairs that passed the prefilter
        std::vector<CcdPair> hits;
        std::uint64_t triangle_pairs = 0;
        std::uint64_t prefilter_rejects = 0;
        std::uint64_t tests = 0;
        double traversal_seconds = 0.0;
        double test_seconds = 0.0;
    };

    void run_job(const Job& job, Local& local) {
        local.kept.clear();
        const auto t0 = Clock::now();
        Traversal trav{m_objects, m_gap, m_request, local.kept};
        trav.run(job);
        const auto t1 = Clock::now();
        local.triangle_pairs += trav.triangle_pairs;
        local.prefilter_rejects += trav.prefilter_rejects;
        for (const auto& c : local.kept) {
            // Before every test: a degenerate test (coplanar faces sweeping through each other)
            // uses its whole work bound, ~2.5 ms in release, and 64 of them overran a frame's
            // deadline by 0.16 s (by seconds under ASan; fuzz_frames). The check costs ~20 ns
            // against a test's >= 100 ns.
            if (m_stopper.should_stop()) {
                break;
            }
            ++local.tests;
            const auto r = elementary(c.kind, points_of(m_objects, c), m_request.elementary);
            if (r.hit) {
                local.hits.push_back(
                    {c.kind, c.object, c.primitive, c.other, c.other_primitive, r.toi, r.capped});
            }
        }
        local.traversal_seconds += std::chrono::duration<double>(t1 - t0).count();
        local.test_seconds += seconds_since(t1);
    }

    const std::vector<ObjectData>& m_objects;
    double m_gap;
    const std::vector<Job>& m_jobs;
    const CcdRequest& m_request;
    Stopper& m_stopper;
    tbb::enumerable_thread_specific<Local> m_local;
};

// Results: sorted pairs, per object pair and overall earliest.
void merge_results(CcdResult& result) {
    std::sort(result.pairs.begin(), result.pairs.end(), [](const CcdPair& x, const CcdPair& y) {
        return std::tie(x.kind, x.object, x.primitive, x.other, x.other_primitive) <
               std::tie(y.kind, y.object, y.primitive, y.other, y.other_primitive);
    });
    std::map<std::pair<std::uint32_t, std::uint32_t>, std::size_t> first;
    for (std::size_t i = 0; i < result.pairs.size(); ++i) {
        const auto& p = result.pairs[i];
        result.stats.capped_tests += p.capped ? 1 : 0;
        const std::pair key{std::min(p.object, p.other), std::max(p.object, p.other)};
        auto [it, inserted] = first.emplace(key, i);
        if (!inserted && p.toi < result.pairs[it->second].toi) {
            it->second = i;
        }
        if (!result.earliest || p.toi < result.pairs[*result.earliest].toi) {
            result.earliest = i;
        }
    }
    for (const auto& [key, i] : first) {
        result.object_pairs.push_back({key.first, key.second, result.pairs[i].toi, i});
    }
}

// Each pair's vertex ids (CcdPair::vertices), from the objects' triangles and edge lists.
void name_vertices(const std::vector<ObjectData>& objects, CcdResult& result) {
    for (auto& p : result.pairs) {
        const auto& a = objects[p.object];
        const auto& b = objects[p.other];
        if (p.kind == CcdKind::vertex_face) {
            p.vertices = {p.primitive, 0, 0};
            const auto& tri = b.object->topology->triangle(p.other_primitive);
            p.other_vertices = {tri[0], tri[1], tri[2]};
        } else {
            p.vertices = {a.edges[p.primitive][0], a.edges[p.primitive][1], 0};
            p.other_vertices = {b.edges[p.other_primitive][0], b.edges[p.other_primitive][1], 0};
        }
    }
}

}  // namespace

std::vector<std::array<std::uint32_t, 2>> mesh_edges(const MeshTopology& topology) {
    std::vector<std::array<std::uint32_t, 2>> edges;
    edges.reserve(3 * topology.triangle_count());
    for (const auto& tri : topology.triangles()) {
        for (int k = 0; k < 3; ++k) {
            const auto a = tri[k];
            const auto b = tri[(k + 1) % 3];
            if (a != b) {
                edges.push_back({std::min(a, b), std::max(a, b)});
            }
        }
    }
    tbb::parallel_sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    return edges;
}

StatusOr<CcdResult> continuous_collisions(const Scene& scene,
                                          std::span<const std::vector<Vec3>> positions_t1,
                                          const CcdRequest& request, const CancelToken* cancel) {
    const auto start = Clock::now();
    if (Status s = validate(scene, positions_t1, request); !s.ok()) {
        return s;
    }
    Stopper stopper(cancel);
    if (stopper.should_stop()) {
        return stopper.status();
    }

    CcdResult result;
    std::vector<ObjectData> objects(scene.size());
    const double scale = prepare_objects(scene, positions_t1, objects);
    const bool tight = request.prefilter && scale <= 0x1p200;
    const double d = request.elementary.min_distance;
    const double gap =
        tight ? (d + request.elementary.tolerance + 0x1p-44 * scale) * (1.0 + 0x1p-40) +
                    0x1p-50 * scale + 0x1p-1000
              : d * (1.0 + 1e-9) + 1e-12 * scale;
    tbb::parallel_for(std::uint32_t{0}, static_cast<std::uint32_t>(scene.size()),
                      [&](std::uint32_t i) { prepare(objects[i], tight); });
    const std::vector<Job> jobs = broad_phase_jobs(objects, gap, request, result.stats);

    result.stats.brute_force_tests = brute_force_count(objects, request);
    result.stats.broad_phase_seconds = seconds_since(start);
    FusedRunner runner(objects, gap, jobs, request, stopper);
    if (!runner.run(result.stats)) {
        return stopper.status();
    }

    const auto merge_start = Clock::now();
    runner.take_hits(result.pairs);
    merge_results(result);
    name_vertices(objects, result);
    result.stats.narrow_phase_seconds += seconds_since(merge_start);
    result.stats.total_seconds = seconds_since(start);
    return result;
}

}  // namespace proxima::ccd
