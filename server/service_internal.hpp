#pragma once
// What the service's reactors share, for the files that implement ProximityService (one file a
// kind of call: service.cpp lists them). Private to server/.

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

#include "auth.hpp"
#include "config.hpp"
#include "encode.hpp"
#include "metrics.hpp"
#include "models.hpp"
#include "proxima/culling/dvd.hpp"
#include "proxima/gpu/failover_backend.hpp"
#include "proxima/query/query.hpp"
#include "proxima/wire/status.hpp"
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
          rooms(REVIEW_MAX_PENDING_EVENTS,
                std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                    std::chrono::duration<double>(c.review_peer_interval))),
          pool(c.worker_threads != 0 ? c.worker_threads
                                     : std::max(4u, std::thread::hardware_concurrency())) {}

    ~Shared() { stop_reaper(); }

    const ServerConfig config;
    // Tokens (auth.hpp): the anonymous principal until start() reads the token file.
    std::unique_ptr<Authenticator> auth = std::make_unique<Authenticator>();
    Metrics metrics;
    SceneRegistry scenes;
    // The GPU backend of the Voronoi culler: one EGL context, owned by its own thread, shared by
    // every scene (GPU jobs run one at a time), behind the failover to the CPU kernel on a context
    // loss. Null when EGL did not start or --gpu off, with the reason.
    std::shared_ptr<gpu::FailoverBackend> gpu;
    std::string gpu_unavailable_reason;
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

    // Idle-scene expiry: a thread that wakes a few times per idle-scene-seconds (at most once a
    // second) and deletes scenes no call used for that long. Stopped by stop_reaper().
    void start_reaper();
    void stop_reaper() {
        {
            std::lock_guard lock(reaper_mu);
            reaper_stop = true;
        }
        reaper_wake.notify_all();
        if (reaper.joinable()) {
            reaper.join();
        }
    }
    std::mutex reaper_mu;
    std::condition_variable reaper_wake;
    bool reaper_stop = false;  // guarded by reaper_mu
    std::thread reaper;

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

// A call's end notice from gRPC (OnCancel): the client cancelled it, vanished, or its deadline
// passed. A client's own deadline reaches the daemon as a cancellation (its library resets the
// stream when its time is up), a moment before or after the daemon's timer for the same deadline:
// a notice within 50 ms of the deadline is the deadline (DEADLINE_EXCEEDED in the log and the
// metrics), anything earlier a cancellation.
inline void end_by_client(CancelToken& token) {
    constexpr auto MARGIN = std::chrono::milliseconds(50);
    if (token.has_deadline() && Clock::now() + MARGIN >= token.deadline()) {
        token.expire();
    } else {
        token.cancel();
    }
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

// The principal a call is made as, from its `authorization` metadata (UNAUTHENTICATED when the
// daemon checks tokens and the call has none it knows).
inline StatusOr<std::shared_ptr<Principal>> authenticate(
    const ProximityService::Shared& shared, const grpc::CallbackServerContext& context) {
    const auto& metadata = context.client_metadata();
    const auto it = metadata.find("authorization");
    return shared.auth->authenticate(
        it == metadata.end() ? std::string() : std::string(it->second.data(), it->second.size()));
}

// One line per finished call, and its metrics. `who` is the principal's log name ("-" when
// anonymous or unknown), `subject` what the call was about ("scene=ID", "model=M", ...).
// Rejections (the caller's mistake or a limit) are warnings; a cancelled call or an expired
// deadline is the caller's choice, so it is info; successes are `ok_level` (debug for the many
// small calls, info for long, rare ones).
inline void log_call(ProximityService::Shared& shared, const char* method, const std::string& who,
                     const std::string& peer, const std::string& subject, Clock::time_point start,
                     const Status& status, const std::string& extra = {},
                     spdlog::level::level_enum ok_level = spdlog::level::debug) {
    const double ms = milliseconds_since(start);
    shared.metrics.record_call(method, status, ms / 1000.0, who);
    if (status.ok()) {
        spdlog::log(ok_level, "call method={} who={} peer={} {} status=OK duration_ms={:.3f}{}",
                    method, who, peer, subject, ms, extra);
        return;
    }
    const auto level =
        (status.code() == StatusCode::cancelled || status.code() == StatusCode::deadline_exceeded)
            ? spdlog::level::info
            : spdlog::level::warn;
    spdlog::log(level,
                "rejected method={} who={} peer={} {} status={} duration_ms={:.3f}{} "
                "message=\"{}\"",
                method, who, peer, subject, status_code_name(status.code()), ms, extra,
                status.message());
}

inline std::string scene_subject(const std::string& scene) {
    return "scene=" + (scene.empty() ? std::string("-") : scene);
}

// NOT_FOUND for a scene id no call may use (or INVALID_ARGUMENT for an empty one).
inline Status unknown_scene(const std::string& id) {
    if (id.empty()) {
        return invalid_argument("scene_id is empty: name a scene made by CreateScene");
    }
    return not_found("scene " + id +
                     " does not exist (never created, deleted, or private to a frame stream)");
}

inline Status shutting_down() {
    return {StatusCode::unavailable,
            "proximad is shutting down; reconnect (to another instance) to go on"};
}

// What a streaming call (StreamFrames, Review, VerifyModel, FetchRegion, UploadObject) holds of its
// principal: the call's place among the principal's max-streams, given back when the reactor is
// deleted.
class StreamAdmission {
  public:
    StreamAdmission() = default;
    StreamAdmission(const StreamAdmission&) = delete;
    StreamAdmission& operator=(const StreamAdmission&) = delete;
    ~StreamAdmission() {
        if (m_counted) {
            m_principal->release_stream();
        }
    }

    // UNAUTHENTICATED, or RESOURCE_EXHAUSTED at the quota max-streams.
    Status admit(const ProximityService::Shared& shared,
                 const grpc::CallbackServerContext& context) {
        auto principal = authenticate(shared, context);
        if (!principal.ok()) {
            return principal.status();
        }
        m_principal = std::move(principal).value();
        if (Status s = m_principal->reserve_stream(); !s.ok()) {
            return s;
        }
        m_counted = true;
        return {};
    }

    // Null until admit() authenticated the call.
    const std::shared_ptr<Principal>& principal() const { return m_principal; }
    const std::string& who() const {
        static const std::string UNKNOWN = "-";
        return m_principal ? m_principal->log_name() : UNKNOWN;
    }

  private:
    std::shared_ptr<Principal> m_principal;
    bool m_counted = false;
};

// A model the principal may use, with the same NOT_FOUND as an unknown name otherwise, so that
// model names a token may not use do not leak.
inline StatusOr<std::shared_ptr<const ModelEntry>> find_model(ProximityService::Shared& shared,
                                                              const Principal& who,
                                                              const std::string& name) {
    if (!who.may_use_model(name)) {
        return shared.models.unknown_model(name);
    }
    return shared.models.find(name);
}

// What a viewer of a model sees (FetchRegion, a model-region Snapshot): the model's store, or,
// with a room, the store the room opened (the generation its members see) and one version of the
// room's edited view, so every piece comes from one model version; object indices below
// object_count exist or existed.
struct ViewedModel {
    std::shared_ptr<const massive::Store> store;
    std::shared_ptr<const massive::ModelView::Snapshot> room_view;  // null without a room
    std::uint32_t object_count = 0;
};

// The model (find_model's rules), and with `room` the room's view: the room's access as for
// joining it (PERMISSION_DENIED), NOT_FOUND for no such room, FAILED_PRECONDITION for a room on
// another model.
inline StatusOr<ViewedModel> find_model_view(ProximityService::Shared& shared, const Principal& who,
                                             const std::string& model_name,
                                             const std::string& room_name) {
    auto model = find_model(shared, who, model_name);
    if (!model.ok()) {
        return model.status();
    }
    ViewedModel out;
    out.store = model.value()->store;
    if (!room_name.empty()) {
        if (!who.may_join_room(room_name)) {
            return Status(StatusCode::permission_denied,
                          "token '" + who.name() + "' may not see review room '" + room_name +
                              "' (no pattern of its rooms matches)");
        }
        const std::shared_ptr<Room> room = shared.rooms.find(room_name);
        if (!room) {
            return not_found("room " + room_name +
                             " does not exist (a room lives while it has members)");
        }
        if (room->model().name != model_name) {
            return failed_precondition("room " + room_name + " reviews model '" +
                                       room->model().name + "', not '" + model_name + "'");
        }
        out.store = room->view()->store();
        out.room_view = room->view()->snapshot();
    }
    out.object_count = static_cast<std::uint32_t>(out.store->objects().size());
    if (out.room_view) {
        for (const auto& o : out.room_view->overlay) {
            out.object_count = std::max(out.object_count, o.object + 1);
        }
    }
    return out;
}

// A unary call: the method fills the response on the worker pool (or inline when it is cheap)
// and calls complete() last. The reactor deletes itself in OnDone, which gRPC may run as soon as
// Finish is called, so nothing may touch it after complete().
//
// While the daemon drains, a new call is refused at once: the constructor completes it with
// UNAVAILABLE and refused() tells the method to return without doing anything; likewise a call
// without a valid token (UNAUTHENTICATED) and one whose request would pass the principal's
// max-bytes-in-flight (`request_bytes` are held for the call's duration). (gRPC runs OnDone only
// after the method has returned the reactor, so reading refused() is safe.)
class UnaryCall final : public grpc::ServerUnaryReactor {
  public:
    UnaryCall(ProximityService::Shared& shared, grpc::CallbackServerContext* context,
              const char* method, std::string scene, std::uint64_t request_bytes = 0)
        : m_shared(shared),
          m_method(method),
          m_peer(context->peer()),
          m_scene(std::move(scene)),
          m_start(Clock::now()) {
        apply_deadline(m_cancel, *context);
        m_refused = !m_shared.enter_call();
        if (m_refused) {
            complete(shutting_down());
            return;
        }
        auto principal = authenticate(m_shared, *context);
        if (!principal.ok()) {
            m_refused = true;
            complete(principal.status());
            return;
        }
        m_principal = std::move(principal).value();
        if (Status s = m_principal->reserve_in_flight(request_bytes); !s.ok()) {
            m_refused = true;
            complete(s);
            return;
        }
        m_in_flight_bytes = request_bytes;
    }

    bool refused() const { return m_refused; }
    const CancelToken& cancel() const { return m_cancel; }
    // Null only when refused().
    const std::shared_ptr<Principal>& principal() const { return m_principal; }
    void set_scene(std::string scene) { m_scene = std::move(scene); }

    void complete(const Status& status, const std::string& extra = {}) {
        if (m_principal) {
            m_principal->release_in_flight(m_in_flight_bytes);
            m_in_flight_bytes = 0;
        }
        log_call(m_shared, m_method, m_principal ? m_principal->log_name() : "-", m_peer,
                 scene_subject(m_scene), m_start, status, extra);
        Finish(wire::to_grpc(status));
    }

    void OnCancel() override { end_by_client(m_cancel); }
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
    std::shared_ptr<Principal> m_principal;
    std::uint64_t m_in_flight_bytes = 0;
};

}  // namespace proxima::server
