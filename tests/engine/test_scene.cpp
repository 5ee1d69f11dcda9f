#include <gtest/gtest.h>

#include "proxima/culling/sweep_and_prune.hpp"
#include "proxima/query/query.hpp"
#include "support/random_scenes.hpp"

namespace proxima {
namespace {

NamedMesh unit_box(const std::string& name, double x) {
    return {name, test::box({x, 0, 0}, {x + 1, 1, 1})};
}

TEST(Scene, UpdateIsAllOrNothing) {
    Scene scene;
    const auto a = scene.add_object(unit_box("a", 0)).value();
    const auto b = scene.add_object(unit_box("b", 2)).value();
    const auto before_a = scene[0].vertices;
    const auto gen = scene.generation();

    // A valid change to `a` plus an invalid one to `b` (wrong count): nothing may change.
    SceneUpdate u;
    test::Rng rng(1);
    u.positions.push_back({a, test::jitter(rng, before_a, 0.1)});
    u.positions.push_back({b, std::vector<Vec3>(3)});
    auto r = scene.apply(u);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.status().code(), StatusCode::invalid_argument);
    EXPECT_NE(r.status().message().find("object " + std::to_string(b)), std::string::npos);
    EXPECT_EQ(scene[0].vertices, before_a);
    EXPECT_EQ(scene.generation(), gen);

    // NaN in one object, unknown id, duplicate id, bad fragment: each rejected whole.
    SceneUpdate nan;
    nan.positions.push_back({a, before_a});
    nan.positions[0].vertices[2].x = std::numeric_limits<double>::quiet_NaN();
    EXPECT_EQ(scene.apply(nan).status().code(), StatusCode::invalid_argument);
    SceneUpdate unknown;
    unknown.removals.push_back(12345);
    EXPECT_EQ(scene.apply(unknown).status().code(), StatusCode::not_found);
    SceneUpdate twice;
    twice.positions.push_back({a, before_a});
    twice.removals.push_back(a);
    EXPECT_EQ(scene.apply(twice).status().code(), StatusCode::invalid_argument);
    SceneUpdate bad_fragment;
    bad_fragment.replacements.push_back(
        {a, {unit_box("ok", 5), {"bad", {{{0, 0, 0}}, {{0, 0, 3}}}}}});
    auto rb = scene.apply(bad_fragment);
    EXPECT_EQ(rb.status().code(), StatusCode::invalid_argument);
    EXPECT_NE(rb.status().message().find("fragment 1"), std::string::npos);
    EXPECT_EQ(scene.size(), 2u);
    EXPECT_EQ(scene[0].vertices, before_a);
    EXPECT_EQ(scene.generation(), gen);
}

TEST(Scene, ReplacementKeepsOrderAndGivesNewIds) {
    Scene scene;
    const auto a = scene.add_object(unit_box("a", 0)).value();
    const auto b = scene.add_object(unit_box("b", 2)).value();
    SceneUpdate u;
    u.replacements.push_back({a, {unit_box("a0", 0), unit_box("a1", 0.5)}});
    u.additions.push_back(unit_box("c", 4));
    auto r = scene.apply(u);
    ASSERT_TRUE(r.ok());
    ASSERT_EQ(scene.size(), 4u);
    EXPECT_EQ(scene[0].name, "a0");
    EXPECT_EQ(scene[1].name, "a1");
    EXPECT_EQ(scene[2].id, b);
    EXPECT_EQ(scene[3].name, "c");
    EXPECT_EQ(r->fragment_ids[0].size(), 2u);
    EXPECT_EQ(scene.index_of(a), -1);
    EXPECT_EQ(scene.index_of(r->added_ids[0]), 3);
    EXPECT_NE(scene[0].topology_version, scene[1].topology_version);
}

TEST(SweepAndPrune, WithinMatchesAllPairsAndStaysCoherent) {
    test::Rng rng(3);
    Scene scene;
    for (int k = 0; k < 60; ++k) {
        auto m = test::box({0, 0, 0}, {test::uniform(rng, 0.05, 0.5), 0.2, 0.2});
        test::transform(m, 1.0, {test::uniform(rng, 0, 5), test::uniform(rng, 0, 5), 0}, 0);
        ASSERT_TRUE(scene.add_object({"b", m}).ok());
    }
    SweepAndPrune sap;
    for (int frame = 0; frame < 5; ++frame) {
        sap.update(scene);
        for (std::size_t i = 0; i < scene.size(); ++i) {
            const double r = 0.3;
            std::vector<std::size_t> got;
            sap.within(scene, i, r, got);
            std::vector<std::size_t> expected;
            for (std::size_t j = 0; j < scene.size(); ++j) {
                if (j != i && box_squared_distance(scene[i].box, scene[j].box) <= r * r) {
                    expected.push_back(j);
                }
            }
            std::sort(got.begin(), got.end());
            EXPECT_EQ(got, expected);
            // The upper bound really bounds the distance to the closest box's farthest corner.
            double closest = std::numeric_limits<double>::infinity();
            for (std::size_t j = 0; j < scene.size(); ++j) {
                if (j != i) {
                    closest = std::min(closest,
                                       std::sqrt(box_squared_distance(scene[i].box, scene[j].box)));
                }
            }
            EXPECT_GE(sap.separation_upper_bound(scene, i), closest);
        }
        SceneUpdate u;
        for (const auto& o : scene.objects()) {
            u.positions.push_back({o.id, test::jitter(rng, o.vertices, 0.01)});
        }
        ASSERT_TRUE(scene.apply(u).ok());
    }
    sap.update(scene);
    // Small motions keep the order nearly sorted: few moves, far below n^2/4.
    EXPECT_LT(sap.last_swaps(), 200u);
}

TEST(ProximityEngine, RejectsBadToleranceAndHonoursCancel) {
    ProximityEngine engine;
    ASSERT_TRUE(engine.scene().add_object(unit_box("a", 0)).ok());
    ASSERT_TRUE(engine.scene().add_object(unit_box("b", 2)).ok());
    QueryRequest bad;
    bad.tolerance = -1;
    EXPECT_EQ(engine.query(bad).status().code(), StatusCode::invalid_argument);
    bad.tolerance = std::numeric_limits<double>::quiet_NaN();
    EXPECT_EQ(engine.query(bad).status().code(), StatusCode::invalid_argument);

    CancelToken token;
    token.cancel();
    EXPECT_EQ(engine.query(QueryRequest{}, &token).status().code(), StatusCode::cancelled);
    CancelToken late;
    late.set_deadline(std::chrono::steady_clock::now() - std::chrono::seconds(1));
    EXPECT_EQ(engine.query(QueryRequest{}, &late).status().code(), StatusCode::deadline_exceeded);

    auto ok = engine.query(QueryRequest{});
    ASSERT_TRUE(ok.ok());
    EXPECT_DOUBLE_EQ(ok->separation[0].distance, 1.0);
    EXPECT_EQ(ok->separation[0].other, 1);
    EXPECT_EQ(ok->stats.culler, "bvh");
}

}  // namespace
}  // namespace proxima
