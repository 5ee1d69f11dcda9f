#pragma once
// The packed buffers of the wire format and the messages built from them: vertex buffers
// (little-endian x, y, z per vertex as float32 or float64), index buffers (little-endian uint32,
// three per triangle), meshes and points. Encoding is the client's direction, decoding the
// daemon's; both live here so that they cannot drift apart.
//
// Decoding checks what the wire format alone can get wrong (buffer sizes, scalar types); what
// needs the scene (known ids, vertex counts, index ranges, finite coordinates, limits) is checked
// later by the daemon (server/frames.hpp) and the engine (validate_mesh).

#include <cstddef>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "proxima/scene.hpp"
#include "proxima/status.hpp"
#include "proxima/v1/proxima.pb.h"

namespace proxima::wire {

// Bytes per vertex and per triangle of the packed buffers.
inline constexpr std::size_t FLOAT64_VERTEX_BYTES = 24;
inline constexpr std::size_t FLOAT32_VERTEX_BYTES = 12;
inline constexpr std::size_t TRIANGLE_BYTES = 12;

v1::ScalarType scalar_type(bool float32);
// Bytes per vertex for a scalar type (12 or 24); 0 for SCALAR_TYPE_UNSPECIFIED or unknown values.
std::size_t vertex_stride(v1::ScalarType type);

// Packed little-endian x, y, z per vertex, as float64 (exact) or float32 (rounded to nearest).
std::string pack_vertices(std::span<const Vec3> vertices, bool float32);
// Packed little-endian uint32, three per triangle.
std::string pack_triangles(std::span<const TriangleIndices> triangles);

// `what` names the buffer's owner in error messages (invalid_argument).
StatusOr<std::vector<Vec3>> decode_vertex_bytes(v1::ScalarType type, std::string_view bytes,
                                                const std::string& what);
StatusOr<std::vector<Vec3>> decode_vertices(const v1::VertexBuffer& buffer,
                                            const std::string& what);
// Index ranges are checked later, against the vertex count, by the engine's validate_mesh.
StatusOr<std::vector<TriangleIndices>> decode_indices(std::string_view bytes,
                                                      const std::string& what);

// Encoded size of a mesh in a message (buffers, name and framing, rounded up): decides whether
// the client sends it inline or through UploadObject.
std::size_t encoded_mesh_bytes(const NamedMesh& mesh, bool float32);
void encode_mesh(const NamedMesh& mesh, bool float32, v1::Mesh* out);
StatusOr<NamedMesh> decode_mesh(const v1::Mesh& mesh, const std::string& what);
// `field` names the repeated field ("objects"); each mesh is "field[i]" in messages.
StatusOr<std::vector<NamedMesh>> decode_meshes(
    const google::protobuf::RepeatedPtrField<v1::Mesh>& meshes, const std::string& field);

void encode_vec3(const Vec3& v, v1::Vec3* out);
Vec3 decode_vec3(const v1::Vec3& v);

// Checks that a tolerance is a finite distance >= 0 (invalid_argument naming `what`).
Status check_tolerance(double tolerance, const std::string& what);

}  // namespace proxima::wire
