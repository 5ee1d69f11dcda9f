#pragma once
// What the service's reactors share, for the files that implement ProximityService
// (service.cpp: scenes and frames; massive_service.cpp: models, verification and review rooms).
// Private to server/.

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <exception>
#include <mutex>
#include <new>
#include <string>
#include <thread>
#include <unordered_set>
#include <utility>

#include <grpcpp/grpcpp.h>
#include <spdlog/spdlog.h>

#include "config.hpp"
#include "convert.hpp"
#include "models.hpp"
#include "proxima/culling/dvd.hpp"
#include "proxima/query/query.hpp"
#include "rooms.hpp"
#include "scene_registry.hpp"
#include "service.hpp"
#include "worker_pool.hpp"

namespace proxima::server {

// Each member of a review room may have this many ordered events (its own answers, edits,
// joins, leaves) waiting to be read before it is disconnected with RESOURCE_EXHAUSTED.
inline constexpr std::size_t REVIEW_MAX_PENDING_EVENTS = 1024;

// A bidirectional stream the shutdown drain must tell to stop reading (FrameStreams, Reviews).
class DrainableStream {
  public:
    virtual void drain() = 0;

  protected:
    ~DrainableStream() = default;
};

struct ProximityService::Shared {
    explicit Shared(const ServerConfig& c)
        : config(c),
          scenes(c.limits.max_scenes),
          models(c.models_dir, c.cache_bytes),
          rooms(REVIEW_MAX_PENDING_EVENTS),
          pool(c.worker_threads != 0 ? c.worker_threads
                                     : std::max(4u, std::thread::hardware_concurrency())) {}

    const ServerConfig config;
    SceneRegistry scenes;
    // The GPU backend of the Voronoi culler: one EGL context, owned by its own thread, shared by
    // every scene (GPU jobs run one at a time). Null when EGL did not start or --gpu off.
    std::shared_ptr<dvd::Backend> gpu;
    std::string gl_renderer;
    // Massive models (models.hpp) and review rooms (rooms.hpp).
    ModelRegistry models;
    RoomRegistry rooms;

    // Every reactor enters when gRPC creates it and leaves in its OnDone: the drain waits for
    // the count to reach zero. Returns false once draining, when the call must be refused (with
    // UNAVAILABLE; it still leaves in OnDone).
    bool enter_call(DrainableStream* stream = nullptr) {
        std::lock_guard lock(calls_mu);
        ++calls;
        if (stream != nullptr) {
            streams.insert(stream);
        }
        return !draining;
    }
    void leave_call(DrainableStream* stream = nullptr) {
        std::lock_guard lock(calls_mu);
        --calls;
        if (stream != nullptr) {
            streams.erase(stream);
        }
        if (calls == 0) {
            calls_idle.notify_all();
        }
    }

    mutable std::mutex calls_mu;
    std::condition_variable calls_idle;
    std::size_t calls = 0;                         // guarded by calls_mu
    std::unordered_set<DrainableStream*> streams;  // guarded by calls_mu: live streams
    bool draining = false;                         // guarded by calls_mu

    // Last member, so it is destroyed first: its destructor runs queued tasks, which use the
    // members above.
    WorkerPool pool;
};

using Clock = std::chrono::steady_clock;

inline double milliseconds_since(Clock::time_point start) {
    return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// Maps the call's deadline onto the token, so the engine stops when the caller's time is up
// rather than when gRPC notices.
inline void apply_deadline(CancelToken& token, const grpc::CallbackServerContext& context) {
    const auto deadline = context.deadline();
    const auto now = std::chrono::system_clock::now();
    // No deadline reads as time_point::max(); anything a year out is as good as none.
    if (deadline > now + std::chrono::hours(24 * 365)) {
        return;
    }
    token.set_deadline(Clock::now() + std::chrono::duration_cast<Clock::duration>(deadline - now));
}

// Exceptions never cross into gRPC: the engine throws only for bugs and exhausted memory.
template <class Fn>
Status guarded(Fn&& fn) {
    try {
        return fn();
    } catch (const std::bad_alloc&) {
        return {StatusCode::resource_exhausted, "out of memory while serving the request"};
    } catch (const std::exception& e) {
        return {StatusCode::internal, std::string("internal error: ") + e.what()};
    }
}

// One line per finished call. Rejections (the caller's mistake or a limit) are warnings; a
// cancelled call or an expired deadline is the caller's choice, so it is info.
inline void log_call(const char* method, const std::string& peer, const std::string& scene,
                     Clock::time_point start, const Status& status, const std::string& extra = {}) {
    const double ms = milliseconds_since(start);
    const auto level =
        status.ok() ? spdlog::level::debug
        : (status.code() == StatusCode::cancelled || status.code() == StatusCode::deadline_exceeded)
            ? spdlog::level::info
            : spdlog::level::warn;
    if (status.ok()) {
        spdlog::log(level, "call method={} peer={} scene={} status=OK duration_ms={:.3f}{}", method,
                    peer, scene.empty() ? "-" : scene, ms, extra);
    } else {
        spdlog::log(level,
                    "rejected method={} peer={} scene={} status={} duration_ms={:.3f}{} "
                    "message=\"{}\"",
                    method, peer, scene.empty() ? "-" : scene, status_code_name(status.code()), ms,
                    extra, status.message());
    }
}

inline Status shutting_down() {
    return {StatusCode::unavailable,
            "proximad is shutting down; reconnect (to another instance) to go on"};
}

// A unary call: the method fills the response on the worker pool (or inline when it is cheap)
// and calls complete() last. The reactor deletes itself in OnDone, which gRPC may run as soon as
// Finish is called, so nothing may touch it after complete().
//
// While the daemon drains, a new call is refused at once: the constructor completes it with
// UNAVAILABLE and refused() tells the method to return without doing anything. (gRPC runs OnDone
// only after the method has returned the reactor, so reading refused() is safe.)
class UnaryCall final : public grpc::ServerUnaryReactor {
  public:
    UnaryCall(ProximityService::Shared& shared, grpc::CallbackServerContext* context,
              const char* method, std::string scene)
        : m_shared(shared),
          m_method(method),
          m_peer(context->peer()),
          m_scene(std::move(scene)),
          m_start(Clock::now()) {
        apply_deadline(m_cancel, *context);
        m_refused = !m_shared.enter_call();
        if (m_refused) {
            complete(shutting_down());
        }
    }

    bool refused() const { return m_refused; }
    const CancelToken& cancel() const { return m_cancel; }
    void set_scene(std::string scene) { m_scene = std::move(scene); }

    void complete(const Status& status, const std::string& extra = {}) {
        log_call(m_method, m_peer, m_scene, m_start, status, extra);
        Finish(to_grpc_status(status));
    }

    void OnCancel() override { m_cancel.cancel(); }
    void OnDone() override {
        m_shared.leave_call();
        delete this;
    }

  private:
    ProximityService::Shared& m_shared;
    bool m_refused = false;
    const char* m_method;
    std::string m_peer;
    std::string m_scene;
    Clock::time_point m_start;
    CancelToken m_cancel;
};

}  // namespace proxima::server
