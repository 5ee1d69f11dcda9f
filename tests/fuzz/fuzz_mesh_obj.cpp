// Fuzz target: OBJ files, through read_mesh_from_memory: the engine's own OBJ reader
// (engine/src/io/obj.cpp: statements, face corners, negative and forward references, polygon
// triangulation by ear clipping). Until 2026-11-24 OBJ went through assimp, whose importer cost
// ~10 ms per file (a 4 MiB buffer cleared per read) and crashed on an OBJ naming itself as its
// material library; the target stayed separate from fuzz_mesh.cpp so that OBJ keeps its own
// corpus and dictionary. The promises checked are fuzz_mesh's.

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
        std::fprintf(stderr, "fuzz_mesh_obj: broken promise: %s\n", what);
        std::abort();
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string_view bytes(reinterpret_cast<const char*>(data), size);
    const auto read = proxima::read_mesh_from_memory(bytes, "obj", "fuzz.obj");
    if (!read.ok()) {
        check(read.status().message().find("fuzz.obj") != std::string::npos,
              "errors name the file");
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
    return 0;
}
