// Local penetration depth (seed §3.3): known answers for boxes (12 triangles and subdivided) along
// the axes and a skew axis, icospheres at known overlaps, non-isolated contacts, open meshes,
// self-penetration, and the exact winding-number test it rests on.

#include "proxima/query/penetration.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <map>
#include <numbers>
#include <set>

#include "support/random_scenes.hpp"

namespace proxima {
namespace {

using Cell = std::array<int, 3>;

// Closed, outward-oriented surface of a union of unit cells (edge h, cell (0,0,0) at origin):
// boundary faces between a filled and an empty cell, two triangles each, vertices shared.
TriangleMesh voxels(const std::vector<Cell>& cells, double h, const Vec3& origin) {
    const std::set<Cell> filled(cells.begin(), cells.end());
    std::map<Cell, std::uint32_t> ids;
    TriangleMesh m;
    auto vid = [&](const Cell& g) {
        auto [it, fresh] = ids.try_emplace(g, static_cast<std::uint32_t>(m.vertices.size()));
        if (fresh) {
            m.vertices.push_back(origin + Vec3{h * g[0], h * g[1], h * g[2]});
        }
        return it->second;
    };
    for (const auto& c : filled) {
        for (int a = 0; a < 3; ++a) {
            for (int sigma : {-1, 1}) {
                Cell nb = c;
                nb[a] += sigma;
                if (filled.count(nb) != 0) {
                    continue;
                }
                const int u = (a + 1) % 3;
                const int v = (a + 2) % 3;
                Cell b0 = c;
                if (sigma > 0) {
                    b0[a] += 1;
                }
                Cell b1 = b0;
                b1[u] += 1;
                Cell b2 = b1;
                b2[v] += 1;
                Cell b3 = b0;
                b3[v] += 1;
                const auto i0 = vid(b0), i1 = vid(b1), i2 = vid(b2), i3 = vid(b3);
                if (sigma > 0) {  // (e_u x e_v) = e_a: counter-clockwise seen from outside
                    m.triangles.push_back({i0, i1, i2});
                    m.triangles.push_back({i0, i2, i3});
                } else {
                    m.triangles.push_back({i0, i2, i1});
                    m.triangles.push_back({i0, i3, i2});
                }
            }
        }
    }
    return m;
}

std::vector<Cell> block(int nx, int ny, int nz) {
    std::vector<Cell> cells;
    for (int i = 0; i < nx; ++i) {
        for (int j = 0; j < ny; ++j) {
            for (int k = 0; k < nz; ++k) {
                cells.push_back({i, j, k});
            }
        }
    }
    return cells;
}

// Unit icosphere: the icosahedron subdivided `levels` times (20 * 4^levels triangles), every
// vertex normalized (so the mesh is inscribed in the unit sphere and centrally symmetric),
// triangles oriented outward.
TriangleMesh icosphere(int levels) {
    const double t = (1.0 + std::sqrt(5.0)) / 2.0;
    TriangleMesh m;
    m.vertices = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                  {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
    for (auto& v : m.vertices) {
        v = v / norm(v);
    }
    m.triangles = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                   {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                   {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                   {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    for (int l = 0; l < levels; ++l) {
        std::map<std::pair<std::uint32_t, std::uint32_t>, std::uint32_t> mid;
        auto midpoint = [&](std::uint32_t a, std::uint32_t b) {
            const auto key = std::minmax(a, b);
            auto [it, fresh] = mid.try_emplace(key, static_cast<std::uint32_t>(m.vertices.size()));
            if (fresh) {
                const Vec3 p = 0.5 * (m.vertices[a] + m.vertices[b]);
                m.vertices.push_back(p / norm(p));
            }
            return it->second;
        };
        std::vector<TriangleIndices> next;
        for (const auto& tri : m.triangles) {
            const auto ab = midpoint(tri[0], tri[1]);
            const auto bc = midpoint(tri[1], tri[2]);
            const auto ca = midpoint(tri[2], tri[0]);
            next.push_back({tri[0], ab, ca});
            next.push_back({tri[1], bc, ab});
            next.push_back({tri[2], ca, bc});
            next.push_back({ab, bc, ca});
        }
        m.triangles = std::move(next);
    }
    for (auto& tri : m.triangles) {
        const Vec3& a = m.vertices[tri[0]];
        const Vec3& b = m.vertices[tri[1]];
        const Vec3& c = m.vertices[tri[2]];
        if (dot(cross(b - a, c - a), a + b + c) < 0) {
            std::swap(tri[1], tri[2]);
        }
    }
    return m;
}

// Rotation about a unit axis (Rodrigues).
Vec3 rotate(const Vec3& p, const Vec3& axis, double angle) {
    const double c = std::cos(angle);
    const double s = std::sin(angle);
    return c * p + s * cross(axis, p) + (1 - c) * dot(axis, p) * axis;
}

TriangleMesh moved(TriangleMesh m, const Vec3& axis, double angle, const Vec3& offset) {
    for (auto& v : m.vertices) {
        v = rotate(v, axis, angle) + offset;
    }
    return m;
}

// Swaps coordinates so that the x axis becomes axis `k` (a cyclic permutation: orientation kept).
TriangleMesh to_axis(TriangleMesh m, int k) {
    for (auto& v : m.vertices) {
        const Vec3 p = v;
        v[k] = p.x;
        v[(k + 1) % 3] = p.y;
        v[(k + 2) % 3] = p.z;
    }
    return m;
}

TriangleMesh merged(const TriangleMesh& a, const TriangleMesh& b) {
    TriangleMesh m = a;
    const auto base = static_cast<std::uint32_t>(a.vertices.size());
    m.vertices.insert(m.vertices.end(), b.vertices.begin(), b.vertices.end());
    for (auto tri : b.triangles) {
        m.triangles.push_back({tri[0] + base, tri[1] + base, tri[2] + base});
    }
    return m;
}

struct Outcome {
    std::vector<FeaturePair> collisions;
    std::vector<Penetration> penetrations;
};

Outcome run_scene(const std::vector<TriangleMesh>& meshes) {
    ProximityEngine engine;
    for (std::size_t i = 0; i < meshes.size(); ++i) {
        EXPECT_TRUE(engine.scene().add_object({std::to_string(i), meshes[i]}).ok());
    }
    QueryRequest request;
    request.separation = false;
    request.collisions = true;
    auto result = engine.query(request);
    EXPECT_TRUE(result.ok()) << result.status().to_string();
    Outcome r;
    r.collisions = result->collisions;
    auto pen = penetration_depths(engine.scene(), r.collisions);
    EXPECT_TRUE(pen.ok()) << pen.status().to_string();
    if (pen.ok()) {
        r.penetrations = std::move(pen.value());
    }
    return r;
}

bool collide(const TriangleMesh& a, const TriangleMesh& b) {
    ProximityEngine engine;
    EXPECT_TRUE(engine.scene().add_object({"a", a}).ok());
    EXPECT_TRUE(engine.scene().add_object({"b", b}).ok());
    QueryRequest request;
    request.separation = false;
    request.collisions = true;
    auto result = engine.query(request);
    EXPECT_TRUE(result.ok());
    for (const auto& c : result->collisions) {
        if (c.object != c.other) {
            return true;
        }
    }
    return false;
}

TriangleMesh translated(TriangleMesh m, const Vec3& d) {
    for (auto& v : m.vertices) {
        v += d;
    }
    return m;
}

// One entry for (0, 1) with the expected depth (relative tolerance) and direction (moving object
// 0 along it separates), and the translation check: 1.02 x the vector separates, 0.95 x does not.
void expect_pair(const TriangleMesh& a, const TriangleMesh& b, double depth, const Vec3& dir,
                 double rel_tol, double max_angle) {
    const Outcome r = run_scene({a, b});
    ASSERT_EQ(r.penetrations.size(), 1u);
    const Penetration& p = r.penetrations[0];
    EXPECT_EQ(p.object, 0u);
    EXPECT_EQ(p.other, 1u);
    EXPECT_TRUE(p.closed);
    EXPECT_TRUE(p.isolated);
    EXPECT_NEAR(p.depth, depth, rel_tol * depth);
    EXPECT_NEAR(norm(p.direction), 1.0, 1e-12);
    EXPECT_GE(dot(p.direction, dir), std::cos(max_angle))
        << p.direction.x << " " << p.direction.y << " " << p.direction.z;
    EXPECT_NEAR(norm(p.vector - p.depth * p.direction), 0.0, 1e-12);
    EXPECT_FALSE(p.triangles.empty());
    EXPECT_FALSE(p.other_triangles.empty());
    EXPECT_TRUE(std::is_sorted(p.triangles.begin(), p.triangles.end()));
    EXPECT_TRUE(std::is_sorted(p.other_triangles.begin(), p.other_triangles.end()));
    EXPECT_FALSE(collide(translated(a, 1.02 * p.vector), b));
    EXPECT_TRUE(collide(translated(a, 0.95 * p.vector), b));
}

TEST(Penetration, WindingNumberIsExactOnDegenerateRays) {
    Scene scene;
    ASSERT_TRUE(scene.add_object({"box", test::box({0, 0, 0}, {1, 1, 1})}).ok());
    TriangleMesh inward = test::box({0, 0, 0}, {1, 1, 1});
    for (auto& tri : inward.triangles) {
        std::swap(tri[1], tri[2]);
    }
    ASSERT_TRUE(scene.add_object({"inward", inward}).ok());
    for (int axis = 0; axis < 3; ++axis) {
        // The ray from the centre meets each face on its diagonal; from (-1, 0, 0) it runs along
        // an edge; from a corner's extension it passes through vertices.
        EXPECT_EQ(detail::winding_number(scene[0], {0.5, 0.5, 0.5}, axis), 1);
        EXPECT_EQ(detail::winding_number(scene[1], {0.5, 0.5, 0.5}, axis), -1);
        EXPECT_EQ(detail::winding_number(scene[0], {0.25, 0.75, 0.5}, axis), 1);
        for (const Vec3 p :
             {Vec3{-1, 0, 0}, Vec3{-1, 1, 1}, Vec3{0, -1, 0}, Vec3{0, 0, -1}, Vec3{2, 0.5, 0.5},
              Vec3{-1, 0.5, 0.5}, Vec3{0.5, 0.5, -3}, Vec3{-1, -1, -1}}) {
            EXPECT_EQ(detail::winding_number(scene[0], p, axis), 0);
            EXPECT_EQ(detail::winding_number(scene[1], p, axis), 0);
        }
    }
    // A non-convex voxel shape: every cell centre, and every point a quarter cell from one, is
    // classified exactly (all these rays pass through grid vertices and face diagonals).
    std::vector<Cell> cells = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {0, 0, 1}, {2, 0, 1},
                               {0, 1, 1}, {0, 0, 2}, {2, 0, 2}, {1, 1, 0}};
    ASSERT_TRUE(scene.add_object({"u", voxels(cells, 1.0, {0, 0, 0})}).ok());
    const std::set<Cell> filled(cells.begin(), cells.end());
    int tested = 0;
    for (int i = -1; i <= 3; ++i) {
        for (int j = -1; j <= 2; ++j) {
            for (int k = -1; k <= 3; ++k) {
                const bool in = filled.count({i, j, k}) != 0;
                for (const Vec3 off :
                     {Vec3{0.5, 0.5, 0.5}, Vec3{0.25, 0.5, 0.75}, Vec3{0.5, 0.25, 0.5}}) {
                    const Vec3 p = Vec3{double(i), double(j), double(k)} + off;
                    for (int axis = 0; axis < 3; ++axis) {
                        EXPECT_EQ(detail::winding_number(scene[2], p, axis), in ? 1 : 0)
                            << p.x << " " << p.y << " " << p.z << " axis " << axis;
                        ++tested;
                    }
                }
            }
        }
    }
    EXPECT_EQ(tested, 5 * 4 * 5 * 3 * 3);
    EXPECT_TRUE(detail::closed_oriented(*scene[0].topology));
    EXPECT_TRUE(detail::closed_oriented(*scene[2].topology));
}

TEST(Penetration, ClosedOrientedDetectsHolesAndFlips) {
    TriangleMesh box = test::box({0, 0, 0}, {1, 1, 1});
    EXPECT_TRUE(detail::closed_oriented(MeshTopology(box.triangles, box.vertices.size())));
    TriangleMesh flipped = box;
    std::swap(flipped.triangles[3][1], flipped.triangles[3][2]);
    EXPECT_FALSE(detail::closed_oriented(MeshTopology(flipped.triangles, box.vertices.size())));
    TriangleMesh open = box;
    open.triangles.pop_back();
    EXPECT_FALSE(detail::closed_oriented(MeshTopology(open.triangles, box.vertices.size())));
}

TEST(Penetration, BoxesAlongEachAxis) {
    // A = [0,2]^3, B = [2-d, 4] x [-1, 3]^2: they overlap by exactly d along the axis, and A
    // leaves along -axis. 12-triangle boxes: the features are A's end face (inside B) and the
    // sides that cross B's face.
    for (int axis = 0; axis < 3; ++axis) {
        for (const double d : {0.05, 0.37, 1.3}) {
            SCOPED_TRACE("axis " + std::to_string(axis) + " d " + std::to_string(d));
            const TriangleMesh a = to_axis(test::box({0, 0, 0}, {2, 2, 2}), axis);
            const TriangleMesh b = to_axis(test::box({2 - d, -1, -1}, {4, 3, 3}), axis);
            Vec3 dir;
            dir[axis] = -1.0;
            expect_pair(a, b, d, dir, 1e-9, 1e-9);
        }
    }
}

TEST(Penetration, SubdividedBoxesAlongAxesAndSkew) {
    // 8x8x8-cell box A = [0,2]^3 (768 triangles) against B = [2-d, 4] x [-0.5, 2.5]^2 in 0.5
    // cells, then both rotated about a skew axis.
    const Vec3 skew = Vec3{1, 2, 3} / std::sqrt(14.0);
    for (const double d : {0.11, 0.63}) {
        const TriangleMesh a0 = voxels(block(8, 8, 8), 0.25, {0, 0, 0});
        const TriangleMesh b0 = voxels(block(4, 6, 6), 0.5, {2 - d, -0.5, -0.5});
        for (int axis = 0; axis < 3; ++axis) {
            SCOPED_TRACE("axis " + std::to_string(axis) + " d " + std::to_string(d));
            Vec3 dir;
            dir[axis] = -1.0;
            expect_pair(to_axis(a0, axis), to_axis(b0, axis), d, dir, 1e-9, 1e-9);
        }
        SCOPED_TRACE("skew d " + std::to_string(d));
        const Vec3 shift{0.3, -0.2, 0.1};
        expect_pair(moved(a0, skew, 0.7, shift), moved(b0, skew, 0.7, shift), d,
                    -rotate({1, 0, 0}, skew, 0.7), 1e-6, 1e-6);
        // 12-triangle boxes on the skew axis too.
        expect_pair(moved(test::box({0, 0, 0}, {2, 2, 2}), skew, 0.7, shift),
                    moved(test::box({2 - d, -1, -1}, {4, 3, 3}), skew, 0.7, shift), d,
                    -rotate({1, 0, 0}, skew, 0.7), 1e-6, 1e-6);
    }
}

TEST(Penetration, IcospheresAtKnownOverlap) {
    // Unit icospheres (5120 triangles, vertices on the sphere: circumscribed radius r = 1) along
    // the axis u through vertex 0. The mesh is centrally symmetric, so its extent along u is
    // exactly [-r, r] (vertices v0 and -v0): A at 0 and B at c u overlap along u over exactly
    // [c - r, r], depth 2r - c for the polyhedra themselves. The estimate must be within 1%.
    const TriangleMesh unit = icosphere(4);
    ASSERT_EQ(unit.triangles.size(), 5120u);
    const Vec3 u = unit.vertices[0];
    for (const double c : {1.9, 1.6, 1.3}) {
        SCOPED_TRACE("c " + std::to_string(c));
        const TriangleMesh b = translated(unit, c * u);
        const Outcome r = run_scene({unit, b});
        ASSERT_EQ(r.penetrations.size(), 1u);
        const Penetration& p = r.penetrations[0];
        EXPECT_NEAR(p.depth, 2.0 - c, 0.01 * (2.0 - c));
        EXPECT_GT(dot(p.direction, -1.0 * u), std::cos(0.1));
        EXPECT_TRUE(p.isolated);
        EXPECT_TRUE(p.closed);
        EXPECT_FALSE(p.normal_fallback);
        // The overlapping features are the caps inside the other sphere plus the crossing band:
        // every feature vertex of A lies within the other ball grown by one edge length.
        for (const auto t : p.triangles) {
            const Vec3 q = unit.vertices[unit.triangles[t][0]];
            EXPECT_LT(norm(q - c * u), 1.0 + 0.1);
        }
        std::printf(
            "icosphere c=%.2f depth %.6f (expected %.6f) direction.(-u) %.8f, %zu + %zu "
            "features\n",
            c, p.depth, 2.0 - c, dot(p.direction, -1.0 * u), p.triangles.size(),
            p.other_triangles.size());
    }
}

TEST(Penetration, SeparateContactsAreNotIsolated) {
    // A U (two prongs up to z = 2) pierces the slab's bottom face z = 1.7 at two places.
    const std::vector<Cell> u_cells = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {0, 0, 1}, {2, 0, 1}};
    const TriangleMesh u_shape = voxels(u_cells, 1.0, {0, 0, 0});
    const TriangleMesh slab = test::box({-1, -1, 1.7}, {4, 2, 3});
    Outcome r = run_scene({u_shape, slab});
    ASSERT_EQ(r.penetrations.size(), 1u);
    EXPECT_FALSE(r.penetrations[0].isolated);
    EXPECT_TRUE(r.penetrations[0].closed);
    EXPECT_NEAR(r.penetrations[0].depth, 0.3, 1e-9);
    EXPECT_GT(dot(r.penetrations[0].direction, {0, 0, -1}), 1 - 1e-12);

    // Two boxes as one object piercing the slab: same.
    const TriangleMesh two =
        merged(test::box({0, 0, 0}, {1, 1, 2}), test::box({2, 0, 0}, {3, 1, 1.9}));
    r = run_scene({two, slab});
    ASSERT_EQ(r.penetrations.size(), 1u);
    EXPECT_FALSE(r.penetrations[0].isolated);

    // One prong only: isolated.
    r = run_scene({test::box({0, 0, 0}, {1, 1, 2}), slab});
    ASSERT_EQ(r.penetrations.size(), 1u);
    EXPECT_TRUE(r.penetrations[0].isolated);
}

TEST(Penetration, OnlyCollidingPairsGetEntries) {
    // 0 and 2 overlap by 0.25 along y; 1 is apart from both.
    const Outcome r = run_scene({test::box({0, 0, 0}, {1, 1, 1}), test::box({5, 5, 5}, {6, 6, 6}),
                                 test::box({-1, 0.75, -1}, {2, 3, 2})});
    ASSERT_EQ(r.penetrations.size(), 1u);
    EXPECT_EQ(r.penetrations[0].object, 0u);
    EXPECT_EQ(r.penetrations[0].other, 2u);
    EXPECT_NEAR(r.penetrations[0].depth, 0.25, 1e-12);
    EXPECT_GT(dot(r.penetrations[0].direction, {0, -1, 0}), 1 - 1e-12);
    EXPECT_TRUE(run_scene({test::box({0, 0, 0}, {1, 1, 1}), test::box({2, 0, 0}, {3, 1, 1})})
                    .penetrations.empty());
}

TEST(Penetration, OpenMeshIsFlagged) {
    TriangleMesh open = test::box({0, 0, 0}, {2, 2, 2});
    open.triangles.erase(open.triangles.begin() + 2, open.triangles.begin() + 4);  // top face
    const Outcome r = run_scene({open, test::box({1.5, -1, -1}, {4, 3, 3})});
    ASSERT_EQ(r.penetrations.size(), 1u);
    const Penetration& p = r.penetrations[0];
    EXPECT_FALSE(p.closed);
    EXPECT_NEAR(norm(p.direction), 1.0, 1e-12);
    EXPECT_TRUE(std::isfinite(p.depth));
    EXPECT_GE(p.depth, 0.0);
    EXPECT_FALSE(p.triangles.empty());
    // The open box's triangles can still be walked into the closed box, but the open box has no
    // inside: the closed box's features are its intersecting triangles only.
    for (const auto t : p.other_triangles) {
        bool hit = false;
        for (const auto& c : r.collisions) {
            hit = hit || (c.other == 1 && c.other_triangle == t);
        }
        EXPECT_TRUE(hit) << t;
    }
}

TEST(Penetration, SelfPenetrationOfTwoBoxesInOneObject) {
    // One object: two closed boxes overlapping by 0.4 along x. Its surface intersects itself; the
    // self entry splits it into the two boxes' overlapping parts.
    const TriangleMesh m =
        merged(test::box({0, 0, 0}, {2, 2, 2}), test::box({1.6, -1, -1}, {4, 3, 3}));
    const Outcome r = run_scene({m});
    ASSERT_EQ(r.penetrations.size(), 1u);
    const Penetration& p = r.penetrations[0];
    EXPECT_EQ(p.object, 0u);
    EXPECT_EQ(p.other, 0u);
    EXPECT_TRUE(p.sides_split);
    EXPECT_TRUE(p.closed);
    EXPECT_TRUE(p.isolated);
    EXPECT_NEAR(p.depth, 0.4, 1e-9);
    EXPECT_GT(std::abs(p.direction.x), 1 - 1e-9);
    // The sides are the two boxes' features (triangles 0..11 and 12..23), disjoint.
    const bool first_is_small = p.triangles.front() < 12;
    for (const auto t : p.triangles) {
        EXPECT_EQ(t < 12, first_is_small);
    }
    for (const auto t : p.other_triangles) {
        EXPECT_EQ(t < 12, !first_is_small);
    }
    // Moving the `triangles` side along the direction separates: the small box moves -x.
    EXPECT_LT(dot(p.direction, {1, 0, 0}) * (first_is_small ? 1 : -1), 0);
}

TEST(Penetration, SelfPenetrationOfAFoldedObject) {
    // A connected closed U whose right prong is sheared over so that it passes through the top of
    // the left prong.
    std::vector<Cell> cells = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {3, 0, 0}, {4, 0, 0}, {0, 0, 1},
                               {0, 0, 2}, {0, 0, 3}, {4, 0, 1}, {4, 0, 2}, {4, 0, 3}, {4, 0, 4}};
    TriangleMesh m = voxels(cells, 1.0, {0, 0, 0});
    for (auto& v : m.vertices) {
        if (v.x >= 4 && v.z >= 1) {
            const double s = (v.z - 1) / 4;
            v += Vec3{-4.5 * s, 0.3 * s, 0.13 * s};
        }
    }
    const Outcome r = run_scene({m});
    ASSERT_FALSE(r.collisions.empty());
    ASSERT_EQ(r.penetrations.size(), 1u);
    const Penetration& p = r.penetrations[0];
    EXPECT_EQ(p.other, p.object);
    EXPECT_TRUE(p.sides_split);
    EXPECT_TRUE(p.closed);
    EXPECT_TRUE(p.isolated);
    EXPECT_FALSE(p.triangles.empty());
    EXPECT_FALSE(p.other_triangles.empty());
    EXPECT_GT(p.depth, 0.05);
    EXPECT_LT(p.depth, 1.5);
    // Sides are disjoint.
    for (const auto t : p.triangles) {
        EXPECT_FALSE(std::binary_search(p.other_triangles.begin(), p.other_triangles.end(), t));
    }
    std::printf("folded U: depth %.4f direction (%.3f %.3f %.3f), %zu + %zu features\n", p.depth,
                p.direction.x, p.direction.y, p.direction.z, p.triangles.size(),
                p.other_triangles.size());
}

TEST(Penetration, RandomScenesGiveWellFormedEntries) {
    // Spheres, open folded sheets, boxes and degenerate soups that overlap, nest and touch: one
    // entry per intersecting object pair and per self-intersecting object, every intersecting
    // triangle among the features, flags consistent with the meshes, finite unit directions.
    int entries = 0;
    for (std::uint64_t seed = 1; seed <= 40; ++seed) {
        SCOPED_TRACE("seed " + std::to_string(seed));
        test::Rng rng(seed);
        std::vector<TriangleMesh> meshes;
        for (auto& nm : test::random_scene(rng)) {
            meshes.push_back(std::move(nm.mesh));
        }
        const Outcome r = run_scene(meshes);
        std::set<std::pair<std::uint32_t, std::uint32_t>> expected;
        for (const auto& c : r.collisions) {
            expected.insert(std::minmax(c.object, c.other));
        }
        ASSERT_EQ(r.penetrations.size(), expected.size());
        auto it = expected.begin();
        for (const auto& p : r.penetrations) {
            EXPECT_EQ(std::make_pair(p.object, p.other), *it++);
            EXPECT_TRUE(std::is_sorted(p.triangles.begin(), p.triangles.end()));
            EXPECT_TRUE(std::is_sorted(p.other_triangles.begin(), p.other_triangles.end()));
            EXPECT_TRUE(std::isfinite(p.depth));
            EXPECT_GE(p.depth, 0.0);
            if (p.sides_split) {
                EXPECT_NEAR(norm(p.direction), 1.0, 1e-12);
            }
            const auto closed = [&](std::uint32_t o) {
                const auto& m = meshes[o];
                return detail::closed_oriented(MeshTopology(m.triangles, m.vertices.size()));
            };
            if (p.object != p.other) {
                EXPECT_EQ(p.closed, closed(p.object) && closed(p.other));
                for (const auto& c : r.collisions) {
                    if (c.object == p.object && c.other == p.other) {
                        EXPECT_TRUE(
                            std::binary_search(p.triangles.begin(), p.triangles.end(), c.triangle));
                        EXPECT_TRUE(std::binary_search(p.other_triangles.begin(),
                                                       p.other_triangles.end(), c.other_triangle));
                    }
                }
            } else if (!closed(p.object)) {
                EXPECT_FALSE(p.closed);
            }
            ++entries;
        }
    }
    EXPECT_GT(entries, 20);
}

TEST(Penetration, BadInputAndCancellation) {
    Scene scene;
    ASSERT_TRUE(scene.add_object({"a", test::box({0, 0, 0}, {1, 1, 1})}).ok());
    ASSERT_TRUE(scene.add_object({"b", test::box({0.5, 0.5, 0.5}, {2, 2, 2})}).ok());
    std::vector<FeaturePair> bad = {{0, 0, 5, 0, 0.0}};
    EXPECT_EQ(penetration_depths(scene, bad).status().code(), StatusCode::invalid_argument);
    bad = {{0, 40, 1, 0, 0.0}};
    EXPECT_EQ(penetration_depths(scene, bad).status().code(), StatusCode::invalid_argument);
    EXPECT_TRUE(penetration_depths(scene, {}).ok());
    CancelToken token;
    token.cancel();
    const std::vector<FeaturePair> one = {{0, 3, 1, 0, 0.0}};
    EXPECT_EQ(penetration_depths(scene, one, &token).status().code(), StatusCode::cancelled);
}

}  // namespace
}  // namespace proxima
