// The daemon's GPU backend: with EGL (Mesa llvmpipe in CI, where it must start) the daemon reports
// the GL renderer and serves the voronoi-gpu culler; with EGL forced to fail
// (PROXIMA_DISABLE_EGL=1) or --gpu off it serves on the CPU backend, says so in server info,
// refuses voronoi-gpu with FAILED_PRECONDITION naming the reason, and every other answer is
// identical.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include "client/proxima_client.hpp"
#include "daemon_process.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scenes/procedural.hpp"

namespace proxima::test {
namespace {

using client::Client;
using client::FrameRequest;

bool in_ci() {
    const char* ci = std::getenv("CI");
    return ci != nullptr && *ci != '\0' && std::string(ci) != "0" && std::string(ci) != "false";
}

// Starts a daemon with PROXIMA_DISABLE_EGL set (or not) in its environment.
std::unique_ptr<DaemonProcess> start_daemon(bool disable_egl, std::vector<std::string> flags = {}) {
    if (disable_egl) {
        setenv("PROXIMA_DISABLE_EGL", "1", 1);
    }
    auto d = std::make_unique<DaemonProcess>(std::move(flags), std::chrono::seconds(30));
    unsetenv("PROXIMA_DISABLE_EGL");
    return d;
}

struct Answers {
    std::vector<QueryResult> frames;
    std::string culler;
};

// Streams five frames of a seed scene with every query and the given culler.
StatusOr<Answers> run_scene(const DaemonProcess& daemon, CullerKind culler) {
    auto c = Client::connect(daemon.address());
    if (!c.ok()) {
        return c.status();
    }
    const auto sc = scenes::bowl(5);
    auto stream = c.value()->open_stream("");
    if (!stream.ok()) {
        return stream.status();
    }
    Scene local;
    Answers out;
    for (std::size_t k = 0; k < 5; ++k) {
        FrameRequest request;
        request.frame = k;
        request.update = k == 0 ? SceneUpdate{{}, {}, {}, sc.initial} : sc.step(k, local);
        if (auto applied = local.apply(request.update); !applied.ok()) {
            return applied.status();
        }
        request.queries.separation = true;
        request.queries.self = true;
        request.queries.collisions = true;
        request.queries.tolerance = 0.02;
        request.queries.culler = culler;
        if (Status s = stream.value()->send(request); !s.ok()) {
            return s;
        }
        auto got = stream.value()->receive();
        if (!got.ok()) {
            return got.status();
        }
        out.culler = got->result.stats.culler;
        out.frames.push_back(std::move(got->result));
    }
    if (Status s = stream.value()->finish(); !s.ok()) {
        return s;
    }
    return out;
}

// Separation and tolerance distances may differ in the last bits between cullers (a pair of
// objects measured as (a, b) or (b, a)); self distances and every pair set are identical.
bool same_distance(double a, double b) {
    return a == b || std::abs(a - b) <= 1e-12 * std::max(1.0, std::max(std::abs(a), std::abs(b)));
}

void expect_same_answers(const Answers& a, const Answers& b) {
    ASSERT_EQ(a.frames.size(), b.frames.size());
    for (std::size_t k = 0; k < a.frames.size(); ++k) {
        SCOPED_TRACE("frame " + std::to_string(k));
        const auto& x = a.frames[k];
        const auto& y = b.frames[k];
        ASSERT_EQ(x.separation.size(), y.separation.size());
        for (std::size_t i = 0; i < x.separation.size(); ++i) {
            EXPECT_EQ(x.separation[i].other, y.separation[i].other);
            EXPECT_TRUE(same_distance(x.separation[i].distance, y.separation[i].distance))
                << x.separation[i].distance << " vs " << y.separation[i].distance;
        }
        ASSERT_EQ(x.self.size(), y.self.size());
        for (std::size_t i = 0; i < x.self.size(); ++i) {
            ASSERT_EQ(x.self[i].size(), y.self[i].size());
            std::size_t different = 0;
            for (std::size_t t = 0; t < x.self[i].size(); ++t) {
                different += x.self[i][t].distance != y.self[i][t].distance ? 1 : 0;
            }
            EXPECT_EQ(different, 0u) << "self distances of object " << i;
        }
        EXPECT_EQ(x.collisions.size(), y.collisions.size());
        EXPECT_TRUE(std::equal(x.collisions.begin(), x.collisions.end(), y.collisions.begin(),
                               y.collisions.end(),
                               [](const auto& p, const auto& q) { return !(p < q) && !(q < p); }));
        ASSERT_EQ(x.tolerance.size(), y.tolerance.size());
        for (std::size_t i = 0; i < x.tolerance.size(); ++i) {
            EXPECT_FALSE(x.tolerance[i] < y.tolerance[i] || y.tolerance[i] < x.tolerance[i]);
            EXPECT_TRUE(same_distance(x.tolerance[i].distance, y.tolerance[i].distance));
        }
    }
}

TEST(GpuBackend, EglDaemonServesVoronoiGpuWithBruteForceAnswers) {
    auto daemon = start_daemon(false);
    ASSERT_TRUE(daemon->ok()) << daemon->error();
    auto c = Client::connect(daemon->address());
    ASSERT_TRUE(c.ok());
    auto info = c.value()->server_info();
    ASSERT_TRUE(info.ok());
    if (info->gl_renderer.empty()) {
        ASSERT_FALSE(in_ci()) << "CI must start EGL on llvmpipe; the daemon says "
                              << info->proximity_backend;
        GTEST_SKIP() << "EGL did not start on this machine (see the daemon's log)";
    }
    EXPECT_EQ(info->proximity_backend, "gpu (voronoi-gpu) + cpu (voronoi-cpu, bvh, brute)");
    if (in_ci()) {
        EXPECT_NE(info->gl_renderer.find("llvmpipe"), std::string::npos) << info->gl_renderer;
    }
    auto gpu = run_scene(*daemon, CullerKind::voronoi_gpu);
    ASSERT_TRUE(gpu.ok()) << gpu.status().to_string();
    EXPECT_EQ(gpu->culler, "voronoi-gpu");
    auto brute = run_scene(*daemon, CullerKind::brute);
    ASSERT_TRUE(brute.ok()) << brute.status().to_string();
    expect_same_answers(gpu.value(), brute.value());
}

TEST(GpuBackend, ForcedEglFailureFallsBackToTheCpuWithIdenticalAnswers) {
    auto cpu_daemon = start_daemon(true);
    ASSERT_TRUE(cpu_daemon->ok()) << cpu_daemon->error();
    auto c = Client::connect(cpu_daemon->address());
    ASSERT_TRUE(c.ok());
    auto info = c.value()->server_info();
    ASSERT_TRUE(info.ok());
    EXPECT_EQ(info->gl_renderer, "");
    EXPECT_EQ(info->proximity_backend, "cpu (voronoi-cpu, bvh, brute)");

    // voronoi-gpu is refused, naming why; the stream's scene is gone with the stream.
    auto refused = run_scene(*cpu_daemon, CullerKind::voronoi_gpu);
    ASSERT_FALSE(refused.ok());
    EXPECT_EQ(refused.status().code(), StatusCode::failed_precondition);
    EXPECT_NE(refused.status().message().find("EGL"), std::string::npos)
        << refused.status().message();

    auto fallback = run_scene(*cpu_daemon, CullerKind::automatic);
    ASSERT_TRUE(fallback.ok()) << fallback.status().to_string();
    auto voronoi_cpu = run_scene(*cpu_daemon, CullerKind::voronoi_cpu);
    ASSERT_TRUE(voronoi_cpu.ok()) << voronoi_cpu.status().to_string();
    EXPECT_EQ(voronoi_cpu->culler, "voronoi-cpu");
    expect_same_answers(fallback.value(), voronoi_cpu.value());

    // The same answers as a daemon whose EGL started (when it can here).
    auto egl_daemon = start_daemon(false);
    ASSERT_TRUE(egl_daemon->ok()) << egl_daemon->error();
    auto with_gpu = run_scene(*egl_daemon, CullerKind::automatic);
    ASSERT_TRUE(with_gpu.ok()) << with_gpu.status().to_string();
    expect_same_answers(fallback.value(), with_gpu.value());
}

TEST(GpuBackend, GpuOffServesOnTheCpu) {
    auto daemon = start_daemon(false, {"--gpu", "off"});
    ASSERT_TRUE(daemon->ok()) << daemon->error();
    auto c = Client::connect(daemon->address());
    ASSERT_TRUE(c.ok());
    auto info = c.value()->server_info();
    ASSERT_TRUE(info.ok());
    EXPECT_EQ(info->gl_renderer, "");
    EXPECT_EQ(info->proximity_backend, "cpu (voronoi-cpu, bvh, brute)");
    auto refused = run_scene(*daemon, CullerKind::voronoi_gpu);
    ASSERT_FALSE(refused.ok());
    EXPECT_EQ(refused.status().code(), StatusCode::failed_precondition);
    EXPECT_NE(refused.status().message().find("--gpu off"), std::string::npos)
        << refused.status().message();
}

}  // namespace
}  // namespace proxima::test
