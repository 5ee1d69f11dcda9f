// ProximityService: the shared state of its calls (service_internal.hpp), the GPU backend,
// metrics, the shutdown drain and GetServerInfo. Each kind of call has a file of its own:
// scene_calls.cpp (CreateScene, DescribeScene, DeleteScene, Query, Snapshot), upload_stream.cpp
// (UploadObject), frame_stream.cpp (StreamFrames), model_calls.cpp (ListModels),
// verify_stream.cpp (VerifyModel), review_stream.cpp (Review), region_stream.cpp (FetchRegion);
// the two bidirectional streams share ordered_stream.hpp.
#include "service.hpp"

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <spdlog/spdlog.h>

#include "encode.hpp"
#include "proxima/gpu/egl_backend.hpp"
#include "proxima/gpu/failover_backend.hpp"
#include "proxima/wire/status.hpp"
#include "scene_registry.hpp"
#include "service_internal.hpp"
#include "worker_pool.hpp"

namespace proxima::server {

ProximityService::ProximityService(const ServerConfig& config)
    : m_shared(std::make_unique<Shared>(config)) {
    std::string reason = "the GPU is off (--gpu off)";
    if (config.gpu != "off") {
        auto backend = gpu::make_egl_backend();
        if (backend.ok()) {
            // name() is "gpu (<GL_RENDERER>)".
            const auto name = backend.value()->name();
            const auto open = name.find('(');
            m_shared->gl_renderer =
                open == std::string::npos ? name : name.substr(open + 1, name.size() - open - 2);
            spdlog::info("gpu backend=egl gl_renderer=\"{}\"", m_shared->gl_renderer);
            // A GPU job that fails (context lost, GL error) is re-run on the CPU kernel, and so is
            // every later one: voronoi-gpu stays served, with the same answers.
            m_shared->gpu = gpu::make_failover_backend(
                std::move(backend).value(), dvd::make_cpu_backend(), [](const std::string& why) {
                    spdlog::warn(
                        "gpu lost backend=cpu reason=\"{}\" (voronoi-gpu now runs on the "
                        "CPU kernel)",
                        why);
                });
        } else {
            reason = "EGL unavailable: " + backend.status().message();
            spdlog::warn("gpu backend=cpu reason=\"{}\" (the Voronoi culler runs on the CPU)",
                         reason);
        }
    }
    if (!m_shared->gpu) {
        m_shared->gpu_unavailable_reason = reason;
    }
    m_shared->scenes.set_gpu(m_shared->gpu, reason);
}

std::string ProximityService::proximity_backend() const {
    if (!m_shared->gpu) {
        return "cpu (voronoi-cpu, bvh, brute)";
    }
    const auto stats = m_shared->gpu->stats();
    return stats.gpu_active ? "gpu (voronoi-gpu) + cpu (voronoi-cpu, bvh, brute)"
                            : "cpu (voronoi-cpu, bvh, brute); gpu lost: " + stats.fallback_reason;
}

dvd::BackendStats ProximityService::gpu_stats() const {
    if (m_shared->gpu) {
        return m_shared->gpu->stats();
    }
    dvd::BackendStats none;
    none.fallback_reason = m_shared->gpu_unavailable_reason;
    return none;
}

std::string ProximityService::gl_renderer() const {
    return m_shared->gl_renderer;
}

ProximityService::~ProximityService() = default;

void ProximityService::Shared::start_reaper() {
    reaper = std::thread([this] {
        const double idle = config.idle_scene_seconds;
        // A scene outlives its idle time by at most a quarter of it (and at most a second).
        const auto period = std::chrono::duration_cast<Clock::duration>(
            std::chrono::duration<double>(std::clamp(idle / 4, 0.01, 1.0)));
        std::unique_lock lock(reaper_mu);
        while (!reaper_wake.wait_for(lock, period, [&] { return reaper_stop; })) {
            lock.unlock();
            auto expired = scenes.expire_idle(idle);
            for (const auto& e : expired) {
                spdlog::info("scene expired who={} scene={} idle_seconds={}", e->owner->log_name(),
                             e->id, idle);
                metrics.add_scene_expired();
            }
            expired.clear();  // frees the engines here, unless a call still holds one
            lock.lock();
        }
    });
}

Status ProximityService::start() {
    auto& shared = *m_shared;
    if (!shared.config.tokens_file.empty()) {
        auto auth = Authenticator::from_file(shared.config.tokens_file);
        if (!auth.ok()) {
            return auth.status();
        }
        shared.auth = std::move(auth).value();
        spdlog::info("tokens file={} principals={}", shared.config.tokens_file,
                     shared.auth->size());
    } else if (!is_loopback_address(shared.config.listen)) {
        spdlog::warn(
            "no token file (--tokens): every client that reaches {} can use every scene, room "
            "and model",
            shared.config.listen);
    }
    shared.metrics.set_sampler([this](std::vector<Sample>& out) { sample_metrics(out); });
    shared.metrics.set_serving([this] {
        std::lock_guard lock(m_shared->calls_mu);
        return !m_shared->draining;
    });
    if (shared.config.idle_scene_seconds > 0) {
        shared.start_reaper();
    }
    return start_models();
}

namespace {

// Resident set size from /proc/self/statm (pages); none where it cannot be read.
std::optional<std::uint64_t> resident_bytes() {
    std::ifstream statm("/proc/self/statm");
    std::uint64_t size = 0;
    std::uint64_t resident = 0;
    if (!(statm >> size >> resident)) {
        return std::nullopt;
    }
    return resident * static_cast<std::uint64_t>(sysconf(_SC_PAGESIZE));
}

double cpu_seconds() {
    rusage usage{};
    getrusage(RUSAGE_SELF, &usage);
    auto seconds = [](const timeval& t) {
        return static_cast<double>(t.tv_sec) + static_cast<double>(t.tv_usec) * 1e-6;
    };
    return seconds(usage.ru_utime) + seconds(usage.ru_stime);
}

}  // namespace

StatusOr<std::string> ProximityService::start_metrics(const std::string& address) {
    return m_shared->metrics.listen(address);
}

std::string ProximityService::metrics_text() const {
    return m_shared->metrics.render();
}

void ProximityService::sample_metrics(std::vector<Sample>& out) const {
    auto& shared = *m_shared;
    auto gauge = [&](const char* name, const char* help, double value,
                     std::vector<std::pair<std::string, std::string>> labels = {}) {
        out.push_back({name, help, false, std::move(labels), value});
    };
    auto counter = [&](const char* name, const char* help, double value,
                       std::vector<std::pair<std::string, std::string>> labels = {}) {
        out.push_back({name, help, true, std::move(labels), value});
    };
    // The process's own resources, under the names Prometheus client libraries use (the
    // load harness, proxima load, samples them over a run).
    if (const auto rss = resident_bytes()) {
        gauge("process_resident_memory_bytes", "Resident memory of the daemon in bytes",
              static_cast<double>(*rss));
    }
    counter("process_cpu_seconds_total", "User and system CPU time of the daemon in seconds",
            cpu_seconds());
    gauge("proxima_live_scenes", "Scenes alive, stream-owned ones included",
          static_cast<double>(live_scenes()));
    gauge("proxima_live_streams", "Frame streams and review members connected",
          static_cast<double>(live_streams()));
    gauge("proxima_live_calls", "Calls in flight (streams, uploads, unary calls)",
          static_cast<double>(live_calls()));

    const auto gpu = gpu_stats();
    gauge("proxima_gpu_active",
          "1 while the GPU backend serves the Voronoi kernel, 0 without one or after a loss",
          gpu.gpu_active ? 1 : 0);
    counter("proxima_dvd_kernel_jobs_total", "Discrete-Voronoi kernel jobs by backend",
            static_cast<double>(gpu.gpu_jobs), {{"backend", "gpu"}});
    counter("proxima_dvd_kernel_jobs_total", "Discrete-Voronoi kernel jobs by backend",
            static_cast<double>(gpu.cpu_jobs), {{"backend", "cpu"}});
    counter("proxima_dvd_kernel_seconds_total", "Time in the discrete-Voronoi kernel by backend",
            gpu.gpu_seconds, {{"backend", "gpu"}});
    counter("proxima_dvd_kernel_seconds_total", "Time in the discrete-Voronoi kernel by backend",
            gpu.cpu_seconds, {{"backend", "cpu"}});

    if (const auto& cache = shared.models.cache()) {
        const auto c = cache->stats();
        gauge("proxima_cache_budget_bytes", "Budget of the shared geometry cache",
              static_cast<double>(c.budget_bytes));
        gauge("proxima_cache_resident_bytes", "Geometry and hierarchies resident in the cache",
              static_cast<double>(c.resident_bytes));
        gauge("proxima_cache_charged_bytes",
              "Review rooms' moved and added objects, charged to the cache's budget",
              static_cast<double>(c.charged_bytes));
        counter("proxima_cache_hits_total", "Cache lookups that found the piece resident",
                static_cast<double>(c.hits));
        counter("proxima_cache_misses_total", "Cache lookups that had to load the piece",
                static_cast<double>(c.misses));
        counter("proxima_cache_loads_total", "Pieces read from disk (lookups and prefetch)",
                static_cast<double>(c.loads));
        counter("proxima_cache_bytes_loaded_total", "Piece bytes read from disk",
                static_cast<double>(c.bytes_loaded));
        counter("proxima_cache_evictions_total", "Pieces evicted from the cache",
                static_cast<double>(c.evictions));
    }

    // Each principal's usage (one series per token; "-" when the daemon checks no tokens).
    struct Usage {
        const char* name;
        const char* help;
        std::uint64_t (Principal::*value)() const;
    };
    static const Usage USAGE[] = {
        {"proxima_principal_scenes", "Live scenes of each token", &Principal::scenes},
        {"proxima_principal_objects", "Objects in each token's scenes", &Principal::objects},
        {"proxima_principal_triangles", "Triangles in each token's scenes", &Principal::triangles},
        {"proxima_principal_bytes_held", "Geometry bytes of each token's scenes",
         &Principal::bytes_held},
        {"proxima_principal_bytes_in_flight", "Request bytes of each token read, not answered",
         &Principal::bytes_in_flight},
        {"proxima_principal_streams", "Streaming calls of each token", &Principal::streams}};
    for (const auto& u : USAGE) {
        for (const auto& p : shared.auth->principals()) {
            gauge(u.name, u.help, static_cast<double>(((*p).*u.value)()),
                  {{"principal", p->log_name()}});
        }
    }
}

std::size_t ProximityService::live_scenes() const {
    return m_shared->scenes.size();
}

std::size_t ProximityService::live_streams() const {
    std::lock_guard lock(m_shared->calls_mu);
    return m_shared->streams.size();
}

std::size_t ProximityService::live_calls() const {
    std::lock_guard lock(m_shared->calls_mu);
    return m_shared->calls;
}

void ProximityService::begin_drain() {
    // Lock order: calls_mu, then a reactor's m_mu (OnDone takes them one after the other).
    std::lock_guard lock(m_shared->calls_mu);
    m_shared->draining = true;
    for (auto* stream : m_shared->streams) {
        stream->drain();
    }
}

bool ProximityService::wait_idle(std::chrono::steady_clock::time_point deadline) {
    std::unique_lock lock(m_shared->calls_mu);
    return m_shared->calls_idle.wait_until(lock, deadline, [&] { return m_shared->calls == 0; });
}

grpc::ServerUnaryReactor* ProximityService::GetServerInfo(grpc::CallbackServerContext* context,
                                                          const v1::GetServerInfoRequest*,
                                                          v1::ServerInfo* response) {
    auto* call = new UnaryCall(*m_shared, context, "GetServerInfo", "");
    if (call->refused()) {
        return call;
    }
    response->set_version(PROXIMA_VERSION);
    response->set_api("proxima.v1");
    encode_limits(m_shared->config.limits, response->mutable_limits());
    response->set_proximity_backend(proximity_backend());
    response->set_gl_renderer(m_shared->gl_renderer);
    const auto gpu_now = gpu_stats();
    response->set_gpu_active(gpu_now.gpu_active);
    response->set_gpu_fallback_reason(gpu_now.fallback_reason);
    response->set_live_scenes(live_scenes());
    response->set_live_streams(live_streams());
    const auto& who = *call->principal();
    response->set_principal(who.name());
    encode_quotas(who.quotas(), response->mutable_quotas());
    call->complete({});
    return call;
}

}  // namespace proxima::server
