#pragma once
// Quake II MD2 models: one triangle list and N keyframes of vertex positions, a recorded deforming
// sequence in one file (the player, `proxima play MODEL.md2`, streams the keyframes as frames).
// Not one of read_mesh's formats (a file is many meshes); read on its own, by this bounds-checked
// parser: every count and offset of the header is checked against the file's size before it is
// followed, every vertex index against the vertex count, so malformed input is an error, never a
// read out of bounds. Skins, texture coordinates, normals and GL commands are ignored.

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "proxima/mesh/mesh.hpp"
#include "proxima/status.hpp"

namespace proxima {

struct Md2Keyframes {
    std::vector<TriangleIndices> triangles;  // in file order
    std::size_t vertex_count = 0;
    std::vector<std::string> names;         // per keyframe ("stand01", ...)
    std::vector<std::vector<Vec3>> frames;  // per keyframe: scale * v + translate, in double
};

// Limits beyond which a header is refused as implausible (Quake II's own: 2048 vertices, 4096
// triangles, 512 frames; these are larger).
inline constexpr std::uint32_t MD2_MAX_VERTICES = 65536;
inline constexpr std::uint32_t MD2_MAX_TRIANGLES = 1u << 20;
inline constexpr std::uint32_t MD2_MAX_FRAMES = 65536;

// Parses MD2 bytes; `name` is used in messages only. invalid_argument for anything malformed:
// the magic ("IDP2") or version (8), counts out of range, sections outside the file, a frame size
// too small for its vertices, a vertex index out of range, non-finite scale or translation.
StatusOr<Md2Keyframes> parse_md2(const std::string& name, std::string_view data);
// Reads the file (not_found when missing), then parse_md2.
StatusOr<Md2Keyframes> read_md2(const std::string& path);

}  // namespace proxima
