#pragma once
// The client's one meeting point of engine types and generated proto types: every conversion in
// both directions, the packed buffer formats and the status mapping live in convert.cpp, so the
// rest of the client (and its tests) never packs a byte by hand. Private to proxima_client: the
// public header stays free of gRPC and Protobuf.
//
// Both directions exist on purpose: the client encodes requests and decodes results, and the
// inverses (decode_frame, encode_result) let tests check that a round trip is lossless and let a
// fake server speak the same format.

#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include <grpcpp/support/status.h>

#include "client/proxima_client.hpp"
#include "proxima/v1/proxima.pb.h"

namespace proxima::client::detail {

namespace pb = ::proxima::v1;

// Bytes per vertex and per triangle of the packed buffers.
inline constexpr std::size_t FLOAT64_VERTEX_BYTES = 24;
inline constexpr std::size_t FLOAT32_VERTEX_BYTES = 12;
inline constexpr std::size_t TRIANGLE_BYTES = 12;

// gRPC status -> engine status, one-to-one by code name. Codes the engine has no name for
// (UNKNOWN, UNIMPLEMENTED, ...) become internal; their gRPC name is kept in front of the server's
// message so nothing is lost.
Status from_grpc(const grpc::Status& status);
// The inverse, for fakes and tests (every engine code has a gRPC namesake).
grpc::Status to_grpc(const Status& status);

// Packed little-endian x, y, z per vertex, as float64 or (rounded to nearest) float32.
std::string pack_vertices(std::span<const Vec3> vertices, bool float32);
// Packed little-endian uint32, three per triangle.
std::string pack_triangles(std::span<const TriangleIndices> triangles);
pb::ScalarType scalar_type(bool float32);
std::size_t vertex_bytes(pb::ScalarType type);  // 0 for an unknown type

// Buffer shape only (known scalar type, whole vertices, whole triangles); `what` names the buffer's
// owner in the message ("object 'a.off'"). Index ranges and finiteness are the engine's checks.
StatusOr<std::vector<Vec3>> unpack_vertices(pb::ScalarType type, const std::string& data,
                                            const std::string& what);
StatusOr<std::vector<Vec3>> unpack_vertices(const pb::VertexBuffer& buffer,
                                            const std::string& what);
StatusOr<std::vector<TriangleIndices>> unpack_triangles(const std::string& data,
                                                        const std::string& what);

// Encoded size of a mesh in a message (buffers, name and framing, rounded up): decides whether it
// travels inline or through UploadObject.
std::size_t encoded_mesh_bytes(const NamedMesh& mesh, bool float32);
void encode_mesh(const NamedMesh& mesh, bool float32, pb::Mesh* out);
StatusOr<NamedMesh> decode_mesh(const pb::Mesh& mesh, const std::string& what);

void encode_query(const QueryRequest& request, bool self_points, pb::QuerySpec* out);
StatusOr<QueryRequest> decode_query(const pb::QuerySpec& spec);

void encode_frame(const FrameRequest& frame, const std::string& scene_id, bool float32,
                  pb::Frame* out);
StatusOr<FrameRequest> decode_frame(const pb::Frame& frame);

// Checks the result's internal consistency (list sizes against the object count, object indices in
// range): a malformed result is an internal error, never an out-of-range read later.
StatusOr<FrameResponse> decode_result(const pb::FrameResult& result);
// A frame's CCD result; object indices are checked against `objects`.
StatusOr<ccd::CcdResult> decode_ccd(const pb::CcdResult& in, std::size_t objects);
// With `self_points` the self entries carry their closest points (6 doubles per triangle).
void encode_result(const FrameResponse& response, bool self_points, pb::FrameResult* out);

RemoteServerInfo decode_server_info(const pb::ServerInfo& info);
RemoteObject decode_object(const pb::ObjectInfo& info);
RemoteScene decode_scene(const pb::SceneInfo& info);

// --- Massive models ---

// 12 doubles, row-major 3x4; decoding checks the count (a malformed answer is internal).
void encode_transform(const massive::Affine& transform, pb::Transform* out);
StatusOr<massive::Affine> decode_transform(const pb::Transform& transform, const std::string& what);
massive::CacheStats decode_cache_stats(const pb::CacheStats& stats);
RemoteModelList decode_model_list(const pb::ListModelsResponse& response);
NamedObjectPair decode_object_pair(const pb::ObjectPairResult& pair);
massive::Progress decode_progress(const pb::VerifyProgress& progress);
RemoteVerifySummary decode_verify_summary(const pb::VerifyStats& stats);

void encode_review_join(const ReviewJoin& join, bool float32, pb::ReviewRequest* out);
StatusOr<ReviewEvent> decode_review_event(const pb::ReviewEvent& event);

}  // namespace proxima::client::detail
