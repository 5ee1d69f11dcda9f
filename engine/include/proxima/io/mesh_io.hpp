#pragma once
// Reading meshes from files. The engine sees only TriangleMesh: one indexed mesh per file.
//
// Precision: PLY (ASCII, binary little and big endian) and ASCII OFF are read by our own readers
// and every coordinate is converted straight to double, so double-precision files keep their
// exact values. Every other format (OBJ, STL, glTF/GLB and whatever else the installed assimp
// reads) goes through assimp, which Debian builds with ai_real = float: those coordinates are
// float32 values widened to double. PLY and OFF are recognised by extension (any case) or, for
// other extensions, by content ("ply" first line, OFF keyword).

#include <string>

#include "proxima/mesh/mesh.hpp"
#include "proxima/status.hpp"

namespace proxima {

struct MeshReadOptions {
    // Merge vertices with bit-identical positions. Formats that store one vertex per triangle
    // corner (STL, and OBJ/PLY files whose corners carry distinct normals or texture coordinates)
    // lose their connectivity otherwise, and every neighbouring triangle would count as a contact.
    bool weld_identical_positions = true;
};

// Reads every triangle of the file, in file order within each mesh and mesh order within the
// file. PLY/OFF polygons are triangulated as fans (v0, vi, vi+1), so triangle ids follow the
// file; faces with fewer than 3 or out-of-range indices are errors. Through assimp, node
// transforms are applied and points and lines dropped. Errors name the file and the problem:
// missing (not_found), unreadable, unknown format, truncated or malformed data, header counts the
// file cannot hold, no triangles, non-finite coordinates (all invalid_argument).
StatusOr<TriangleMesh> read_mesh(const std::string& path, const MeshReadOptions& options = {});

// Writes an ASCII OFF file (for tests and tools; exact round trip of doubles with %.17g).
Status write_off(const std::string& path, const TriangleMesh& mesh);

}  // namespace proxima
