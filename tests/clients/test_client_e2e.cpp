// The C++ client library against a real proximad (started here on a free loopback port): scenes
// built inline and through chunked uploads, answers equal to an in-process engine bit for bit,
// pipelined frames on a stream, and the stream's error, cancel and destructor paths.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <bit>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>

#include "client/proxima_client.hpp"
#include "proxima/query/query.hpp"
#include "proxima/render/snapshot.hpp"
#include "support/random_scenes.hpp"

namespace proxima::client {
namespace {

// proximad as a child process; the address comes from its first stdout line.
class DaemonEnvironment : public ::testing::Environment {
  public:
    static inline std::string address;

    void SetUp() override {
        int out[2];
        ASSERT_EQ(pipe(out), 0);
        m_pid = fork();
        ASSERT_GE(m_pid, 0);
        if (m_pid == 0) {
            dup2(out[1], STDOUT_FILENO);
            close(out[0]);
            close(out[1]);
            // The daemon's info log would bury the test output; warnings and errors still show.
            execl(PROXIMAD_PATH, PROXIMAD_PATH, "--listen", "127.0.0.1:0", "--log-level", "warn",
                  static_cast<char*>(nullptr));
            _exit(127);
        }
        close(out[1]);
        m_stdout = fdopen(out[0], "r");
        char line[256] = {};
        ASSERT_NE(fgets(line, sizeof line, m_stdout), nullptr) << "proximad printed nothing";
        std::string s(line);
        const std::string prefix = "listening on ";
        ASSERT_EQ(s.rfind(prefix, 0), 0u) << s;
        address = s.substr(prefix.size());
        while (!address.empty() && (address.back() == '\n' || address.back() == '\r')) {
            address.pop_back();
        }
    }

    void TearDown() override {
        if (m_pid <= 0) {
            return;
        }
        kill(m_pid, SIGTERM);
        int status = 0;
        ASSERT_EQ(waitpid(m_pid, &status, 0), m_pid);
        EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0)
            << "proximad did not exit 0 after SIGTERM (status " << status << ")";
        if (m_stdout) {
            fclose(m_stdout);
        }
    }

  private:
    pid_t m_pid = -1;
    FILE* m_stdout = nullptr;
};

std::unique_ptr<Client> connect_or_die(ConnectOptions options = {}) {
    auto c = Client::connect(DaemonEnvironment::address, options);
    EXPECT_TRUE(c.ok()) << c.status().to_string();
    return c.ok() ? std::move(c).value() : nullptr;
}

std::vector<NamedMesh> some_objects(std::uint64_t seed) {
    test::Rng rng(seed);
    std::vector<NamedMesh> out;
    out.push_back({"ball", test::sphere(rng, 8, 12, 1.0, 0.1)});
    out.push_back({"sheet", test::sheet(rng, 10, 8, 0.2)});
    test::transform(out.back().mesh, 1.0, {1.2, 0.0, 0.0}, 0.3);
    out.push_back({"box", test::box({-0.5, -0.5, 1.2}, {0.5, 0.5, 1.6})});
    return out;
}

QueryRequest all_queries() {
    QueryRequest q;
    q.self = true;
    q.collisions = true;
    q.tolerance = 0.1;
    return q;
}

std::uint64_t bits(double d) {
    return std::bit_cast<std::uint64_t>(d);
}

// Rounds to float and back. Through a volatile because GCC 12.2's SLP vectorizer (-O2) drops the
// rounding of `v = {float(v.x), float(v.y), float(v.z)}` over a vector of Vec3.
double to_float(double d) {
    volatile float f = static_cast<float>(d);
    return f;
}

// Same answers (timings aside): separation, self distances and pairs, exactly.
void expect_same_answers(const QueryResult& local, const QueryResult& remote) {
    ASSERT_EQ(local.separation.size(), remote.separation.size());
    for (std::size_t i = 0; i < local.separation.size(); ++i) {
        EXPECT_EQ(local.separation[i].other, remote.separation[i].other);
        EXPECT_EQ(bits(local.separation[i].distance), bits(remote.separation[i].distance));
        EXPECT_EQ(local.separation[i].triangle, remote.separation[i].triangle);
        EXPECT_EQ(local.separation[i].point, remote.separation[i].point);
    }
    ASSERT_EQ(local.self.size(), remote.self.size());
    for (std::size_t i = 0; i < local.self.size(); ++i) {
        ASSERT_EQ(local.self[i].size(), remote.self[i].size());
        for (std::size_t t = 0; t < local.self[i].size(); ++t) {
            EXPECT_EQ(bits(local.self[i][t].distance), bits(remote.self[i][t].distance));
        }
    }
    auto same_pairs = [](const std::vector<FeaturePair>& a, const std::vector<FeaturePair>& b) {
        ASSERT_EQ(a.size(), b.size());
        for (std::size_t i = 0; i < a.size(); ++i) {
            EXPECT_FALSE(a[i] < b[i] || b[i] < a[i]);
            EXPECT_EQ(bits(a[i].distance), bits(b[i].distance));
        }
    };
    same_pairs(local.collisions, remote.collisions);
    same_pairs(local.tolerance, remote.tolerance);
}

TEST(ClientE2e, ScenesInlineAndUploadedAnswerLikeTheEngine) {
    const auto objects = some_objects(1);
    ProximityEngine engine;
    for (const auto& o : objects) {
        ASSERT_TRUE(engine.scene().add_object(o).ok());
    }
    auto local = engine.query(all_queries());
    ASSERT_TRUE(local.ok());

    // All inline, the first inline and the rest uploaded, all uploaded: same scene, same order.
    for (std::size_t inline_bytes : {std::size_t{1} << 20, std::size_t{12000}, std::size_t{0}}) {
        ConnectOptions options;
        options.inline_mesh_bytes = inline_bytes;
        auto c = connect_or_die(options);
        ASSERT_TRUE(c);
        auto scene = c->create_scene("e2e", objects);
        ASSERT_TRUE(scene.ok()) << scene.status().to_string();
        ASSERT_EQ(scene->objects.size(), objects.size());
        auto described = c->describe_scene(scene->scene_id);
        ASSERT_TRUE(described.ok());
        for (std::size_t i = 0; i < objects.size(); ++i) {
            EXPECT_EQ(described->objects[i].name, objects[i].name);
            EXPECT_EQ(described->objects[i].id, scene->objects[i].id);
            EXPECT_EQ(described->objects[i].triangle_count, objects[i].mesh.triangles.size());
        }
        EXPECT_EQ(described->triangle_count, scene->triangle_count);

        FrameRequest frame;
        frame.frame = 7;
        frame.queries = all_queries();
        auto remote = c->query(scene->scene_id, frame);
        ASSERT_TRUE(remote.ok()) << remote.status().to_string();
        EXPECT_EQ(remote->frame, 7u);
        EXPECT_EQ(remote->object_ids.size(), objects.size());
        EXPECT_GT(remote->server_seconds, 0.0);
        expect_same_answers(local.value(), remote->result);
        EXPECT_TRUE(c->delete_scene(scene->scene_id).ok());
        EXPECT_EQ(c->describe_scene(scene->scene_id).status().code(), StatusCode::not_found);
    }
}

TEST(ClientE2e, LargeMeshTravelsInSeveralChunks) {
    // 400 x 400 quads: 160,801 vertices (3.9 MB in float64) and 320,000 triangles (3.8 MB), so
    // four 1 MiB chunks of each, and far over the 1 MiB inline budget.
    test::Rng rng(5);
    std::vector<NamedMesh> objects{{"big sheet", test::sheet(rng, 400, 400, 0.3)},
                                   {"box", test::box({0.2, 0.2, 0.7}, {0.4, 0.4, 0.9})}};
    ASSERT_GT(objects[0].mesh.vertices.size() * 24, std::size_t{3} << 20);
    ASSERT_GT(objects[0].mesh.triangles.size() * 12, std::size_t{3} << 20);
    ProximityEngine engine;
    for (const auto& o : objects) {
        ASSERT_TRUE(engine.scene().add_object(o).ok());
    }
    auto local = engine.query({});
    ASSERT_TRUE(local.ok());
    auto c = connect_or_die();
    auto scene = c->create_scene("big", objects);
    ASSERT_TRUE(scene.ok()) << scene.status().to_string();
    EXPECT_EQ(scene->objects[0].vertex_count, objects[0].mesh.vertices.size());
    auto remote = c->query(scene->scene_id, {});
    ASSERT_TRUE(remote.ok()) << remote.status().to_string();
    expect_same_answers(local.value(), remote->result);
    EXPECT_TRUE(c->delete_scene(scene->scene_id).ok());
}

TEST(ClientE2e, Float32VerticesAreRoundedOnce) {
    auto objects = some_objects(2);
    ConnectOptions options;
    options.float32_vertices = true;
    auto c = connect_or_die(options);
    auto scene = c->create_scene("f32", objects);
    ASSERT_TRUE(scene.ok());
    for (auto& o : objects) {
        for (auto& v : o.mesh.vertices) {
            v = {to_float(v.x), to_float(v.y), to_float(v.z)};
        }
    }
    ProximityEngine engine;
    for (const auto& o : objects) {
        ASSERT_TRUE(engine.scene().add_object(o).ok());
    }
    auto local = engine.query(all_queries());
    FrameRequest frame;
    frame.queries = all_queries();
    auto remote = c->query(scene->scene_id, frame);
    ASSERT_TRUE(local.ok() && remote.ok());
    expect_same_answers(local.value(), remote->result);
    EXPECT_TRUE(c->delete_scene(scene->scene_id).ok());
}

TEST(ClientE2e, PipelinedFramesAnswerInOrder) {
    auto c = connect_or_die();
    auto info = c->server_info();
    ASSERT_TRUE(info.ok());
    ASSERT_GE(info->max_frames_in_flight, 1u);
    const auto objects = some_objects(3);
    auto scene = c->create_scene("pipelined", objects);
    ASSERT_TRUE(scene.ok());

    ProximityEngine engine;
    for (const auto& o : objects) {
        ASSERT_TRUE(engine.scene().add_object(o).ok());
    }
    auto stream = c->open_stream(scene->scene_id);
    ASSERT_TRUE(stream.ok());
    auto& s = *stream.value();
    test::Rng rng(9);
    const std::size_t batch = info->max_frames_in_flight;
    std::vector<QueryResult> expected;
    for (std::size_t k = 0; k < 2 * batch; ++k) {
        // Object 1 (the sheet) jitters every frame; ids are the daemon's.
        FrameRequest frame;
        frame.frame = 100 + k;
        frame.queries = all_queries();
        auto moved = test::jitter(rng, engine.scene()[1].vertices, 0.01);
        frame.update.positions.push_back({scene->objects[1].id, moved});
        SceneUpdate local;
        local.positions.push_back({engine.scene()[1].id, moved});
        ASSERT_TRUE(engine.scene().apply(local).ok());
        auto r = engine.query(all_queries());
        ASSERT_TRUE(r.ok());
        expected.push_back(std::move(r).value());
        ASSERT_TRUE(s.send(frame).ok());
        if ((k + 1) % batch == 0) {
            for (std::size_t j = k + 1 - batch; j <= k; ++j) {
                auto got = s.receive();
                ASSERT_TRUE(got.ok()) << got.status().to_string();
                EXPECT_EQ(got->frame, 100 + j);
                EXPECT_EQ(got->scene_id, scene->scene_id);
                expect_same_answers(expected[j], got->result);
            }
        }
    }
    // Nothing in flight: an immediate error, not a hang.
    EXPECT_EQ(s.receive().status().code(), StatusCode::failed_precondition);
    EXPECT_TRUE(s.finish().ok());
    auto after = c->describe_scene(scene->scene_id);
    ASSERT_TRUE(after.ok());  // not stream-owned: still there
    EXPECT_EQ(after->frames, 2 * batch);
    EXPECT_TRUE(c->delete_scene(scene->scene_id).ok());
}

TEST(ClientE2e, RejectedFrameEndsTheStreamWithTheServersStatus) {
    auto c = connect_or_die();
    auto stream = c->open_stream("");
    ASSERT_TRUE(stream.ok());
    auto& s = *stream.value();
    FrameRequest first;
    first.update.additions = some_objects(4);
    ASSERT_TRUE(s.send(first).ok());
    auto r = s.receive();
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    EXPECT_EQ(r->added_ids.size(), 3u);
    EXPECT_FALSE(r->scene_id.empty());

    FrameRequest bad;
    bad.frame = 1;
    bad.update.removals.push_back(987654);
    ASSERT_TRUE(s.send(bad).ok());
    auto failed = s.receive();
    EXPECT_EQ(failed.status().code(), StatusCode::not_found);
    EXPECT_NE(failed.status().message().find("987654"), std::string::npos)
        << failed.status().to_string();
    // The stream is over: later calls repeat why instead of hanging.
    EXPECT_EQ(s.send(first).code(), StatusCode::not_found);
    EXPECT_EQ(s.receive().status().code(), StatusCode::not_found);
    EXPECT_EQ(s.finish().code(), StatusCode::not_found);
    // The stream-owned scene went with the stream.
    EXPECT_EQ(c->describe_scene(r->scene_id).status().code(), StatusCode::not_found);
}

TEST(ClientE2e, CancelAndDestructorEndTheStream) {
    auto c = connect_or_die();
    std::string owned;
    {
        auto stream = c->open_stream("");
        ASSERT_TRUE(stream.ok());
        FrameRequest first;
        first.update.additions = some_objects(5);
        ASSERT_TRUE(stream.value()->send(first).ok());
        auto r = stream.value()->receive();
        ASSERT_TRUE(r.ok());
        owned = r->scene_id;
        stream.value()->cancel();
        EXPECT_EQ(stream.value()->finish().code(), StatusCode::cancelled);
    }
    {
        // Sent and never read: the destructor cancels instead of waiting for the answer.
        auto stream = c->open_stream("");
        ASSERT_TRUE(stream.ok());
        FrameRequest first;
        first.update.additions = some_objects(6);
        first.queries = all_queries();
        ASSERT_TRUE(stream.value()->send(first).ok());
    }
    // Both stream-owned scenes go once the daemon has seen the cancellations.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    std::uint64_t streams = 0;
    do {
        auto info = c->server_info();
        ASSERT_TRUE(info.ok());
        streams = info->live_streams;
        if (streams == 0) {
            break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    } while (std::chrono::steady_clock::now() < deadline);
    EXPECT_EQ(streams, 0u);
    EXPECT_EQ(c->describe_scene(owned).status().code(), StatusCode::not_found);
}

TEST(ClientE2e, ErrorsKeepTheServersCodeAndMessage) {
    auto c = connect_or_die();
    auto st = c->delete_scene("no-such-scene");
    EXPECT_EQ(st.code(), StatusCode::not_found);
    EXPECT_NE(st.message().find("no-such-scene"), std::string::npos) << st.to_string();
    auto scene = c->create_scene("bad", {{"empty", {}}});
    EXPECT_EQ(scene.status().code(), StatusCode::invalid_argument) << scene.status().to_string();
    EXPECT_NE(scene.status().message().find("empty"), std::string::npos);
    // An upload that cannot succeed (unknown scene) reports the daemon's reason, not a write error.
    auto up = c->upload_object("no-such-scene", some_objects(7)[0]);
    EXPECT_EQ(up.status().code(), StatusCode::not_found) << up.status().to_string();

    ConnectOptions quick;
    quick.connect_timeout = std::chrono::milliseconds(200);
    auto nobody = Client::connect("127.0.0.1:1", quick);
    EXPECT_EQ(nobody.status().code(), StatusCode::unavailable);
    EXPECT_NE(nobody.status().message().find("127.0.0.1:1"), std::string::npos);
}

}  // namespace
}  // namespace proxima::client

namespace proxima::client {
namespace {

// Snapshot RPC: the daemon's PNG equals the in-process one (same scene, same queries, same
// renderer: llvmpipe in CI), and bad requests get INVALID_ARGUMENT / NOT_FOUND.
TEST(ClientE2e, SnapshotEqualsTheLocalRendering) {
    std::vector<NamedMesh> objects;
    objects.push_back({"a", test::box({0, 0, 0}, {1, 1, 1})});
    objects.push_back({"b", test::box({0.5, 0.2, 0.2}, {1.5, 0.8, 0.8})});
    objects.push_back({"c", test::box({4, 0, 0}, {5, 1, 1})});
    render::SnapshotRequest request;
    request.render.width = 160;
    request.render.height = 90;
    request.tolerance = 0.01;

    ProximityEngine engine;
    for (const auto& o : objects) {
        ASSERT_TRUE(engine.scene().add_object(o).ok());
    }
    auto local = render::take_snapshot(engine, request);
    if (local.status().code() == StatusCode::unavailable && std::getenv("CI") == nullptr) {
        GTEST_SKIP() << "no EGL context here: " << local.status().message();
    }
    ASSERT_TRUE(local.ok()) << local.status().to_string();

    auto c = connect_or_die();
    ASSERT_NE(c, nullptr);
    auto scene = c->create_scene("snapshot", objects);
    ASSERT_TRUE(scene.ok()) << scene.status().to_string();
    auto remote = c->snapshot(scene->scene_id, request);
    ASSERT_TRUE(remote.ok()) << remote.status().to_string();
    EXPECT_EQ(remote->width, 160);
    EXPECT_EQ(remote->height, 90);
    EXPECT_GT(remote->collision_count, 0u);
    EXPECT_EQ(remote->collision_count, local->collision_count);
    EXPECT_EQ(remote->segment_count, local->segment_count);
    EXPECT_EQ(remote->camera.eye, local->camera.eye);
    if (remote->renderer == local->renderer) {
        EXPECT_TRUE(remote->png == local->png) << "the daemon's PNG differs from the local one";
    }
    auto decoded = render::decode_png(remote->png);
    ASSERT_TRUE(decoded.ok()) << decoded.status().to_string();
    EXPECT_EQ(decoded->width, 160);
    EXPECT_EQ(decoded->height, 90);

    // A given camera comes back as used.
    render::Camera camera;
    camera.eye = {2.5, -10, 0.5};
    camera.target = {2.5, 0, 0.5};
    request.render.camera = camera;
    auto framed = c->snapshot(scene->scene_id, request);
    ASSERT_TRUE(framed.ok()) << framed.status().to_string();
    EXPECT_EQ(framed->camera.eye, camera.eye);
    EXPECT_EQ(framed->camera.up, (Vec3{0, 0, 1}));

    request.render.camera.reset();
    request.render.width = 0;
    EXPECT_EQ(c->snapshot(scene->scene_id, request).status().code(), StatusCode::invalid_argument);
    request.render.width = 5000;
    request.render.height = 5000;
    auto huge = c->snapshot(scene->scene_id, request);
    EXPECT_EQ(huge.status().code(), StatusCode::invalid_argument);
    EXPECT_NE(huge.status().message().find("5000x5000"), std::string::npos)
        << huge.status().message();
    request.render.width = 16;
    request.render.height = 16;
    EXPECT_EQ(c->snapshot("no-such-scene", request).status().code(), StatusCode::not_found);
    EXPECT_TRUE(c->delete_scene(scene->scene_id).ok());
}

}  // namespace
}  // namespace proxima::client

int main(int argc, char** argv) {
    // Mesa's shader cache stays out of $HOME (the daemon inherits this).
    setenv("MESA_SHADER_CACHE_DISABLE", "true", 0);
    ::testing::InitGoogleTest(&argc, argv);
    ::testing::AddGlobalTestEnvironment(new proxima::client::DaemonEnvironment);
    return RUN_ALL_TESTS();
}
