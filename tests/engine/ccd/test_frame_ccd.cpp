// Full-frame CCD (proxima/ccd/frame_ccd.hpp): known contacts (a vertex dropping through a plane,
// two crossing edges, a self-folding sheet), adjacency exclusion, minimum distance, invalid input
// and cancellation, and the culling against brute force: every vf / ee pair of a scene (small
// scenes) or of subsampled regions of the real frame pairs, tested with the same elementary
// tests and no culling, must be in the result with the same time of impact.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <map>
#include <numeric>
#include <random>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include "proxima/ccd/elementary.hpp"
#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/io/mesh_io.hpp"
#include "proxima/mesh/mesh.hpp"
#include "proxima/scene.hpp"
#include "proxima/scenes/procedural.hpp"

namespace proxima::ccd {
namespace {

namespace fs = std::filesystem;

using Frame = std::vector<std::vector<Vec3>>;
using Key = std::tuple<int, std::uint32_t, std::uint32_t, std::uint32_t, std::uint32_t>;

Key key_of(const CcdPair& p) {
    return {static_cast<int>(p.kind), p.object, p.primitive, p.other, p.other_primitive};
}

Scene make_scene(const std::vector<TriangleMesh>& meshes) {
    Scene scene;
    for (std::size_t i = 0; i < meshes.size(); ++i) {
        auto id = scene.add_object({"object" + std::to_string(i), meshes[i]});
        EXPECT_TRUE(id.ok()) << id.status().to_string();
    }
    return scene;
}

// A flat n x m grid of squares (two triangles each) at height z over [x0, x0 + n h] x [y0, y0 +
// m h].
TriangleMesh grid(int n, int m, double h, double x0, double y0, double z) {
    TriangleMesh mesh;
    for (int j = 0; j <= m; ++j) {
        for (int i = 0; i <= n; ++i) {
            mesh.vertices.push_back({x0 + i * h, y0 + j * h, z});
        }
    }
    auto at = [&](int i, int j) { return static_cast<std::uint32_t>(j * (n + 1) + i); };
    for (int j = 0; j < m; ++j) {
        for (int i = 0; i < n; ++i) {
            mesh.triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
            mesh.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
        }
    }
    return mesh;
}

Frame positions_of(const Scene& scene) {
    Frame f;
    for (const auto& o : scene.objects()) {
        f.push_back(o.vertices);
    }
    return f;
}

// The primitives of one object that a brute-force check covers (all of them, or a region).
struct Subset {
    std::vector<std::uint32_t> vertices;  // used by some triangle
    std::vector<std::uint32_t> triangles;
    std::vector<std::uint32_t> edges;  // indices in mesh_edges
};

Subset everything(const SceneObject& obj) {
    Subset s;
    const auto& topo = *obj.topology;
    for (std::uint32_t v = 0; v < topo.vertex_count(); ++v) {
        if (!topo.vertex_triangles(v).empty()) {
            s.vertices.push_back(v);
        }
    }
    s.triangles.resize(topo.triangle_count());
    std::iota(s.triangles.begin(), s.triangles.end(), 0u);
    s.edges.resize(mesh_edges(topo).size());
    std::iota(s.edges.begin(), s.edges.end(), 0u);
    return s;
}

constexpr CcdKind VF_KIND = CcdKind::vertex_face;
constexpr CcdKind EE_KIND = CcdKind::edge_edge;

// The per-frame box test of continuous_collisions with the prefilter on (point 2' in
// frame_ccd.cpp): the points of the first primitive (pts[0, n) at t = 0, pts[4, 4 + n) at t = 1)
// lie beyond those of the second by more than `gap` on one axis, on the same side at both frames.
// `gap` is the engine's: (d + tol + 2^-44 s)(1 + 2^-40) + 2^-50 s + 2^-1000, s the largest
// |coordinate| of the scene at both frames.
bool apart_at_both_frames(CcdKind kind, const CcdPoints& pts, double gap) {
    const int n = kind == CcdKind::vertex_face ? 1 : 2;
    for (int k = 0; k < 3; ++k) {
        bool below[2];
        bool above[2];
        for (int end = 0; end < 2; ++end) {
            const auto* q = pts.data() + std::ptrdiff_t{4} * end;
            double lo1 = q[0][k];
            double hi1 = q[0][k];
            double lo2 = q[n][k];
            double hi2 = q[n][k];
            for (int j = 0; j < 4; ++j) {
                auto& lo = j < n ? lo1 : lo2;
                auto& hi = j < n ? hi1 : hi2;
                lo = std::min(lo, q[j][k]);
                hi = std::max(hi, q[j][k]);
            }
            above[end] = lo1 - gap > hi2;
            below[end] = lo2 - gap > hi1;
        }
        if ((above[0] && above[1]) || (below[0] && below[1])) {
            return true;
        }
    }
    return false;
}

double culling_gap(const Scene& scene, const Frame& p1, const ElementaryOptions& options) {
    double s = 0.0;
    for (std::size_t i = 0; i < scene.size(); ++i) {
        for (const auto* points : {&scene[i].vertices, &p1[i]}) {
            for (const auto& p : *points) {
                s = std::max({s, std::abs(p.x), std::abs(p.y), std::abs(p.z)});
            }
        }
    }
    return (options.min_distance + options.tolerance + 0x1p-44 * s) * (1.0 + 0x1p-40) +
           0x1p-50 * s + 0x1p-1000;
}

// A capped hit (the work bound reached, no decision) on a pair that provably never comes within
// min_distance + tolerance: continuous_collisions does not report it (the per-frame boxes or the
// prefilter drop it before testing), and a larger work bound would reject it (CcdPrefilterVsBrute
// checks the prefilter's half). An uncapped hit is never dropped: neither ever rejects one (checked
// here on every brute-force hit).
bool dropped_by_culling(CcdKind kind, const CcdPoints& pts, const ElementaryResult& r,
                        const ElementaryOptions& options, double gap) {
    const bool apart = apart_at_both_frames(kind, pts, gap);
    EXPECT_TRUE(!apart || r.capped) << "an uncapped hit whose boxes are apart at both frames";
    return r.capped && (apart || elementary_prefilter_rejects(kind, pts, options));
}

// Every vf and ee pair among the subsets, with the same conventions as continuous_collisions
// (point order, adjacency exclusion within an object, ee with object <= other and primitive <
// other_primitive within an object), tested with no culling at all. Sorted like the result.
std::vector<CcdPair> brute_force(const Scene& scene, const Frame& p1,
                                 const std::vector<Subset>& subsets,
                                 const ElementaryOptions& options, bool prefilter = true) {
    const auto n = static_cast<std::uint32_t>(scene.size());
    std::vector<std::vector<std::array<std::uint32_t, 2>>> edges(n);
    for (std::uint32_t i = 0; i < n; ++i) {
        edges[i] = mesh_edges(*scene[i].topology);
    }
    // Work items: (object, other) ordered pairs for vf, unordered for ee.
    std::vector<std::pair<std::uint32_t, std::uint32_t>> items;
    for (std::uint32_t a = 0; a < n; ++a) {
        for (std::uint32_t b = 0; b < n; ++b) {
            items.emplace_back(a, b);
        }
    }
    const double gap = culling_gap(scene, p1, options);
    std::vector<std::vector<CcdPair>> found(items.size());
    tbb::parallel_for(std::size_t{0}, items.size(), [&](std::size_t k) {
        const auto [a, b] = items[k];
        const auto& A = scene[a];
        const auto& B = scene[b];
        auto& out = found[k];
        for (auto v : subsets[a].vertices) {
            for (auto f : subsets[b].triangles) {
                const auto& tri = B.triangle(f);
                if (a == b && (v == tri[0] || v == tri[1] || v == tri[2])) {
                    continue;
                }
                const CcdPoints pts{A.vertices[v],      B.vertices[tri[0]], B.vertices[tri[1]],
                                    B.vertices[tri[2]], p1[a][v],           p1[b][tri[0]],
                                    p1[b][tri[1]],      p1[b][tri[2]]};
                const auto r = vertex_face(pts, options);
                if (r.hit && !(prefilter && dropped_by_culling(VF_KIND, pts, r, options, gap))) {
                    out.push_back({CcdKind::vertex_face, a, v, b, f, r.toi, r.capped});
                }
            }
        }
        if (a > b) {
            return;
        }
        for (auto e1 : subsets[a].edges) {
            for (auto e2 : subsets[b].edges) {
                const auto& x = edges[a][e1];
                const auto& y = edges[b][e2];
                if (a == b &&
                    (e1 >= e2 || x[0] == y[0] || x[0] == y[1] || x[1] == y[0] || x[1] == y[1])) {
                    continue;
                }
                const CcdPoints pts{A.vertices[x[0]], A.vertices[x[1]], B.vertices[y[0]],
                                    B.vertices[y[1]], p1[a][x[0]],      p1[a][x[1]],
                                    p1[b][y[0]],      p1[b][y[1]]};
                const auto r = edge_edge(pts, options);
                if (r.hit && !(prefilter && dropped_by_culling(EE_KIND, pts, r, options, gap))) {
                    out.push_back({CcdKind::edge_edge, a, e1, b, e2, r.toi, r.capped});
                }
            }
        }
    });
    std::vector<CcdPair> all;
    for (auto& f : found) {
        all.insert(all.end(), f.begin(), f.end());
    }
    std::sort(all.begin(), all.end(),
              [](const CcdPair& x, const CcdPair& y) { return key_of(x) < key_of(y); });
    return all;
}

std::vector<CcdPair> brute_force_all(const Scene& scene, const Frame& p1,
                                     const ElementaryOptions& options, bool prefilter = true) {
    std::vector<Subset> subsets;
    for (const auto& o : scene.objects()) {
        subsets.push_back(everything(o));
    }
    return brute_force(scene, p1, subsets, options, prefilter);
}

// The result must hold every brute-force hit with the same toi and capped flag.
void expect_contains(const CcdResult& result, const std::vector<CcdPair>& expected,
                     const std::string& what) {
    std::size_t missing = 0;
    for (const auto& e : expected) {
        auto it = std::lower_bound(
            result.pairs.begin(), result.pairs.end(), e,
            [](const CcdPair& x, const CcdPair& y) { return key_of(x) < key_of(y); });
        if (it == result.pairs.end() || key_of(*it) != key_of(e)) {
            if (++missing <= 5) {
                ADD_FAILURE() << what << ": missed " << ccd_kind_name(e.kind) << " object "
                              << e.object << " primitive " << e.primitive << " other " << e.other
                              << " primitive " << e.other_primitive << " toi " << e.toi;
            }
            continue;
        }
        EXPECT_EQ(it->toi, e.toi) << what;
        EXPECT_EQ(it->capped, e.capped) << what;
    }
    EXPECT_EQ(missing, 0u) << what << ": " << missing << " of " << expected.size()
                           << " brute-force pairs missing";
}

void expect_equal(const CcdResult& result, const std::vector<CcdPair>& expected,
                  const std::string& what) {
    EXPECT_EQ(result.pairs.size(), expected.size()) << what;
    expect_contains(result, expected, what);
}

// The summary fields follow from the pairs.
void expect_consistent(const CcdResult& r) {
    ASSERT_TRUE(
        std::is_sorted(r.pairs.begin(), r.pairs.end(),
                       [](const CcdPair& x, const CcdPair& y) { return key_of(x) < key_of(y); }));
    std::map<std::pair<std::uint32_t, std::uint32_t>, double> best;
    double earliest = 2.0;
    for (const auto& p : r.pairs) {
        EXPECT_GE(p.toi, 0.0);
        EXPECT_LE(p.toi, 1.0);
        const std::pair k{std::min(p.object, p.other), std::max(p.object, p.other)};
        auto [it, inserted] = best.emplace(k, p.toi);
        if (!inserted) {
            it->second = std::min(it->second, p.toi);
        }
        earliest = std::min(earliest, p.toi);
    }
    ASSERT_EQ(r.object_pairs.size(), best.size());
    std::size_t i = 0;
    for (const auto& [k, toi] : best) {
        EXPECT_EQ(r.object_pairs[i].object, k.first);
        EXPECT_EQ(r.object_pairs[i].other, k.second);
        EXPECT_EQ(r.object_pairs[i].toi, toi);
        ASSERT_LT(r.object_pairs[i].pair, r.pairs.size());
        EXPECT_EQ(r.pairs[r.object_pairs[i].pair].toi, toi);
        ++i;
    }
    if (r.pairs.empty()) {
        EXPECT_FALSE(r.earliest.has_value());
    } else {
        ASSERT_TRUE(r.earliest.has_value());
        EXPECT_EQ(r.pairs[*r.earliest].toi, earliest);
    }
    EXPECT_LE(r.stats.elementary_tests, r.stats.brute_force_tests);
}

CcdResult run_ccd(const Scene& scene, const Frame& p1, const CcdRequest& request = {}) {
    auto r = continuous_collisions(scene, p1, request);
    EXPECT_TRUE(r.ok()) << r.status().to_string();
    if (!r.ok()) {
        return {};
    }
    expect_consistent(r.value());
    return std::move(r).value();
}

constexpr double TOL = 1e-6;  // the default elementary tolerance

// ---------------------------------------------------------------------------------------------

TEST(FrameCcd, MeshEdgesAreUniqueSortedAndSkipPointSides) {
    const MeshTopology quad({{0, 1, 2}, {2, 1, 3}}, 4);
    const auto e = mesh_edges(quad);
    const std::vector<std::array<std::uint32_t, 2>> expected{
        {0, 1}, {0, 2}, {1, 2}, {1, 3}, {2, 3}};
    EXPECT_EQ(e, expected);
    // A triangle listing vertex 0 twice is the segment 0-1: one edge, no (0, 0).
    const MeshTopology degenerate({{0, 0, 1}}, 2);
    const std::vector<std::array<std::uint32_t, 2>> one{{0, 1}};
    EXPECT_EQ(mesh_edges(degenerate), one);
}

TEST(FrameCcd, VertexDroppingThroughAPlane) {
    // Object 0: a static 4 x 4 plane at z = 0; object 1: a small triangle falling from z = 1 to
    // z = -1, every vertex crossing the plane at t = 0.5 inside it.
    auto plane = grid(4, 4, 1.0, 0.0, 0.0, 0.0);
    TriangleMesh tri;
    tri.vertices = {{1.3, 1.2, 1.0}, {2.4, 1.7, 1.0}, {1.6, 2.8, 1.0}};
    tri.triangles = {{0, 1, 2}};
    const Scene scene = make_scene({plane, tri});
    Frame p1 = positions_of(scene);
    for (auto& v : p1[1]) {
        v.z = -1.0;
    }
    const auto r = run_ccd(scene, p1);
    ASSERT_TRUE(r.earliest.has_value());
    EXPECT_LE(r.pairs[*r.earliest].toi, 0.5);
    EXPECT_GE(r.pairs[*r.earliest].toi, 0.5 - TOL);
    // Each falling vertex hits the plane triangle below it at t = 0.5.
    for (std::uint32_t v = 0; v < 3; ++v) {
        const auto& p = tri.vertices[v];
        bool found = false;
        for (const auto& c : r.pairs) {
            if (c.kind == CcdKind::vertex_face && c.object == 1 && c.primitive == v &&
                c.other == 0) {
                found = true;
                EXPECT_LE(c.toi, 0.5);
                EXPECT_GE(c.toi, 0.5 - TOL);
                // The triangle's xy-box contains the vertex's xy position.
                const auto& f = scene[0].triangle(c.other_primitive);
                const auto box =
                    triangle_box(plane.vertices[f[0]], plane.vertices[f[1]], plane.vertices[f[2]]);
                EXPECT_LE(box.lo.x, p.x);
                EXPECT_GE(box.hi.x, p.x);
            }
        }
        EXPECT_TRUE(found) << "vertex " << v;
    }
    ASSERT_EQ(r.object_pairs.size(), 1u);
    EXPECT_EQ(r.object_pairs[0].object, 0u);
    EXPECT_EQ(r.object_pairs[0].other, 1u);
    expect_equal(r, brute_force_all(scene, p1, {}), "vertex through plane");

    // Without between-object pairs nothing is left (both objects are flat and rigid).
    CcdRequest self_only;
    self_only.between_objects = false;
    EXPECT_TRUE(run_ccd(scene, p1, self_only).pairs.empty());
}

TEST(FrameCcd, TwoCrossingEdges) {
    // Object 0: a static triangle in the plane y = 0 hanging below its top edge (0,0,0)-(1,0,0).
    // Object 1: a triangle in the plane x = 0.5 standing on its bottom edge, which runs along y
    // at height 0.5 and moves down to -0.5: the two edges cross at (0.5, 0, 0) at t = 0.5, and
    // nothing else ever touches.
    TriangleMesh a;
    a.vertices = {{0.0, 0.0, 0.0}, {1.0, 0.0, 0.0}, {0.5, 0.0, -1.0}};
    a.triangles = {{0, 1, 2}};
    TriangleMesh b;
    b.vertices = {{0.5, -0.5, 0.5}, {0.5, 0.5, 0.5}, {0.5, 0.0, 1.5}};
    b.triangles = {{0, 1, 2}};
    const Scene scene = make_scene({a, b});
    Frame p1 = positions_of(scene);
    for (auto& v : p1[1]) {
        v.z -= 1.0;
    }
    const auto r = run_ccd(scene, p1);
    ASSERT_EQ(r.pairs.size(), 1u);
    const auto& c = r.pairs[0];
    EXPECT_EQ(c.kind, CcdKind::edge_edge);
    const auto ea = mesh_edges(*scene[0].topology);
    const auto eb = mesh_edges(*scene[1].topology);
    EXPECT_EQ(c.object, 0u);
    EXPECT_EQ(c.other, 1u);
    EXPECT_EQ(ea[c.primitive], (std::array<std::uint32_t, 2>{0, 1}));
    EXPECT_EQ(eb[c.other_primitive], (std::array<std::uint32_t, 2>{0, 1}));
    EXPECT_LE(c.toi, 0.5);
    EXPECT_GE(c.toi, 0.5 - TOL);
    expect_equal(r, brute_force_all(scene, p1, {}), "crossing edges");
}

// One object folded like a U: a lower layer at z = 0, a step at x = 3, an upper layer at z = 1
// back over it. The upper layer's vertices with x <= 2 drop to z = -1: they pass through
// the lower layer at t = 0.5.
struct Fold {
    TriangleMesh mesh;
    std::vector<Vec3> p1;
};
Fold folded_sheet() {
    std::vector<std::pair<double, double>> path;  // (x, z) along the sheet
    for (int i = 0; i <= 6; ++i) {
        path.emplace_back(0.5 * i, 0.0);
    }
    for (int i = 6; i >= 0; --i) {
        path.emplace_back(0.5 * i, 1.0);
    }
    const int rows = 3;
    Fold f;
    const auto cols = static_cast<std::uint32_t>(path.size());
    for (int j = 0; j < rows; ++j) {
        for (const auto& [x, z] : path) {
            // The upper layer is shifted a little in x and y so that no vertex or edge of it meets
            // one of the lower layer exactly (generic contacts).
            const Vec3 p{z == 1.0 ? x + 0.07 : x, z == 1.0 ? 0.5 * j + 0.11 : 0.5 * j, z};
            f.mesh.vertices.push_back(p);
            f.p1.push_back({p.x, p.y, (z == 1.0 && x <= 2.0) ? -1.0 : z});
        }
    }
    for (std::uint32_t j = 0; j + 1 < rows; ++j) {
        for (std::uint32_t i = 0; i + 1 < cols; ++i) {
            const auto a = j * cols + i;
            const auto b = a + 1;
            const auto c = a + cols;
            const auto d = c + 1;
            f.mesh.triangles.push_back({a, b, d});
            f.mesh.triangles.push_back({a, d, c});
        }
    }
    return f;
}

TEST(FrameCcd, SelfFoldingSheet) {
    const auto fold = folded_sheet();
    const Scene scene = make_scene({fold.mesh});
    const Frame p1{fold.p1};
    const auto r = run_ccd(scene, p1);
    ASSERT_TRUE(r.earliest.has_value());
    EXPECT_LE(r.pairs[*r.earliest].toi, 0.5);
    EXPECT_GE(r.pairs[*r.earliest].toi, 0.5 - TOL);
    ASSERT_EQ(r.object_pairs.size(), 1u);
    EXPECT_EQ(r.object_pairs[0].object, 0u);
    EXPECT_EQ(r.object_pairs[0].other, 0u);
    // Every dropping vertex above the lower layer ([0, 3] x [0, 1]) meets it no later than 0.5.
    for (std::uint32_t v = 0; v < fold.mesh.vertices.size(); ++v) {
        const auto& p = fold.mesh.vertices[v];
        if (fold.p1[v] == p || p.y > 1.0) {
            continue;
        }
        double toi = 2.0;
        for (const auto& c : r.pairs) {
            if (c.kind == CcdKind::vertex_face && c.primitive == v) {
                toi = std::min(toi, c.toi);
            }
        }
        EXPECT_LE(toi, 0.5) << "vertex " << v;
    }
    // No reported pair is adjacent.
    const auto edges = mesh_edges(*scene[0].topology);
    for (const auto& c : r.pairs) {
        if (c.kind == CcdKind::vertex_face) {
            const auto& tri = scene[0].triangle(c.other_primitive);
            EXPECT_TRUE(c.primitive != tri[0] && c.primitive != tri[1] && c.primitive != tri[2]);
        } else {
            const auto& x = edges[c.primitive];
            const auto& y = edges[c.other_primitive];
            EXPECT_LT(c.primitive, c.other_primitive);
            EXPECT_TRUE(x[0] != y[0] && x[0] != y[1] && x[1] != y[0] && x[1] != y[1]);
        }
    }
    expect_equal(r, brute_force_all(scene, p1, {}), "folded sheet");

    // Self pairs only come with `self`.
    CcdRequest between_only;
    between_only.self = false;
    EXPECT_TRUE(run_ccd(scene, p1, between_only).pairs.empty());
}

TEST(FrameCcd, AdjacentPrimitivesAreExcludedWithinAnObjectOnly) {
    // A static flat sheet: adjacent primitives touch all the time, non-adjacent ones never.
    const auto sheet = grid(6, 5, 1.0, 0.0, 0.0, 0.0);
    const Scene one = make_scene({sheet});
    const auto r = run_ccd(one, positions_of(one));
    EXPECT_TRUE(r.pairs.empty()) << r.pairs.size() << " pairs in a static flat sheet";
    EXPECT_GT(r.stats.elementary_tests, 0u);  // neighbours across an edge were tested

    // Two coincident copies as two objects: nothing is excluded between objects, so every vertex
    // touches every triangle of the other copy that has it as a corner, at t = 0.
    const Scene two = make_scene({sheet, sheet});
    const auto p1 = positions_of(two);
    const auto r2 = run_ccd(two, p1);
    for (std::uint32_t f = 0; f < sheet.triangles.size(); ++f) {
        for (auto v : sheet.triangles[f]) {
            const CcdPair probe{CcdKind::vertex_face, 1, v, 0, f, 0.0, false};
            auto it = std::lower_bound(
                r2.pairs.begin(), r2.pairs.end(), probe,
                [](const CcdPair& x, const CcdPair& y) { return key_of(x) < key_of(y); });
            ASSERT_TRUE(it != r2.pairs.end() && key_of(*it) == key_of(probe))
                << "vertex " << v << " of the copy vs triangle " << f;
            EXPECT_EQ(it->toi, 0.0);
        }
    }
    expect_equal(r2, brute_force_all(two, p1, {}), "coincident copies");

    // A hinge: the free corner of the second triangle swings through the first one (not
    // adjacent to it: it is not its corner); every other pair is adjacent.
    TriangleMesh hinge;
    hinge.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0.2}};
    hinge.triangles = {{0, 1, 2}, {1, 3, 2}};
    const Scene h = make_scene({hinge});
    Frame hp1 = positions_of(h);
    hp1[0][3] = {0.1, 0.1, -0.02};
    const auto rh = run_ccd(h, hp1);
    ASSERT_FALSE(rh.pairs.empty());
    for (const auto& c : rh.pairs) {
        EXPECT_EQ(c.kind, CcdKind::vertex_face);
        EXPECT_EQ(c.primitive, 3u);
        EXPECT_EQ(c.other_primitive, 0u);
    }
    expect_equal(rh, brute_force_all(h, hp1, {}), "hinge");
}

TEST(FrameCcd, MinimumDistance) {
    // A vertex hovering 0.1 above a plane, static: a contact only when min_distance >= 0.1.
    auto plane = grid(2, 2, 1.0, 0.0, 0.0, 0.0);
    TriangleMesh tri;
    tri.vertices = {{0.5, 0.5, 0.1}, {1.5, 0.6, 0.5}, {0.7, 1.5, 0.5}};
    tri.triangles = {{0, 1, 2}};
    const Scene scene = make_scene({plane, tri});
    const auto p1 = positions_of(scene);
    EXPECT_TRUE(run_ccd(scene, p1).pairs.empty());
    CcdRequest req;
    req.elementary.min_distance = 0.15;
    const auto r = run_ccd(scene, p1, req);
    ASSERT_TRUE(r.earliest.has_value());
    EXPECT_EQ(r.pairs[*r.earliest].toi, 0.0);
    expect_equal(r, brute_force_all(scene, p1, req.elementary), "min distance");
    // Far below the distance: still nothing.
    req.elementary.min_distance = 0.05;
    EXPECT_TRUE(run_ccd(scene, p1, req).pairs.empty());
}

TEST(FrameCcd, InvalidInputAndCancellation) {
    const auto sheet = grid(2, 2, 1.0, 0.0, 0.0, 0.0);
    const Scene scene = make_scene({sheet, sheet});
    const auto p1 = positions_of(scene);
    auto expect_invalid = [&](const Frame& f, const CcdRequest& req, const std::string& fragment) {
        auto r = continuous_collisions(scene, f, req);
        ASSERT_FALSE(r.ok()) << fragment;
        EXPECT_EQ(r.status().code(), StatusCode::invalid_argument);
        EXPECT_NE(r.status().message().find(fragment), std::string::npos)
            << "expected '" << fragment << "' in: " << r.status().to_string();
    };
    expect_invalid(Frame{p1[0]}, {}, "1 position sets at t = 1 for 2 objects");
    Frame short_frame = p1;
    short_frame[1].pop_back();
    expect_invalid(short_frame, {}, "object 1");
    Frame nan_frame = p1;
    nan_frame[0][3].y = std::nan("");
    expect_invalid(nan_frame, {}, "object 0");
    Frame inf_frame = p1;
    inf_frame[1][0].z = std::numeric_limits<double>::infinity();
    expect_invalid(inf_frame, {}, "object 1");
    CcdRequest negative;
    negative.elementary.min_distance = -1.0;
    expect_invalid(p1, negative, "min_distance");
    CcdRequest nan_distance;
    nan_distance.elementary.min_distance = std::nan("");
    expect_invalid(p1, nan_distance, "min_distance");
    CcdRequest zero_tolerance;
    zero_tolerance.elementary.tolerance = 0.0;
    expect_invalid(p1, zero_tolerance, "tolerance");
    CcdRequest no_boxes;
    no_boxes.elementary.max_boxes = 0;
    expect_invalid(p1, no_boxes, "max_boxes");

    CancelToken cancelled;
    cancelled.cancel();
    auto c = continuous_collisions(scene, p1, {}, &cancelled);
    ASSERT_FALSE(c.ok());
    EXPECT_EQ(c.status().code(), StatusCode::cancelled);
    CancelToken late;
    late.set_deadline(std::chrono::steady_clock::now() - std::chrono::seconds(1));
    auto d = continuous_collisions(scene, p1, {}, &late);
    ASSERT_FALSE(d.ok());
    EXPECT_EQ(d.status().code(), StatusCode::deadline_exceeded);
}

TEST(FrameCcd, ProceduralScenesEqualBruteForce) {
    // The smallest procedural scene, two consecutive frames, every primitive pair brute-forced
    // (with a minimum distance, so that many pairs are reported). Also: the same answer with one
    // thread.
    auto ps = scenes::bowl(3);
    Scene scene;
    for (const auto& m : ps.initial) {
        ASSERT_TRUE(scene.add_object(m).ok());
    }
    ASSERT_TRUE(scene.apply(ps.step(1, scene)).ok());
    Scene next = scene;
    ASSERT_TRUE(next.apply(ps.step(2, next)).ok());
    const auto p1 = positions_of(next);
    double size = 0.0;
    for (const auto& o : scene.objects()) {
        size = std::max(size, norm(o.box.extent()));
    }
    // Without a minimum distance the two frames hold no contact (brute force agrees; not repeated
    // here to keep the test short); with 1% of the largest object's size, tens of thousands.
    EXPECT_TRUE(run_ccd(scene, p1).pairs.empty());
    CcdRequest req;
    req.elementary.min_distance = 0.01 * size;
    const auto r = run_ccd(scene, p1, req);
    const auto brute = brute_force_all(scene, p1, req.elementary);
    std::printf("bowl, min_distance %g: %zu pairs, %llu elementary tests of %llu\n",
                req.elementary.min_distance, brute.size(),
                static_cast<unsigned long long>(r.stats.elementary_tests),
                static_cast<unsigned long long>(r.stats.brute_force_tests));
    EXPECT_GT(brute.size(), 1000u) << "the check needs contacts to mean something";
    expect_equal(r, brute, "bowl");
    // Without the prefilter the boxes are the swept boxes of the triangles' parallelograms (point 1
    // at the top of frame_ccd.cpp): every hit of every pair, capped ones included.
    CcdRequest unfiltered = req;
    unfiltered.prefilter = false;
    const auto r_unfiltered = run_ccd(scene, p1, unfiltered);
    EXPECT_GT(r_unfiltered.stats.candidate_pairs, r.stats.candidate_pairs);
    expect_equal(r_unfiltered, brute_force_all(scene, p1, req.elementary, false),
                 "bowl unfiltered");
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    const auto serial = run_ccd(scene, p1, req);
    ASSERT_EQ(serial.pairs.size(), r.pairs.size());
    for (std::size_t i = 0; i < r.pairs.size(); ++i) {
        EXPECT_EQ(key_of(serial.pairs[i]), key_of(r.pairs[i]));
        EXPECT_EQ(serial.pairs[i].toi, r.pairs[i].toi);
    }
}

// ---------------------------------------------------------------------------------------------
// Real frame pairs

std::string data_dir() {
    std::string dir = PROXIMA_DATA_DIR;
    std::error_code ec;
    if (dir.empty() || !fs::is_directory(dir + "/frames", ec)) {
        return {};
    }
    return dir;
}

constexpr const char* NO_DATA = "shared data folder not found (PROXIMA_DATA_DIR='" PROXIMA_DATA_DIR
                                "'): the real-frame CCD tests need ../shared/data/frames";

struct FramePair {
    const char* name;
    const char* t0;
    const char* t1;
};
constexpr std::array<FramePair, 5> FRAME_PAIRS{{
    {"armadillo-rollers", "armadillo-rollers/326.ply", "armadillo-rollers/327.ply"},
    {"cloth-ball", "cloth-ball/cloth_ball92.ply", "cloth-ball/cloth_ball93.ply"},
    {"cloth-funnel", "cloth-funnel/227.ply", "cloth-funnel/228.ply"},
    {"n-body-simulation", "n-body-simulation/balls16_18.ply", "n-body-simulation/balls16_19.ply"},
    {"rod-twist", "rod-twist/3036.ply", "rod-twist/3037.ply"},
}};

// Reads both frames without welding (the file's connectivity is the simulation's), checks they
// share their topology, and splits them into objects by the connected components of t0.
bool load_frames(const std::string& dir, const FramePair& fp, Scene& scene, Frame& p1) {
    MeshReadOptions raw;
    raw.weld = WeldMode::never;
    auto m0 = read_mesh(dir + "/frames/" + fp.t0, raw);
    auto m1 = read_mesh(dir + "/frames/" + fp.t1, raw);
    EXPECT_TRUE(m0.ok()) << m0.status().to_string();
    EXPECT_TRUE(m1.ok()) << m1.status().to_string();
    if (!m0.ok() || !m1.ok()) {
        return false;
    }
    EXPECT_EQ(m0->triangles, m1->triangles) << fp.name;
    EXPECT_EQ(m0->vertices.size(), m1->vertices.size()) << fp.name;
    if (m0->triangles != m1->triangles || m0->vertices.size() != m1->vertices.size()) {
        return false;
    }
    auto split = split_components(m0.value());
    for (std::size_t c = 0; c < split.meshes.size(); ++c) {
        EXPECT_TRUE(scene.add_object({fp.name, split.meshes[c]}).ok());
        std::vector<Vec3> v;
        v.reserve(split.vertex_ids[c].size());
        for (auto id : split.vertex_ids[c]) {
            v.push_back(m1->vertices[id]);
        }
        p1.push_back(std::move(v));
    }
    return true;
}

Aabb swept(const Vec3& a, const Vec3& b) {
    return {cwise_min(a, b), cwise_max(a, b)};
}

// Largest per-axis gap between two boxes (0 when they meet).
double linf_gap(const Aabb& a, const Aabb& b) {
    double g = 0.0;
    for (int k = 0; k < 3; ++k) {
        g = std::max({g, a.lo[k] - b.hi[k], b.lo[k] - a.hi[k]});
    }
    return g;
}

Aabb triangle_sweep(const SceneObject& o, const std::vector<Vec3>& p1, std::uint32_t t) {
    Aabb b;
    for (auto v : o.triangle(t)) {
        b.extend(swept(o.vertices[v], p1[v]));
    }
    return b;
}

// The seed's box grown so that about n triangles' swept boxes meet it.
Aabb grown_to(const Scene& scene, const Frame& p1, const Aabb& seed, std::size_t n) {
    std::vector<double> gaps;
    for (std::size_t i = 0; i < scene.size(); ++i) {
        for (std::uint32_t t = 0; t < scene[i].triangle_count(); ++t) {
            gaps.push_back(linf_gap(seed, triangle_sweep(scene[i], p1[i], t)));
        }
    }
    n = std::min(n, gaps.size());
    std::nth_element(gaps.begin(), gaps.begin() + static_cast<std::ptrdiff_t>(n - 1), gaps.end());
    return seed.grown(gaps[n - 1]);
}

Aabb vertex_sweep(const Scene& scene, const Frame& p1, std::uint32_t object, std::uint32_t v) {
    return swept(scene[object].vertices[v], p1[object][v]);
}

// The primitives whose swept boxes meet one of the boxes.
std::vector<Subset> region(const Scene& scene, const Frame& p1, const std::vector<Aabb>& boxes) {
    std::vector<Subset> out(scene.size());
    auto in = [&](const Aabb& b) {
        return std::any_of(boxes.begin(), boxes.end(),
                           [&](const Aabb& r) { return linf_gap(b, r) == 0.0; });
    };
    for (std::uint32_t i = 0; i < scene.size(); ++i) {
        const auto& o = scene[i];
        const auto& topo = *o.topology;
        for (std::uint32_t v = 0; v < topo.vertex_count(); ++v) {
            if (!topo.vertex_triangles(v).empty() && in(vertex_sweep(scene, p1, i, v))) {
                out[i].vertices.push_back(v);
            }
        }
        for (std::uint32_t t = 0; t < topo.triangle_count(); ++t) {
            if (in(triangle_sweep(o, p1[i], t))) {
                out[i].triangles.push_back(t);
            }
        }
        const auto edges = mesh_edges(topo);
        for (std::uint32_t e = 0; e < edges.size(); ++e) {
            Aabb b = vertex_sweep(scene, p1, i, edges[e][0]);
            b.extend(vertex_sweep(scene, p1, i, edges[e][1]));
            if (in(b)) {
                out[i].edges.push_back(e);
            }
        }
    }
    return out;
}

// The triangles whose swept boxes meet `box`, as a scene of their own (vertices renumbered, the
// same vertex shared as before, so adjacency among them is unchanged).
void crop(const Scene& scene, const Frame& p1, const Aabb& box, Scene& out, Frame& out_p1) {
    for (std::uint32_t i = 0; i < scene.size(); ++i) {
        const auto& o = scene[i];
        TriangleMesh mesh;
        std::vector<Vec3> q;
        std::vector<std::uint32_t> id(o.vertices.size(), ~0u);
        for (std::uint32_t t = 0; t < o.triangle_count(); ++t) {
            if (linf_gap(triangle_sweep(o, p1[i], t), box) > 0.0) {
                continue;
            }
            TriangleIndices tri;
            for (int k = 0; k < 3; ++k) {
                const auto v = o.triangle(t)[k];
                if (id[v] == ~0u) {
                    id[v] = static_cast<std::uint32_t>(mesh.vertices.size());
                    mesh.vertices.push_back(o.vertices[v]);
                    q.push_back(p1[i][v]);
                }
                tri[k] = id[v];
            }
            mesh.triangles.push_back(tri);
        }
        if (!mesh.triangles.empty()) {
            EXPECT_TRUE(out.add_object({o.name, std::move(mesh)}).ok());
            out_p1.push_back(std::move(q));
        }
    }
}

// Brute force over a region of a scene (about 5 x 500 triangles: around 3 reported contacts and
// 2 random vertices) against the CCD result of that scene.
std::size_t check_regions(const Scene& scene, const Frame& p1, const CcdResult& r,
                          std::mt19937_64& rng, const std::string& what) {
    std::vector<Aabb> boxes;
    const std::size_t picks = std::min<std::size_t>(3, r.pairs.size());
    for (std::size_t k = 0; k < picks; ++k) {
        const auto& c = r.pairs[(2 * k + 1) * r.pairs.size() / (2 * picks)];
        const auto v = c.kind == CcdKind::vertex_face
                           ? c.primitive
                           : mesh_edges(*scene[c.object].topology)[c.primitive][0];
        boxes.push_back(grown_to(scene, p1, vertex_sweep(scene, p1, c.object, v), 500));
    }
    while (boxes.size() < 5) {
        const auto o = static_cast<std::uint32_t>(rng() % scene.size());
        const auto v = static_cast<std::uint32_t>(rng() % scene[o].vertices.size());
        boxes.push_back(grown_to(scene, p1, vertex_sweep(scene, p1, o, v), 500));
    }
    const auto subsets = region(scene, p1, boxes);
    std::size_t nv = 0;
    std::size_t nt = 0;
    std::size_t ne = 0;
    for (const auto& s : subsets) {
        nv += s.vertices.size();
        nt += s.triangles.size();
        ne += s.edges.size();
    }
    const auto brute = brute_force(scene, p1, subsets, {});
    std::printf(
        "%s: %zu objects, %zu triangles, %zu contacts, %llu elementary tests; region of "
        "%zu vertices, %zu triangles, %zu edges: %zu brute-force contacts\n",
        what.c_str(), scene.size(), scene.triangle_count(), r.pairs.size(),
        static_cast<unsigned long long>(r.stats.elementary_tests), nv, nt, ne, brute.size());
    expect_contains(r, brute, what);
    // The result restricted to the region is exactly the brute force.
    std::size_t inside = 0;
    for (const auto& c : r.pairs) {
        const auto& sa = subsets[c.object];
        const auto& sb = subsets[c.other];
        const bool in =
            c.kind == CcdKind::vertex_face
                ? std::binary_search(sa.vertices.begin(), sa.vertices.end(), c.primitive) &&
                      std::binary_search(sb.triangles.begin(), sb.triangles.end(),
                                         c.other_primitive)
                : std::binary_search(sa.edges.begin(), sa.edges.end(), c.primitive) &&
                      std::binary_search(sb.edges.begin(), sb.edges.end(), c.other_primitive);
        inside += in ? 1 : 0;
    }
    EXPECT_EQ(inside, brute.size()) << what;
    return brute.size();
}

TEST(FrameCcd, RealFramePairsAgreeWithBruteForceOnRegions) {
    // The whole frame pair for the smallest scene; for each scene, a crop of about 4,000
    // triangles around a random vertex (the same triangles, vertices shared as in the frame, so
    // adjacency is unchanged). In each, every pair of primitives of a region is brute-forced.
    const auto dir = data_dir();
    if (dir.empty()) {
        GTEST_SKIP() << NO_DATA;
    }
    // PROXIMA_CCD_FULL_FRAMES=1: the whole frame pair of every scene as well (about a minute on
    // a 2-core machine; run by hand, not in CI).
    const char* env = std::getenv("PROXIMA_CCD_FULL_FRAMES");
    const bool full_frames = env != nullptr && std::string(env) == "1";
    std::mt19937_64 rng(12345);
    std::size_t contacts = 0;
    for (const auto& fp : FRAME_PAIRS) {
        Scene scene;
        Frame p1;
        if (!load_frames(dir, fp, scene, p1)) {
            continue;
        }
        if (full_frames || std::string(fp.name) == "cloth-funnel") {
            const auto r = run_ccd(scene, p1);
            EXPECT_FALSE(r.pairs.empty()) << fp.name;
            contacts += check_regions(scene, p1, r, rng, fp.name);
        }
        const auto o = static_cast<std::uint32_t>(rng() % scene.size());
        const auto v = static_cast<std::uint32_t>(rng() % scene[o].vertices.size());
        Scene part;
        Frame part_p1;
        crop(scene, p1, grown_to(scene, p1, vertex_sweep(scene, p1, o, v), 4000), part, part_p1);
        const auto r = run_ccd(part, part_p1);
        contacts += check_regions(part, part_p1, r, rng, std::string(fp.name) + " (crop)");
    }
    EXPECT_GT(contacts, 0u) << "the regions held no contact: the check would mean little";
}

}  // namespace
}  // namespace proxima::ccd
