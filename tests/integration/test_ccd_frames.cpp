// Continuous collisions through proximad: a frame with queries.ccd gets the pairs that touch while
// the vertices move from their previous positions to the frame's, equal to the in-process
// ccd::continuous_collisions on the same doubles; a CCD frame that changes topology is refused
// whole and leaves the scene as it was.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "client/proxima_client.hpp"
#include "daemon_process.hpp"
#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scenes/procedural.hpp"

namespace proxima::test {
namespace {

using client::Client;
using client::FrameRequest;

void expect_same_ccd(const ccd::CcdResult& remote, const ccd::CcdResult& local) {
    ASSERT_EQ(remote.pairs.size(), local.pairs.size());
    for (std::size_t i = 0; i < local.pairs.size(); ++i) {
        SCOPED_TRACE("pair " + std::to_string(i));
        const auto& r = remote.pairs[i];
        const auto& l = local.pairs[i];
        EXPECT_EQ(r.kind, l.kind);
        EXPECT_EQ(r.object, l.object);
        EXPECT_EQ(r.primitive, l.primitive);
        EXPECT_EQ(r.other, l.other);
        EXPECT_EQ(r.other_primitive, l.other_primitive);
        EXPECT_EQ(r.toi, l.toi);
        EXPECT_EQ(r.capped, l.capped);
    }
    ASSERT_EQ(remote.object_pairs.size(), local.object_pairs.size());
    for (std::size_t i = 0; i < local.object_pairs.size(); ++i) {
        EXPECT_EQ(remote.object_pairs[i].object, local.object_pairs[i].object);
        EXPECT_EQ(remote.object_pairs[i].other, local.object_pairs[i].other);
        EXPECT_EQ(remote.object_pairs[i].toi, local.object_pairs[i].toi);
        EXPECT_EQ(remote.object_pairs[i].pair, local.object_pairs[i].pair);
    }
    EXPECT_EQ(remote.earliest, local.earliest);
}

// A unit square (two triangles) at height z.
NamedMesh square(const std::string& name, double z) {
    NamedMesh m;
    m.name = name;
    m.mesh.vertices = {{0, 0, z}, {1, 0, z}, {1, 1, z}, {0, 1, z}};
    m.mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
    return m;
}

TEST(CcdFrames, StreamedFramesMatchInProcessCcd) {
    DaemonProcess daemon;
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = Client::connect(daemon.address());
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    const auto sc = scenes::bowl(5);
    auto stream = c.value()->open_stream("");
    ASSERT_TRUE(stream.ok());
    ProximityEngine local;
    std::size_t contacts = 0;
    for (std::size_t k = 0; k < 5; ++k) {
        SCOPED_TRACE("frame " + std::to_string(k));
        FrameRequest request;
        request.frame = k;
        request.queries.separation = true;
        const Scene before = local.scene();
        if (k == 0) {
            request.update.additions = sc.initial;
        } else {
            request.update = sc.step(k, local.scene());
            request.ccd = true;
        }
        ASSERT_TRUE(local.scene().apply(request.update).ok());
        ASSERT_TRUE(stream.value()->send(request).ok());
        auto got = stream.value()->receive();
        ASSERT_TRUE(got.ok()) << got.status().to_string();
        if (k == 0) {
            EXPECT_FALSE(got->ccd.has_value());
            continue;
        }
        ASSERT_TRUE(got->ccd.has_value());
        std::vector<std::vector<Vec3>> t1;
        for (const auto& o : local.scene().objects()) {
            t1.push_back(o.vertices);
        }
        auto expected = ccd::continuous_collisions(before, t1);
        ASSERT_TRUE(expected.ok()) << expected.status().to_string();
        expect_same_ccd(*got->ccd, expected.value());
        // The broad phase ran and its counts came through (the prefilter may leave no
        // elementary test: in this scene it rejects every candidate).
        EXPECT_GT(got->ccd->stats.candidate_pairs, 0u);
        contacts += expected->pairs.size();
    }
    EXPECT_TRUE(stream.value()->finish().ok());
    (void)contacts;  // the bowl's balls may or may not touch in 5 frames: equality is the point
}

TEST(CcdFrames, VertexThroughSquareIsReportedWithItsTimeOfImpact) {
    DaemonProcess daemon;
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = Client::connect(daemon.address());
    ASSERT_TRUE(c.ok());
    // A small triangle above the square falls through it between the two frames.
    NamedMesh dart;
    dart.name = "dart";
    dart.mesh.vertices = {{0.5, 0.25, 1.0}, {0.6, 0.25, 1.5}, {0.5, 0.35, 1.5}};
    dart.mesh.triangles = {{0, 1, 2}};
    auto scene = c.value()->create_scene("fall", {square("floor", 0.0), dart});
    ASSERT_TRUE(scene.ok()) << scene.status().to_string();
    auto stream = c.value()->open_stream(scene->scene_id);
    ASSERT_TRUE(stream.ok());
    FrameRequest request;
    request.frame = 1;
    request.ccd = true;
    request.queries.separation = false;
    request.update.positions.push_back(
        {scene->objects[1].id, {{0.5, 0.25, -1.0}, {0.6, 0.25, -0.5}, {0.5, 0.35, -0.5}}});
    ASSERT_TRUE(stream.value()->send(request).ok());
    auto got = stream.value()->receive();
    ASSERT_TRUE(got.ok()) << got.status().to_string();
    ASSERT_TRUE(got->ccd.has_value());
    ASSERT_TRUE(got->ccd->earliest.has_value());
    const auto& first = got->ccd->pairs[*got->ccd->earliest];
    // The tip (vertex 0 of the dart) crosses z = 0 at t = 0.5; a conservative toi is <= 0.5 and,
    // with the default tolerance, within 1e-5 of it.
    EXPECT_EQ(first.kind, ccd::CcdKind::vertex_face);
    EXPECT_EQ(first.object, 1u);
    EXPECT_EQ(first.primitive, 0u);
    EXPECT_EQ(first.other, 0u);
    EXPECT_LE(first.toi, 0.5);
    EXPECT_GT(first.toi, 0.5 - 1e-5);
    ASSERT_EQ(got->ccd->object_pairs.size(), 1u);
    EXPECT_EQ(got->ccd->object_pairs[0].object, 0u);
    EXPECT_EQ(got->ccd->object_pairs[0].other, 1u);
    EXPECT_TRUE(stream.value()->finish().ok());
}

TEST(CcdFrames, CcdFrameThatChangesTopologyIsRefusedWhole) {
    DaemonProcess daemon;
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = Client::connect(daemon.address());
    ASSERT_TRUE(c.ok());
    auto scene = c.value()->create_scene("s", {square("a", 0.0)});
    ASSERT_TRUE(scene.ok());
    FrameRequest request;
    request.ccd = true;
    request.update.positions.push_back(
        {scene->objects[0].id, {{0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}}});
    request.update.additions.push_back(square("b", 2.0));
    auto got = c.value()->query(scene->scene_id, request);
    ASSERT_FALSE(got.ok());
    EXPECT_EQ(got.status().code(), StatusCode::invalid_argument);
    EXPECT_NE(got.status().message().find("queries.ccd"), std::string::npos)
        << got.status().message();
    auto described = c.value()->describe_scene(scene->scene_id);
    ASSERT_TRUE(described.ok());
    EXPECT_EQ(described->objects.size(), 1u);
    EXPECT_EQ(described->frames, 0u);

    request.update.additions.clear();
    request.ccd_request.elementary.min_distance = -1.0;
    got = c.value()->query(scene->scene_id, request);
    ASSERT_FALSE(got.ok());
    EXPECT_EQ(got.status().code(), StatusCode::invalid_argument);
    EXPECT_NE(got.status().message().find("ccd_min_distance"), std::string::npos);
}

}  // namespace
}  // namespace proxima::test
