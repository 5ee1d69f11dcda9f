#pragma once
// Helpers of the mesh reader tests (test_mesh_io.cpp, test_gltf.cpp): scratch files and the
// no-welding read option.
#include <gtest/gtest.h>
#include <unistd.h>

#include <fstream>
#include <iterator>
#include <string>

#include "proxima/io/mesh_io.hpp"

namespace proxima::test {

// Unique per process: ctest runs test cases as parallel processes sharing TempDir().
inline std::string temp_path(const std::string& name) {
    return ::testing::TempDir() + "proxima_mesh_io_" + std::to_string(::getpid()) + "_" + name;
}

inline void write_bytes(const std::string& path, const std::string& bytes) {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    ASSERT_TRUE(out.good()) << path;
}

inline std::string read_bytes(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

inline MeshReadOptions no_weld() {
    MeshReadOptions options;
    options.weld = WeldMode::never;
    return options;
}

}  // namespace proxima::test
