#pragma once
// The discrete-Voronoi kernel as a GLSL 4.30 compute shader (embedded source, no file lookup at
// run time). See dvd_shader.cpp for the arithmetic and why it matches the CPU backend.

#include <cstddef>
#include <string>

namespace proxima::gpu {

// Invocations per work group (local_size_x in the shader).
inline constexpr std::size_t DVD_LOCAL_SIZE = 64;

// The complete shader source, with DVD_LOCAL_SIZE substituted.
std::string dvd_shader_source();

}  // namespace proxima::gpu
