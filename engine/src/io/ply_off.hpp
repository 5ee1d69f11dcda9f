#pragma once
// Native PLY and OFF readers. Debian's assimp stores positions as float (ai_real = float), which
// would round double-precision frames before the engine sees them; these readers convert every
// coordinate straight to double so answers are exact on the file's own numbers.
//
// Both readers work on the whole file held in memory and treat it as untrusted: every read is
// bounds-checked, counts from headers are checked against the bytes that follow before anything
// is allocated, and every problem comes back as an invalid_argument status naming the file. They
// check indices (range and sign) but not finiteness: read_mesh runs validate_mesh afterwards.

#include <string>
#include <string_view>

#include "proxima/mesh/mesh.hpp"
#include "proxima/status.hpp"

namespace proxima::detail {

enum class NativeMeshFormat { none, ply, off };

// ".ply" / ".off", any case; `none` for every other extension.
NativeMeshFormat native_format_from_extension(const std::string& path);
// Looks at the start of a file: "ply" on the first line, or an OFF keyword (OFF, COFF, NOFF, ...)
// as the first token after '#' comment lines. `head` may be a prefix of the file.
NativeMeshFormat native_format_from_content(std::string_view head);

// Polygons are triangulated as fans (v0, vi, vi+1) in file order, so triangle ids follow the
// file. `path` is used only in messages.
StatusOr<TriangleMesh> read_ply(const std::string& path, std::string_view data);
StatusOr<TriangleMesh> read_off(const std::string& path, std::string_view data);

}  // namespace proxima::detail
