// proximad as a process, driven with the generated stub: start-up contract, health, config,
// validation of malformed requests (each rejected whole with the right code, the scene left as it
// was), limits, chunked uploads, pipelined frames and the SIGTERM drain.
#include <google/protobuf/util/message_differencer.h>
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "daemon_process.hpp"
#include "support/random_scenes.hpp"
#include "wire.hpp"

namespace proxima::test {
namespace {

using namespace std::chrono_literals;

NamedMesh unit_box(const std::string& name, double x) {
    return {name, box({x, 0, 0}, {x + 1, 1, 1})};
}

// A sphere of about 2 * rings * segments triangles around `centre`.
NamedMesh ball(const std::string& name, const Vec3& centre, int rings, int segments,
               std::uint64_t seed = 1) {
    Rng rng(seed);
    NamedMesh m{name, sphere(rng, rings, segments, 1.0, 0.05)};
    for (auto& v : m.mesh.vertices) {
        v = v + centre;
    }
    return m;
}

struct Fixture {
    explicit Fixture(std::vector<std::string> flags = {}) : daemon(std::move(flags)) {
        EXPECT_TRUE(daemon.ok()) << daemon.error();
        stub = make_stub(daemon.address());
    }
    DaemonProcess daemon;
    std::unique_ptr<v1::Proximity::Stub> stub;

    v1::ServerInfo info() {
        grpc::ClientContext context;
        deadline_in(context, 5s);
        v1::ServerInfo out;
        const auto s = stub->GetServerInfo(&context, {}, &out);
        EXPECT_TRUE(s.ok()) << s.error_message();
        return out;
    }

    grpc::Status create(const std::vector<NamedMesh>& objects, v1::SceneInfo* out,
                        const std::string& name = "test") {
        v1::CreateSceneRequest request;
        request.set_name(name);
        for (const auto& o : objects) {
            set_mesh(o, request.add_objects());
        }
        grpc::ClientContext context;
        deadline_in(context, 10s);
        return stub->CreateScene(&context, request, out);
    }

    grpc::Status describe(const std::string& scene_id, v1::SceneInfo* out) {
        v1::DescribeSceneRequest request;
        request.set_scene_id(scene_id);
        grpc::ClientContext context;
        deadline_in(context, 5s);
        return stub->DescribeScene(&context, request, out);
    }

    grpc::Status query(const v1::Frame& frame, v1::FrameResult* out) {
        grpc::ClientContext context;
        deadline_in(context, 10s);
        return stub->Query(&context, frame, out);
    }
};

// Every query that has an answer: what "the scene is unchanged" is checked against.
v1::Frame probe_frame(const std::string& scene_id) {
    v1::Frame f;
    f.set_scene_id(scene_id);
    f.mutable_queries()->set_separation(true);
    f.mutable_queries()->set_self(true);
    f.mutable_queries()->set_collisions(true);
    f.mutable_queries()->set_tolerance(0.75);
    f.mutable_queries()->set_self_points(true);
    return f;
}

// The answer without the parts that legitimately differ between two runs (timings).
v1::FrameResult answers(v1::FrameResult r) {
    r.clear_stats();
    r.clear_frame();
    return r;
}

bool same(const google::protobuf::Message& a, const google::protobuf::Message& b) {
    return google::protobuf::util::MessageDifferencer::Equals(a, b);
}

TEST(Daemon, FirstLineHealthAndServerInfo) {
    Fixture fx;
    ASSERT_TRUE(fx.daemon.ok()) << fx.daemon.error();
    EXPECT_TRUE(std::regex_match(fx.daemon.first_line(),
                                 std::regex(R"(listening on 127\.0\.0\.1:[1-9][0-9]*)")))
        << fx.daemon.first_line();

    EXPECT_EQ(health_check(fx.daemon.address(), ""), 1);  // SERVING
    EXPECT_EQ(health_check(fx.daemon.address(), "proxima.v1.Proximity"), 1);

    const auto info = fx.info();
    EXPECT_EQ(info.api(), "proxima.v1");
    EXPECT_FALSE(info.version().empty());
    // With EGL (llvmpipe in CI, tests/integration/test_gpu_backend.cpp) or without.
    if (info.gl_renderer().empty()) {
        EXPECT_EQ(info.proximity_backend(), "cpu (voronoi-cpu, bvh, brute)");
    } else {
        EXPECT_EQ(info.proximity_backend(), "gpu (voronoi-gpu) + cpu (voronoi-cpu, bvh, brute)");
    }
    EXPECT_EQ(info.live_scenes(), 0u);
    EXPECT_EQ(info.live_streams(), 0u);
    // The documented defaults (docs/server.md).
    EXPECT_EQ(info.limits().max_scenes(), 64u);
    EXPECT_EQ(info.limits().max_objects_per_scene(), 100000u);
    EXPECT_EQ(info.limits().max_triangles_per_scene(), 50000000u);
    EXPECT_EQ(info.limits().max_message_bytes(), 256u << 20);
    EXPECT_EQ(info.limits().max_frames_in_flight(), 4u);
}

TEST(Daemon, ConfigFileWithFlagOverrides) {
    const auto dir = std::filesystem::temp_directory_path();
    const auto good = dir / ("proximad_config_" + std::to_string(getpid()) + ".json");
    const auto bad = dir / ("proximad_config_bad_" + std::to_string(getpid()) + ".json");
    std::ofstream(good) << R"({"max-scenes": 3, "max-frames-in-flight": 2, "log-level": "warn"})";
    std::ofstream(bad) << R"({"max-scenes": 3, "max-scene": 4})";
    {
        Fixture fx({"--config", good.string(), "--max-scenes", "5"});
        ASSERT_TRUE(fx.daemon.ok()) << fx.daemon.error();
        const auto info = fx.info();
        EXPECT_EQ(info.limits().max_scenes(), 5u);            // the flag beats the file
        EXPECT_EQ(info.limits().max_frames_in_flight(), 2u);  // from the file
    }
    {
        // A misspelt key is an error (exit status 2), not a silently ignored setting.
        DaemonProcess daemon({"--config", bad.string()}, 5s);
        EXPECT_FALSE(daemon.ok());
        const auto status = daemon.wait_exit(5s);
        ASSERT_TRUE(status.has_value());
        EXPECT_TRUE(WIFEXITED(*status));
        EXPECT_EQ(WEXITSTATUS(*status), 2);
    }
    std::filesystem::remove(good);
    std::filesystem::remove(bad);
}

TEST(Daemon, MalformedRequestsLeaveTheSceneUnchanged) {
    Fixture fx;
    ASSERT_TRUE(fx.daemon.ok()) << fx.daemon.error();
    v1::SceneInfo scene;
    ASSERT_TRUE(fx.create({unit_box("a", 0), unit_box("b", 1.5), unit_box("c", 3.2)}, &scene).ok());
    const std::string id = scene.scene_id();
    EXPECT_EQ(id.size(), 16u);
    const auto a = scene.objects(0).id();
    const auto b = scene.objects(1).id();
    const auto box_vertices = unit_box("", 0).mesh.vertices;

    v1::FrameResult baseline;
    ASSERT_TRUE(fx.query(probe_frame(id), &baseline).ok());

    struct Case {
        std::string what;
        grpc::StatusCode code;
        std::string message_has;  // the message names what is wrong
        v1::Frame frame;
    };
    std::vector<Case> cases;
    auto add = [&](std::string what, grpc::StatusCode code, std::string has) -> v1::Frame& {
        cases.push_back({std::move(what), code, std::move(has), probe_frame(id)});
        return cases.back().frame;
    };
    {
        // A valid change to `a` next to a wrong vertex count for `b`: all or nothing.
        auto& f = add("wrong vertex count", grpc::StatusCode::INVALID_ARGUMENT, "positions[1]");
        auto moved = box_vertices;
        for (auto& v : moved) {
            v.z += 5;
        }
        auto* p = f.add_positions();
        p->set_object_id(a);
        set_vertices(moved, p->mutable_vertices());
        p = f.add_positions();
        p->set_object_id(b);
        set_vertices(std::vector<Vec3>(box_vertices.begin(), box_vertices.end() - 1),
                     p->mutable_vertices());
    }
    {
        auto& f = add("index out of range", grpc::StatusCode::INVALID_ARGUMENT, "out of range");
        auto m = unit_box("bad-index", 10);
        m.mesh.triangles[3][1] = static_cast<std::uint32_t>(m.mesh.vertices.size());
        set_mesh(m, f.add_additions());
    }
    {
        auto& f = add("NaN coordinate", grpc::StatusCode::INVALID_ARGUMENT, "non-finite");
        auto moved = box_vertices;
        moved[4].y = std::numeric_limits<double>::quiet_NaN();
        auto* p = f.add_positions();
        p->set_object_id(a);
        set_vertices(moved, p->mutable_vertices());
    }
    {
        auto& f = add("unknown scene", grpc::StatusCode::NOT_FOUND, "0123456789abcdef");
        f.set_scene_id("0123456789abcdef");
    }
    {
        auto& f = add("unknown object id", grpc::StatusCode::NOT_FOUND, "object 999");
        auto* p = f.add_positions();
        p->set_object_id(999);
        set_vertices(box_vertices, p->mutable_vertices());
    }
    {
        auto& f = add("truncated vertex buffer", grpc::StatusCode::INVALID_ARGUMENT,
                      "not a multiple of 24");
        auto* p = f.add_positions();
        p->set_object_id(a);
        set_vertices(box_vertices, p->mutable_vertices());
        p->mutable_vertices()->mutable_data()->pop_back();
    }
    {
        auto& f =
            add("float32 buffer size", grpc::StatusCode::INVALID_ARGUMENT, "not a multiple of 12");
        auto* p = f.add_positions();
        p->set_object_id(a);
        p->mutable_vertices()->set_type(v1::SCALAR_TYPE_FLOAT32);
        p->mutable_vertices()->set_data(std::string(12 * 8 + 4, '\0'));
    }
    {
        auto& f =
            add("index buffer size", grpc::StatusCode::INVALID_ARGUMENT, "not a multiple of 12");
        auto m = unit_box("torn", 10);
        set_mesh(m, f.add_additions());
        f.mutable_additions(0)->mutable_indices()->resize(12 * 5 + 8);
    }
    {
        auto& f = add("unspecified scalar type", grpc::StatusCode::INVALID_ARGUMENT,
                      "SCALAR_TYPE_FLOAT64");
        set_mesh(unit_box("typeless", 10), f.add_additions());
        f.mutable_additions(0)->mutable_vertices()->set_type(v1::SCALAR_TYPE_UNSPECIFIED);
    }
    {
        auto& f = add("object named twice", grpc::StatusCode::INVALID_ARGUMENT, "more than once");
        f.add_removals(a);
        auto* p = f.add_positions();
        p->set_object_id(a);
        set_vertices(box_vertices, p->mutable_vertices());
    }
    {
        auto& f = add("negative tolerance", grpc::StatusCode::INVALID_ARGUMENT, "tolerance");
        f.mutable_queries()->set_tolerance(-1.0);
        f.add_removals(b);
    }
    {
        auto& f = add("empty mesh", grpc::StatusCode::INVALID_ARGUMENT, "no triangles");
        auto* m = f.add_additions();
        m->set_name("empty");
        m->mutable_vertices()->set_type(v1::SCALAR_TYPE_FLOAT64);
    }

    for (const auto& c : cases) {
        SCOPED_TRACE(c.what);
        v1::SceneInfo before;
        ASSERT_TRUE(fx.describe(id, &before).ok());
        v1::FrameResult ignored;
        const auto s = fx.query(c.frame, &ignored);
        EXPECT_EQ(s.error_code(), c.code) << s.error_message();
        EXPECT_NE(s.error_message().find(c.message_has), std::string::npos) << s.error_message();
        v1::SceneInfo after;
        ASSERT_TRUE(fx.describe(id, &after).ok());
        EXPECT_TRUE(same(before, after)) << before.DebugString() << after.DebugString();
        v1::FrameResult again;
        ASSERT_TRUE(fx.query(probe_frame(id), &again).ok());
        EXPECT_TRUE(same(answers(again), answers(baseline)));
    }

    // On a stream, a bad frame ends the stream with its status, after the good frames' results.
    grpc::ClientContext context;
    deadline_in(context, 10s);
    auto stream = fx.stub->StreamFrames(&context);
    v1::SceneInfo before;
    ASSERT_TRUE(fx.describe(id, &before).ok());
    ASSERT_TRUE(stream->Write(probe_frame(id)));
    ASSERT_TRUE(stream->Write(cases.front().frame));
    v1::FrameResult first;
    ASSERT_TRUE(stream->Read(&first));
    EXPECT_TRUE(same(answers(first), answers(baseline)));
    stream->WritesDone();
    v1::FrameResult none;
    EXPECT_FALSE(stream->Read(&none));
    const auto s = stream->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
    v1::SceneInfo after;
    ASSERT_TRUE(fx.describe(id, &after).ok());
    EXPECT_EQ(after.frames(), before.frames() + 1);  // the good frame only
    EXPECT_TRUE(same(answers(first), answers(baseline)));
}

TEST(Daemon, OversizedMessageIsResourceExhausted) {
    Fixture fx({"--max-message-bytes", "65536"});
    ASSERT_TRUE(fx.daemon.ok()) << fx.daemon.error();
    v1::SceneInfo scene;
    // ~2 * 40 * 40 triangles: ~115 KB of float64 vertices and indices, over the 64 KiB limit.
    const auto s = fx.create({ball("big", {0, 0, 0}, 40, 40)}, &scene);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
    EXPECT_EQ(fx.info().live_scenes(), 0u);
    // Still serving, and a message under the limit goes through.
    ASSERT_TRUE(fx.create({unit_box("small", 0)}, &scene).ok());
    EXPECT_EQ(fx.info().live_scenes(), 1u);

    // The limit holds for answers too: self distances with points of ~2000 triangles (~115 KB,
    // from a request of ~48 KB).
    ASSERT_TRUE(fx.create({ball("medium", {0, 0, 0}, 32, 32)}, &scene).ok());
    v1::Frame frame;
    frame.set_scene_id(scene.scene_id());
    frame.mutable_queries()->set_self(true);
    frame.mutable_queries()->set_self_points(true);
    v1::FrameResult result;
    const auto big_answer = fx.query(frame, &result);
    EXPECT_EQ(big_answer.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED)
        << big_answer.error_message();
    EXPECT_NE(big_answer.error_message().find("max-message-bytes = 65536"), std::string::npos)
        << big_answer.error_message();
    frame.mutable_queries()->set_self_points(false);
    frame.mutable_queries()->set_self(false);
    frame.mutable_queries()->set_separation(true);
    EXPECT_TRUE(fx.query(frame, &result).ok());
}

TEST(Daemon, BusyPortIsAnError) {
    Fixture first;
    ASSERT_TRUE(first.daemon.ok()) << first.daemon.error();
    // Not the fixture (which listens on port 0): the same port as the first daemon.
    int out[2];
    ASSERT_EQ(pipe(out), 0);
    const pid_t pid = fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
        prctl(PR_SET_PDEATHSIG, SIGKILL);
        dup2(out[1], STDOUT_FILENO);
        const std::string listen = first.daemon.address();
        execl(PROXIMAD_PATH, PROXIMAD_PATH, "--listen", listen.c_str(), "--log-level", "off",
              static_cast<char*>(nullptr));
        _exit(127);
    }
    close(out[1]);
    int status = 0;
    ASSERT_EQ(waitpid(pid, &status, 0), pid);
    char buffer[64];
    EXPECT_EQ(read(out[0], buffer, sizeof(buffer)), 0) << "a second daemon printed a line";
    close(out[0]);
    EXPECT_TRUE(WIFEXITED(status));
    EXPECT_EQ(WEXITSTATUS(status), 1);
    EXPECT_EQ(first.info().api(), "proxima.v1");  // the first one is unaffected
}

TEST(Daemon, LimitsOnScenesObjectsAndTriangles) {
    Fixture fx(
        {"--max-scenes", "2", "--max-objects-per-scene", "3", "--max-triangles-per-scene", "40"});
    ASSERT_TRUE(fx.daemon.ok()) << fx.daemon.error();
    v1::SceneInfo s1;
    v1::SceneInfo s2;
    v1::SceneInfo s3;

    // Objects: four boxes in one scene is one too many.
    auto st =
        fx.create({unit_box("a", 0), unit_box("b", 2), unit_box("c", 4), unit_box("d", 6)}, &s1);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_NE(st.error_message().find("max-objects-per-scene = 3"), std::string::npos)
        << st.error_message();
    EXPECT_EQ(fx.info().live_scenes(), 0u);

    ASSERT_TRUE(fx.create({unit_box("a", 0), unit_box("b", 2)}, &s1).ok());
    // Additions in a frame over the object limit: rejected whole, scene unchanged.
    v1::Frame grow = probe_frame(s1.scene_id());
    set_mesh(unit_box("c", 4), grow.add_additions());
    set_mesh(unit_box("d", 6), grow.add_additions());
    v1::FrameResult r;
    st = fx.query(grow, &r);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_NE(st.error_message().find("max-objects-per-scene"), std::string::npos);
    v1::SceneInfo after;
    ASSERT_TRUE(fx.describe(s1.scene_id(), &after).ok());
    EXPECT_EQ(after.objects_size(), 2);

    // Triangles: 2 boxes hold 24 triangles; a third object of 24 makes 48 > 40.
    grow.mutable_additions()->RemoveLast();
    set_mesh(ball("c", {6, 0, 0}, 4, 4), grow.mutable_additions(0));
    st = fx.query(grow, &r);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_NE(st.error_message().find("max-triangles-per-scene = 40"), std::string::npos)
        << st.error_message();

    // Scenes: two are allowed, a third (created or stream-owned) is not.
    ASSERT_TRUE(fx.create({unit_box("a", 0)}, &s2).ok());
    st = fx.create({unit_box("a", 0)}, &s3);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_NE(st.error_message().find("max-scenes = 2"), std::string::npos) << st.error_message();

    grpc::ClientContext context;
    deadline_in(context, 10s);
    auto stream = fx.stub->StreamFrames(&context);
    v1::Frame first;
    set_mesh(unit_box("a", 0), first.add_additions());
    ASSERT_TRUE(stream->Write(first));
    stream->WritesDone();
    EXPECT_FALSE(stream->Read(&r));
    st = stream->Finish();
    EXPECT_EQ(st.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_NE(st.error_message().find("max-scenes"), std::string::npos) << st.error_message();
    EXPECT_EQ(fx.info().live_scenes(), 2u);
}

TEST(Daemon, ChunkedUploadAddsOnlyCompleteValidObjects) {
    Fixture fx({"--max-message-bytes", "65536"});
    ASSERT_TRUE(fx.daemon.ok()) << fx.daemon.error();
    v1::SceneInfo scene;
    ASSERT_TRUE(fx.create({unit_box("a", 0)}, &scene).ok());
    const auto big = ball("big", {5, 0, 0}, 40, 40);  // larger than one message
    const std::string vertices = float64_bytes(big.mesh.vertices);
    const std::string indices = index_bytes(big.mesh.triangles);

    // Sends the header, then the buffers in 16 KiB chunks, cut short or padded as asked.
    auto upload = [&](std::size_t vertex_bytes, std::size_t index_bytes_sent, bool header,
                      v1::ObjectInfo* out) {
        grpc::ClientContext context;
        deadline_in(context, 10s);
        auto writer = fx.stub->UploadObject(&context, out);
        if (header) {
            v1::UploadChunk h;
            h.mutable_header()->set_scene_id(scene.scene_id());
            h.mutable_header()->set_name(big.name);
            h.mutable_header()->set_type(v1::SCALAR_TYPE_FLOAT64);
            h.mutable_header()->set_vertex_count(
                static_cast<std::uint32_t>(big.mesh.vertices.size()));
            h.mutable_header()->set_triangle_count(
                static_cast<std::uint32_t>(big.mesh.triangles.size()));
            writer->Write(h);
        }
        auto send = [&](const std::string& data, std::size_t n, bool vertex) {
            std::string all = data.substr(0, std::min(n, data.size()));
            all.resize(n, '\0');
            for (std::size_t at = 0; at < all.size(); at += 16384) {
                v1::UploadChunk c;
                if (vertex) {
                    c.set_vertex_bytes(all.substr(at, 16384));
                } else {
                    c.set_index_bytes(all.substr(at, 16384));
                }
                if (!writer->Write(c)) {
                    return;  // the daemon already refused the upload
                }
            }
        };
        send(vertices, vertex_bytes, true);
        send(indices, index_bytes_sent, false);
        writer->WritesDone();
        return writer->Finish();
    };

    v1::ObjectInfo info;
    auto st = upload(vertices.size() + 24, indices.size(), true, &info);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << st.error_message();
    EXPECT_NE(st.error_message().find("exceed"), std::string::npos) << st.error_message();
    st = upload(vertices.size(), indices.size() - 12, true, &info);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << st.error_message();
    EXPECT_NE(st.error_message().find("incomplete"), std::string::npos) << st.error_message();
    st = upload(vertices.size(), indices.size(), false, &info);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << st.error_message();
    v1::SceneInfo after;
    ASSERT_TRUE(fx.describe(scene.scene_id(), &after).ok());
    EXPECT_EQ(after.objects_size(), 1);

    st = upload(vertices.size(), indices.size(), true, &info);
    ASSERT_TRUE(st.ok()) << st.error_message();
    EXPECT_EQ(info.name(), "big");
    EXPECT_EQ(info.triangle_count(), big.mesh.triangles.size());
    ASSERT_TRUE(fx.describe(scene.scene_id(), &after).ok());
    ASSERT_EQ(after.objects_size(), 2);
    EXPECT_EQ(after.objects(1).id(), info.id());
    EXPECT_EQ(after.objects(1).vertex_count(), big.mesh.vertices.size());
}

TEST(Daemon, PipelinedFramesAreAnsweredInOrder) {
    Fixture fx({"--max-frames-in-flight", "2"});
    ASSERT_TRUE(fx.daemon.ok()) << fx.daemon.error();
    grpc::ClientContext context;
    deadline_in(context, 15s);
    auto stream = fx.stub->StreamFrames(&context);
    v1::Frame first = probe_frame("");
    set_mesh(unit_box("a", 0), first.add_additions());
    set_mesh(unit_box("b", 1.5), first.add_additions());
    first.set_frame(100);
    ASSERT_TRUE(stream->Write(first));
    v1::FrameResult r;
    ASSERT_TRUE(stream->Read(&r));
    const std::string id = r.scene_id();
    EXPECT_EQ(r.object_ids_size(), 2);
    EXPECT_EQ(fx.info().live_streams(), 1u);
    // More frames than may be in flight, written before any is read: backpressure holds the
    // extra ones in the transport, and answers come back in order.
    std::thread writer([&] {
        for (int k = 1; k <= 12; ++k) {
            v1::Frame f = probe_frame(k % 2 == 0 ? id : "");
            f.set_frame(100 + k);
            if (!stream->Write(f)) {
                return;
            }
        }
        stream->WritesDone();
    });
    for (int k = 1; k <= 12; ++k) {
        ASSERT_TRUE(stream->Read(&r));
        EXPECT_EQ(r.frame(), 100u + k);
        EXPECT_EQ(r.scene_id(), id);
    }
    writer.join();
    EXPECT_FALSE(stream->Read(&r));
    EXPECT_TRUE(stream->Finish().ok());
    // The stream-owned scene went with the stream.
    v1::SceneInfo gone;
    EXPECT_EQ(fx.describe(id, &gone).error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST(Daemon, SigtermDrainsAndExitsZero) {
    Fixture fx({"--drain-seconds", "3"});
    ASSERT_TRUE(fx.daemon.ok()) << fx.daemon.error();
    grpc::ClientContext context;
    deadline_in(context, 15s);
    auto stream = fx.stub->StreamFrames(&context);
    v1::Frame first = probe_frame("");
    set_mesh(unit_box("a", 0), first.add_additions());
    ASSERT_TRUE(stream->Write(first));
    v1::FrameResult r;
    ASSERT_TRUE(stream->Read(&r));

    // The stream is open and idle: the drain ends it (UNAVAILABLE, so the client knows to
    // reconnect) and the daemon exits 0 well within the drain deadline.
    const auto start = std::chrono::steady_clock::now();
    fx.daemon.signal(SIGTERM);
    EXPECT_FALSE(stream->Read(&r));
    const auto s = stream->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE) << s.error_message();
    const auto status = fx.daemon.wait_exit(6s);
    ASSERT_TRUE(status.has_value()) << "proximad still running 6 s after SIGTERM";
    EXPECT_TRUE(WIFEXITED(*status));
    EXPECT_EQ(WEXITSTATUS(*status), 0);
    EXPECT_LT(std::chrono::steady_clock::now() - start, 4s);
}

// A stream-owned scene's first frame with brute-force self on balls of ~1100 triangles, 10 balls a
// hardware thread: about a second of work on any machine.
v1::Frame heavy_first_frame() {
    v1::Frame first;
    const int balls = 10 * static_cast<int>(std::max(2u, std::thread::hardware_concurrency()));
    for (int i = 0; i < balls; ++i) {
        set_mesh(ball(std::string("b").append(std::to_string(i)), {3.0 * i, 0, 0}, 24, 24, i + 1),
                 first.add_additions());
    }
    first.mutable_queries()->set_self(true);
    first.mutable_queries()->set_culler(v1::CULLER_BRUTE);
    return first;
}

TEST(Daemon, SigtermLetsAFrameInFlightFinish) {
    Fixture fx({"--drain-seconds", "10"});
    ASSERT_TRUE(fx.daemon.ok()) << fx.daemon.error();
    // About a second of work, in flight when SIGTERM arrives.
    const v1::Frame first = heavy_first_frame();
    grpc::ClientContext context;
    deadline_in(context, 20s);
    auto stream = fx.stub->StreamFrames(&context);
    ASSERT_TRUE(stream->Write(first));
    std::this_thread::sleep_for(150ms);
    fx.daemon.signal(SIGTERM);
    std::this_thread::sleep_for(50ms);

    // Draining: health says NOT_SERVING and new calls are refused, while the frame goes on.
    EXPECT_EQ(health_check(fx.daemon.address(), ""), 2);
    v1::ServerInfo info;
    grpc::ClientContext info_context;
    deadline_in(info_context, 5s);
    EXPECT_EQ(fx.stub->GetServerInfo(&info_context, {}, &info).error_code(),
              grpc::StatusCode::UNAVAILABLE);

    v1::FrameResult r;
    ASSERT_TRUE(stream->Read(&r)) << "the frame in flight was not answered";
    EXPECT_EQ(r.self_size(), first.additions_size());
    EXPECT_FALSE(stream->Read(&r));
    EXPECT_EQ(stream->Finish().error_code(), grpc::StatusCode::UNAVAILABLE);
    const auto status = fx.daemon.wait_exit(10s);
    ASSERT_TRUE(status.has_value());
    EXPECT_TRUE(WIFEXITED(*status));
    EXPECT_EQ(WEXITSTATUS(*status), 0);
}

TEST(Daemon, DrainDeadlineCancelsWorkThatOutlastsIt) {
    Fixture fx({"--drain-seconds", "0.2"});
    ASSERT_TRUE(fx.daemon.ok()) << fx.daemon.error();
    const v1::Frame first = heavy_first_frame();
    grpc::ClientContext context;
    deadline_in(context, 20s);
    auto stream = fx.stub->StreamFrames(&context);
    ASSERT_TRUE(stream->Write(first));
    std::this_thread::sleep_for(150ms);
    const auto start = std::chrono::steady_clock::now();
    fx.daemon.signal(SIGTERM);
    v1::FrameResult r;
    EXPECT_FALSE(stream->Read(&r));
    EXPECT_FALSE(stream->Finish().ok());
    const auto status = fx.daemon.wait_exit(5s);
    ASSERT_TRUE(status.has_value());
    EXPECT_TRUE(WIFEXITED(*status));
    EXPECT_EQ(WEXITSTATUS(*status), 0);
    // The cancel reached the engine: no waiting for the rest of the query.
    EXPECT_LT(std::chrono::steady_clock::now() - start, 700ms);
}

}  // namespace
}  // namespace proxima::test
