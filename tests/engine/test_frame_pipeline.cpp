// The engine's frame pipeline (proxima/frame_pipeline.hpp): a refused frame changes nothing, the
// outcome is the steps done by hand (and brute force), and every stop status comes from
// stop_status.

#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <string>
#include <vector>

#include "proxima/cancel.hpp"
#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/frame_pipeline.hpp"
#include "proxima/query/penetration.hpp"
#include "proxima/query/query.hpp"
#include "support/random_scenes.hpp"

namespace proxima {
namespace {

NamedMesh box_at(const std::string& name, double x, double y = 0) {
    return {name, test::box({x, y, 0}, {x + 1, y + 1, 1})};
}

// Everything a frame could change, bit for bit.
struct Snapshot {
    std::uint64_t generation = 0;
    std::vector<ObjectId> ids;
    std::vector<std::string> names;
    std::vector<std::vector<unsigned char>> vertex_bytes;
    std::vector<std::vector<TriangleIndices>> triangles;
    std::vector<std::uint64_t> topology_versions;
    bool operator==(const Snapshot&) const = default;
};

Snapshot snapshot(const Scene& scene) {
    Snapshot s;
    s.generation = scene.generation();
    for (const auto& obj : scene.objects()) {
        s.ids.push_back(obj.id);
        s.names.push_back(obj.name);
        std::vector<unsigned char> bytes(obj.vertices.size() * sizeof(Vec3));
        if (!bytes.empty()) {
            std::memcpy(bytes.data(), obj.vertices.data(), bytes.size());
        }
        s.vertex_bytes.push_back(std::move(bytes));
        s.triangles.push_back(obj.topology->triangles());
        s.topology_versions.push_back(obj.topology_version);
    }
    return s;
}

// Three boxes: a and b 0.5 apart along x, c far away.
std::vector<ObjectId> fill(ProximityEngine& engine) {
    SceneUpdate u;
    u.additions = {box_at("a", 0), box_at("b", 1.5), box_at("c", 10, 10)};
    return engine.scene().apply(std::move(u)).value().added_ids;
}

std::vector<Vec3> shifted(const std::vector<Vec3>& v, const Vec3& by) {
    std::vector<Vec3> out = v;
    for (auto& p : out) {
        p = {p.x + by.x, p.y + by.y, p.z + by.z};
    }
    return out;
}

// Runs `frame` and requires it refused with `code` and a message containing `text`, the scene
// bit-identical and `before_apply` never called.
void expect_refused(FrameRequest frame, const FrameLimits& limits, StatusCode code,
                    const std::string& text) {
    ProximityEngine engine;
    fill(engine);
    const auto before = snapshot(engine.scene());
    FrameOptions options;
    options.limits = limits;
    options.scene_id = "s1";
    int charged = 0;
    options.before_apply = [&](const Scene&, const SceneUpdate&) {
        ++charged;
        return Status{};
    };
    auto outcome = run_frame(engine, std::move(frame), nullptr, options);
    ASSERT_FALSE(outcome.ok());
    EXPECT_EQ(outcome.status().code(), code) << outcome.status().to_string();
    EXPECT_NE(outcome.status().message().find(text), std::string::npos)
        << outcome.status().message();
    EXPECT_EQ(charged, 0);
    EXPECT_TRUE(snapshot(engine.scene()) == before);
}

TEST(FramePipeline, RefusedFrameLeavesSceneBitIdentical) {
    ProximityEngine probe;
    const auto ids = fill(probe);
    const auto& a_vertices = probe.scene()[0].vertices;
    // Each frame also carries a valid move of `a`: it must not be applied either.
    auto with_move = [&] {
        FrameRequest f;
        f.update.positions.push_back({ids[0], shifted(a_vertices, {0.25, 0, 0})});
        return f;
    };

    // Bad index: a fragment's triangle names vertex 99 of 3.
    auto bad_index = with_move();
    TriangleMesh bad;
    bad.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
    bad.triangles = {{0, 1, 99}};
    bad_index.update.replacements.push_back({ids[1], {{"frag", bad}}});
    expect_refused(std::move(bad_index), {}, StatusCode::invalid_argument,
                   "topology_changes[0] (object " + std::to_string(ids[1]) + ") fragments[0]");

    // Wrong vertex count of a position update, after a valid one.
    auto bad_count = with_move();
    bad_count.update.positions.push_back({ids[1], std::vector<Vec3>(3)});
    expect_refused(std::move(bad_count), {}, StatusCode::invalid_argument, "positions[1]");

    // Unknown object.
    auto unknown = with_move();
    unknown.update.removals.push_back(12345);
    expect_refused(std::move(unknown), {}, StatusCode::not_found,
                   "removals[0]: object 12345 is not in scene s1");

    // An object named twice.
    auto twice = with_move();
    twice.update.removals.push_back(ids[0]);
    expect_refused(std::move(twice), {}, StatusCode::invalid_argument,
                   "is named more than once in one frame");

    // A topology change (and an addition) in a CCD frame.
    auto ccd_topology = with_move();
    ccd_topology.ccd = true;
    ccd_topology.update.replacements.push_back({ids[1], {box_at("b1", 1.5), box_at("b2", 3)}});
    expect_refused(std::move(ccd_topology), {}, StatusCode::invalid_argument,
                   "queries.ccd: a CCD frame may only move vertices, but this frame has "
                   "topology_changes");
    auto ccd_addition = with_move();
    ccd_addition.ccd = true;
    ccd_addition.update.additions.push_back(box_at("d", 5));
    expect_refused(std::move(ccd_addition), {}, StatusCode::invalid_argument,
                   "but this frame has additions");

    // Limits: objects and triangles.
    auto more = with_move();
    more.update.additions.push_back(box_at("d", 5));
    FrameLimits three_objects;
    three_objects.max_objects = 3;
    expect_refused(more, three_objects, StatusCode::resource_exhausted,
                   "scene s1 would hold 4 objects after this change, over the limit "
                   "max-objects-per-scene = 3");
    FrameLimits few_triangles;
    few_triangles.max_triangles = 40;
    expect_refused(std::move(more), few_triangles, StatusCode::resource_exhausted,
                   "over the limit max-triangles-per-scene = 40");
}

TEST(FramePipeline, BeforeApplyRefusalChangesNothing) {
    ProximityEngine engine;
    const auto ids = fill(engine);
    const auto before = snapshot(engine.scene());
    FrameRequest frame;
    frame.update.positions.push_back({ids[0], shifted(engine.scene()[0].vertices, {0.25, 0, 0})});
    FrameOptions options;
    bool after = false;
    options.before_apply = [](const Scene&, const SceneUpdate& update) {
        EXPECT_EQ(update.positions.size(), 1u);
        return Status{StatusCode::resource_exhausted, "quota"};
    };
    options.after_apply = [&] {
        after = true;
        return Status{};
    };
    auto outcome = run_frame(engine, std::move(frame), nullptr, options);
    EXPECT_EQ(outcome.status().code(), StatusCode::resource_exhausted);
    EXPECT_FALSE(after);
    EXPECT_TRUE(snapshot(engine.scene()) == before);
}

// Penetration implies collisions in-process as on the wire (proto/wire's decode_frame): a frame
// asking only for penetration gets the collisions and their penetration vectors.
TEST(FramePipeline, PenetrationAloneImpliesCollisions) {
    ProximityEngine with_flag;
    ProximityEngine both;
    const auto ids = fill(with_flag);
    fill(both);
    auto frame_for = [&](ProximityEngine& engine, bool collisions) {
        FrameRequest frame;
        frame.update.positions.push_back(
            {ids[1], shifted(engine.scene()[1].vertices, {-0.75, 0.1, 0})});
        frame.queries.separation = false;
        frame.queries.collisions = collisions;
        frame.penetration = true;
        return frame;
    };
    auto alone = run_frame(with_flag, frame_for(with_flag, false), nullptr);
    auto asked = run_frame(both, frame_for(both, true), nullptr);
    ASSERT_TRUE(alone.ok()) << alone.status().to_string();
    ASSERT_TRUE(asked.ok()) << asked.status().to_string();
    ASSERT_FALSE(asked->result.collisions.empty());
    EXPECT_EQ(alone->result.collisions.size(), asked->result.collisions.size());
    ASSERT_FALSE(asked->penetrations.empty());
    EXPECT_EQ(alone->penetrations.size(), asked->penetrations.size());
}

// The same frame by hand: apply, query, penetration of the collisions, CCD from a copy.
TEST(FramePipeline, OutcomeEqualsStepsByHandAndBruteForce) {
    ProximityEngine piped;
    ProximityEngine by_hand;
    ProximityEngine brute;
    const auto ids = fill(piped);
    fill(by_hand);
    fill(brute);
    // b moves 0.75 towards a: through the 0.5 gap, into a (a CCD contact and a collision).
    SceneUpdate update;
    update.positions.push_back({ids[1], shifted(piped.scene()[1].vertices, {-0.75, 0.1, 0})});

    FrameRequest frame;
    frame.update = update;
    frame.queries.separation = true;
    frame.queries.collisions = true;
    frame.queries.tolerance = 2.0;
    frame.queries.culler = CullerKind::bvh;
    frame.penetration = true;
    frame.ccd = true;
    int after = 0;
    FrameOptions options;
    options.after_apply = [&] {
        ++after;
        return Status{};
    };
    auto outcome = run_frame(piped, frame, nullptr, options);
    ASSERT_TRUE(outcome.ok()) << outcome.status().to_string();
    EXPECT_EQ(after, 1);

    const Scene t0 = by_hand.scene();
    ASSERT_TRUE(by_hand.scene().apply(update).ok());
    auto result = by_hand.query(frame.queries);
    ASSERT_TRUE(result.ok());
    auto penetrations = penetration_depths(by_hand.scene(), result->collisions);
    ASSERT_TRUE(penetrations.ok());
    std::vector<std::vector<Vec3>> t1;
    for (const auto& obj : by_hand.scene().objects()) {
        t1.push_back(obj.vertices);
    }
    auto ccd = ccd::continuous_collisions(t0, t1, frame.ccd_request);
    ASSERT_TRUE(ccd.ok());

    QueryRequest brute_request = frame.queries;
    brute_request.culler = CullerKind::brute;
    ASSERT_TRUE(brute.scene().apply(update).ok());
    auto brute_result = brute.query(brute_request);
    ASSERT_TRUE(brute_result.ok());

    EXPECT_EQ(outcome->object_ids, ids);
    EXPECT_TRUE(outcome->added_ids.empty());
    EXPECT_TRUE(snapshot(piped.scene()) == snapshot(by_hand.scene()));
    for (const auto* expected : {&result.value(), &brute_result.value()}) {
        ASSERT_EQ(outcome->result.separation.size(), expected->separation.size());
        for (std::size_t i = 0; i < expected->separation.size(); ++i) {
            EXPECT_EQ(outcome->result.separation[i].other, expected->separation[i].other);
            EXPECT_EQ(outcome->result.separation[i].distance, expected->separation[i].distance);
        }
        ASSERT_EQ(outcome->result.collisions.size(), expected->collisions.size());
        ASSERT_EQ(outcome->result.tolerance.size(), expected->tolerance.size());
        for (std::size_t i = 0; i < expected->tolerance.size(); ++i) {
            EXPECT_FALSE(outcome->result.tolerance[i] < expected->tolerance[i] ||
                         expected->tolerance[i] < outcome->result.tolerance[i]);
            EXPECT_EQ(outcome->result.tolerance[i].distance, expected->tolerance[i].distance);
        }
    }
    EXPECT_FALSE(outcome->result.collisions.empty());  // a and b intersect now

    ASSERT_EQ(outcome->penetrations.size(), penetrations->size());
    ASSERT_FALSE(outcome->penetrations.empty());
    for (std::size_t i = 0; i < penetrations->size(); ++i) {
        EXPECT_EQ(outcome->penetrations[i].object, (*penetrations)[i].object);
        EXPECT_EQ(outcome->penetrations[i].other, (*penetrations)[i].other);
        EXPECT_EQ(outcome->penetrations[i].depth, (*penetrations)[i].depth);
    }

    ASSERT_TRUE(outcome->ccd.has_value());
    ASSERT_EQ(outcome->ccd->pairs.size(), ccd->pairs.size());
    ASSERT_FALSE(ccd->pairs.empty());  // b swept into a
    for (std::size_t i = 0; i < ccd->pairs.size(); ++i) {
        EXPECT_EQ(outcome->ccd->pairs[i].object, ccd->pairs[i].object);
        EXPECT_EQ(outcome->ccd->pairs[i].primitive, ccd->pairs[i].primitive);
        EXPECT_EQ(outcome->ccd->pairs[i].other_primitive, ccd->pairs[i].other_primitive);
        EXPECT_EQ(outcome->ccd->pairs[i].toi, ccd->pairs[i].toi);
    }
    EXPECT_EQ(outcome->ccd->earliest, ccd->earliest);

    // Not asked: no penetrations, no CCD.
    FrameRequest plain;
    plain.queries = frame.queries;
    auto quiet = run_frame(piped, plain, nullptr);
    ASSERT_TRUE(quiet.ok());
    EXPECT_TRUE(quiet->penetrations.empty());
    EXPECT_FALSE(quiet->ccd.has_value());
}

TEST(FramePipeline, AdditionsAndFragmentsGetIds) {
    ProximityEngine engine;
    const auto ids = fill(engine);
    FrameRequest frame;
    frame.update.replacements.push_back({ids[2], {box_at("c1", 10, 10), box_at("c2", 12, 10)}});
    frame.update.additions.push_back(box_at("d", 20));
    auto outcome = run_frame(engine, std::move(frame), nullptr);
    ASSERT_TRUE(outcome.ok()) << outcome.status().to_string();
    ASSERT_EQ(outcome->fragment_ids.size(), 1u);
    EXPECT_EQ(outcome->fragment_ids[0].size(), 2u);
    EXPECT_EQ(outcome->added_ids.size(), 1u);
    EXPECT_EQ(outcome->object_ids.size(), engine.scene().size());
    EXPECT_EQ(outcome->result.separation.size(), engine.scene().size());
}

TEST(FramePipeline, StopStatusesComeFromTheOneHelper) {
    CancelToken cancelled;
    cancelled.cancel();
    CancelToken expired;
    expired.set_deadline(std::chrono::steady_clock::now() - std::chrono::seconds(1));
    CancelToken both;
    both.cancel();
    both.set_deadline(std::chrono::steady_clock::now() - std::chrono::seconds(1));

    EXPECT_EQ(stop_status(cancelled, "query").code(), StatusCode::cancelled);
    EXPECT_EQ(stop_status(cancelled, "query").message(), "query cancelled by the caller");
    EXPECT_EQ(stop_status(expired, "query").code(), StatusCode::deadline_exceeded);
    EXPECT_EQ(stop_status(expired, "query").message(), "query stopped: deadline exceeded");
    // gRPC cancels a call whose deadline passed: the deadline is the reason.
    EXPECT_EQ(stop_status(both, "x").code(), StatusCode::deadline_exceeded);

    for (const CancelToken* token : {&cancelled, &expired}) {
        ProximityEngine engine;
        const auto ids = fill(engine);
        const auto before = snapshot(engine.scene());
        // Stopped before it ran: refused whole, the helper's status.
        FrameRequest frame;
        frame.update.positions.push_back(
            {ids[0], shifted(engine.scene()[0].vertices, {0.25, 0, 0})});
        auto outcome = run_frame(engine, frame, token);
        const Status expected = stop_status(*token, "frame");
        EXPECT_EQ(outcome.status().code(), expected.code());
        EXPECT_EQ(outcome.status().message(), expected.message());
        EXPECT_TRUE(snapshot(engine.scene()) == before);
        // The query, penetration and CCD stages report theirs the same way.
        const auto query = engine.query(QueryRequest{}, token);
        EXPECT_EQ(query.status().message(), stop_status(*token, "query").message());
        std::vector<std::vector<Vec3>> t1;
        for (const auto& obj : engine.scene().objects()) {
            t1.push_back(obj.vertices);
        }
        const auto ccd = ccd::continuous_collisions(engine.scene(), t1, {}, token);
        EXPECT_EQ(ccd.status().code(), expected.code());
        EXPECT_EQ(ccd.status().message(), stop_status(*token, "ccd").message());
    }
}

}  // namespace
}  // namespace proxima
