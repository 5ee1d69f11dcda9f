// Fuzz target: the mesh formats the importer accepts (mesh_io.hpp's allowlist), through
// read_mesh_from_memory, the same readers and checks as read_mesh. The first byte chooses the
// format (and welding); the rest is the file. PLY, OFF, glTF and GLB are the engine's own readers
// (glTF since 2026-11-24: Debian's assimp crashed on inputs this target found); STL is Debian's
// assimp (not instrumented: ASan sees its allocations, not its reads) restricted to its STL
// importer, plus our conversion of its scene. OBJ has a target of its own, fuzz_mesh_obj.cpp. A
// mesh that comes back must satisfy what the engine relies on: triangles, indices in range,
// finite coordinates. Input that starts with the gzip magic (1f 8b) is decompressed first, under
// every format (zlib, then the same readers; the corpus holds compressed PLY and OFF seeds); the
// decompressed size is capped at 64 MiB here, so a bomb is an error, not an out-of-memory.

#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "proxima/io/mesh_io.hpp"

namespace {

void check(bool condition, const char* what) {
    if (!condition) {
        std::fprintf(stderr, "fuzz_mesh: broken promise: %s\n", what);
        std::abort();
    }
}

constexpr std::array<std::string_view, 5> FORMATS = {"ply", "off", "stl", "gltf", "glb"};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    if (size == 0) {
        return 0;
    }
    const std::string_view format = FORMATS[data[0] % FORMATS.size()];
    const std::string_view bytes(reinterpret_cast<const char*>(data) + 1, size - 1);
    proxima::MeshReadOptions options;
    // The three weld modes in turn: every path must hold its promises.
    constexpr std::array<proxima::WeldMode, 3> WELDS = {
        proxima::WeldMode::triangle_soups, proxima::WeldMode::always, proxima::WeldMode::never};
    options.weld = WELDS[(data[0] / FORMATS.size()) % WELDS.size()];
    options.max_uncompressed_bytes = std::uint64_t{64} << 20;
    std::vector<std::uint32_t> file_vertex;
    const auto read = proxima::read_mesh_from_memory(bytes, format, "fuzz", options, &file_vertex);
    if (!read.ok()) {
        check(read.status().message().find("fuzz") != std::string::npos, "errors name the file");
        return 0;
    }
    const auto& mesh = read.value();
    check(!mesh.triangles.empty(), "a mesh has triangles");
    for (const auto& v : mesh.vertices) {
        check(std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z),
              "coordinates are finite");
    }
    for (const auto& t : mesh.triangles) {
        for (const auto i : t) {
            check(i < mesh.vertices.size(), "indices in range");
        }
    }
    check(file_vertex.size() == mesh.vertices.size(), "every vertex has its file id");
    for (std::size_t k = 1; k < file_vertex.size(); ++k) {
        check(file_vertex[k - 1] < file_vertex[k], "file ids in file order, each once");
    }
    return 0;
}
