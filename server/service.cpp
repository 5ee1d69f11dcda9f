#include "service.hpp"

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <exception>
#include <mutex>
#include <new>
#include <optional>
#include <string>
#include <thread>
#include <unordered_set>
#include <utility>

#include <spdlog/spdlog.h>

#include "encode.hpp"
#include "frames.hpp"
#include "proxima/gpu/egl_backend.hpp"
#include "proxima/gpu/failover_backend.hpp"
#include "proxima/wire/buffers.hpp"
#include "proxima/wire/status.hpp"
#include "scene_registry.hpp"
#include "service_internal.hpp"
#include "worker_pool.hpp"

namespace proxima::server {

namespace {

Status unknown_scene(const std::string& id) {
    if (id.empty()) {
        return invalid_argument("scene_id is empty: name a scene made by CreateScene");
    }
    return not_found("scene " + id +
                     " does not exist (never created, deleted, or private to a frame stream)");
}

// UploadObject: a header, then vertex and index bytes in chunks. Sizes are checked as bytes
// arrive (an upload that sends more than its header announced is refused at once, before it
// is buffered); the object is built and added on the worker pool once the client half-closes with
// exactly the announced bytes.
class UploadReactor final : public grpc::ServerReadReactor<v1::UploadChunk> {
  public:
    UploadReactor(ProximityService::Shared& shared, grpc::CallbackServerContext* context,
                  v1::ObjectInfo* response)
        : m_shared(shared),
          m_context(context),
          m_response(response),
          m_peer(context->peer()),
          m_start(Clock::now()) {
        if (!m_shared.enter_call()) {
            complete(shutting_down());
            return;
        }
        if (Status s = m_admission.admit(m_shared, *m_context); !s.ok()) {
            complete(s);
            return;
        }
        StartRead(&m_chunk);
    }

    void OnReadDone(bool ok) override {
        if (!ok) {
            end_of_upload();
            return;
        }
        Status s = guarded([&] { return take_chunk(); });
        if (!s.ok()) {
            complete(s);
            return;
        }
        m_chunk.Clear();
        StartRead(&m_chunk);
    }

    void OnDone() override {
        m_shared.leave_call();
        delete this;
    }

  private:
    Status take_chunk() {
        switch (m_chunk.part_case()) {
            case v1::UploadChunk::kHeader:
                if (m_have_header) {
                    return invalid_argument("upload: a second header; send exactly one, first");
                }
                return take_header(m_chunk.header());
            case v1::UploadChunk::kVertexBytes:
                return append(m_chunk.vertex_bytes(), m_vertex_bytes, m_expected_vertex_bytes,
                              "vertex", "vertex_count", m_header.vertex_count());
            case v1::UploadChunk::kIndexBytes:
                return append(m_chunk.index_bytes(), m_index_bytes, m_expected_index_bytes, "index",
                              "triangle_count", m_header.triangle_count());
            default:
                return invalid_argument(
                    "upload: an empty chunk (set header, vertex_bytes or "
                    "index_bytes)");
        }
    }

    std::string label() const {
        return "upload of object" + (m_header.name().empty() ? "" : " '" + m_header.name() + "'");
    }

    Status take_header(const v1::UploadHeader& header) {
        m_header = header;
        m_have_header = true;
        m_scene_id = header.scene_id();
        auto entry = m_shared.scenes.find(m_scene_id, *m_admission.principal());
        if (!entry) {
            return unknown_scene(m_scene_id);
        }
        const std::size_t stride = wire::vertex_stride(header.type());
        if (stride == 0) {
            return invalid_argument(label() +
                                    ": header.type must be SCALAR_TYPE_FLOAT32 or "
                                    "SCALAR_TYPE_FLOAT64");
        }
        if (header.triangle_count() == 0) {
            return invalid_argument(label() +
                                    ": header.triangle_count is 0 (a mesh needs at "
                                    "least one triangle)");
        }
        // Early limit checks from the scene's published sizes; add_objects repeats them under
        // the scene's mutex.
        const auto& limits = m_shared.config.limits;
        const auto objects = entry->object_count.load() + 1;
        if (objects > limits.max_objects_per_scene) {
            return {StatusCode::resource_exhausted,
                    label() + ": scene " + m_scene_id + " would hold " + std::to_string(objects) +
                        " objects, over the limit max-objects-per-scene = " +
                        std::to_string(limits.max_objects_per_scene)};
        }
        const auto triangles = entry->triangle_count.load() + header.triangle_count();
        if (triangles > limits.max_triangles_per_scene) {
            return {StatusCode::resource_exhausted,
                    label() + ": scene " + m_scene_id + " would hold " + std::to_string(triangles) +
                        " triangles, over the limit max-triangles-per-scene = " +
                        std::to_string(limits.max_triangles_per_scene)};
        }
        // Vertices beyond three per triangle of the scene limit cannot belong to a sane mesh;
        // without this bound a header alone could make the daemon buffer ~100 GB.
        if (header.vertex_count() > 3 * limits.max_triangles_per_scene) {
            return {StatusCode::resource_exhausted,
                    label() + ": header.vertex_count " + std::to_string(header.vertex_count()) +
                        " exceeds 3 x max-triangles-per-scene = " +
                        std::to_string(3 * limits.max_triangles_per_scene)};
        }
        m_expected_vertex_bytes = std::uint64_t{header.vertex_count()} * stride;
        m_expected_index_bytes = std::uint64_t{header.triangle_count()} * 12;
        return {};
    }

    Status append(const std::string& chunk, std::string& buffer, std::uint64_t expected,
                  const char* what, const char* count_field, std::uint32_t count) {
        if (!m_have_header) {
            return invalid_argument(std::string("upload: ") + what +
                                    "_bytes before the header; the header comes first");
        }
        if (buffer.size() + chunk.size() > expected) {
            return invalid_argument(label() + ": " + what + " bytes exceed the header's " +
                                    count_field + " " + std::to_string(count) + " (" +
                                    std::to_string(expected) + " bytes); received at least " +
                                    std::to_string(buffer.size() + chunk.size()));
        }
        // Buffered bytes are in flight until the object is added (or the upload fails).
        if (Status s = m_admission.principal()->reserve_in_flight(chunk.size()); !s.ok()) {
            return s;
        }
        m_in_flight_bytes += chunk.size();
        buffer += chunk;
        return {};
    }

    void end_of_upload() {
        if (m_context->IsCancelled()) {
            complete({StatusCode::cancelled, "upload cancelled by the client; nothing added"});
            return;
        }
        if (!m_have_header) {
            complete(invalid_argument("upload ended before its header; nothing added"));
            return;
        }
        if (m_vertex_bytes.size() != m_expected_vertex_bytes ||
            m_index_bytes.size() != m_expected_index_bytes) {
            complete(invalid_argument(
                label() + " ended incomplete: " + std::to_string(m_vertex_bytes.size()) + " of " +
                std::to_string(m_expected_vertex_bytes) + " vertex bytes and " +
                std::to_string(m_index_bytes.size()) + " of " +
                std::to_string(m_expected_index_bytes) + " index bytes; nothing added"));
            return;
        }
        m_shared.pool.submit([this] { complete(guarded([&] { return add(); })); });
    }

    Status add() {
        auto vertices = wire::decode_vertex_bytes(m_header.type(), m_vertex_bytes, label());
        if (!vertices.ok()) {
            return vertices.status();
        }
        auto triangles = wire::decode_indices(m_index_bytes, label());
        if (!triangles.ok()) {
            return triangles.status();
        }
        auto entry = m_shared.scenes.find(m_scene_id, *m_admission.principal());
        if (!entry) {
            return unknown_scene(m_scene_id);
        }
        if (m_context->IsCancelled()) {
            return {StatusCode::cancelled, "upload cancelled by the client; nothing added"};
        }
        NamedMesh mesh;
        mesh.name = m_header.name();
        mesh.mesh.vertices = std::move(vertices).value();
        mesh.mesh.triangles = std::move(triangles).value();
        m_response->set_name(mesh.name);
        m_response->set_vertex_count(static_cast<std::uint32_t>(mesh.mesh.vertices.size()));
        m_response->set_triangle_count(static_cast<std::uint32_t>(mesh.mesh.triangles.size()));
        std::vector<NamedMesh> meshes;
        meshes.push_back(std::move(mesh));
        auto added = add_objects(*entry, std::move(meshes), m_shared.config.limits, "upload");
        if (!added.ok()) {
            return added.status();
        }
        m_response->set_id(added->added_ids.front());
        return {};
    }

    // Last thing done with this reactor: Finish lets gRPC run OnDone (which deletes it).
    void complete(const Status& status) {
        if (m_in_flight_bytes != 0) {
            m_admission.principal()->release_in_flight(m_in_flight_bytes);
            m_in_flight_bytes = 0;
        }
        log_call(m_shared, "UploadObject", m_admission.who(), m_peer, scene_subject(m_scene_id),
                 m_start, status,
                 " bytes=" + std::to_string(m_vertex_bytes.size() + m_index_bytes.size()));
        Finish(wire::to_grpc(status));
    }

    ProximityService::Shared& m_shared;
    grpc::CallbackServerContext* m_context;
    v1::ObjectInfo* m_response;
    std::string m_peer;
    Clock::time_point m_start;
    v1::UploadChunk m_chunk;
    bool m_have_header = false;
    v1::UploadHeader m_header;
    std::string m_scene_id;
    std::uint64_t m_expected_vertex_bytes = 0;
    std::uint64_t m_expected_index_bytes = 0;
    std::string m_vertex_bytes;
    std::string m_index_bytes;
    StreamAdmission m_admission;
    std::uint64_t m_in_flight_bytes = 0;  // of m_admission's principal
};

}  // namespace

// StreamFrames. Frames are read while fewer than max_frames_in_flight are read but unanswered
// (backpressure: past that, no read is started, so gRPC's flow control pushes back on the
// client instead of the daemon buffering). One worker task at a time processes the stream's
// frames in order and queues results; results are written in order, one write outstanding.
//
// Every state change happens under m_mu. Finish is called exactly once, by
// maybe_finish_locked(), and only when no worker task runs and no write is outstanding; OnDone
// takes m_mu once before deleting the reactor, so the thread that called Finish has let go.
class FrameStreamReactor final : public grpc::ServerBidiReactor<v1::Frame, v1::FrameResult>,
                                 public DrainableStream {
  public:
    FrameStreamReactor(ProximityService::Shared& shared, grpc::CallbackServerContext* context)
        : m_shared(shared), m_peer(context->peer()), m_start(Clock::now()) {
        apply_deadline(m_cancel, *context);
        const bool accepted = m_shared.enter_call(this);
        std::lock_guard lock(m_mu);
        m_draining = !accepted;
        if (accepted) {
            if (Status s = m_admission.admit(m_shared, *context); !s.ok()) {
                m_error = s;
            }
        }
        start_read_if_room_locked();
        maybe_finish_locked();
    }

    void OnReadDone(bool ok) override {
        std::lock_guard lock(m_mu);
        m_reading = false;
        if (!ok) {
            m_read_done = true;  // half-close (or the call is going away)
            maybe_finish_locked();
            return;
        }
        if (m_finished || stopped_locked()) {
            return;
        }
        // A frame's bytes count against its principal's max-bytes-in-flight until it is answered.
        const std::uint64_t bytes = m_incoming.ByteSizeLong();
        if (Status s = m_admission.principal()->reserve_in_flight(bytes); !s.ok()) {
            m_error = s;
            drop_frames_locked();
            maybe_finish_locked();
            return;
        }
        m_frames.push_back(std::move(m_incoming));
        m_frame_bytes.push_back(bytes);
        m_incoming.Clear();
        ++m_in_flight;
        start_read_if_room_locked();
        if (!m_processing) {
            m_processing = true;
            m_shared.pool.submit([this] { process(); });
        }
    }

    void OnWriteDone(bool ok) override {
        std::lock_guard lock(m_mu);
        m_writing = false;
        if (!ok) {
            // The client is gone: stop the frame that may be running and drop the rest.
            m_write_failed = true;
            m_cancel.cancel();
            drop_frames_locked();
            maybe_finish_locked();
            return;
        }
        m_results.pop_front();
        --m_in_flight;
        if (!m_results.empty()) {
            m_writing = true;
            StartWrite(&m_results.front());
        }
        start_read_if_room_locked();
        maybe_finish_locked();
    }

    void OnCancel() override {
        std::lock_guard lock(m_mu);
        m_cancelled = true;
        m_cancel.cancel();
        drop_frames_locked();
        maybe_finish_locked();
    }

    void OnDone() override {
        {
            std::lock_guard lock(m_mu);  // the thread that called Finish has released m_mu
            drop_frames_locked();
        }
        // The scene goes before the stream count drops, so a client that sees live_streams back
        // to its old value also sees live_scenes back.
        const std::string scene_id = m_scene ? m_scene->id : "";
        if (m_owns_scene && m_scene) {
            m_shared.scenes.erase(scene_id);
        }
        // Freeing a large engine takes a while: a worker does it, not gRPC's callback thread.
        if (m_scene) {
            m_shared.pool.submit([doomed = std::move(m_scene)] {});
        }
        m_shared.leave_call(this);
        const std::string extra = " frames=" + std::to_string(m_frames_answered) +
                                  " owned_scene=" + (m_owns_scene ? "true" : "false");
        log_call(m_shared, "StreamFrames", m_admission.who(), m_peer, scene_subject(scene_id),
                 m_start, m_final, extra, spdlog::level::info);
        delete this;
    }

    // Shutdown: read no more; finish once what was read is answered (now, when idle).
    void drain() override {
        std::lock_guard lock(m_mu);
        m_draining = true;
        maybe_finish_locked();
    }

  private:
    bool stopped_locked() const { return m_cancelled || m_write_failed || m_error.has_value(); }

    // Drops the frames read but not processed, giving their bytes back.
    void drop_frames_locked() {
        std::uint64_t bytes = 0;
        for (const auto b : m_frame_bytes) {
            bytes += b;
        }
        if (bytes != 0) {
            m_admission.principal()->release_in_flight(bytes);
        }
        m_frames.clear();
        m_frame_bytes.clear();
    }

    void start_read_if_room_locked() {
        if (m_reading || m_read_done || m_finished || m_draining || stopped_locked() ||
            m_in_flight >= m_shared.config.limits.max_frames_in_flight) {
            return;
        }
        m_reading = true;
        StartRead(&m_incoming);
    }

    void maybe_finish_locked() {
        if (m_finished || m_processing || m_writing) {
            return;
        }
        Status final;
        if (m_cancelled || m_write_failed) {
            final = {StatusCode::cancelled, "stream cancelled by the client"};
        } else if (m_error) {
            final = *m_error;
        } else if (m_frames.empty() && m_read_done) {
            final = {};
        } else if (m_frames.empty() && m_draining) {
            final = shutting_down();
        } else {
            return;
        }
        m_finished = true;
        m_final = final;
        Finish(wire::to_grpc(final));
    }

    // Worker task: processes queued frames in order until none is left or the stream stops.
    void process() {
        for (;;) {
            v1::Frame frame;
            std::uint64_t frame_bytes = 0;
            {
                std::lock_guard lock(m_mu);
                if (m_frames.empty() || stopped_locked()) {
                    m_processing = false;
                    maybe_finish_locked();
                    return;
                }
                frame = std::move(m_frames.front());
                m_frames.pop_front();
                frame_bytes = m_frame_bytes.front();
                m_frame_bytes.pop_front();
            }
            v1::FrameResult result;
            Status s = m_admission.principal()->admit_frame();
            if (s.ok()) {
                s = guarded([&] { return handle(frame, &result); });
            }
            m_admission.principal()->release_in_flight(frame_bytes);
            if (s.ok()) {
                m_shared.metrics.add_frames(1, result.stats().exact_tests());
            }
            std::lock_guard lock(m_mu);
            if (!s.ok()) {
                if (!m_error) {
                    m_error = s;
                }
                drop_frames_locked();
                m_processing = false;
                maybe_finish_locked();
                return;
            }
            ++m_frames_answered;
            m_results.push_back(std::move(result));
            if (!m_writing && !m_finished) {
                m_writing = true;
                StartWrite(&m_results.front());
            }
        }
    }

    // One frame, off the lock. m_scene and m_owns_scene are only touched here (one task at a
    // time) and in OnDone (after the last task).
    Status handle(const v1::Frame& frame, v1::FrameResult* out) {
        const auto& limits = m_shared.config.limits;
        if (m_scene) {
            if (!frame.scene_id().empty() && frame.scene_id() != m_scene->id) {
                return invalid_argument("frame " + std::to_string(frame.frame()) + " names scene " +
                                        frame.scene_id() + " but this stream is bound to scene " +
                                        m_scene->id);
            }
            return run_frame(*m_scene, frame, limits, &m_cancel, out);
        }
        const auto& principal = m_admission.principal();
        if (!frame.scene_id().empty()) {
            auto entry = m_shared.scenes.find(frame.scene_id(), *principal);
            if (!entry) {
                return unknown_scene(frame.scene_id());
            }
            m_scene = entry;
            spdlog::info(
                "stream start method=StreamFrames who={} peer={} scene={} owned_scene=false",
                m_admission.who(), m_peer, m_scene->id);
            return run_frame(*m_scene, frame, limits, &m_cancel, out);
        }
        // An empty scene_id on the first frame: a scene owned by this stream, built from the
        // frame's additions, registered only once they are valid and applied.
        if (!principal->may_create_scene("")) {
            return {StatusCode::permission_denied,
                    "token '" + principal->name() +
                        "' may not create stream-owned scenes (their name is \"\"; its scenes "
                        "patterns must match it, e.g. \"*\"); name a scene made by CreateScene"};
        }
        if (Status s = m_shared.scenes.check_capacity(); !s.ok()) {
            return s;
        }
        auto entry = m_shared.scenes.make_entry("", true, principal);
        return run_frame(*entry, frame, limits, &m_cancel, out, [&]() -> Status {
            if (Status s = m_shared.scenes.insert(entry); !s.ok()) {
                return s;
            }
            m_scene = entry;
            m_owns_scene = true;
            spdlog::info(
                "stream start method=StreamFrames who={} peer={} scene={} owned_scene=true",
                m_admission.who(), m_peer, m_scene->id);
            return {};
        });
    }

    ProximityService::Shared& m_shared;
    const std::string m_peer;
    const Clock::time_point m_start;
    CancelToken m_cancel;  // deadline set before any task runs; cancel() is atomic

    std::mutex m_mu;
    v1::Frame m_incoming;                     // target of the outstanding read
    std::deque<v1::Frame> m_frames;           // read, not yet processed
    std::deque<std::uint64_t> m_frame_bytes;  // their sizes, in flight for the principal
    std::deque<v1::FrameResult> m_results;    // answered, not yet written; front is being written
    std::size_t m_in_flight = 0;              // read, result not yet written
    bool m_reading = false;
    bool m_read_done = false;
    bool m_writing = false;
    bool m_processing = false;
    bool m_finished = false;
    bool m_cancelled = false;
    bool m_write_failed = false;
    bool m_draining = false;
    std::optional<Status> m_error;
    Status m_final;
    std::uint64_t m_frames_answered = 0;

    std::shared_ptr<SceneEntry> m_scene;
    bool m_owns_scene = false;
    // Set once in the constructor, before any other callback can run.
    StreamAdmission m_admission;
};

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
    if (shared.config.idle_scene_seconds > 0) {
        shared.start_reaper();
    }
    return start_models();
}

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

grpc::ServerUnaryReactor* ProximityService::CreateScene(grpc::CallbackServerContext* context,
                                                        const v1::CreateSceneRequest* request,
                                                        v1::SceneInfo* response) {
    auto* call = new UnaryCall(*m_shared, context, "CreateScene", "", request->ByteSizeLong());
    if (call->refused()) {
        return call;
    }
    m_shared->pool.submit([this, call, request, response] {
        std::string extra;
        Status s = guarded([&]() -> Status {
            auto& shared = *m_shared;
            const auto& principal = call->principal();
            if (!principal->may_create_scene(request->name())) {
                return {StatusCode::permission_denied,
                        "token '" + principal->name() + "' may not create a scene named '" +
                            request->name() + "' (no pattern of its scenes matches)"};
            }
            if (Status full = shared.scenes.check_capacity(); !full.ok()) {
                return full;
            }
            auto meshes = wire::decode_meshes(request->objects(), "objects");
            if (!meshes.ok()) {
                return meshes.status();
            }
            auto entry = shared.scenes.make_entry(request->name(), false, principal);
            call->set_scene(entry->id);
            auto added =
                add_objects(*entry, std::move(meshes).value(), shared.config.limits, "objects");
            if (!added.ok()) {
                return added.status();
            }
            {
                std::lock_guard lock(entry->mutex);
                encode_scene(entry->id, entry->name, entry->engine.scene(), entry->frames,
                             response);
            }
            extra = " objects=" + std::to_string(response->objects_size()) +
                    " triangles=" + std::to_string(response->triangle_count());
            return shared.scenes.insert(entry);
        });
        if (s.ok()) {
            spdlog::info("scene created method=CreateScene who={} scene={}{}",
                         call->principal()->log_name(), response->scene_id(), extra);
        }
        call->complete(s, extra);
    });
    return call;
}

grpc::ServerUnaryReactor* ProximityService::DescribeScene(grpc::CallbackServerContext* context,
                                                          const v1::DescribeSceneRequest* request,
                                                          v1::SceneInfo* response) {
    auto* call = new UnaryCall(*m_shared, context, "DescribeScene", request->scene_id());
    if (call->refused()) {
        return call;
    }
    // Off the callback thread: it waits for the scene's mutex while a frame runs.
    m_shared->pool.submit([this, call, request, response] {
        call->complete(guarded([&]() -> Status {
            auto entry = m_shared->scenes.find(request->scene_id(), *call->principal());
            if (!entry) {
                return unknown_scene(request->scene_id());
            }
            std::lock_guard lock(entry->mutex);
            encode_scene(entry->id, entry->name, entry->engine.scene(), entry->frames, response);
            return {};
        }));
    });
    return call;
}

grpc::ServerUnaryReactor* ProximityService::DeleteScene(grpc::CallbackServerContext* context,
                                                        const v1::DeleteSceneRequest* request,
                                                        v1::DeleteSceneResponse*) {
    auto* call = new UnaryCall(*m_shared, context, "DeleteScene", request->scene_id());
    if (call->refused()) {
        return call;
    }
    Status s;
    auto entry = m_shared->scenes.find(request->scene_id(), *call->principal());
    // Unknown, or deleted by someone else meanwhile: the same NOT_FOUND.
    if (entry && m_shared->scenes.erase(entry->id)) {
        spdlog::info("scene deleted method=DeleteScene who={} scene={}",
                     call->principal()->log_name(), entry->id);
    } else {
        s = unknown_scene(request->scene_id());
    }
    // Freeing a large engine takes a while: let a worker do it, not gRPC's callback thread. (A
    // frame still holding the scene frees it when it ends instead.)
    if (entry) {
        m_shared->pool.submit([doomed = std::move(entry)] {});
    }
    call->complete(s);
    return call;
}

grpc::ServerReadReactor<v1::UploadChunk>* ProximityService::UploadObject(
    grpc::CallbackServerContext* context, v1::ObjectInfo* response) {
    return new UploadReactor(*m_shared, context, response);
}

grpc::ServerBidiReactor<v1::Frame, v1::FrameResult>* ProximityService::StreamFrames(
    grpc::CallbackServerContext* context) {
    return new FrameStreamReactor(*m_shared, context);
}

grpc::ServerUnaryReactor* ProximityService::Query(grpc::CallbackServerContext* context,
                                                  const v1::Frame* request,
                                                  v1::FrameResult* response) {
    auto* call =
        new UnaryCall(*m_shared, context, "Query", request->scene_id(), request->ByteSizeLong());
    if (call->refused()) {
        return call;
    }
    m_shared->pool.submit([this, call, request, response] {
        call->complete(guarded([&]() -> Status {
            if (Status s = call->principal()->admit_frame(); !s.ok()) {
                return s;
            }
            auto entry = m_shared->scenes.find(request->scene_id(), *call->principal());
            if (!entry) {
                return unknown_scene(request->scene_id());
            }
            Status s =
                run_frame(*entry, *request, m_shared->config.limits, &call->cancel(), response);
            if (s.ok()) {
                m_shared->metrics.add_frames(1, response->stats().exact_tests());
            }
            return s;
        }));
    });
    return call;
}

}  // namespace proxima::server
