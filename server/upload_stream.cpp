// UploadObject: one object uploaded in chunks into an existing scene.
#include <cstdint>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include <spdlog/spdlog.h>

#include "encode.hpp"
#include "frames.hpp"
#include "proxima/wire/buffers.hpp"
#include "scene_registry.hpp"
#include "service.hpp"
#include "service_internal.hpp"

namespace proxima::server {

namespace {

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

grpc::ServerReadReactor<v1::UploadChunk>* ProximityService::UploadObject(
    grpc::CallbackServerContext* context, v1::ObjectInfo* response) {
    return new UploadReactor(*m_shared, context, response);
}

}  // namespace proxima::server
