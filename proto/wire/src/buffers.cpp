#include "proxima/wire/buffers.hpp"

#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <utility>

namespace proxima::wire {

namespace {

static_assert(sizeof(Vec3) == 3 * sizeof(double) && std::is_standard_layout_v<Vec3>,
              "Vec3 must be three packed doubles for the float64 fast path");
static_assert(sizeof(TriangleIndices) == TRIANGLE_BYTES);

constexpr bool LITTLE_ENDIAN_HOST = std::endian::native == std::endian::little;

// Writes `value` little-endian at dst, whatever the host's byte order.
template <class T>
void store_le(char* dst, T value) {
    using U = std::conditional_t<sizeof(T) == 8, std::uint64_t, std::uint32_t>;
    auto bits = std::bit_cast<U>(value);
    for (std::size_t i = 0; i < sizeof(U); ++i) {
        dst[i] = static_cast<char>(static_cast<unsigned char>(bits >> (8 * i)));
    }
}

template <class T>
T load_le(const char* src) {
    using U = std::conditional_t<sizeof(T) == 8, std::uint64_t, std::uint32_t>;
    U bits = 0;
    for (std::size_t i = 0; i < sizeof(U); ++i) {
        bits |= static_cast<U>(static_cast<unsigned char>(src[i])) << (8 * i);
    }
    return std::bit_cast<T>(bits);
}

}  // namespace

v1::ScalarType scalar_type(bool float32) {
    return float32 ? v1::SCALAR_TYPE_FLOAT32 : v1::SCALAR_TYPE_FLOAT64;
}

std::size_t vertex_stride(v1::ScalarType type) {
    switch (type) {
        case v1::SCALAR_TYPE_FLOAT32:
            return FLOAT32_VERTEX_BYTES;
        case v1::SCALAR_TYPE_FLOAT64:
            return FLOAT64_VERTEX_BYTES;
        default:
            return 0;
    }
}

std::string pack_vertices(std::span<const Vec3> vertices, bool float32) {
    std::string out;
    if (!float32) {
        out.resize(vertices.size() * FLOAT64_VERTEX_BYTES);
        if constexpr (LITTLE_ENDIAN_HOST) {
            // The wire format is the host's memory layout here: one copy, no per-value work.
            if (!vertices.empty()) {
                std::memcpy(out.data(), vertices.data(), out.size());
            }
        } else {
            char* p = out.data();
            for (const auto& v : vertices) {
                store_le(p, v.x);
                store_le(p + 8, v.y);
                store_le(p + 16, v.z);
                p += FLOAT64_VERTEX_BYTES;
            }
        }
        return out;
    }
    out.resize(vertices.size() * FLOAT32_VERTEX_BYTES);
    char* p = out.data();
    if constexpr (LITTLE_ENDIAN_HOST && sizeof(float) == 4) {
        // The same conversions, stored as whole floats: one straight loop over the doubles that
        // the compiler vectorizes (the byte-by-byte stores below cost as much as the bytes' trip
        // to the server for a 15K-vertex frame).
        // (Vec3 is three packed doubles, asserted above: its bytes are 3n doubles.)
        const std::size_t n = vertices.size() * 3;
        const auto* src = reinterpret_cast<const char*>(vertices.data());
        for (std::size_t i = 0; i < n; ++i) {
            double d = 0;
            std::memcpy(&d, src + 8 * i, 8);
            const auto f = static_cast<float>(d);
            std::memcpy(p + 4 * i, &f, 4);
        }
        return out;
    }
    for (const auto& v : vertices) {
        store_le(p, static_cast<float>(v.x));
        store_le(p + 4, static_cast<float>(v.y));
        store_le(p + 8, static_cast<float>(v.z));
        p += FLOAT32_VERTEX_BYTES;
    }
    return out;
}

std::string pack_triangles(std::span<const TriangleIndices> triangles) {
    std::string out(triangles.size() * TRIANGLE_BYTES, '\0');
    if constexpr (LITTLE_ENDIAN_HOST) {
        if (!triangles.empty()) {
            std::memcpy(out.data(), triangles.data(), out.size());
        }
    } else {
        char* p = out.data();
        for (const auto& t : triangles) {
            for (int k = 0; k < 3; ++k) {
                store_le(p + 4 * static_cast<std::ptrdiff_t>(k), t[static_cast<std::size_t>(k)]);
            }
            p += TRIANGLE_BYTES;
        }
    }
    return out;
}

StatusOr<std::vector<Vec3>> decode_vertex_bytes(v1::ScalarType type, std::string_view bytes,
                                                const std::string& what) {
    const std::size_t stride = vertex_stride(type);
    if (stride == 0) {
        return invalid_argument(what +
                                ": vertex scalar type must be SCALAR_TYPE_FLOAT32 or "
                                "SCALAR_TYPE_FLOAT64, got " +
                                std::to_string(static_cast<int>(type)));
    }
    if (bytes.size() % stride != 0) {
        return invalid_argument(what + ": vertex buffer is " + std::to_string(bytes.size()) +
                                " bytes, not a multiple of " + std::to_string(stride) +
                                " (x, y, z as " + (stride == 12 ? "float32" : "float64") +
                                " per vertex)");
    }
    std::vector<Vec3> out(bytes.size() / stride);
    const char* p = bytes.data();
    if (stride == FLOAT64_VERTEX_BYTES && LITTLE_ENDIAN_HOST) {
        if (!bytes.empty()) {  // memcpy from/to null (an empty vector's data()) is undefined
            std::memcpy(out.data(), p, bytes.size());
        }
    } else if (stride == FLOAT64_VERTEX_BYTES) {
        for (auto& v : out) {
            v = {load_le<double>(p), load_le<double>(p + 8), load_le<double>(p + 16)};
            p += stride;
        }
    } else if (LITTLE_ENDIAN_HOST && sizeof(float) == 4) {
        // Whole floats, widened in one straight loop (vectorized), as for packing.
        auto* dst = reinterpret_cast<char*>(out.data());
        const std::size_t n = out.size() * 3;
        for (std::size_t i = 0; i < n; ++i) {
            float f = 0;
            std::memcpy(&f, p + 4 * i, 4);
            const double d = f;
            std::memcpy(dst + 8 * i, &d, 8);
        }
    } else {
        for (auto& v : out) {
            v = {load_le<float>(p), load_le<float>(p + 4), load_le<float>(p + 8)};
            p += stride;
        }
    }
    return out;
}

StatusOr<std::vector<Vec3>> decode_vertices(const v1::VertexBuffer& buffer,
                                            const std::string& what) {
    return decode_vertex_bytes(buffer.type(), buffer.data(), what);
}

StatusOr<std::vector<TriangleIndices>> decode_indices(std::string_view bytes,
                                                      const std::string& what) {
    if (bytes.size() % TRIANGLE_BYTES != 0) {
        return invalid_argument(what + ": index buffer is " + std::to_string(bytes.size()) +
                                " bytes, not a multiple of 12 (three uint32 per triangle)");
    }
    std::vector<TriangleIndices> out(bytes.size() / TRIANGLE_BYTES);
    if constexpr (LITTLE_ENDIAN_HOST) {
        if (!bytes.empty()) {  // memcpy from/to null (an empty vector's data()) is undefined
            std::memcpy(out.data(), bytes.data(), bytes.size());
        }
    } else {
        const char* p = bytes.data();
        for (auto& t : out) {
            t = {load_le<std::uint32_t>(p), load_le<std::uint32_t>(p + 4),
                 load_le<std::uint32_t>(p + 8)};
            p += TRIANGLE_BYTES;
        }
    }
    return out;
}

std::size_t encoded_mesh_bytes(const NamedMesh& mesh, bool float32) {
    // 32 bytes covers the tags and varint lengths of the mesh and its three fields.
    return mesh.name.size() +
           mesh.mesh.vertices.size() * (float32 ? FLOAT32_VERTEX_BYTES : FLOAT64_VERTEX_BYTES) +
           mesh.mesh.triangles.size() * TRIANGLE_BYTES + 32;
}

void encode_mesh(const NamedMesh& mesh, bool float32, v1::Mesh* out) {
    out->set_name(mesh.name);
    out->mutable_vertices()->set_type(scalar_type(float32));
    out->mutable_vertices()->set_data(pack_vertices(mesh.mesh.vertices, float32));
    out->set_indices(pack_triangles(mesh.mesh.triangles));
}

StatusOr<NamedMesh> decode_mesh(const v1::Mesh& mesh, const std::string& what) {
    const std::string label = mesh.name().empty() ? what : what + " ('" + mesh.name() + "')";
    auto vertices = decode_vertices(mesh.vertices(), label);
    if (!vertices.ok()) {
        return vertices.status();
    }
    auto triangles = decode_indices(mesh.indices(), label);
    if (!triangles.ok()) {
        return triangles.status();
    }
    NamedMesh out;
    out.name = mesh.name();
    out.mesh.vertices = std::move(vertices).value();
    out.mesh.triangles = std::move(triangles).value();
    return out;
}

StatusOr<std::vector<NamedMesh>> decode_meshes(
    const google::protobuf::RepeatedPtrField<v1::Mesh>& meshes, const std::string& field) {
    std::vector<NamedMesh> out;
    out.reserve(static_cast<std::size_t>(meshes.size()));
    for (int i = 0; i < meshes.size(); ++i) {
        auto mesh = decode_mesh(meshes[i], field + "[" + std::to_string(i) + "]");
        if (!mesh.ok()) {
            return mesh.status();
        }
        out.push_back(std::move(mesh).value());
    }
    return out;
}

void encode_vec3(const Vec3& v, v1::Vec3* out) {
    out->set_x(v.x);
    out->set_y(v.y);
    out->set_z(v.z);
}

Vec3 decode_vec3(const v1::Vec3& v) {
    return {v.x(), v.y(), v.z()};
}

Status check_tolerance(double tolerance, const std::string& what) {
    if (!std::isfinite(tolerance) || tolerance < 0.0) {
        return invalid_argument(what + " must be a finite distance >= 0, got " +
                                std::to_string(tolerance));
    }
    return {};
}

}  // namespace proxima::wire
