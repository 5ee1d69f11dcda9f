#include "proxima/io/md2.hpp"

#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <system_error>

namespace proxima {

namespace {

constexpr std::size_t HEADER_BYTES = 68;        // 17 little-endian int32
constexpr std::size_t TRIANGLE_BYTES = 12;      // 3 vertex indices, 3 texture indices (uint16)
constexpr std::size_t FRAME_HEADER_BYTES = 40;  // scale, translate (float32 x 3 each), name[16]
constexpr std::size_t VERTEX_BYTES = 4;         // x, y, z (uint8), normal index

std::uint32_t u32_at(std::string_view d, std::size_t at) {
    std::uint32_t v = 0;
    for (std::size_t k = 0; k < 4; ++k) {
        v |= static_cast<std::uint32_t>(static_cast<unsigned char>(d[at + k])) << (8 * k);
    }
    return v;
}

std::uint16_t u16_at(std::string_view d, std::size_t at) {
    return static_cast<std::uint16_t>(static_cast<unsigned char>(d[at]) |
                                      (static_cast<unsigned char>(d[at + 1]) << 8));
}

float f32_at(std::string_view d, std::size_t at) {
    return std::bit_cast<float>(u32_at(d, at));
}

std::uint8_t u8_at(std::string_view d, std::size_t at) {
    return static_cast<std::uint8_t>(d[at]);
}

}  // namespace

StatusOr<Md2Keyframes> parse_md2(const std::string& name, std::string_view data) {
    auto bad = [&](const std::string& what) {
        return invalid_argument("'" + name + "': not a valid MD2 file: " + what);
    };
    if (data.size() < HEADER_BYTES) {
        return bad("shorter than its 68-byte header");
    }
    if (data.substr(0, 4) != "IDP2") {
        return bad("no IDP2 magic");
    }
    if (u32_at(data, 4) != 8) {
        return bad("version " + std::to_string(u32_at(data, 4)) + " (expected 8)");
    }
    const std::uint64_t frame_size = u32_at(data, 16);
    const std::uint32_t num_vertices = u32_at(data, 24);
    const std::uint32_t num_tris = u32_at(data, 32);
    const std::uint32_t num_frames = u32_at(data, 40);
    const std::uint64_t ofs_tris = u32_at(data, 52);
    const std::uint64_t ofs_frames = u32_at(data, 56);
    if (num_vertices < 3 || num_vertices > MD2_MAX_VERTICES) {
        return bad(std::to_string(num_vertices) + " vertices (3 to " +
                   std::to_string(MD2_MAX_VERTICES) + ")");
    }
    if (num_tris < 1 || num_tris > MD2_MAX_TRIANGLES) {
        return bad(std::to_string(num_tris) + " triangles (1 to " +
                   std::to_string(MD2_MAX_TRIANGLES) + ")");
    }
    if (num_frames < 1 || num_frames > MD2_MAX_FRAMES) {
        return bad(std::to_string(num_frames) + " frames (1 to " + std::to_string(MD2_MAX_FRAMES) +
                   ")");
    }
    // 64-bit sums of 32-bit values: no overflow.
    if (ofs_tris + std::uint64_t{num_tris} * TRIANGLE_BYTES > data.size()) {
        return bad("the triangles lie outside the file");
    }
    if (frame_size < FRAME_HEADER_BYTES + std::uint64_t{num_vertices} * VERTEX_BYTES) {
        return bad("frame size " + std::to_string(frame_size) + " is too small for " +
                   std::to_string(num_vertices) + " vertices");
    }
    if (ofs_frames + std::uint64_t{num_frames} * frame_size > data.size()) {
        return bad("the frames lie outside the file");
    }
    Md2Keyframes out;
    out.vertex_count = num_vertices;
    out.triangles.reserve(num_tris);
    for (std::uint32_t t = 0; t < num_tris; ++t) {
        const std::size_t at = ofs_tris + std::size_t{t} * TRIANGLE_BYTES;
        TriangleIndices tri{};
        for (int k = 0; k < 3; ++k) {
            const std::uint16_t v = u16_at(data, at + 2 * static_cast<std::size_t>(k));
            if (v >= num_vertices) {
                return bad("triangle " + std::to_string(t) + " names vertex " + std::to_string(v) +
                           " of " + std::to_string(num_vertices));
            }
            tri[static_cast<std::size_t>(k)] = v;
        }
        out.triangles.push_back(tri);
    }
    out.frames.reserve(num_frames);
    out.names.reserve(num_frames);
    for (std::uint32_t f = 0; f < num_frames; ++f) {
        const std::size_t at = ofs_frames + std::size_t{f} * frame_size;
        double scale[3];
        double translate[3];
        for (std::size_t k = 0; k < 3; ++k) {
            scale[k] = f32_at(data, at + 4 * k);
            translate[k] = f32_at(data, at + 12 + 4 * k);
            if (!std::isfinite(scale[k]) || !std::isfinite(translate[k])) {
                return bad("frame " + std::to_string(f) + " has a non-finite scale or translation");
            }
        }
        const std::string_view raw = data.substr(at + 24, 16);
        out.names.emplace_back(raw.substr(0, std::min(raw.find('\0'), raw.size())));
        std::vector<Vec3> vertices(num_vertices);
        for (std::uint32_t v = 0; v < num_vertices; ++v) {
            const std::size_t p = at + FRAME_HEADER_BYTES + std::size_t{v} * VERTEX_BYTES;
            vertices[v] = {scale[0] * u8_at(data, p) + translate[0],
                           scale[1] * u8_at(data, p + 1) + translate[1],
                           scale[2] * u8_at(data, p + 2) + translate[2]};
        }
        out.frames.push_back(std::move(vertices));
    }
    return out;
}

StatusOr<Md2Keyframes> read_md2(const std::string& path) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec)) {
        return Status(StatusCode::not_found, "'" + path + "' does not exist or is not a file");
    }
    std::ifstream in(path, std::ios::binary);
    std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (in.bad()) {
        return invalid_argument("cannot read '" + path + "'");
    }
    return parse_md2(path, data);
}

}  // namespace proxima
