// Issue #7: the daemon's GPU context is lost while it serves. PROXIMA_EGL_LOSE_CONTEXT_AFTER=N
// makes the daemon's EGL backend end its (N+1)-th job as on a real reset (the job fails, the
// context is destroyed); the daemon must re-run that job and every later one on the CPU kernel,
// keep serving voronoi-gpu with the answers an in-process engine gives, say so in ServerInfo
// (gpu_active, gpu_fallback_reason, proximity_backend) and log one warning.
#include <fcntl.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <memory>
#include <string>
#include <vector>

#include "client/proxima_client.hpp"
#include "integration/daemon_process.hpp"
#include "integration/wire.hpp"
#include "proxima/culling/dvd.hpp"
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

// While alive, this process's standard error is `path`, so a daemon started meanwhile writes its
// log there (children inherit descriptor 2 at fork).
class StderrToFile {
  public:
    explicit StderrToFile(const std::string& path) {
        std::fflush(stderr);
        m_saved = dup(STDERR_FILENO);
        const int fd = open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
        if (m_saved >= 0 && fd >= 0) {
            dup2(fd, STDERR_FILENO);  // the duplicate is inheritable: no O_CLOEXEC on it
        }
        if (fd >= 0) {
            close(fd);
        }
    }
    ~StderrToFile() {
        std::fflush(stderr);
        if (m_saved >= 0) {
            dup2(m_saved, STDERR_FILENO);
            close(m_saved);
        }
    }
    StderrToFile(const StderrToFile&) = delete;
    StderrToFile& operator=(const StderrToFile&) = delete;

  private:
    int m_saved = -1;
};

std::string read_file(const std::string& path) {
    std::ifstream in(path);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::size_t count(const std::string& text, const std::string& what) {
    std::size_t n = 0;
    for (auto p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) {
        ++n;
    }
    return n;
}

// A daemon whose GPU context is lost after `lose_after` GPU jobs, its log in `log_path`.
std::unique_ptr<DaemonProcess> start_losing_daemon(std::uint64_t lose_after,
                                                   const std::string& log_path) {
    setenv("PROXIMA_EGL_LOSE_CONTEXT_AFTER", std::to_string(lose_after).c_str(), 1);
    std::unique_ptr<DaemonProcess> daemon;
    {
        StderrToFile redirect(log_path);
        daemon =
            std::make_unique<DaemonProcess>(std::vector<std::string>{}, std::chrono::seconds(30));
    }
    unsetenv("PROXIMA_EGL_LOSE_CONTEXT_AFTER");
    return daemon;
}

v1::ServerInfo server_info(const DaemonProcess& daemon) {
    auto stub = make_stub(daemon.address());
    grpc::ClientContext context;
    deadline_in(context, std::chrono::seconds(10));
    v1::ServerInfo info;
    const grpc::Status s = stub->GetServerInfo(&context, v1::GetServerInfoRequest(), &info);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return info;
}

void expect_same_pairs(const std::vector<FeaturePair>& remote,
                       const std::vector<FeaturePair>& local, const char* what) {
    ASSERT_EQ(remote.size(), local.size()) << what;
    std::size_t mismatches = 0;
    for (std::size_t i = 0; i < local.size(); ++i) {
        const bool same = remote[i].object == local[i].object &&
                          remote[i].triangle == local[i].triangle &&
                          remote[i].other == local[i].other &&
                          remote[i].other_triangle == local[i].other_triangle &&
                          remote[i].distance == local[i].distance;
        mismatches += same ? 0 : 1;
    }
    EXPECT_EQ(mismatches, 0u) << what << ": of " << local.size() << " pairs";
}

// Exact equality: both sides ran the same engine code on the same doubles (vertices travel as
// float64), with kernels that agree bit for bit on llvmpipe. PNS (the culler's candidates, not an
// exact answer) is compared where the daemon's kernel is llvmpipe's.
void expect_same(const QueryResult& remote, const QueryResult& local, bool compare_pns) {
    ASSERT_EQ(remote.separation.size(), local.separation.size());
    for (std::size_t i = 0; i < local.separation.size(); ++i) {
        SCOPED_TRACE("separation of object " + std::to_string(i));
        EXPECT_EQ(remote.separation[i].other, local.separation[i].other);
        EXPECT_EQ(remote.separation[i].distance, local.separation[i].distance);
        EXPECT_EQ(remote.separation[i].triangle, local.separation[i].triangle);
        EXPECT_EQ(remote.separation[i].other_triangle, local.separation[i].other_triangle);
    }
    ASSERT_EQ(remote.self.size(), local.self.size());
    for (std::size_t i = 0; i < local.self.size(); ++i) {
        ASSERT_EQ(remote.self[i].size(), local.self[i].size());
        std::size_t mismatches = 0;
        for (std::size_t t = 0; t < local.self[i].size(); ++t) {
            mismatches += remote.self[i][t].closest == local.self[i][t].closest &&
                                  remote.self[i][t].distance == local.self[i][t].distance
                              ? 0
                              : 1;
        }
        EXPECT_EQ(mismatches, 0u) << "self distances of object " << i;
    }
    expect_same_pairs(remote.collisions, local.collisions, "collisions");
    expect_same_pairs(remote.tolerance, local.tolerance, "tolerance");
    if (compare_pns) {
        expect_same_pairs(remote.pns, local.pns, "pns");
    }
}

// The CPU kernel, counting the jobs that reach a GPU (those with samples: an empty job returns
// before the EGL backend's context thread sees it, and its loss counter with it).
class CountingBackend final : public dvd::Backend {
  public:
    std::string name() const override { return "gpu (counting)"; }
    bool is_gpu() const override { return true; }
    Status run(const dvd::KernelInput& input, dvd::KernelOutput& output) override {
        if (!input.sample_owner.empty()) {
            ++m_jobs;
        }
        return m_cpu->run(input, output);
    }
    std::atomic<std::uint64_t> m_jobs{0};

  private:
    std::shared_ptr<dvd::Backend> m_cpu = dvd::make_cpu_backend();
};

QueryRequest all_queries() {
    QueryRequest q;
    q.separation = true;
    q.self = true;
    q.collisions = true;
    q.tolerance = 0.02;
    q.pns = true;
    return q;
}

// Kernel jobs the voronoi-gpu culler runs for each of the bowl's first `frames` frames.
std::vector<std::uint64_t> kernel_jobs_per_frame(std::size_t frames) {
    const auto sc = scenes::bowl(frames);
    auto counting = std::make_shared<CountingBackend>();
    ProximityEngine engine;
    engine.set_gpu_backend(counting);
    std::vector<std::uint64_t> jobs;
    for (std::size_t k = 0; k < frames; ++k) {
        const SceneUpdate update =
            k == 0 ? SceneUpdate{{}, {}, {}, sc.initial} : sc.step(k, engine.scene());
        EXPECT_TRUE(engine.scene().apply(update).ok());
        QueryRequest q = all_queries();
        q.culler = CullerKind::voronoi_gpu;
        const std::uint64_t before = counting->m_jobs;
        EXPECT_TRUE(engine.query(q).ok());
        jobs.push_back(counting->m_jobs - before);
    }
    return jobs;
}

struct StreamOutcome {
    std::vector<bool> gpu_active_after;  // ServerInfo.gpu_active after each frame
};

// Streams `frames` frames of the bowl scene with culler voronoi-gpu, every query, and compares
// each answer with an in-process engine running the CPU kernel (voronoi-cpu).
void stream_and_compare(const DaemonProcess& daemon, std::size_t frames, bool compare_pns,
                        StreamOutcome& outcome) {
    auto c = Client::connect(daemon.address());
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    const auto sc = scenes::bowl(frames);
    auto stream = c.value()->open_stream("");
    ASSERT_TRUE(stream.ok()) << stream.status().to_string();
    ProximityEngine local;
    for (std::size_t k = 0; k < frames; ++k) {
        SCOPED_TRACE("frame " + std::to_string(k));
        FrameRequest request;
        request.frame = k;
        request.update = k == 0 ? SceneUpdate{{}, {}, {}, sc.initial} : sc.step(k, local.scene());
        ASSERT_TRUE(local.scene().apply(request.update).ok());
        request.queries = all_queries();
        QueryRequest local_request = request.queries;
        request.queries.culler = CullerKind::voronoi_gpu;
        local_request.culler = CullerKind::voronoi_cpu;
        const auto expected = local.query(local_request);
        ASSERT_TRUE(expected.ok()) << expected.status().to_string();

        ASSERT_TRUE(stream.value()->send(request).ok());
        auto got = stream.value()->receive();
        ASSERT_TRUE(got.ok()) << got.status().to_string();  // served, lost GPU or not
        EXPECT_EQ(got->result.stats.culler, "voronoi-gpu");
        EXPECT_GT(got->result.stats.dvd_samples, 0u);  // the kernel ran: the loss path is hit
        expect_same(got->result, expected.value(), compare_pns);
        outcome.gpu_active_after.push_back(server_info(daemon).gpu_active());
    }
    EXPECT_TRUE(stream.value()->finish().ok());
}

std::string log_path(const std::string& name) {
    return std::string(PROXIMA_BINARY_DIR) + "/proxima_hardening_gpu_loss_" + name + ".log";
}

// Skips (or fails in CI) when the daemon has no GPU backend at all on this machine.
bool gpu_started(const v1::ServerInfo& info, const std::string& log) {
    if (!info.gl_renderer().empty()) {
        return true;
    }
    EXPECT_FALSE(in_ci()) << "CI must start EGL on llvmpipe; the daemon says "
                          << info.proximity_backend() << "\n"
                          << log;
    return false;
}

TEST(GpuLoss, StreamAcrossTheLossIsServedOnTheCpuWithTheSameAnswers) {
    constexpr std::size_t FRAMES = 6;
    // Lose the context in the middle of frame 1: frame 0 is answered on the GPU, frame 1 partly
    // on each, the rest on the CPU.
    const std::vector<std::uint64_t> jobs = kernel_jobs_per_frame(2);
    ASSERT_GE(jobs[1], 2u) << "frame 1 runs too few kernel jobs to lose the GPU in its middle";
    const std::uint64_t lose_after = jobs[0] + jobs[1] / 2;
    const std::string log = log_path("stream");
    auto daemon = start_losing_daemon(lose_after, log);
    ASSERT_TRUE(daemon->ok()) << daemon->error() << "\n" << read_file(log);

    const v1::ServerInfo before = server_info(*daemon);
    if (!gpu_started(before, read_file(log))) {
        GTEST_SKIP() << "EGL did not start on this machine: " << before.gpu_fallback_reason();
    }
    EXPECT_TRUE(before.gpu_active());
    EXPECT_EQ(before.gpu_fallback_reason(), "");
    EXPECT_EQ(before.proximity_backend(), "gpu (voronoi-gpu) + cpu (voronoi-cpu, bvh, brute)");
    const bool llvmpipe = before.gl_renderer().find("llvmpipe") != std::string::npos;
    if (in_ci()) {
        EXPECT_TRUE(llvmpipe) << before.gl_renderer();
    }

    StreamOutcome outcome;
    stream_and_compare(*daemon, FRAMES, llvmpipe, outcome);
    ASSERT_EQ(outcome.gpu_active_after.size(), FRAMES);
    // Lost during frame 1, and never back.
    std::vector<bool> expected(FRAMES, false);
    expected[0] = true;
    EXPECT_EQ(outcome.gpu_active_after, expected)
        << "kernel jobs per frame: " << jobs[0] << ", " << jobs[1] << "; lost after " << lose_after;

    const v1::ServerInfo after = server_info(*daemon);
    EXPECT_FALSE(after.gpu_active());
    EXPECT_NE(after.gpu_fallback_reason().find("GL context reset (GL_UNKNOWN_CONTEXT_RESET)"),
              std::string::npos)
        << after.gpu_fallback_reason();
    EXPECT_NE(after.gpu_fallback_reason().find(
                  "simulated after " + std::to_string(lose_after) +
                  " jobs (PROXIMA_EGL_LOSE_CONTEXT_AFTER=" + std::to_string(lose_after) + ")"),
              std::string::npos)
        << after.gpu_fallback_reason();
    EXPECT_EQ(after.proximity_backend(),
              "cpu (voronoi-cpu, bvh, brute); gpu lost: " + after.gpu_fallback_reason());
    EXPECT_EQ(after.gl_renderer(), before.gl_renderer());  // the renderer that was lost

    // A new stream after the loss: voronoi-gpu is still served (on the CPU), not refused.
    StreamOutcome later;
    stream_and_compare(*daemon, 3, llvmpipe, later);
    for (bool active : later.gpu_active_after) {
        EXPECT_FALSE(active);
    }

    // One warning, at the loss, with the reason ServerInfo gives.
    const std::string text = read_file(log);
    EXPECT_EQ(count(text, "warning gpu lost backend=cpu reason=\"" + after.gpu_fallback_reason() +
                              "\" (voronoi-gpu now runs on the CPU kernel)"),
              1u)
        << text;
}

// Lost at the very first job: no frame ever reaches the GPU, every one is answered.
TEST(GpuLoss, LossAtTheFirstJobServesEveryFrame) {
    const std::string log = log_path("first_job");
    auto daemon = start_losing_daemon(0, log);
    ASSERT_TRUE(daemon->ok()) << daemon->error() << "\n" << read_file(log);
    const v1::ServerInfo before = server_info(*daemon);
    if (!gpu_started(before, read_file(log))) {
        GTEST_SKIP() << "EGL did not start on this machine: " << before.gpu_fallback_reason();
    }
    EXPECT_TRUE(before.gpu_active());  // nothing ran yet
    StreamOutcome outcome;
    stream_and_compare(*daemon, 3, before.gl_renderer().find("llvmpipe") != std::string::npos,
                       outcome);
    for (bool active : outcome.gpu_active_after) {
        EXPECT_FALSE(active);
    }
    EXPECT_NE(server_info(*daemon).gpu_fallback_reason().find("simulated after 0 jobs"),
              std::string::npos);
}

// Without a GPU at all, ServerInfo says so the same way (gpu_active false, the start-up reason).
TEST(GpuLoss, NoGpuAtStartUpIsReportedInServerInfo) {
    auto daemon = std::make_unique<DaemonProcess>(std::vector<std::string>{"--gpu", "off"},
                                                  std::chrono::seconds(30));
    ASSERT_TRUE(daemon->ok()) << daemon->error();
    const v1::ServerInfo info = server_info(*daemon);
    EXPECT_FALSE(info.gpu_active());
    EXPECT_EQ(info.gpu_fallback_reason(), "the GPU is off (--gpu off)");
    EXPECT_EQ(info.proximity_backend(), "cpu (voronoi-cpu, bvh, brute)");
}

}  // namespace
}  // namespace proxima::test
