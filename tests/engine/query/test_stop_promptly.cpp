// A stopped query stops within its current work item, even where that item is one huge loop
// (issue #18: with the brute-force culler, separation between two large objects checked the token
// only between objects, so a cancelled call kept the daemon busy for seconds). The brute force
// here would take minutes; the query must come back with the stop status well inside a second of
// its deadline (the bound is loose on purpose: sanitizer builds on a loaded CI machine).

#include <gtest/gtest.h>

#include <chrono>

#include "proxima/cancel.hpp"
#include "proxima/query/query.hpp"
#include "support/random_scenes.hpp"

namespace proxima {
namespace {

using Clock = std::chrono::steady_clock;

// Two folded sheets of 2 x 120 x 120 = 28,800 triangles: brute-force separation is 2 x 8.3e8
// triangle tests, brute-force self distance 4e8 pairs per sheet.
void fill(ProximityEngine& engine) {
    test::Rng rng(7);
    SceneUpdate update;
    update.additions.push_back({"a", test::sheet(rng, 120, 120, 0.3)});
    TriangleMesh b = test::sheet(rng, 120, 120, 0.3);
    for (auto& v : b.vertices) {
        v.z += 2.0;
    }
    update.additions.push_back({"b", std::move(b)});
    ASSERT_TRUE(engine.scene().apply(std::move(update)).ok());
}

void expect_prompt_stop(bool separation, bool self) {
    ProximityEngine engine;
    fill(engine);
    QueryRequest request;
    request.culler = CullerKind::brute;
    request.separation = separation;
    request.self = self;
    CancelToken token;
    token.set_deadline(Clock::now() + std::chrono::milliseconds(100));
    const auto start = Clock::now();
    const auto result = engine.query(request, &token);
    const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
    ASSERT_FALSE(result.ok()) << "the brute force finished inside its deadline: make it larger";
    EXPECT_EQ(result.status().code(), StatusCode::deadline_exceeded) << result.status().to_string();
    EXPECT_LT(seconds, 1.5) << "stopped " << seconds << " s after it started (deadline 0.1 s)";
}

TEST(StopPromptly, BruteForceSeparationOfTwoLargeObjects) {
    expect_prompt_stop(true, false);
}

TEST(StopPromptly, BruteForceSelfDistanceOfOneLargeObject) {
    expect_prompt_stop(false, true);
}

}  // namespace
}  // namespace proxima
