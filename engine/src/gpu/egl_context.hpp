#pragma once
// A headless OpenGL 4.3+ core context through EGL, with no window system and no surface:
//   1. EGL_PLATFORM_SURFACELESS_MESA (Mesa: a GPU's render node, or llvmpipe on a machine with
//      none, as in CI);
//   2. the EGL device platform (EGL_EXT_platform_device: eglQueryDevicesEXT, one display per
//      device; how NVIDIA's driver offers headless contexts through GLVND).
// When the surfaceless platform yields only a software renderer (llvmpipe), the hardware devices
// of the device platform are tried as well and the first that gives a context wins, so a machine
// with both Mesa and an NVIDIA driver computes on the GPU.
//
// An EglContext is not thread-safe: create, use and destroy it on one thread (the backend's
// context thread), where it stays current for its whole life.
//
// Context loss: a GPU reset (a hung or killed job, a driver update, a suspended device) leaves
// the context unusable. It is created robust where the driver allows (reset notification
// LOSE_CONTEXT_ON_RESET: EGL 1.5 / EGL_KHR_create_context, or EGL_EXT_create_context_robustness),
// so that glGetGraphicsResetStatus reports the reset instead of the driver misbehaving silently;
// lost_reason() checks that and whether the context is still current (EGL_CONTEXT_LOST).

#include <memory>
#include <string>

#include "gpu/gl_api.hpp"
#include "proxima/status.hpp"

namespace proxima::gpu {

class EglContext {
  public:
    // Creates the context and makes it current on the calling thread. `unavailable` with every
    // platform's reason on failure.
    static StatusOr<std::unique_ptr<EglContext>> create();
    ~EglContext();  // releases the context (and the display when no other context uses it)

    EglContext(const EglContext&) = delete;
    EglContext& operator=(const EglContext&) = delete;

    const GlApi& gl() const { return m_gl; }
    const std::string& renderer() const { return m_renderer; }  // GL_RENDERER
    const std::string& version() const { return m_version; }    // GL_VERSION
    const std::string& platform() const { return m_platform; }  // "surfaceless" or "device 0"
    bool is_software() const { return m_software; }
    // True when the context reports resets (LOSE_CONTEXT_ON_RESET granted).
    bool reset_notification() const { return m_reset_notification; }

    // "" while the context works; otherwise what broke, e.g. "GL context reset
    // (GL_GUILTY_CONTEXT_RESET) on llvmpipe (...)" or "eglMakeCurrent failed (EGL_CONTEXT_LOST)
    // ...". `simulated_reset` (a GL reset status, for the backend's test hook) is reported as if
    // the driver had returned it. Once non-empty the context must be destroyed, never reused.
    std::string lost_reason(GLenum simulated_reset = GL_NO_ERROR) const;

  private:
    EglContext() = default;

    void* m_display = nullptr;  // EGLDisplay
    void* m_context = nullptr;  // EGLContext
    GlApi m_gl;
    std::string m_renderer;
    std::string m_version;
    std::string m_platform;
    bool m_software = false;
    bool m_reset_notification = false;
    // glGetGraphicsResetStatus (GL 4.5) or its KHR/ARB robustness name; null without either.
    PFNGLGETGRAPHICSRESETSTATUSPROC m_get_reset_status = nullptr;

    friend struct EglContextFactory;
};

}  // namespace proxima::gpu
