#pragma once
// The GPU backend of the discrete-Voronoi kernel (proxima/culling/dvd.hpp): an OpenGL 4.3+ core
// context on a headless EGL display (surfaceless or device platform, no window system), compute
// shaders, and one thread that owns the context and runs every GPU job in turn. On a machine
// without a GPU, Mesa's llvmpipe provides the same context on the CPU.

#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "proxima/culling/dvd.hpp"
#include "proxima/status.hpp"

namespace proxima::gpu {

struct EglOptions {
    // For tests and operators: behave as if EGL could not start (the daemon then falls back to
    // the CPU backend). The environment variable PROXIMA_DISABLE_EGL=1 does the same.
    bool force_failure = false;
    // For tests and operators: after this many jobs ran on the GPU, the next one ends as on a
    // real context loss (its reset status reads GL_UNKNOWN_CONTEXT_RESET): the job fails, the
    // context is destroyed, and the backend stays lost. The environment variable
    // PROXIMA_EGL_LOSE_CONTEXT_AFTER=N does the same when this is unset.
    std::optional<std::uint64_t> lose_context_after_jobs;
};

// Starts the context thread and compiles the kernel. On failure (no EGL display, no GL 4.3
// context, shader compile error, forced failure) returns `unavailable` with the reason, e.g.
// "EGL: eglInitialize failed (EGL_NOT_INITIALIZED) on the surfaceless platform";
// `invalid_argument` when PROXIMA_EGL_LOSE_CONTEXT_AFTER is not a job count.
//
// Context loss while serving: the context is robust where the driver allows, and after every job
// the backend checks the reset status, that the context is still current (EGL_CONTEXT_LOST) and
// the GL error flags. Any of them failing fails that job with a status saying what happened
// (`unavailable` for a loss, `resource_exhausted` for GL_OUT_OF_MEMORY, `internal` otherwise),
// destroys the context (a context after a GL error or reset is undefined: no half-working
// backend) and makes lost_reason() non-empty; every later run() fails with `unavailable`.
// gpu::FailoverBackend (failover_backend.hpp) turns that into the CPU kernel.
StatusOr<std::shared_ptr<dvd::Backend>> make_egl_backend(const EglOptions& options = {});

}  // namespace proxima::gpu
