#pragma once
// The OpenGL 4.3 core entry points the GPU backend uses, loaded at run time with
// eglGetProcAddress (Debian ships no GL loader such as glad, and going through EGL keeps the
// vendor choice with GLVND: Mesa's or NVIDIA's driver, whichever owns the context). The types come
// from Khronos' <GL/glcorearb.h> (libgl-dev / mesa-common-dev); nothing here is linked from
// libGL/libOpenGL, so the only link dependency is libEGL.

#include <GL/glcorearb.h>

#include <initializer_list>
#include <string>

#include "proxima/status.hpp"

namespace proxima::gpu {

// X-macro list: (type, name).
#define PROXIMA_GL_FUNCTIONS(X)                          \
    X(PFNGLGETERRORPROC, glGetError)                     \
    X(PFNGLGETSTRINGPROC, glGetString)                   \
    X(PFNGLGETINTEGERVPROC, glGetIntegerv)               \
    X(PFNGLGETINTEGERI_VPROC, glGetIntegeri_v)           \
    X(PFNGLGETINTEGER64VPROC, glGetInteger64v)           \
    X(PFNGLCREATESHADERPROC, glCreateShader)             \
    X(PFNGLSHADERSOURCEPROC, glShaderSource)             \
    X(PFNGLCOMPILESHADERPROC, glCompileShader)           \
    X(PFNGLGETSHADERIVPROC, glGetShaderiv)               \
    X(PFNGLGETSHADERINFOLOGPROC, glGetShaderInfoLog)     \
    X(PFNGLDELETESHADERPROC, glDeleteShader)             \
    X(PFNGLCREATEPROGRAMPROC, glCreateProgram)           \
    X(PFNGLATTACHSHADERPROC, glAttachShader)             \
    X(PFNGLLINKPROGRAMPROC, glLinkProgram)               \
    X(PFNGLGETPROGRAMIVPROC, glGetProgramiv)             \
    X(PFNGLGETPROGRAMINFOLOGPROC, glGetProgramInfoLog)   \
    X(PFNGLDELETEPROGRAMPROC, glDeleteProgram)           \
    X(PFNGLUSEPROGRAMPROC, glUseProgram)                 \
    X(PFNGLGETUNIFORMLOCATIONPROC, glGetUniformLocation) \
    X(PFNGLUNIFORM1UIPROC, glUniform1ui)                 \
    X(PFNGLUNIFORM1FPROC, glUniform1f)                   \
    X(PFNGLGENBUFFERSPROC, glGenBuffers)                 \
    X(PFNGLDELETEBUFFERSPROC, glDeleteBuffers)           \
    X(PFNGLBINDBUFFERPROC, glBindBuffer)                 \
    X(PFNGLBUFFERDATAPROC, glBufferData)                 \
    X(PFNGLBUFFERSUBDATAPROC, glBufferSubData)           \
    X(PFNGLGETBUFFERSUBDATAPROC, glGetBufferSubData)     \
    X(PFNGLBINDBUFFERRANGEPROC, glBindBufferRange)       \
    X(PFNGLDISPATCHCOMPUTEPROC, glDispatchCompute)       \
    X(PFNGLMEMORYBARRIERPROC, glMemoryBarrier)           \
    X(PFNGLFINISHPROC, glFinish)

struct GlApi {
#define PROXIMA_GL_MEMBER(type, name) type name = nullptr;
    PROXIMA_GL_FUNCTIONS(PROXIMA_GL_MEMBER)
#undef PROXIMA_GL_MEMBER
};

// Loads every entry point; `unavailable` naming the first one missing. Needs a current context
// on some drivers, so it is called after eglMakeCurrent.
Status load_gl_api(GlApi& api);

// Compiles one shader of `kind` from `source`: its name, or 0 with the driver's info log in `log`
// (the failed shader deleted).
GLuint compile_shader(const GlApi& gl, GLenum kind, const std::string& source, std::string& log);

// Links the shaders into a new program and deletes them (flagged: freed with the program): its
// name, or 0 with the driver's info log in `log` (the program deleted).
GLuint link_program(const GlApi& gl, std::initializer_list<GLuint> shaders, std::string& log);

// "GL_OUT_OF_MEMORY", "GL_GUILTY_CONTEXT_RESET" etc. (glGetError and glGetGraphicsResetStatus
// values) for messages.
std::string gl_error_name(GLenum error);

}  // namespace proxima::gpu
