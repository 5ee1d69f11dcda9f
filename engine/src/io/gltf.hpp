#pragma once
// Native glTF 2.0 reader (.gltf and .glb). Debian's assimp 5.2.5 crashed on fuzzed glTF/GLB
// inputs (docs/reliability.md, "Fuzzing"); this reader treats the file as untrusted: every
// index, offset, stride and count is checked against the bytes that exist before anything is
// read or allocated, and every problem comes back as an invalid_argument status naming the file
// (a buffer the loader cannot load keeps the loader's code, such as not_found). The JSON must be
// valid UTF-8, as glTF requires.
//
// What it reads: the default scene (`scene`, else the first of `scenes`, else every root node),
// its node trees with their transforms (`matrix`, or translation * rotation * scale), and every
// primitive of mode TRIANGLES (4), TRIANGLE_STRIP (5) or TRIANGLE_FAN (6); points and lines are
// dropped. Positions are converted to double first, then the node transforms are composed and
// applied in double.
// Each instance of a mesh appends its POSITION vertices and its triangles, in node order (depth
// first) and primitive order; primitives of a mesh that share a POSITION accessor share its
// vertices.
//
// Choices where the spec leaves room or the input is wrong:
// - Refused: glTF 1.0; extensionsRequired other than KHR_mesh_quantization (implemented) and
//   extensions that change no geometry (KHR_texture_transform, KHR_texture_basisu,
//   EXT_texture_webp, EXT_texture_avif, KHR_lights_punctual, KHR_materials_*); node graphs that
//   are not forests (a cycle, two parents, a child listed twice, a scene listing a node twice or
//   a non-root node); TRIANGLES whose index (or vertex) count is not a multiple of 3; any other
//   mode than 0 to 6; a zero-length rotation quaternion; JSON of the wrong type for any field read.
// - Supported: sparse accessors (indices strictly increasing, within the accessor), accessors
//   without a bufferView (zeros, then the sparse values), byteStride, KHR_mesh_quantization
//   POSITION (byte/short, normalized or not), base64 data URIs of any media type, a GLB's BIN
//   chunk as buffer 0 when it has no uri, external buffers through `load_buffer` (percent-decoded).
// - Ignored: every attribute but POSITION (never validated), morph targets, skins, cameras,
//   materials, the last row of a `matrix`, TRS beside a `matrix` (the matrix wins), GLB chunks
//   after the JSON other than a BIN chunk in second place, trailing bytes after the GLB's length.
//   A primitive without POSITION and a strip or fan of fewer than 3 vertices add nothing.
// - Output bound: vertices and triangles are each limited to max(2^20, 16 * (file bytes + loaded
//   external buffer bytes)), and vertices to 2^32 - 1, checked before anything is decoded or
//   appended, so instancing a large mesh many times from a small file is refused, not allocated.

#include <functional>
#include <string>
#include <string_view>

#include "proxima/mesh/mesh.hpp"
#include "proxima/status.hpp"

namespace proxima::detail {

// Loads an external buffer named by a relative `uri` (already percent-decoded); returns
// not_found/invalid_argument when it cannot. read_mesh passes one that reads files in the
// .gltf's directory (never an absolute path or one leaving it); read_mesh_from_memory passes one
// that finds nothing.
using GltfBufferLoader = std::function<StatusOr<std::string>(const std::string& uri)>;

// `binary`: the data is a .glb container (else a .gltf JSON document). `name` is used only in
// messages.
StatusOr<TriangleMesh> read_gltf(const std::string& name, std::string_view data, bool binary,
                                 const GltfBufferLoader& load_buffer);

}  // namespace proxima::detail
