#pragma once
// Native Wavefront OBJ reader. Replaces assimp's OBJ importer, which crashed on fuzzed input
// (an OBJ naming itself as its material library; docs/reliability.md, "Fuzzing") and stored
// coordinates as float: every coordinate here is converted straight to double.
//
// Reads `v` (x y z, optional w and colours ignored) and `f` statements (v, v/vt, v//vn, v/vt/vn;
// negative indices count back from the last vertex); faces with fewer than three corners and
// `l`/`p` statements are dropped, as assimp did. Polygons are triangulated in face order: a
// convex polygon as a fan from its first corner; a non-convex one by ear clipping in the plane
// of its Newell normal. Materials, groups, texture coordinates and normals are ignored (no other
// file is ever opened). Only vertices that faces use are kept, in order of first use.

#include <string>
#include <string_view>

#include "proxima/mesh/mesh.hpp"
#include "proxima/status.hpp"

namespace proxima::detail {

StatusOr<TriangleMesh> read_obj(const std::string& name, std::string_view data);

}  // namespace proxima::detail
