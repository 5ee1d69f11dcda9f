#pragma once
// The GPU backend of the discrete-Voronoi kernel (proxima/culling/dvd.hpp): an OpenGL 4.3+ core
// context on a headless EGL display (surfaceless or device platform, no window system), compute
// shaders, and one thread that owns the context and runs every GPU job in turn. On a machine
// without a GPU, Mesa's llvmpipe provides the same context on the CPU.

#include <memory>
#include <string>

#include "proxima/culling/dvd.hpp"
#include "proxima/status.hpp"

namespace proxima::gpu {

struct EglOptions {
    // For tests and operators: behave as if EGL could not start (the daemon then falls back to
    // the CPU backend). The environment variable PROXIMA_DISABLE_EGL=1 does the same.
    bool force_failure = false;
};

// Starts the context thread and compiles the kernel. On failure (no EGL display, no GL 4.3
// context, shader compile error, forced failure) returns `unavailable` with the reason, e.g.
// "EGL: eglInitialize failed (EGL_NOT_INITIALIZED) on the surfaceless platform".
StatusOr<std::shared_ptr<dvd::Backend>> make_egl_backend(const EglOptions& options = {});

}  // namespace proxima::gpu
