#pragma once
// Turning mesh files into scene objects the way every client mode does: one object per file, or
// one per connected component with --split-components; keeps the maps back to the file's own
// triangle, vertex and edge ids, so that every answer names the caller's input.

#include <cstdint>
#include <string>
#include <vector>

#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/io/mesh_io.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"

namespace proxima::client {

struct InputObject {
    std::string file;
    std::int64_t component = -1;  // -1 when the whole file is the object
    NamedMesh mesh;
    // Object-local triangle index -> triangle index in the file.
    std::vector<std::uint32_t> file_triangle;
    // Object-local vertex index -> vertex index in the file (a welded vertex: its first
    // occurrence; see WeldMode).
    std::vector<std::uint32_t> file_vertex;
};

// The objects of one mesh read from `file`: the whole mesh, or each connected component in the
// order of its first triangle (named FILE#C), with their maps back to the file's triangles and
// vertices. `file_vertex` maps the mesh's vertices to the file's (read_mesh's; empty: the
// identity).
void split_objects(const std::string& file, TriangleMesh mesh,
                   std::vector<std::uint32_t> file_vertex, bool split_components,
                   std::vector<InputObject>& out);

// Reads every file; `weld` as MeshReadOptions::weld (the default welds triangle soups only).
StatusOr<std::vector<InputObject>> load_objects(const std::vector<std::string>& files,
                                                bool split_components,
                                                WeldMode weld = WeldMode::triangle_soups);

// For each object, its edge indices (ccd::mesh_edges of its triangles) as edge indices of its
// file: positions in the sorted list of the file's unique edges, written with the file's vertex
// ids. Without --split-components and welding these are the object's own indices.
std::vector<std::vector<std::uint32_t>> file_edge_ids(const std::vector<InputObject>& objects);

// A CCD pair in the files' numbering: vertex and triangle ids through file_vertex and
// file_triangle, edge indices through `file_edges` (file_edge_ids), `vertices` through
// file_vertex. Objects stay indices into `objects`.
ccd::CcdPair in_file_numbering(const std::vector<InputObject>& objects,
                               const std::vector<std::vector<std::uint32_t>>& file_edges,
                               const ccd::CcdPair& pair);

}  // namespace proxima::client
