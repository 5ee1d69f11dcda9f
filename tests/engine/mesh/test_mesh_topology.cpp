#include <gtest/gtest.h>

#include <algorithm>

#include "proxima/mesh/mesh.hpp"
#include "support/random_scenes.hpp"

namespace proxima {
namespace {

// A 2x2-quad grid: 9 vertices, 8 triangles.
TriangleMesh grid() {
    TriangleMesh m;
    for (int j = 0; j < 3; ++j) {
        for (int i = 0; i < 3; ++i) {
            m.vertices.push_back({double(i), double(j), 0});
        }
    }
    auto id = [](int i, int j) { return static_cast<std::uint32_t>(j * 3 + i); };
    for (int j = 0; j < 2; ++j) {
        for (int i = 0; i < 2; ++i) {
            m.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
            m.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
        }
    }
    return m;
}

std::vector<std::uint32_t> brute_ring(const TriangleMesh& m, std::uint32_t t) {
    std::vector<std::uint32_t> out;
    for (std::uint32_t u = 0; u < m.triangles.size(); ++u) {
        if (u != t && share_vertex(m.triangles[t], m.triangles[u])) {
            out.push_back(u);
        }
    }
    return out;
}

TEST(MeshTopology, OneRingMatchesDefinition) {
    test::Rng rng(7);
    for (auto m : {grid(), test::sphere(rng, 6, 8, 1, 0.1), test::degenerate_soup(rng, 30, 1)}) {
        MeshTopology topo(m.triangles, m.vertices.size());
        for (std::uint32_t t = 0; t < m.triangles.size(); ++t) {
            const auto ring = topo.one_ring(t);
            EXPECT_EQ(std::vector<std::uint32_t>(ring.begin(), ring.end()), brute_ring(m, t));
            for (std::uint32_t u = 0; u < m.triangles.size(); ++u) {
                EXPECT_EQ(topo.adjacent(t, u),
                          u == t || share_vertex(m.triangles[t], m.triangles[u]));
            }
        }
    }
}

TEST(MeshTopology, TwoRingExcludesSelfAndOneRing) {
    const auto m = grid();
    MeshTopology topo(m.triangles, m.vertices.size());
    for (std::uint32_t t = 0; t < m.triangles.size(); ++t) {
        const auto two = topo.two_ring(t);
        std::vector<std::uint32_t> expected;
        const auto one = brute_ring(m, t);
        for (auto u : one) {
            for (auto w : brute_ring(m, u)) {
                if (w != t && !std::binary_search(one.begin(), one.end(), w)) {
                    expected.push_back(w);
                }
            }
        }
        std::sort(expected.begin(), expected.end());
        expected.erase(std::unique(expected.begin(), expected.end()), expected.end());
        EXPECT_EQ(two, expected) << "triangle " << t;
    }
    // Triangle 2 = (1, 2, 5): its 1-ring is {0, 3, 6}; the triangles touching those but not it are
    // the three others around the centre vertex 4; triangle 5 = (3, 7, 6) is farther.
    EXPECT_EQ(topo.two_ring(2), (std::vector<std::uint32_t>{1, 4, 7}));
}

TEST(MeshTopology, RepeatedCornerIsNotDoubleCounted) {
    std::vector<TriangleIndices> tris{{0, 0, 1}, {1, 2, 3}};
    MeshTopology topo(tris, 4);
    EXPECT_EQ(topo.vertex_triangles(0).size(), 1u);
    EXPECT_EQ(topo.one_ring(0).size(), 1u);
    EXPECT_TRUE(topo.adjacent(0, 1));
}

TEST(MeshTopology, ComponentsOrderedBySmallestTriangle) {
    TriangleMesh m;
    m.vertices.resize(9);
    // Component of vertices 6..8 appears first (triangle 0), then 0..2, then 3..5.
    m.triangles = {{6, 7, 8}, {0, 1, 2}, {3, 4, 5}, {2, 0, 1}, {8, 6, 7}};
    MeshTopology topo(m.triangles, m.vertices.size());
    ASSERT_EQ(topo.component_count(), 3u);
    EXPECT_EQ(topo.component_of(0), 0u);
    EXPECT_EQ(topo.component_of(1), 1u);
    EXPECT_EQ(topo.component_of(2), 2u);
    EXPECT_EQ(topo.component_of(3), 1u);
    EXPECT_EQ(topo.component_of(4), 0u);
    const auto split = split_components(m);
    ASSERT_EQ(split.meshes.size(), 3u);
    EXPECT_EQ(split.triangle_ids[0], (std::vector<std::uint32_t>{0, 4}));
    EXPECT_EQ(split.triangle_ids[1], (std::vector<std::uint32_t>{1, 3}));
    EXPECT_EQ(split.meshes[0].vertices.size(), 3u);
    for (const auto& part : split.meshes) {
        EXPECT_TRUE(validate_mesh(part, "part").ok());
    }
}

TEST(MeshValidation, NamesObjectAndProblem) {
    TriangleMesh m = grid();
    EXPECT_TRUE(validate_mesh(m, "object 'g'").ok());
    m.triangles[5][2] = 99;
    auto s = validate_mesh(m, "object 'g'");
    EXPECT_EQ(s.code(), StatusCode::invalid_argument);
    EXPECT_NE(s.message().find("object 'g'"), std::string::npos);
    EXPECT_NE(s.message().find("triangle 5"), std::string::npos);
    EXPECT_NE(s.message().find("99"), std::string::npos);

    m = grid();
    m.vertices[3].y = std::numeric_limits<double>::quiet_NaN();
    s = validate_mesh(m, "object 'g'");
    EXPECT_EQ(s.code(), StatusCode::invalid_argument);
    EXPECT_NE(s.message().find("vertex 3"), std::string::npos);

    m = grid();
    m.vertices[0].z = std::numeric_limits<double>::infinity();
    EXPECT_FALSE(validate_mesh(m, "x").ok());

    EXPECT_FALSE(validate_mesh(TriangleMesh{}, "empty").ok());
    EXPECT_NE(validate_mesh(TriangleMesh{}, "empty").message().find("no triangles"),
              std::string::npos);
}

}  // namespace
}  // namespace proxima
