// The recorded-sequence logic of proxima play (clients/common/sequence.hpp): natural file order,
// and diff_frames, whose update must turn the scene holding one frame's objects into exactly the
// next frame's objects, in the next frame's order, whatever changed between them.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "common/sequence.hpp"

namespace proxima::client {
namespace {

// A tetrahedron of `n_tets` disjoint parts (different n: different topology), shifted by `x`.
InputObject object(const std::string& name, int n_tets, double x) {
    InputObject o;
    o.mesh.name = name;
    for (int t = 0; t < n_tets; ++t) {
        const auto base = static_cast<std::uint32_t>(o.mesh.mesh.vertices.size());
        const double dx = x + 2.0 * t;
        o.mesh.mesh.vertices.insert(o.mesh.mesh.vertices.end(),
                                    {{dx, 0, 0}, {dx + 1, 0, 0}, {dx, 1, 0}, {dx, 0, 1}});
        o.mesh.mesh.triangles.insert(o.mesh.mesh.triangles.end(), {{base, base + 2, base + 1},
                                                                   {base, base + 1, base + 3},
                                                                   {base, base + 3, base + 2},
                                                                   {base + 1, base + 2, base + 3}});
    }
    return o;
}

// Applies diff_frames(prev, next) to a scene holding `prev` and checks the scene is `next`.
FrameDiff check_diff(const std::vector<InputObject>& prev, const std::vector<InputObject>& next) {
    Scene scene;
    std::vector<ObjectId> ids;
    for (const auto& o : prev) {
        auto id = scene.add_object(o.mesh);
        EXPECT_TRUE(id.ok());
        ids.push_back(id.value());
    }
    FrameDiff diff = diff_frames(prev, ids, next);
    auto applied = scene.apply(diff.update);
    EXPECT_TRUE(applied.ok()) << applied.status().to_string();
    EXPECT_EQ(scene.size(), next.size());
    for (std::size_t i = 0; i < std::min(scene.size(), next.size()); ++i) {
        EXPECT_EQ(scene[i].vertices, next[i].mesh.mesh.vertices) << "object " << i;
        EXPECT_EQ(scene[i].topology->triangles(), next[i].mesh.mesh.triangles) << "object " << i;
    }
    return diff;
}

TEST(Sequence, NaturalOrder) {
    std::vector<std::string> names = {"frame_10.obj",   "frame_9.obj",   "frame_010b.obj",
                                      "frame_1.obj",    "a.obj",         "frame_0002.obj",
                                      "balls16_19.ply", "balls16_18.ply"};
    std::sort(names.begin(), names.end(), natural_less);
    EXPECT_EQ(names, (std::vector<std::string>{"a.obj", "balls16_18.ply", "balls16_19.ply",
                                               "frame_1.obj", "frame_0002.obj", "frame_9.obj",
                                               "frame_10.obj", "frame_010b.obj"}));
    EXPECT_FALSE(natural_less("x", "x"));
}

TEST(Sequence, MovingOnlyIsPositions) {
    const auto diff = check_diff({object("a", 1, 0), object("b", 2, 5)},
                                 {object("a", 1, 0.5), object("b", 2, 5)});
    EXPECT_FALSE(diff.topology_change);
    EXPECT_EQ(diff.update.positions.size(), 1u);  // b did not move
    EXPECT_TRUE(diff.update.replacements.empty());
}

TEST(Sequence, SameCountNewTopologyIsReplaced) {
    const auto diff = check_diff({object("a", 1, 0), object("b", 2, 5)},
                                 {object("a", 3, 0), object("b", 2, 5.5)});
    EXPECT_TRUE(diff.topology_change);
    EXPECT_EQ(diff.update.replacements.size(), 1u);
    EXPECT_EQ(diff.update.positions.size(), 1u);
}

TEST(Sequence, BreakWithoutNamesKeepsOrder) {
    // b breaks into three pieces between a and c (names say nothing).
    const auto diff = check_diff({object("a", 1, 0), object("b", 2, 5), object("c", 1, 20)},
                                 {object("a", 1, 0.1), object("x", 1, 5), object("y", 1, 7),
                                  object("z", 3, 9), object("c", 1, 20.1)});
    EXPECT_TRUE(diff.topology_change);
    ASSERT_EQ(diff.update.replacements.size(), 1u);
    EXPECT_EQ(diff.update.replacements[0].fragments.size(), 3u);
}

TEST(Sequence, BreakByNamesReplacesEachObjectByItsPieces) {
    const auto diff =
        check_diff({object("ball0", 2, 0), object("ball1", 2, 10), object("ball2", 2, 20)},
                   {object("ball0.piece0", 1, 0), object("ball0.piece1", 1, 2),
                    object("ball1.piece0", 1, 10), object("ball1.piece1", 1, 12),
                    object("ball1.piece2", 1, 14), object("ball2.piece0", 1, 20)});
    ASSERT_EQ(diff.update.replacements.size(), 3u);
    EXPECT_EQ(diff.update.replacements[0].fragments.size(), 2u);
    EXPECT_EQ(diff.update.replacements[1].fragments.size(), 3u);
    EXPECT_EQ(diff.update.replacements[2].fragments.size(), 1u);
    EXPECT_TRUE(diff.update.removals.empty());
}

TEST(Sequence, AdditionsRemovalsAndInsertions) {
    check_diff({object("a", 1, 0)}, {object("a", 1, 0), object("b", 1, 5), object("c", 2, 9)});
    check_diff({object("a", 1, 0), object("b", 1, 5), object("c", 2, 9)}, {object("c", 2, 9)});
    check_diff({object("a", 1, 0), object("b", 1, 5), object("c", 2, 9)},
               {object("a", 1, 0), object("c", 2, 9)});
    // An object inserted before the last one (no old object between the kept runs).
    check_diff({object("a", 1, 0), object("c", 2, 9)},
               {object("a", 1, 0), object("b", 1, 5), object("c", 2, 9)});
    // Everything different, more objects than before.
    check_diff({object("a", 1, 0), object("b", 2, 5)},
               {object("p", 3, 0), object("q", 1, 5), object("r", 1, 9)});
}

}  // namespace
}  // namespace proxima::client
