// Fuzz target: Quake II MD2 models, through parse_md2 (engine/src/io/md2.cpp: the header's counts
// and offsets against the file's size, triangle indices, each keyframe's scale and translation),
// the reader behind `proxima play MODEL.md2`. The promises checked: errors name the file; a model
// that comes back has triangles with indices in range, at least one keyframe, and every keyframe
// has exactly the model's vertices, all finite.

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "proxima/io/md2.hpp"

namespace {

void check(bool condition, const char* what) {
    if (!condition) {
        std::fprintf(stderr, "fuzz_md2: broken promise: %s\n", what);
        std::abort();
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string_view bytes(reinterpret_cast<const char*>(data), size);
    const auto read = proxima::parse_md2("fuzz.md2", bytes);
    if (!read.ok()) {
        check(read.status().message().find("fuzz.md2") != std::string::npos,
              "errors name the file");
        return 0;
    }
    const auto& md2 = read.value();
    check(!md2.triangles.empty(), "a model has triangles");
    check(!md2.frames.empty() && md2.frames.size() == md2.names.size(), "keyframes and names");
    for (const auto& t : md2.triangles) {
        for (const auto i : t) {
            check(i < md2.vertex_count, "indices in range");
        }
    }
    for (const auto& frame : md2.frames) {
        check(frame.size() == md2.vertex_count, "every keyframe has every vertex");
        for (const auto& v : frame) {
            check(std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z),
                  "coordinates are finite");
        }
    }
    return 0;
}
