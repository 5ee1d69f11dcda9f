// Full-frame CCD (seed 000 §3.2, §5.3): swept boxes, one hierarchy per object over its triangles'
// swept boxes, object pairs culled by their swept boxes (sort and sweep, as Stage I), dual
// traversal between objects and self traversal within an object, then the elementary vf / ee
// tests on the distinct primitive pairs whose swept boxes still meet.
//
// Why the culling never drops a pair the elementary test would report (so the result equals
// testing every primitive pair with the same tests), rounding included. A pair that truly touches
// (within d) has its two swept boxes within d of each other, so this covers every contact; the
// point of the argument is that it also covers the elementary tests' conservative false positives.
//
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
// 2. Our boxes. Box corners are exact copies of input coordinates (min / max round nothing),
//    except the fourth parallelogram corner b + c - a, computed with an error below 2 ulp(3 s),
//    where s is the largest coordinate magnitude in the scene (both frames). Two boxes are
//    declared apart only when fl(X.lo - g) > Y.hi on some axis (or the mirror), with
//        g = d (1 + 1e-9) + 1e-12 s      (computed; its own rounding is covered by the margins).
//    fl(X.lo - g) > Y.hi implies X.lo - Y.hi > g - ulp(s + g) > d + 2e + 2 ulp(3 s), since
//    2e <= 2^-46 s < 1.5e-14 s is far below the 1e-12 s margin. So a pair we drop has boxes more
//    than d + 2e apart on some axis: the elementary test would reject it at its root region. Every
//    containment used by the hierarchy (triangle box >= vertex and edge boxes, node box
//    >= children) is exact, so a pair of primitives whose boxes meet is always reached.
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
//    So the result is what testing every primitive pair reports, less such capped pairs.

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
#include <tbb/task_arena.h>

namespace proxima::ccd {

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

constexpr std::uint32_t NONE = ~0u;

// Whether boxes a and b may come within g of each other (see the argument at the top).
inline bool near(const Aabb& a, const Aabb& b, double g) {
    return a.lo.x - g <= b.hi.x && b.lo.x - g <= a.hi.x && a.lo.y - g <= b.hi.y &&
           b.lo.y - g <= a.hi.y && a.lo.z - g <= b.hi.z && b.lo.z - g <= a.hi.z;
}

// A hierarchy over boxes (one per triangle), nodes in depth-first pre-order: the left child of an
// inner node is the next node. Subtree triangles are order[begin, end).
class SweptBvh {
  public:
    struct Node {
        Aabb box;
        std::uint32_t begin = 0;
        std::uint32_t end = 0;
        std::uint32_t right = 0;  // 0 for leaves (node 0 is the root, never a right child)
        bool leaf() const { return right == 0; }
        std::uint32_t size() const { return end - begin; }
    };
    static constexpr std::uint32_t LEAF_SIZE = 4;

    void build(const std::vector<Aabb>& boxes) {
        const auto n = static_cast<std::uint32_t>(boxes.size());
        m_order.resize(n);
        std::iota(m_order.begin(), m_order.end(), 0u);
        m_nodes.clear();
        m_nodes.reserve(2 * ((n + LEAF_SIZE - 1) / LEAF_SIZE) + 1);
        m_centers.resize(n);
        for (std::uint32_t t = 0; t < n; ++t) {
            m_centers[t] = boxes[t].center();
        }
        if (n > 0) {
            build(boxes, 0, n);
        }
        m_centers = {};
    }
    const std::vector<Node>& nodes() const { return m_nodes; }
    const std::vector<std::uint32_t>& order() const { return m_order; }

  private:
    // Median split on the longest axis of the centre bounds; depth is log2(n / LEAF_SIZE).
    std::uint32_t build(const std::vector<Aabb>& boxes, std::uint32_t begin, std::uint32_t end) {
        const auto index = static_cast<std::uint32_t>(m_nodes.size());
        m_nodes.emplace_back();
        Aabb box;
        Aabb cbox;
        for (auto i = begin; i < end; ++i) {
            box.extend(boxes[m_order[i]]);
            cbox.extend(m_centers[m_order[i]]);
        }
        m_nodes[index].box = box;
        m_nodes[index].begin = begin;
        m_nodes[index].end = end;
        if (end - begin <= LEAF_SIZE) {
            return index;
        }
        const Vec3 ext = cbox.extent();
        const int axis = ext.x >= ext.y && ext.x >= ext.z ? 0 : (ext.y >= ext.z ? 1 : 2);
        const auto mid = begin + (end - begin) / 2;
        std::nth_element(m_order.begin() + begin, m_order.begin() + mid, m_order.begin() + end,
                         [&](std::uint32_t a, std::uint32_t b) {
                             return std::tie(m_centers[a][axis], a) <
                                    std::tie(m_centers[b][axis], b);
                         });
        build(boxes, begin, mid);
        const auto right = build(boxes, mid, end);
        m_nodes[index].right = right;
        return index;
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
    std::vector<Aabb> vertex_box;  // swept box of each vertex
    std::vector<Aabb> edge_box;    // swept box of each edge
    std::vector<Aabb> face_box;    // swept box of each triangle's parallelogram
    Aabb box;                      // of all face boxes
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

void prepare(ObjectData& d) {
    const auto& obj = *d.object;
    const auto& topo = *obj.topology;
    const auto& p0 = obj.vertices;
    const auto& p1 = *d.p1;
    const auto nt = static_cast<std::uint32_t>(topo.triangle_count());
    d.edges = mesh_edges(topo);
    d.tri_edges.resize(nt);
    d.owns.assign(nt, 0);
    std::vector<std::uint32_t> edge_owner(d.edges.size(), NONE);
    std::vector<std::uint32_t> vertex_owner(p0.size(), NONE);
    for (std::uint32_t t = 0; t < nt; ++t) {
        const auto& tri = topo.triangle(t);
        for (int k = 0; k < 3; ++k) {
            if (vertex_owner[tri[k]] == NONE) {
                vertex_owner[tri[k]] = t;
                d.owns[t] |= static_cast<std::uint8_t>(1u << k);
            }
            const auto e = edge_index(d.edges, tri[k], tri[(k + 1) % 3]);
            d.tri_edges[t][k] = e;
            if (e != NONE && edge_owner[e] == NONE) {
                edge_owner[e] = t;
                d.owns[t] |= static_cast<std::uint8_t>(8u << k);
            }
        }
    }
    d.vertex_box.resize(p0.size());
    for (std::size_t v = 0; v < p0.size(); ++v) {
        d.vertex_box[v] = {cwise_min(p0[v], p1[v]), cwise_max(p0[v], p1[v])};
    }
    d.edge_box.resize(d.edges.size());
    for (std::size_t e = 0; e < d.edges.size(); ++e) {
        Aabb b = d.vertex_box[d.edges[e][0]];
        b.extend(d.vertex_box[d.edges[e][1]]);
        d.edge_box[e] = b;
    }
    d.face_box.resize(nt);
    d.box = Aabb{};
    for (std::uint32_t t = 0; t < nt; ++t) {
        const auto& tri = topo.triangle(t);
        Aabb b = d.vertex_box[tri[0]];
        b.extend(d.vertex_box[tri[1]]);
        b.extend(d.vertex_box[tri[2]]);
        b.extend(p0[tri[1]] + p0[tri[2]] - p0[tri[0]]);
        b.extend(p1[tri[1]] + p1[tri[2]] - p1[tri[0]]);
        d.face_box[t] = b;
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

struct Traversal {
    const std::vector<ObjectData>& objects;
    double gap;
    std::vector<Candidate>& out;
    std::uint64_t triangle_pairs = 0;

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
                out.push_back({a, tri_a[k], b, tb, CcdKind::vertex_face});
            }
            if ((own_b & (1u << k)) != 0 && near(B.vertex_box[tri_b[k]], A.face_box[ta], gap)) {
                out.push_back({b, tri_b[k], a, ta, CcdKind::vertex_face});
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
                    out.push_back({a, ea, b, eb, CcdKind::edge_edge});
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
                out.push_back({o, tri_t[k], o, u, CcdKind::vertex_face});
            }
            if ((own_u & (1u << k)) != 0 && !corner_of(tri_u[k], tri_t) &&
                near(O.vertex_box[tri_u[k]], O.face_box[t], gap)) {
                out.push_back({o, tri_u[k], o, t, CcdKind::vertex_face});
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
                    out.push_back({o, std::min(e1, e2), o, std::max(e1, e2), CcdKind::edge_edge});
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
constexpr std::uint32_t JOB_TRIANGLES = 1024;

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
    std::sort(by_x.begin(), by_x.end(), [&](std::uint32_t a, std::uint32_t b) {
        return std::tie(objects[a].box.lo.x, a) < std::tie(objects[b].box.lo.x, b);
    });
    std::vector<std::pair<std::uint32_t, std::uint32_t>> object_pairs;
    for (std::uint32_t k = 0; k < n; ++k) {
        const auto& bi = objects[by_x[k]].box;
        for (auto l = k + 1; l < n; ++l) {
            const auto& bj = objects[by_x[l]].box;
            if (bj.lo.x - gap > bi.hi.x) {
                break;  // sorted by lo.x: every later box starts further right
            }
            if (near(bi, bj, gap)) {
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

// Broad phase, part 3, and narrow phase, in batches of jobs so that the candidate lists stay
// small (tens of MB, not one list of every candidate of the frame): each batch collects the
// candidate primitive pairs of its jobs in parallel, then runs their elementary tests in
// parallel. The hits go to per-thread lists, in no particular order.
class BatchRunner {
  public:
    BatchRunner(const std::vector<ObjectData>& objects, double gap, const std::vector<Job>& jobs,
                const CcdRequest& request, Stopper& stopper)
        : m_objects(objects),
          m_gap(gap),
          m_jobs(jobs),
          m_request(request),
          m_stopper(stopper),
          m_batch(std::max<std::size_t>(
              32, 8 * static_cast<std::size_t>(tbb::this_task_arena::max_concurrency()))),
          m_candidates(m_batch),
          m_offsets(m_batch + 1, 0) {}

    // False when stopped (the caller's stopper then says why).
    bool run(CcdStats& stats) {
        for (std::size_t first_job = 0; first_job < m_jobs.size(); first_job += m_batch) {
            const auto t0 = Clock::now();
            const auto count = std::min(m_batch, m_jobs.size() - first_job);
            collect(first_job, count);
            if (m_stopper.should_stop()) {
                return false;
            }
            for (std::size_t j = 0; j < count; ++j) {
                m_offsets[j + 1] = m_offsets[j] + m_candidates[j].size();
            }
            const auto t1 = Clock::now();
            const auto rejected = test(count);
            stats.elementary_tests += m_offsets[count] - rejected;
            stats.prefilter_rejects += rejected;
            if (m_stopper.should_stop()) {
                return false;
            }
            const auto t2 = Clock::now();
            stats.broad_phase_seconds += std::chrono::duration<double>(t1 - t0).count();
            stats.narrow_phase_seconds += std::chrono::duration<double>(t2 - t1).count();
        }
        m_candidates = {};
        stats.candidate_pairs = m_triangle_pairs.load();
        return true;
    }

    tbb::enumerable_thread_specific<std::vector<CcdPair>>& hits() { return m_hits; }

  private:
    // The candidate primitive pairs of jobs [first_job, first_job + count), one list per job.
    void collect(std::size_t first_job, std::size_t count) {
        tbb::parallel_for(std::size_t{0}, count, [&](std::size_t j) {
            m_candidates[j].clear();
            if (m_stopper.should_stop()) {
                return;
            }
            Traversal trav{m_objects, m_gap, m_candidates[j]};
            trav.run(m_jobs[first_job + j]);
            m_triangle_pairs.fetch_add(trav.triangle_pairs, std::memory_order_relaxed);
        });
    }

    // The elementary tests of the candidates of the batch's first `count` jobs, each after the
    // prefilter (point 4 at the top). Returns how many candidates the prefilter rejected.
    std::uint64_t test(std::size_t count) {
        std::atomic<std::uint64_t> rejected{0};
        tbb::parallel_for(
            tbb::blocked_range<std::size_t>(0, m_offsets[count], 64), [&](const auto& range) {
                if (m_stopper.should_stop()) {
                    return;
                }
                auto& local = m_hits.local();
                std::uint64_t filtered = 0;
                struct Flush {  // adds this range's count on every way out
                    std::atomic<std::uint64_t>& total;
                    std::uint64_t& count;
                    ~Flush() { total.fetch_add(count, std::memory_order_relaxed); }
                } flush{rejected, filtered};
                auto job = static_cast<std::size_t>(std::upper_bound(m_offsets.begin(),
                                                                     m_offsets.begin() + count + 1,
                                                                     range.begin()) -
                                                    m_offsets.begin() - 1);
                for (auto i = range.begin(); i < range.end(); ++i) {
                    // Before every test, not once per range: a degenerate test (coplanar faces
                    // sweeping through each other) uses its whole work bound, ~2.5 ms in release,
                    // and 64 of them overran a frame's deadline by 0.16 s (by seconds under ASan;
                    // fuzz_frames). The check costs ~20 ns against a test's >= 100 ns.
                    if (m_stopper.should_stop()) {
                        return;
                    }
                    while (i >= m_offsets[job + 1]) {
                        ++job;
                    }
                    const auto& c = m_candidates[job][i - m_offsets[job]];
                    const auto points = points_of(m_objects, c);
                    if (m_request.prefilter &&
                        elementary_prefilter_rejects(c.kind, points, m_request.elementary)) {
                        ++filtered;
                        continue;
                    }
                    const auto r = elementary(c.kind, points, m_request.elementary);
                    if (r.hit) {
                        local.push_back({c.kind, c.object, c.primitive, c.other, c.other_primitive,
                                         r.toi, r.capped});
                    }
                }
            });
        return rejected.load();
    }

    const std::vector<ObjectData>& m_objects;
    double m_gap;
    const std::vector<Job>& m_jobs;
    const CcdRequest& m_request;
    Stopper& m_stopper;
    std::size_t m_batch;
    tbb::enumerable_thread_specific<std::vector<CcdPair>> m_hits;
    std::vector<std::vector<Candidate>> m_candidates;
    std::vector<std::size_t> m_offsets;
    std::atomic<std::uint64_t> m_triangle_pairs{0};
};

// Results: sorted pairs, per object pair and overall earliest.
void merge_results(tbb::enumerable_thread_specific<std::vector<CcdPair>>& hits, CcdResult& result) {
    for (auto& local : hits) {
        result.pairs.insert(result.pairs.end(), local.begin(), local.end());
    }
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
    std::sort(edges.begin(), edges.end());
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
    const double gap = request.elementary.min_distance * (1.0 + 1e-9) + 1e-12 * scale;
    tbb::parallel_for(std::uint32_t{0}, static_cast<std::uint32_t>(scene.size()),
                      [&](std::uint32_t i) { prepare(objects[i]); });
    const std::vector<Job> jobs = broad_phase_jobs(objects, gap, request, result.stats);

    result.stats.brute_force_tests = brute_force_count(objects, request);
    result.stats.broad_phase_seconds = seconds_since(start);
    BatchRunner runner(objects, gap, jobs, request, stopper);
    if (!runner.run(result.stats)) {
        return stopper.status();
    }

    const auto merge_start = Clock::now();
    merge_results(runner.hits(), result);
    name_vertices(objects, result);
    result.stats.narrow_phase_seconds += seconds_since(merge_start);
    result.stats.total_seconds = seconds_since(start);
    return result;
}

}  // namespace proxima::ccd
