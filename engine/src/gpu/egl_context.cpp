#include "gpu/egl_context.hpp"

#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <dlfcn.h>
#include <link.h>
#include <algorithm>

#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <vector>

namespace proxima::gpu {

namespace {

Status unavailable(std::string message) {
    return {StatusCode::unavailable, std::move(message)};
}

std::string egl_error_name(EGLint error) {
    switch (error) {
        case EGL_SUCCESS:
            return "EGL_SUCCESS";
        case EGL_NOT_INITIALIZED:
            return "EGL_NOT_INITIALIZED";
        case EGL_BAD_ACCESS:
            return "EGL_BAD_ACCESS";
        case EGL_BAD_ALLOC:
            return "EGL_BAD_ALLOC";
        case EGL_BAD_ATTRIBUTE:
            return "EGL_BAD_ATTRIBUTE";
        case EGL_BAD_CONFIG:
            return "EGL_BAD_CONFIG";
        case EGL_BAD_CONTEXT:
            return "EGL_BAD_CONTEXT";
        case EGL_BAD_CURRENT_SURFACE:
            return "EGL_BAD_CURRENT_SURFACE";
        case EGL_BAD_DISPLAY:
            return "EGL_BAD_DISPLAY";
        case EGL_BAD_MATCH:
            return "EGL_BAD_MATCH";
        case EGL_BAD_NATIVE_PIXMAP:
            return "EGL_BAD_NATIVE_PIXMAP";
        case EGL_BAD_NATIVE_WINDOW:
            return "EGL_BAD_NATIVE_WINDOW";
        case EGL_BAD_PARAMETER:
            return "EGL_BAD_PARAMETER";
        case EGL_BAD_SURFACE:
            return "EGL_BAD_SURFACE";
        case EGL_CONTEXT_LOST:
            return "EGL_CONTEXT_LOST";
        default:
            return "EGL error " + std::to_string(error);
    }
}

std::string last_egl_error() {
    return egl_error_name(eglGetError());
}

bool has_extension(const char* list, const char* name) {
    if (list == nullptr) {
        return false;
    }
    const std::size_t n = std::strlen(name);
    for (const char* p = list; (p = std::strstr(p, name)) != nullptr; p += n) {
        const bool starts = p == list || p[-1] == ' ';
        const bool ends = p[n] == '\0' || p[n] == ' ';
        if (starts && ends) {
            return true;
        }
    }
    return false;
}

// eglInitialize is not reference counted (without EGL_KHR_display_reference): the display of a
// platform is one object per process, and eglTerminate would pull it from under every other
// context on it (several backends in one process: tests, a daemon restarting its backend). So
// count the users here and terminate when the last one leaves.
std::mutex g_display_mutex;
std::map<EGLDisplay, int> g_display_users;

bool acquire_display(EGLDisplay display) {
    std::lock_guard lock(g_display_mutex);
    EGLint major = 0;
    EGLint minor = 0;
    if (eglInitialize(display, &major, &minor) != EGL_TRUE) {
        return false;
    }
    ++g_display_users[display];
    return true;
}

void release_display(EGLDisplay display) {
    std::lock_guard lock(g_display_mutex);
    auto it = g_display_users.find(display);
    if (it == g_display_users.end()) {
        return;
    }
    if (--it->second == 0) {
        g_display_users.erase(it);
        eglTerminate(display);
    }
}

// Mesa unloads its DRI driver (e.g. swrast_dri.so) at eglTerminate, and LeakSanitizer then
// reports the driver's few static allocations it can no longer see. Pinning the loaded driver
// with RTLD_NODELETE keeps it mapped until exit, so sanitizer runs stay clean; it costs nothing.
void pin_loaded_drivers() {
    std::vector<std::string> names;
    dl_iterate_phdr(
        [](dl_phdr_info* info, std::size_t, void* data) {
            const char* name = info->dlpi_name;
            if (name != nullptr && std::strstr(name, "_dri.so") != nullptr) {
                static_cast<std::vector<std::string>*>(data)->emplace_back(name);
            }
            return 0;
        },
        &names);
    for (const auto& name : names) {
        if (void* handle = dlopen(name.c_str(), RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE)) {
            dlclose(handle);  // the NODELETE flag stays with the library
        }
    }
}

bool is_software_renderer(const std::string& renderer) {
    for (const char* name : {"llvmpipe", "softpipe", "swrast", "SwiftShader"}) {
        if (renderer.find(name) != std::string::npos) {
            return true;
        }
    }
    return false;
}

}  // namespace

struct EglContextFactory {
    // Initializes `display`, creates a 4.3+ core context and makes it current. On failure,
    // everything acquired is released and the reason returned.
    static StatusOr<std::unique_ptr<EglContext>> on_display(EGLDisplay display,
                                                            const std::string& platform) {
        if (display == EGL_NO_DISPLAY) {
            return unavailable("eglGetPlatformDisplay failed (" + last_egl_error() + ") on the " +
                               platform + " platform");
        }
        if (!acquire_display(display)) {
            return unavailable("eglInitialize failed (" + last_egl_error() + ") on the " +
                               platform + " platform");
        }
        pin_loaded_drivers();
        auto fail = [&](const std::string& what) -> Status {
            const std::string error = last_egl_error();
            release_display(display);
            return unavailable(what + " (" + error + ") on the " + platform + " platform");
        };
        if (eglBindAPI(EGL_OPENGL_API) != EGL_TRUE) {
            return fail("eglBindAPI(EGL_OPENGL_API) failed: no desktop OpenGL");
        }
        const EGLint config_attribs[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE,
                                         EGL_OPENGL_BIT, EGL_NONE};
        EGLConfig config = nullptr;
        EGLint config_count = 0;
        if (eglChooseConfig(display, config_attribs, &config, 1, &config_count) != EGL_TRUE ||
            config_count < 1) {
            // A compute-only context needs no framebuffer configuration at all.
            if (!has_extension(eglQueryString(display, EGL_EXTENSIONS),
                               "EGL_KHR_no_config_context")) {
                return fail("eglChooseConfig found no OpenGL configuration");
            }
            config = EGL_NO_CONFIG_KHR;
        }
        // 4.3 is where compute shaders and shader storage buffers became core; drivers return the
        // highest compatible core version (Mesa llvmpipe: 4.5).
        std::vector<EGLint> context_attribs = {
            EGL_CONTEXT_MAJOR_VERSION,       4,
            EGL_CONTEXT_MINOR_VERSION,       3,
            EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT};
        // Ask for reset notification first, so that a GPU reset is reported by
        // glGetGraphicsResetStatus (and the backend falls back to the CPU) rather than left to
        // the driver's default (no notification: calls may silently do nothing). EGL 1.5 and
        // EGL_KHR_create_context spell it for desktop OpenGL; EGL_EXT_create_context_robustness
        // has its own attribute. A driver without robustness refuses the attribute: then a plain
        // context, whose loss still shows as GL_CONTEXT_LOST errors or EGL_CONTEXT_LOST.
        const char* display_extensions = eglQueryString(display, EGL_EXTENSIONS);
        const char* version = eglQueryString(display, EGL_VERSION);
        const bool egl15 = version != nullptr && std::strncmp(version, "1.", 2) == 0 &&
                           std::atoi(version + 2) >= 5;
        EGLint robust_attribute = EGL_NONE;
        if (egl15 || has_extension(display_extensions, "EGL_KHR_create_context")) {
            robust_attribute = EGL_CONTEXT_OPENGL_RESET_NOTIFICATION_STRATEGY;
        } else if (has_extension(display_extensions, "EGL_EXT_create_context_robustness")) {
            robust_attribute = EGL_CONTEXT_OPENGL_RESET_NOTIFICATION_STRATEGY_EXT;
        }
        EGLContext context = EGL_NO_CONTEXT;
        if (robust_attribute != EGL_NONE) {
            std::vector<EGLint> robust = context_attribs;
            robust.insert(robust.end(), {robust_attribute, EGL_LOSE_CONTEXT_ON_RESET, EGL_NONE});
            context = eglCreateContext(display, config, EGL_NO_CONTEXT, robust.data());
        }
        if (context == EGL_NO_CONTEXT) {
            context_attribs.push_back(EGL_NONE);
            context = eglCreateContext(display, config, EGL_NO_CONTEXT, context_attribs.data());
        }
        if (context == EGL_NO_CONTEXT) {
            return fail("eglCreateContext for OpenGL 4.3 core failed");
        }
        // No surface: compute shaders read and write buffers only (EGL_KHR_surfaceless_context).
        if (eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context) != EGL_TRUE) {
            const std::string error = last_egl_error();
            eglDestroyContext(display, context);
            release_display(display);
            return unavailable("eglMakeCurrent without a surface failed (" + error + ") on the " +
                               platform + " platform");
        }

        std::unique_ptr<EglContext> result(new EglContext());
        result->m_display = display;
        result->m_context = context;
        result->m_platform = platform;
        if (Status s = load_gl_api(result->m_gl); !s.ok()) {
            return Status(s.code(), s.message() + " on the " + platform + " platform");
        }
        const GlApi& gl = result->m_gl;
        GLint major = 0;
        GLint minor = 0;
        gl.glGetIntegerv(GL_MAJOR_VERSION, &major);
        gl.glGetIntegerv(GL_MINOR_VERSION, &minor);
        auto str = [&](GLenum name) {
            const GLubyte* s = gl.glGetString(name);
            return s == nullptr ? std::string("?") : std::string(reinterpret_cast<const char*>(s));
        };
        result->m_renderer = str(GL_RENDERER);
        result->m_version = str(GL_VERSION);
        result->m_software = is_software_renderer(result->m_renderer);
        if (major < 4 || (major == 4 && minor < 3)) {
            return unavailable("OpenGL " + std::to_string(major) + "." + std::to_string(minor) +
                               " (" + result->m_renderer + ") on the " + platform +
                               " platform: compute shaders need 4.3");
        }
        // Core since 4.5; before, GL_KHR_robustness / GL_ARB_robustness name it with a suffix
        // (through GLVND eglGetProcAddress may return a stub for a missing one: it returns
        // GL_NO_ERROR, which is what a context without resets says anyway).
        for (const char* name : {"glGetGraphicsResetStatus", "glGetGraphicsResetStatusKHR",
                                 "glGetGraphicsResetStatusARB"}) {
            if (std::strcmp(name, "glGetGraphicsResetStatus") == 0 && major == 4 && minor < 5) {
                continue;
            }
            result->m_get_reset_status =
                reinterpret_cast<PFNGLGETGRAPHICSRESETSTATUSPROC>(eglGetProcAddress(name));
            if (result->m_get_reset_status != nullptr) {
                break;
            }
        }
        GLint strategy = 0;
        gl.glGetIntegerv(GL_RESET_NOTIFICATION_STRATEGY, &strategy);
        result->m_reset_notification = result->m_get_reset_status != nullptr &&
                                       static_cast<GLenum>(strategy) == GL_LOSE_CONTEXT_ON_RESET;
        (void)gl.glGetError();  // a driver without the query raises GL_INVALID_ENUM: not an error
        return result;
    }

    static StatusOr<std::unique_ptr<EglContext>> surfaceless() {
        if (!has_extension(eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS),
                           "EGL_MESA_platform_surfaceless")) {
            return unavailable("no EGL_MESA_platform_surfaceless (no Mesa EGL)");
        }
        return on_display(
            eglGetPlatformDisplay(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr),
            "surfaceless");
    }

    // The device platform's devices, hardware ones only when `hardware_only`.
    static StatusOr<std::unique_ptr<EglContext>> device(bool hardware_only) {
        const char* client = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
        if (!has_extension(client, "EGL_EXT_platform_device") ||
            !(has_extension(client, "EGL_EXT_device_enumeration") ||
              has_extension(client, "EGL_EXT_device_base"))) {
            return unavailable("no EGL_EXT_platform_device / EGL_EXT_device_enumeration");
        }
        auto query_devices =
            reinterpret_cast<PFNEGLQUERYDEVICESEXTPROC>(eglGetProcAddress("eglQueryDevicesEXT"));
        auto query_device_string = reinterpret_cast<PFNEGLQUERYDEVICESTRINGEXTPROC>(
            eglGetProcAddress("eglQueryDeviceStringEXT"));
        if (query_devices == nullptr || query_device_string == nullptr) {
            return unavailable("eglQueryDevicesEXT is missing");
        }
        EGLint count = 0;
        if (query_devices(0, nullptr, &count) != EGL_TRUE || count <= 0) {
            return unavailable("eglQueryDevicesEXT found no EGL device");
        }
        std::vector<EGLDeviceEXT> devices(static_cast<std::size_t>(count));
        if (query_devices(count, devices.data(), &count) != EGL_TRUE) {
            return unavailable("eglQueryDevicesEXT failed (" + last_egl_error() + ")");
        }
        std::string reasons;
        for (EGLint i = 0; i < count; ++i) {
            const bool software = has_extension(query_device_string(devices[i], EGL_EXTENSIONS),
                                                "EGL_MESA_device_software");
            if (hardware_only && software) {
                continue;
            }
            auto r = on_display(eglGetPlatformDisplay(EGL_PLATFORM_DEVICE_EXT, devices[i], nullptr),
                                "device " + std::to_string(i));
            if (r.ok()) {
                return r;
            }
            reasons += (reasons.empty() ? "" : "; ") + r.status().message();
        }
        return unavailable(reasons.empty() ? std::string("no hardware EGL device") : reasons);
    }
};

StatusOr<std::unique_ptr<EglContext>> EglContext::create() {
    auto surfaceless = EglContextFactory::surfaceless();
    if (surfaceless.ok() && !surfaceless.value()->is_software()) {
        return surfaceless;
    }
    // Software (or nothing) so far: a hardware device of the device platform wins if it works.
    auto device = EglContextFactory::device(/*hardware_only=*/surfaceless.ok());
    if (device.ok()) {
        return device;
    }
    if (surfaceless.ok()) {
        // The device attempt may have left nothing current: make the software context current
        // again (it was current before).
        auto& ctx = *surfaceless.value();
        eglMakeCurrent(static_cast<EGLDisplay>(ctx.m_display), EGL_NO_SURFACE, EGL_NO_SURFACE,
                       static_cast<EGLContext>(ctx.m_context));
        return surfaceless;
    }
    return unavailable("EGL: " + surfaceless.status().message() + "; " + device.status().message());
}

EglContext::~EglContext() {
    auto display = static_cast<EGLDisplay>(m_display);
    if (display == EGL_NO_DISPLAY) {
        return;
    }
    if (eglGetCurrentContext() == static_cast<EGLContext>(m_context)) {
        eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    }
    eglDestroyContext(display, static_cast<EGLContext>(m_context));
    release_display(display);
}

std::string EglContext::lost_reason(GLenum simulated_reset) const {
    const std::string where = " on " + m_renderer + " (" + m_platform + " platform)";
    // Our context is made current once, at creation, and stays current on this thread; if it is
    // not current any more, making it current again says whether EGL still knows it (a power
    // event or a device reset reports EGL_CONTEXT_LOST there).
    auto display = static_cast<EGLDisplay>(m_display);
    auto context = static_cast<EGLContext>(m_context);
    if (eglGetCurrentContext() != context &&
        eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context) != EGL_TRUE) {
        return "eglMakeCurrent failed (" + last_egl_error() + ")" + where;
    }
    GLenum reset = simulated_reset;
    if (reset == GL_NO_ERROR && m_get_reset_status != nullptr) {
        reset = m_get_reset_status();
    }
    if (reset == GL_NO_ERROR) {
        return {};
    }
    return "GL context reset (" + gl_error_name(reset) + ")" + where;
}

Status load_gl_api(GlApi& api) {
#define PROXIMA_GL_LOAD(type, name)                                                  \
    api.name = reinterpret_cast<type>(eglGetProcAddress(#name));                     \
    if (api.name == nullptr) {                                                       \
        return {StatusCode::unavailable, "eglGetProcAddress(\"" #name "\") failed"}; \
    }
    PROXIMA_GL_FUNCTIONS(PROXIMA_GL_LOAD)
#undef PROXIMA_GL_LOAD
    return Status::ok_status();
}

GLuint compile_shader(const GlApi& gl, GLenum kind, const std::string& source, std::string& log) {
    const GLuint shader = gl.glCreateShader(kind);
    const GLchar* text = source.c_str();
    gl.glShaderSource(shader, 1, &text, nullptr);
    gl.glCompileShader(shader);
    GLint ok = GL_FALSE;
    gl.glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
    if (ok == GL_TRUE) {
        return shader;
    }
    log.assign(4096, '\0');
    GLsizei length = 0;
    gl.glGetShaderInfoLog(shader, static_cast<GLsizei>(log.size()), &length, log.data());
    log.resize(static_cast<std::size_t>(std::max(length, 0)));
    gl.glDeleteShader(shader);
    return 0;
}

GLuint link_program(const GlApi& gl, std::initializer_list<GLuint> shaders, std::string& log) {
    const GLuint program = gl.glCreateProgram();
    for (const GLuint s : shaders) {
        gl.glAttachShader(program, s);
    }
    gl.glLinkProgram(program);
    for (const GLuint s : shaders) {
        gl.glDeleteShader(s);
    }
    GLint ok = GL_FALSE;
    gl.glGetProgramiv(program, GL_LINK_STATUS, &ok);
    if (ok == GL_TRUE) {
        return program;
    }
    log.assign(4096, '\0');
    GLsizei length = 0;
    gl.glGetProgramInfoLog(program, static_cast<GLsizei>(log.size()), &length, log.data());
    log.resize(static_cast<std::size_t>(std::max(length, 0)));
    gl.glDeleteProgram(program);
    return 0;
}

std::string gl_error_name(GLenum error) {
    switch (error) {
        case GL_NO_ERROR:
            return "GL_NO_ERROR";
        case GL_INVALID_ENUM:
            return "GL_INVALID_ENUM";
        case GL_INVALID_VALUE:
            return "GL_INVALID_VALUE";
        case GL_INVALID_OPERATION:
            return "GL_INVALID_OPERATION";
        case GL_INVALID_FRAMEBUFFER_OPERATION:
            return "GL_INVALID_FRAMEBUFFER_OPERATION";
        case GL_OUT_OF_MEMORY:
            return "GL_OUT_OF_MEMORY";
        case GL_CONTEXT_LOST:
            return "GL_CONTEXT_LOST";
        // glGetGraphicsResetStatus
        case GL_GUILTY_CONTEXT_RESET:
            return "GL_GUILTY_CONTEXT_RESET";
        case GL_INNOCENT_CONTEXT_RESET:
            return "GL_INNOCENT_CONTEXT_RESET";
        case GL_UNKNOWN_CONTEXT_RESET:
            return "GL_UNKNOWN_CONTEXT_RESET";
        default:
            return "GL error " + std::to_string(error);
    }
}

}  // namespace proxima::gpu
