#pragma once
// The one place where proto messages become engine types and back, and where engine statuses
// become gRPC statuses. Everything else in server/ speaks engine types (Scene, SceneUpdate,
// QueryRequest, QueryResult, Status) plus the message objects gRPC hands it.
//
// Decoding checks what the wire format alone can get wrong (buffer sizes, scalar types, a negative
// tolerance); what needs the scene (known ids, vertex counts, index ranges, finite coordinates,
// limits) is checked by validate_update() in frames.hpp before anything changes.

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include <grpcpp/support/status.h>

#include "auth.hpp"
#include "config.hpp"
#include "models.hpp"
#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/massive/verify.hpp"
#include "proxima/query/penetration.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"
#include "proxima/v1/proxima.pb.h"
#include "rooms.hpp"

namespace proxima::server {

// The single mapping of engine status codes onto gRPC codes; the message goes through unchanged.
grpc::Status to_grpc_status(const Status& status);

// Bytes per vertex for a scalar type (12 or 24); 0 for SCALAR_TYPE_UNSPECIFIED or unknown values.
std::size_t vertex_stride(v1::ScalarType type);

// Packed little-endian x, y, z per vertex. `what` names the buffer in error messages.
StatusOr<std::vector<Vec3>> decode_vertex_bytes(v1::ScalarType type, std::string_view bytes,
                                                const std::string& what);
StatusOr<std::vector<Vec3>> decode_vertices(const v1::VertexBuffer& buffer,
                                            const std::string& what);
// Packed little-endian uint32, three per triangle (index ranges are checked later, against the
// vertex count, by the engine's validate_mesh).
StatusOr<std::vector<TriangleIndices>> decode_indices(std::string_view bytes,
                                                      const std::string& what);
StatusOr<NamedMesh> decode_mesh(const v1::Mesh& mesh, const std::string& what);

// A Frame in engine terms. SceneUpdate's vectors keep the proto's order, so index k of
// `update.positions` is `positions[k]` of the request (error messages use these indices).
struct DecodedFrame {
    SceneUpdate update;
    QueryRequest queries;
    bool self_points = false;
    // Continuous collisions from the positions before this frame to those after it.
    bool ccd = false;
    ccd::CcdRequest ccd_request;
    // Local penetration vectors (the collisions query runs too).
    bool penetration = false;
};
StatusOr<DecodedFrame> decode_frame(const v1::Frame& frame);
StatusOr<std::vector<NamedMesh>> decode_meshes(
    const google::protobuf::RepeatedPtrField<v1::Mesh>& meshes, const std::string& field);

// Fills everything of a FrameResult but scene_id, frame and stats.server_seconds, which the
// caller knows better. `scene` is the scene the query ran on (for object ids in result order).
void encode_frame_result(const Scene& scene, const SceneUpdateResult& changes,
                         const QueryResult& result, bool self_points, v1::FrameResult* out);
void encode_ccd_result(const ccd::CcdResult& result, v1::CcdResult* out);
void encode_penetration(const Penetration& p, v1::Penetration* out);
void encode_object(const SceneObject& object, v1::ObjectInfo* out);
void encode_scene(const std::string& scene_id, const std::string& name, const Scene& scene,
                  std::uint64_t frames, v1::SceneInfo* out);
void encode_limits(const Limits& limits, v1::Limits* out);
// A principal's quotas (0: unlimited).
void encode_quotas(const Quotas& quotas, v1::Quotas* out);

// --- Massive models ---

// Exactly 12 finite doubles, row-major 3x4. `what` names the field in the message.
StatusOr<massive::Affine> decode_transform(const v1::Transform& transform, const std::string& what);
void encode_transform(const massive::Affine& transform, v1::Transform* out);
// A finite distance >= 0.
Status check_tolerance(double tolerance, const std::string& what);

void encode_cache_stats(const massive::CacheStats& stats, v1::CacheStats* out);
void encode_model(const ModelEntry& model, v1::ModelInfo* out);
void encode_unavailable_model(const UnavailableModel& model, v1::UnavailableModel* out);

void encode_progress(const massive::Progress& progress, v1::VerifyProgress* out);
// Names come from the store's objects.
void encode_object_pair(const massive::ObjectPairResult& pair, const massive::Store& store,
                        v1::ObjectPairResult* out);
void encode_verify_stats(const massive::VerifyStats& stats, double server_seconds,
                         v1::VerifyStats* out);

// A Review request in engine terms. The avatar and an added object are decoded with
// decode_mesh (wire format); the engine validates them (validate_mesh) before anything changes.
struct ReviewJoinRequest {
    std::string room;
    std::string model;
    std::string member;
    NamedMesh avatar;
    double tolerance = 0.0;
    bool nearest = false;
};
struct ReviewPoseRequest {
    std::uint64_t sequence = 0;
    massive::Affine transform;
};
using ReviewRequest = std::variant<ReviewJoinRequest, ReviewPoseRequest, RoomEdit>;
StatusOr<ReviewRequest> decode_review_request(const v1::ReviewRequest& request);
void encode_room_event(const RoomEvent& event, v1::ReviewEvent* out);

}  // namespace proxima::server
