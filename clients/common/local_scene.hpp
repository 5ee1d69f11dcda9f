#pragma once
// Turning mesh files into scene objects the way every client mode does: one object per file, or
// one per connected component with --split-components; keeps the map back to file triangle ids.

#include <cstdint>
#include <string>
#include <vector>

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
};

// `read_options`: how read_mesh reads each file (vertex welding on by default).
StatusOr<std::vector<InputObject>> load_objects(const std::vector<std::string>& files,
                                                bool split_components,
                                                const MeshReadOptions& read_options = {});

}  // namespace proxima::client
