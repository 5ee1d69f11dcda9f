#include "client/proxima_client.hpp"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <thread>
#include <utility>

#include <grpcpp/grpcpp.h>

#include "client/convert.hpp"
#include "proxima/v1/proxima.grpc.pb.h"

namespace proxima::client {

namespace pb = ::proxima::v1;
using detail::from_grpc;

namespace {

// Upload chunks stay at or under 1 MiB so that each message is far below any sane server limit,
// and hold whole vertices / triangles so that each chunk is packed independently (no full copy
// of a large mesh in wire format).
constexpr std::size_t UPLOAD_CHUNK_BYTES = 1u << 20;

std::chrono::system_clock::time_point deadline_after(std::chrono::milliseconds ms) {
    return std::chrono::system_clock::now() + ms;
}

}  // namespace

struct Client::Impl {
    std::string address;
    ConnectOptions options;
    std::shared_ptr<grpc::Channel> channel;
    std::unique_ptr<pb::Proximity::Stub> stub;

    void prepare(grpc::ClientContext& context) const {
        if (options.call_timeout.count() > 0) {
            context.set_deadline(deadline_after(options.call_timeout));
        }
    }
};

struct FrameStream::Impl {
    bool float32 = false;
    // Sent on every frame: the existing scene's id, or empty for a stream-owned scene (whose id
    // the first result names; later frames need not repeat it).
    std::string scene_id;
    grpc::ClientContext context;
    std::unique_ptr<grpc::ClientReaderWriter<pb::Frame, pb::FrameResult>> stream;
    // Results read ahead while closing after a failed write: they were sent by the server before
    // it ended the stream, so receive() still hands them out, in order, before the final status.
    std::deque<pb::FrameResult> read_ahead;
    std::size_t in_flight = 0;
    bool writes_done = false;
    bool finished = false;
    Status final_status;

    // Reads what is left, then collects the status. Only after WritesDone, a failed write or a
    // failed read: Finish would otherwise wait for a server that waits for us.
    void close() {
        if (finished) {
            return;
        }
        pb::FrameResult result;
        while (stream->Read(&result)) {
            read_ahead.push_back(std::move(result));
            result.Clear();
        }
        final_status = from_grpc(stream->Finish());
        finished = true;
    }

    Status ended_status() const {
        if (!final_status.ok()) {
            return final_status;
        }
        return {StatusCode::failed_precondition, "the frame stream has ended"};
    }
};

// --- Client ----------------------------------------------------------------------------------

Client::Client(std::unique_ptr<Impl> impl) : m_impl(std::move(impl)) {}
Client::~Client() = default;

StatusOr<std::unique_ptr<Client>> Client::connect(const std::string& address,
                                                  ConnectOptions options) {
    grpc::ChannelArguments args;
    // Results of big scenes (self distances per triangle) outgrow gRPC's 4 MiB default; the
    // server's own limits bound what it accepts, so the client does not cap either direction.
    args.SetMaxReceiveMessageSize(-1);
    args.SetMaxSendMessageSize(-1);
    auto channel = grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args);
    if (!channel->WaitForConnected(deadline_after(options.connect_timeout))) {
        return Status(StatusCode::unavailable, "cannot reach proximad at " + address + " within " +
                                                   std::to_string(options.connect_timeout.count()) +
                                                   " ms");
    }
    auto impl = std::make_unique<Impl>();
    impl->address = address;
    impl->options = options;
    impl->stub = pb::Proximity::NewStub(channel);
    impl->channel = std::move(channel);
    return std::unique_ptr<Client>(new Client(std::move(impl)));
}

StatusOr<RemoteServerInfo> Client::server_info() {
    grpc::ClientContext context;
    m_impl->prepare(context);
    pb::ServerInfo info;
    if (auto st = m_impl->stub->GetServerInfo(&context, pb::GetServerInfoRequest(), &info);
        !st.ok()) {
        return from_grpc(st);
    }
    return detail::decode_server_info(info);
}

StatusOr<RemoteScene> Client::create_scene(const std::string& name,
                                           const std::vector<NamedMesh>& objects) {
    const bool float32 = m_impl->options.float32_vertices;
    const std::size_t budget = m_impl->options.inline_mesh_bytes;
    // Results list objects in creation order and uploads append, so only a leading run of
    // objects can travel inline: the first one too big for the budget and everything after it
    // are uploaded, in order.
    pb::CreateSceneRequest request;
    request.set_name(name);
    std::size_t inline_count = 0;
    std::size_t used = 0;
    for (; inline_count < objects.size(); ++inline_count) {
        const auto bytes = detail::encoded_mesh_bytes(objects[inline_count], float32);
        if (used + bytes > budget) {
            break;
        }
        used += bytes;
        detail::encode_mesh(objects[inline_count], float32, request.add_objects());
    }
    pb::SceneInfo info;
    {
        grpc::ClientContext context;
        m_impl->prepare(context);
        if (auto st = m_impl->stub->CreateScene(&context, request, &info); !st.ok()) {
            return from_grpc(st);
        }
    }
    auto scene = detail::decode_scene(info);
    for (std::size_t i = inline_count; i < objects.size(); ++i) {
        auto object = upload_object(scene.scene_id, objects[i]);
        if (!object.ok()) {
            // A half-built scene is of no use to the caller and would hold the daemon's memory.
            (void)delete_scene(scene.scene_id);
            return object.status();
        }
        scene.triangle_count += object->triangle_count;
        scene.objects.push_back(std::move(object).value());
    }
    return scene;
}

StatusOr<RemoteScene> Client::describe_scene(const std::string& scene_id) {
    grpc::ClientContext context;
    m_impl->prepare(context);
    pb::DescribeSceneRequest request;
    request.set_scene_id(scene_id);
    pb::SceneInfo info;
    if (auto st = m_impl->stub->DescribeScene(&context, request, &info); !st.ok()) {
        return from_grpc(st);
    }
    return detail::decode_scene(info);
}

Status Client::delete_scene(const std::string& scene_id) {
    grpc::ClientContext context;
    m_impl->prepare(context);
    pb::DeleteSceneRequest request;
    request.set_scene_id(scene_id);
    pb::DeleteSceneResponse response;
    return from_grpc(m_impl->stub->DeleteScene(&context, request, &response));
}

StatusOr<RemoteObject> Client::upload_object(const std::string& scene_id, const NamedMesh& mesh) {
    const auto& vertices = mesh.mesh.vertices;
    const auto& triangles = mesh.mesh.triangles;
    constexpr auto MAX_COUNT = std::numeric_limits<std::uint32_t>::max();
    if (vertices.size() > MAX_COUNT || triangles.size() > MAX_COUNT) {
        return invalid_argument("object '" + mesh.name + "': " + std::to_string(vertices.size()) +
                                " vertices and " + std::to_string(triangles.size()) +
                                " triangles exceed the API's 32-bit counts");
    }
    const bool float32 = m_impl->options.float32_vertices;

    grpc::ClientContext context;
    m_impl->prepare(context);
    pb::ObjectInfo info;
    auto writer = m_impl->stub->UploadObject(&context, &info);

    // A failed write means the server has ended the call: stop sending, Finish says why.
    bool open = true;
    auto write = [&](const pb::UploadChunk& chunk) { open = open && writer->Write(chunk); };

    pb::UploadChunk chunk;
    auto* header = chunk.mutable_header();
    header->set_scene_id(scene_id);
    header->set_name(mesh.name);
    header->set_type(detail::scalar_type(float32));
    header->set_vertex_count(static_cast<std::uint32_t>(vertices.size()));
    header->set_triangle_count(static_cast<std::uint32_t>(triangles.size()));
    write(chunk);

    const std::size_t stride =
        float32 ? detail::FLOAT32_VERTEX_BYTES : detail::FLOAT64_VERTEX_BYTES;
    const std::size_t vertices_per_chunk = UPLOAD_CHUNK_BYTES / stride;
    for (std::size_t first = 0; open && first < vertices.size(); first += vertices_per_chunk) {
        const auto count = std::min(vertices_per_chunk, vertices.size() - first);
        chunk.set_vertex_bytes(
            detail::pack_vertices(std::span<const Vec3>(vertices).subspan(first, count), float32));
        write(chunk);
    }
    const std::size_t triangles_per_chunk = UPLOAD_CHUNK_BYTES / detail::TRIANGLE_BYTES;
    for (std::size_t first = 0; open && first < triangles.size(); first += triangles_per_chunk) {
        const auto count = std::min(triangles_per_chunk, triangles.size() - first);
        chunk.set_index_bytes(detail::pack_triangles(
            std::span<const TriangleIndices>(triangles).subspan(first, count)));
        write(chunk);
    }
    if (open) {
        writer->WritesDone();
    }
    if (auto st = writer->Finish(); !st.ok()) {
        return from_grpc(st);
    }
    return detail::decode_object(info);
}

StatusOr<FrameResponse> Client::query(const std::string& scene_id, const FrameRequest& frame) {
    pb::Frame request;
    detail::encode_frame(frame, scene_id, m_impl->options.float32_vertices, &request);
    grpc::ClientContext context;
    m_impl->prepare(context);
    pb::FrameResult result;
    if (auto st = m_impl->stub->Query(&context, request, &result); !st.ok()) {
        return from_grpc(st);
    }
    return detail::decode_result(result);
}

StatusOr<std::unique_ptr<FrameStream>> Client::open_stream(const std::string& scene_id) {
    auto impl = std::make_unique<FrameStream::Impl>();
    impl->float32 = m_impl->options.float32_vertices;
    impl->scene_id = scene_id;
    // No deadline: a stream lives as long as the simulation. The call starts lazily; a daemon
    // that refuses it (unknown scene, too many streams) answers on the first receive().
    impl->stream = m_impl->stub->StreamFrames(&impl->context);
    if (!impl->stream) {
        return Status(StatusCode::internal, "could not start a frame stream");
    }
    return std::make_unique<FrameStream>(std::move(impl));
}

// --- FrameStream -----------------------------------------------------------------------------

FrameStream::FrameStream(std::unique_ptr<Impl> impl) : m_impl(std::move(impl)) {}

FrameStream::~FrameStream() {
    if (m_impl && !m_impl->finished) {
        // Cancelling first makes Finish return at once instead of waiting for the server to
        // answer frames nobody will read.
        m_impl->context.TryCancel();
        m_impl->final_status = from_grpc(m_impl->stream->Finish());
        m_impl->finished = true;
    }
}

Status FrameStream::send(const FrameRequest& frame) {
    auto& s = *m_impl;
    if (s.finished) {
        return s.ended_status();
    }
    if (s.writes_done) {
        return {StatusCode::failed_precondition, "send() after finish()"};
    }
    pb::Frame message;
    detail::encode_frame(frame, s.scene_id, s.float32, &message);
    if (!s.stream->Write(message)) {
        // The server ended the stream (a rejected frame, shutdown, cancellation): its status is
        // the useful answer, not "write failed".
        s.close();
        return s.final_status.ok()
                   ? Status(StatusCode::unavailable, "the server closed the frame stream")
                   : s.final_status;
    }
    ++s.in_flight;
    return {};
}

StatusOr<FrameResponse> FrameStream::receive() {
    auto& s = *m_impl;
    pb::FrameResult result;
    if (!s.read_ahead.empty()) {
        result = std::move(s.read_ahead.front());
        s.read_ahead.pop_front();
    } else if (s.finished) {
        return s.ended_status();
    } else if (s.in_flight == 0) {
        // Reading now would block forever: the server answers frames, it never speaks first.
        return Status(StatusCode::failed_precondition, "receive() with no frame in flight");
    } else if (!s.stream->Read(&result)) {
        s.close();
        return s.final_status.ok()
                   ? Status(StatusCode::internal,
                            "the server ended the frame stream without answering a frame")
                   : s.final_status;
    }
    if (s.in_flight > 0) {
        --s.in_flight;
    }
    return detail::decode_result(result);
}

Status FrameStream::finish() {
    auto& s = *m_impl;
    if (!s.finished) {
        if (!s.writes_done) {
            s.stream->WritesDone();
            s.writes_done = true;
        }
        s.close();
    }
    // Results nobody asked for are dropped: finish() is the end of the conversation.
    s.read_ahead.clear();
    s.in_flight = 0;
    return s.final_status;
}

void FrameStream::cancel() {
    m_impl->context.TryCancel();
}

// --- Massive models ----------------------------------------------------------------------------

StatusOr<RemoteModelList> Client::list_models() {
    grpc::ClientContext context;
    m_impl->prepare(context);
    pb::ListModelsResponse response;
    if (auto st = m_impl->stub->ListModels(&context, pb::ListModelsRequest(), &response);
        !st.ok()) {
        return from_grpc(st);
    }
    return detail::decode_model_list(response);
}

StatusOr<RemoteVerifySummary> Client::verify_model(
    const std::string& model, double tolerance,
    const std::function<bool(const VerifyEvent&)>& on_event, std::chrono::milliseconds timeout) {
    grpc::ClientContext context;
    if (timeout.count() > 0) {
        context.set_deadline(deadline_after(timeout));
    }
    pb::VerifyModelRequest request;
    request.set_model(model);
    request.set_tolerance(tolerance);
    auto reader = m_impl->stub->VerifyModel(&context, request);
    pb::VerifyModelEvent event;
    std::optional<RemoteVerifySummary> summary;
    bool stopped = false;
    while (reader->Read(&event)) {
        if (stopped) {
            continue;  // cancelled: drain what is in flight until the call ends
        }
        VerifyEvent out;
        switch (event.event_case()) {
            case pb::VerifyModelEvent::kProgress:
                out.kind = VerifyEvent::Kind::progress;
                out.progress = detail::decode_progress(event.progress());
                break;
            case pb::VerifyModelEvent::kPair:
                out.kind = VerifyEvent::Kind::pair;
                out.pair = detail::decode_object_pair(event.pair());
                break;
            case pb::VerifyModelEvent::kSummary:
                summary = detail::decode_verify_summary(event.summary());
                continue;
            default:
                continue;
        }
        if (on_event && !on_event(out)) {
            stopped = true;
            context.TryCancel();
        }
    }
    Status status = from_grpc(reader->Finish());
    if (stopped) {
        return Status(StatusCode::cancelled, "verification cancelled by the caller");
    }
    if (!status.ok()) {
        return status;
    }
    if (!summary) {
        return Status(StatusCode::internal, "the server ended VerifyModel without a summary");
    }
    return *summary;
}

// A reader thread moves events from the stream into `events` (at most MAX_QUEUED; past that it
// waits for next(), so the daemon's flow control and bounds apply rather than this queue
// growing). Writes happen on the caller's thread under `write_mu`, which the reader also takes
// for Finish (gRPC wants no write in progress while Finish runs).
struct ReviewSession::Impl {
    static constexpr std::size_t MAX_QUEUED = 64;

    bool float32 = false;
    grpc::ClientContext context;
    std::unique_ptr<grpc::ClientReaderWriter<pb::ReviewRequest, pb::ReviewEvent>> stream;
    ReviewJoined joined;

    std::mutex write_mu;
    bool writes_done = false;  // guarded by write_mu

    std::mutex mu;
    std::condition_variable changed;
    std::deque<StatusOr<ReviewEvent>> events;  // guarded by mu
    bool ended = false;                        // guarded by mu: Finish has returned
    bool discard = false;                      // guarded by mu: drop events (finishing)
    Status final_status;                       // guarded by mu
    std::thread reader;

    void read_loop() {
        pb::ReviewEvent event;
        while (stream->Read(&event)) {
            auto decoded = detail::decode_review_event(event);
            std::unique_lock lock(mu);
            changed.wait(lock, [&] { return discard || events.size() < MAX_QUEUED; });
            if (!discard) {
                events.push_back(std::move(decoded));
                changed.notify_all();
            }
        }
        Status status;
        {
            std::lock_guard writes(write_mu);
            status = from_grpc(stream->Finish());
            writes_done = true;  // no write after Finish
        }
        std::lock_guard lock(mu);
        ended = true;
        final_status = status;
        changed.notify_all();
    }

    // A failed write means the daemon ended the call: the reader collects its status, which
    // is the answer here once known (and always from next()).
    Status write(const pb::ReviewRequest& request) {
        {
            std::lock_guard writes(write_mu);
            if (!writes_done) {
                if (stream->Write(request)) {
                    return {};
                }
                writes_done = true;
            }
        }
        std::lock_guard lock(mu);
        if (ended && !final_status.ok()) {
            return final_status;
        }
        return {StatusCode::failed_precondition,
                ended ? "the review stream has ended"
                      : "the review stream is ending (next() returns its final status)"};
    }

    void stop_reader() {
        if (reader.joinable()) {
            reader.join();
        }
    }
};

StatusOr<std::unique_ptr<ReviewSession>> Client::join_review(const ReviewJoin& join,
                                                             std::chrono::milliseconds timeout) {
    auto impl = std::make_unique<ReviewSession::Impl>();
    impl->float32 = m_impl->options.float32_vertices;
    impl->stream = m_impl->stub->Review(&impl->context);
    if (!impl->stream) {
        return Status(StatusCode::internal, "could not start a review stream");
    }
    pb::ReviewRequest request;
    detail::encode_review_join(join, impl->float32, &request);
    auto* raw = impl.get();
    impl->reader = std::thread([raw] { raw->read_loop(); });
    auto session = std::make_unique<ReviewSession>(std::move(impl));
    if (Status s = raw->write(request); !s.ok()) {
        return s;
    }
    auto first = session->next(timeout);
    if (!first.ok()) {
        return first.status();
    }
    if (first->kind != ReviewEvent::Kind::joined) {
        return Status(StatusCode::internal, "the server answered join with another event");
    }
    raw->joined = std::move(first->joined);
    return session;
}

ReviewSession::ReviewSession(std::unique_ptr<Impl> impl) : m_impl(std::move(impl)) {}

ReviewSession::~ReviewSession() {
    if (!m_impl) {
        return;
    }
    {
        std::lock_guard lock(m_impl->mu);
        m_impl->discard = true;
        m_impl->changed.notify_all();
        if (!m_impl->ended) {
            m_impl->context.TryCancel();
        }
    }
    m_impl->stop_reader();
}

const ReviewJoined& ReviewSession::joined() const {
    return m_impl->joined;
}

Status ReviewSession::send_pose(std::uint64_t sequence, const massive::Affine& pose) {
    pb::ReviewRequest request;
    request.mutable_pose()->set_sequence(sequence);
    detail::encode_transform(pose, request.mutable_pose()->mutable_transform());
    return m_impl->write(request);
}

Status ReviewSession::move_object(std::uint64_t sequence, std::uint32_t object,
                                  const massive::Affine& transform) {
    pb::ReviewRequest request;
    auto* edit = request.mutable_edit();
    edit->set_sequence(sequence);
    edit->mutable_move()->set_object(object);
    detail::encode_transform(transform, edit->mutable_move()->mutable_transform());
    return m_impl->write(request);
}

Status ReviewSession::add_object(std::uint64_t sequence, const NamedMesh& object) {
    pb::ReviewRequest request;
    auto* edit = request.mutable_edit();
    edit->set_sequence(sequence);
    detail::encode_mesh(object, m_impl->float32, edit->mutable_add());
    return m_impl->write(request);
}

Status ReviewSession::delete_object(std::uint64_t sequence, std::uint32_t object) {
    pb::ReviewRequest request;
    auto* edit = request.mutable_edit();
    edit->set_sequence(sequence);
    edit->mutable_remove()->set_object(object);
    return m_impl->write(request);
}

StatusOr<ReviewEvent> ReviewSession::next(std::chrono::milliseconds timeout) {
    auto& s = *m_impl;
    std::unique_lock lock(s.mu);
    if (!s.changed.wait_for(lock, timeout, [&] { return !s.events.empty() || s.ended; })) {
        return Status(StatusCode::deadline_exceeded,
                      "no review event within " + std::to_string(timeout.count()) + " ms");
    }
    if (!s.events.empty()) {
        auto event = std::move(s.events.front());
        s.events.pop_front();
        s.changed.notify_all();
        return event;
    }
    return s.final_status.ok()
               ? Status(StatusCode::failed_precondition, "the review stream has ended")
               : s.final_status;
}

StatusOr<ReviewPoseResult> ReviewSession::wait_result(
    std::uint64_t sequence, const std::function<void(const ReviewEvent&)>& other,
    std::chrono::milliseconds timeout) {
    const auto until = std::chrono::steady_clock::now() + timeout;
    for (;;) {
        const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
            until - std::chrono::steady_clock::now());
        auto event = next(std::max(left, std::chrono::milliseconds(0)));
        if (!event.ok()) {
            return event.status();
        }
        if (event->kind == ReviewEvent::Kind::result && event->result.sequence == sequence) {
            return std::move(event->result);
        }
        if (other) {
            other(event.value());
        }
    }
}

Status ReviewSession::finish() {
    auto& s = *m_impl;
    {
        std::lock_guard writes(s.write_mu);
        if (!s.writes_done) {
            s.stream->WritesDone();
            s.writes_done = true;
        }
    }
    {
        std::lock_guard lock(s.mu);
        s.discard = true;
        s.events.clear();
        s.changed.notify_all();
    }
    s.stop_reader();
    std::lock_guard lock(s.mu);
    return s.final_status;
}

void ReviewSession::cancel() {
    m_impl->context.TryCancel();
}

}  // namespace proxima::client
