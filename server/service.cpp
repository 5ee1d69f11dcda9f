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

#include "convert.hpp"
#include "frames.hpp"
#include "proxima/gpu/egl_backend.hpp"
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
        auto entry = m_shared.scenes.find(m_scene_id);
        if (!entry) {
            return unknown_scene(m_scene_id);
        }
        const std::size_t stride = vertex_stride(header.type());
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
        auto vertices = decode_vertex_bytes(m_header.type(), m_vertex_bytes, label());
        if (!vertices.ok()) {
            return vertices.status();
        }
        auto triangles = decode_indices(m_index_bytes, label());
        if (!triangles.ok()) {
            return triangles.status();
        }
        auto entry = m_shared.scenes.find(m_scene_id);
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
        log_call("UploadObject", m_peer, m_scene_id, m_start, status,
                 " bytes=" + std::to_string(m_vertex_bytes.size() + m_index_bytes.size()));
        Finish(to_grpc_status(status));
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
        m_frames.push_back(std::move(m_incoming));
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
            m_frames.clear();
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
        m_frames.clear();
        maybe_finish_locked();
    }

    void OnDone() override {
        { std::lock_guard lock(m_mu); }  // the thread that called Finish has released m_mu
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
        if (m_final.ok()) {
            spdlog::info(
                "stream end method=StreamFrames peer={} scene={} status=OK "
                "duration_ms={:.3f}{}",
                m_peer, scene_id.empty() ? "-" : scene_id, milliseconds_since(m_start), extra);
        } else {
            log_call("StreamFrames", m_peer, scene_id, m_start, m_final, extra);
        }
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
        Finish(to_grpc_status(final));
    }

    // Worker task: processes queued frames in order until none is left or the stream stops.
    void process() {
        for (;;) {
            v1::Frame frame;
            {
                std::lock_guard lock(m_mu);
                if (m_frames.empty() || stopped_locked()) {
                    m_processing = false;
                    maybe_finish_locked();
                    return;
                }
                frame = std::move(m_frames.front());
                m_frames.pop_front();
            }
            v1::FrameResult result;
            Status s = guarded([&] { return handle(frame, &result); });
            std::lock_guard lock(m_mu);
            if (!s.ok()) {
                if (!m_error) {
                    m_error = s;
                }
                m_frames.clear();
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
        if (!frame.scene_id().empty()) {
            auto entry = m_shared.scenes.find(frame.scene_id());
            if (!entry) {
                return unknown_scene(frame.scene_id());
            }
            m_scene = entry;
            spdlog::info("stream start method=StreamFrames peer={} scene={} owned_scene=false",
                         m_peer, m_scene->id);
            return run_frame(*m_scene, frame, limits, &m_cancel, out);
        }
        // An empty scene_id on the first frame: a scene owned by this stream, built from the
        // frame's additions, registered only once they are valid and applied.
        if (Status s = m_shared.scenes.check_capacity(); !s.ok()) {
            return s;
        }
        auto entry = m_shared.scenes.make_entry("", true);
        return run_frame(*entry, frame, limits, &m_cancel, out, [&]() -> Status {
            if (Status s = m_shared.scenes.insert(entry); !s.ok()) {
                return s;
            }
            m_scene = entry;
            m_owns_scene = true;
            spdlog::info("stream start method=StreamFrames peer={} scene={} owned_scene=true",
                         m_peer, m_scene->id);
            return {};
        });
    }

    ProximityService::Shared& m_shared;
    const std::string m_peer;
    const Clock::time_point m_start;
    CancelToken m_cancel;  // deadline set before any task runs; cancel() is atomic

    std::mutex m_mu;
    v1::Frame m_incoming;                   // target of the outstanding read
    std::deque<v1::Frame> m_frames;         // read, not yet processed
    std::deque<v1::FrameResult> m_results;  // answered, not yet written; front is being written
    std::size_t m_in_flight = 0;            // read, result not yet written
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
};

ProximityService::ProximityService(const ServerConfig& config)
    : m_shared(std::make_unique<Shared>(config)) {
    std::string reason = "the GPU is off (--gpu off)";
    if (config.gpu != "off") {
        auto backend = gpu::make_egl_backend();
        if (backend.ok()) {
            m_shared->gpu = std::move(backend).value();
            // name() is "gpu (<GL_RENDERER>)".
            const auto name = m_shared->gpu->name();
            const auto open = name.find('(');
            m_shared->gl_renderer =
                open == std::string::npos ? name : name.substr(open + 1, name.size() - open - 2);
            spdlog::info("gpu backend=egl gl_renderer=\"{}\"", m_shared->gl_renderer);
        } else {
            reason = "EGL unavailable: " + backend.status().message();
            spdlog::warn("gpu backend=cpu reason=\"{}\" (the Voronoi culler runs on the CPU)",
                         reason);
        }
    }
    m_shared->scenes.set_gpu(m_shared->gpu, reason);
}

std::string ProximityService::proximity_backend() const {
    return m_shared->gpu ? "gpu (voronoi-gpu) + cpu (voronoi-cpu, bvh, brute)"
                         : "cpu (voronoi-cpu, bvh, brute)";
}

std::string ProximityService::gl_renderer() const {
    return m_shared->gl_renderer;
}

ProximityService::~ProximityService() = default;

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
    response->set_live_scenes(live_scenes());
    response->set_live_streams(live_streams());
    call->complete({});
    return call;
}

grpc::ServerUnaryReactor* ProximityService::CreateScene(grpc::CallbackServerContext* context,
                                                        const v1::CreateSceneRequest* request,
                                                        v1::SceneInfo* response) {
    auto* call = new UnaryCall(*m_shared, context, "CreateScene", "");
    if (call->refused()) {
        return call;
    }
    m_shared->pool.submit([this, call, request, response] {
        std::string extra;
        Status s = guarded([&]() -> Status {
            auto& shared = *m_shared;
            if (Status full = shared.scenes.check_capacity(); !full.ok()) {
                return full;
            }
            auto meshes = decode_meshes(request->objects(), "objects");
            if (!meshes.ok()) {
                return meshes.status();
            }
            auto entry = shared.scenes.make_entry(request->name(), false);
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
            spdlog::info("scene created method=CreateScene scene={}{}", response->scene_id(),
                         extra);
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
            auto entry = m_shared->scenes.find(request->scene_id());
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
    auto entry = m_shared->scenes.find(request->scene_id());
    if (!entry) {
        s = unknown_scene(request->scene_id());
    } else if (m_shared->scenes.erase(entry->id)) {
        spdlog::info("scene deleted method=DeleteScene scene={}", entry->id);
    } else {
        s = unknown_scene(request->scene_id());  // deleted by someone else meanwhile
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
    auto* call = new UnaryCall(*m_shared, context, "Query", request->scene_id());
    if (call->refused()) {
        return call;
    }
    m_shared->pool.submit([this, call, request, response] {
        call->complete(guarded([&]() -> Status {
            auto entry = m_shared->scenes.find(request->scene_id());
            if (!entry) {
                return unknown_scene(request->scene_id());
            }
            return run_frame(*entry, *request, m_shared->config.limits, &call->cancel(), response);
        }));
    });
    return call;
}

}  // namespace proxima::server
