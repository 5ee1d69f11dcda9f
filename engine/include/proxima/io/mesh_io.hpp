#pragma once
// Reading meshes from files. The engine sees only TriangleMesh: one indexed mesh per file.
//
// Formats: an allowlist, by extension (any case): PLY (ASCII, binary little and big endian), OFF
// (ASCII), OBJ, STL (ASCII and binary), glTF 2.0 (.gltf, .glb; glTF 1.0 is refused), each also
// gzip-compressed (".ply.gz": decompressed in memory, then the same reader; a .gltf.gz's external
// buffers are not read). PLY and OFF
// are also recognised by content under any other extension ("ply" first line, OFF keyword); every
// other file is refused (invalid_argument naming the accepted formats), although the installed
// assimp reads ~40 more: those importers are not fuzzed (tests/fuzz, docs/reliability.md), so no
// file reaches them.
//
// Readers: PLY, OFF, OBJ and glTF are the engine's own (engine/src/io/), and every coordinate is
// converted straight to double, so double-precision files keep their exact values (glTF stores
// float32; its node transforms are applied in double). STL goes through assimp, which Debian
// builds with ai_real = float: binary STL is float32 anyway, ASCII STL is rounded to float32.
// OBJ and glTF went through assimp until fuzzing found crashes in it (docs/reliability.md,
// "Fuzzing"). No reader opens another file, except the glTF reader for a .gltf's external
// buffers named relatively, beside the file or below it (read_mesh only). Material libraries
// (.mtl) are never read.

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "proxima/mesh/mesh.hpp"
#include "proxima/status.hpp"

namespace proxima {

// When vertices with bit-identical positions are merged into one.
enum class WeldMode {
    // Only a triangle soup: a file in which no vertex is used by two triangle corners (STL, and
    // exporters that write every corner on its own). Such a file has no connectivity otherwise, and
    // every neighbouring triangle would count as a contact. An indexed file that shares vertices
    // keeps them all: coincident but distinct vertices are distinct, and their contacts count.
    triangle_soups,
    always,  // every file (the CLI's --weld)
    never,
};

struct MeshReadOptions {
    WeldMode weld = WeldMode::triangle_soups;
    // gzip-compressed files (".ply.gz", or gzip data under a name no reader claims) are
    // decompressed in memory
    // up to this many bytes, then read like the file they hold; past it the read fails (a
    // decompression bomb stops here).
    std::uint64_t max_uncompressed_bytes = std::uint64_t{4} << 30;
};

// Reads every triangle of the file, in file order within each mesh and mesh order within the
// file. PLY/OFF polygons are triangulated as fans (v0, vi, vi+1), so triangle ids follow the
// file; faces with fewer than 3 or out-of-range indices are errors. OBJ polygons are triangulated
// in face order, by ear clipping (a fan for convex ones), and faces with fewer than 3 corners are
// dropped. glTF: every primitive of triangle mode in the default scene, node transforms applied,
// points and lines dropped (engine/src/io/gltf.hpp). Errors name the file and the problem:
// missing (not_found), unreadable, a format outside the allowlist, truncated or malformed data,
// header counts the file cannot hold, no triangles, non-finite coordinates (all invalid_argument).
// `file_vertex`, when given, receives for each vertex of the mesh its index in the file as read
// (before any weld; a welded vertex names its first occurrence), so that answers can name the
// caller's own vertex ids.
StatusOr<TriangleMesh> read_mesh(const std::string& path, const MeshReadOptions& options = {},
                                 std::vector<std::uint32_t>* file_vertex = nullptr);

// The accepted formats, as error messages list them.
inline constexpr std::string_view ACCEPTED_MESH_FORMATS =
    ".ply, .off, .obj, .stl, .gltf, .glb, each also gzip-compressed (.ply.gz) (PLY and OFF also "
    "by content)";

// read_mesh on bytes already in memory; `format` is one of the accepted extensions, with or
// without the dot, any case (no content detection, except that gzip data, recognised by its magic
// bytes or a format ending in ".gz", is decompressed first; "gz" alone detects PLY or OFF in what
// it holds), and `name` is used only in messages.
// Nothing else is read: files the data refers to (a .gltf's external buffers) are not found. The
// fuzz target tests/fuzz/fuzz_mesh.cpp reads through this.
StatusOr<TriangleMesh> read_mesh_from_memory(std::string_view data, std::string_view format,
                                             const std::string& name,
                                             const MeshReadOptions& options = {},
                                             std::vector<std::uint32_t>* file_vertex = nullptr);

// Writes an ASCII OFF file (for tests and tools; exact round trip of doubles with %.17g).
Status write_off(const std::string& path, const TriangleMesh& mesh);

}  // namespace proxima
