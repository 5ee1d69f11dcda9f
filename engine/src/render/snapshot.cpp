// Offscreen snapshots (proxima/render/snapshot.hpp): a headless EGL context on a thread of its
// own, an FBO with colour and depth renderbuffers, one flat-shaded triangle pass and one line
// pass, glReadPixels, and PNG through libpng's simplified API.

#include "proxima/render/snapshot.hpp"

#include <EGL/egl.h>
#include <png.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <mutex>
#include <new>
#include <thread>

#include "gpu/egl_context.hpp"
#include "gpu/gl_api.hpp"

namespace proxima::render {

namespace {

constexpr double PI = 3.14159265358979323846;

// Entry points the renderer needs beyond gpu::GlApi (all core in OpenGL 3.3).
#define PROXIMA_RENDER_GL_FUNCTIONS(X)                             \
    X(PFNGLGENVERTEXARRAYSPROC, glGenVertexArrays)                 \
    X(PFNGLBINDVERTEXARRAYPROC, glBindVertexArray)                 \
    X(PFNGLDELETEVERTEXARRAYSPROC, glDeleteVertexArrays)           \
    X(PFNGLVERTEXATTRIBPOINTERPROC, glVertexAttribPointer)         \
    X(PFNGLENABLEVERTEXATTRIBARRAYPROC, glEnableVertexAttribArray) \
    X(PFNGLGENFRAMEBUFFERSPROC, glGenFramebuffers)                 \
    X(PFNGLBINDFRAMEBUFFERPROC, glBindFramebuffer)                 \
    X(PFNGLDELETEFRAMEBUFFERSPROC, glDeleteFramebuffers)           \
    X(PFNGLGENRENDERBUFFERSPROC, glGenRenderbuffers)               \
    X(PFNGLBINDRENDERBUFFERPROC, glBindRenderbuffer)               \
    X(PFNGLDELETERENDERBUFFERSPROC, glDeleteRenderbuffers)         \
    X(PFNGLRENDERBUFFERSTORAGEPROC, glRenderbufferStorage)         \
    X(PFNGLFRAMEBUFFERRENDERBUFFERPROC, glFramebufferRenderbuffer) \
    X(PFNGLCHECKFRAMEBUFFERSTATUSPROC, glCheckFramebufferStatus)   \
    X(PFNGLVIEWPORTPROC, glViewport)                               \
    X(PFNGLCLEARCOLORPROC, glClearColor)                           \
    X(PFNGLCLEARDEPTHPROC, glClearDepth)                           \
    X(PFNGLCLEARPROC, glClear)                                     \
    X(PFNGLENABLEPROC, glEnable)                                   \
    X(PFNGLDISABLEPROC, glDisable)                                 \
    X(PFNGLDEPTHFUNCPROC, glDepthFunc)                             \
    X(PFNGLDRAWARRAYSPROC, glDrawArrays)                           \
    X(PFNGLREADPIXELSPROC, glReadPixels)                           \
    X(PFNGLPIXELSTOREIPROC, glPixelStorei)                         \
    X(PFNGLUNIFORMMATRIX4FVPROC, glUniformMatrix4fv)               \
    X(PFNGLUNIFORM3FPROC, glUniform3f)                             \
    X(PFNGLUNIFORM1IPROC, glUniform1i)

struct RenderGl {
#define PROXIMA_RENDER_MEMBER(type, name) type name = nullptr;
    PROXIMA_RENDER_GL_FUNCTIONS(PROXIMA_RENDER_MEMBER)
#undef PROXIMA_RENDER_MEMBER
};

Status load_render_gl(RenderGl& api) {
#define PROXIMA_RENDER_LOAD(type, name)                                              \
    api.name = reinterpret_cast<type>(eglGetProcAddress(#name));                     \
    if (api.name == nullptr) {                                                       \
        return {StatusCode::unavailable, "eglGetProcAddress(\"" #name "\") failed"}; \
    }
    PROXIMA_RENDER_GL_FUNCTIONS(PROXIMA_RENDER_LOAD)
#undef PROXIMA_RENDER_LOAD
    return Status::ok_status();
}

const char* const VERTEX_SHADER = R"(#version 330 core
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec3 a_normal;
layout(location = 2) in vec3 a_colour;
uniform mat4 u_view_projection;
uniform vec3 u_eye;
uniform int u_lit;
flat out vec3 v_colour;
void main() {
    gl_Position = u_view_projection * vec4(a_position, 1.0);
    if (u_lit != 0) {
        // Headlight: light from the eye; both faces lit (meshes need not be oriented).
        vec3 to_eye = normalize(u_eye - a_position);
        float lambert = abs(dot(normalize(a_normal), to_eye));
        v_colour = a_colour * (0.35 + 0.65 * lambert);
    } else {
        v_colour = a_colour;
    }
}
)";

const char* const FRAGMENT_SHADER = R"(#version 330 core
flat in vec3 v_colour;
out vec4 f_colour;
void main() { f_colour = vec4(v_colour, 1.0); }
)";

struct Vertex {
    std::array<float, 3> position;
    std::array<float, 3> normal;
    std::array<float, 3> colour;
};

std::array<float, 3> to_float(const Vec3& v) {
    return {static_cast<float>(v.x), static_cast<float>(v.y), static_cast<float>(v.z)};
}

std::array<float, 3> to_float(const Rgb& c) {
    return {static_cast<float>(c.r) / 255.0f, static_cast<float>(c.g) / 255.0f,
            static_cast<float>(c.b) / 255.0f};
}

Vec3 normalized(const Vec3& v) {
    const double n = norm(v);
    return n > 0 ? v / n : Vec3{};
}

// Column-major 4x4 (OpenGL's layout): view-projection of `camera` with the scene translated by
// -camera.target (vertices are uploaded relative to the target, so float keeps precision).
std::array<float, 16> view_projection(const Camera& camera, double aspect, double near_plane,
                                      double far_plane) {
    const Vec3 f = normalized(camera.target - camera.eye);
    const Vec3 s = normalized(cross(f, camera.up));
    const Vec3 u = cross(s, f);
    const Vec3 eye = camera.eye - camera.target;
    // View matrix rows.
    const std::array<std::array<double, 4>, 4> view = {{{s.x, s.y, s.z, -dot(s, eye)},
                                                        {u.x, u.y, u.z, -dot(u, eye)},
                                                        {-f.x, -f.y, -f.z, dot(f, eye)},
                                                        {0, 0, 0, 1}}};
    const double t = 1.0 / std::tan(camera.fov_degrees * PI / 360.0);
    const std::array<std::array<double, 4>, 4> projection = {
        {{t / aspect, 0, 0, 0},
         {0, t, 0, 0},
         {0, 0, (far_plane + near_plane) / (near_plane - far_plane),
          2 * far_plane * near_plane / (near_plane - far_plane)},
         {0, 0, -1, 0}}};
    std::array<float, 16> m{};
    for (std::size_t r = 0; r < 4; ++r) {
        for (std::size_t c = 0; c < 4; ++c) {
            double sum = 0;
            for (std::size_t k = 0; k < 4; ++k) {
                sum += projection[r][k] * view[k][c];
            }
            m[c * 4 + r] = static_cast<float>(sum);
        }
    }
    return m;
}

Aabb scene_box(const Scene& scene) {
    Aabb box;
    for (const auto& object : scene.objects()) {
        box.extend(object.box);
    }
    return box;
}

bool egl_disabled() {
    const char* v = std::getenv("PROXIMA_DISABLE_EGL");
    return v != nullptr && *v != '\0' && std::strcmp(v, "0") != 0;
}

// GL objects of one render, deleted on every path.
struct GlObjects {
    const gpu::GlApi* gl = nullptr;
    const RenderGl* rgl = nullptr;
    GLuint framebuffer = 0;
    std::array<GLuint, 2> renderbuffers{};  // colour, depth
    GLuint vertex_array = 0;
    GLuint buffer = 0;
    GLuint program = 0;

    ~GlObjects() {
        if (gl == nullptr) {
            return;
        }
        if (program != 0) {
            gl->glDeleteProgram(program);
        }
        if (buffer != 0) {
            gl->glDeleteBuffers(1, &buffer);
        }
        if (vertex_array != 0) {
            rgl->glDeleteVertexArrays(1, &vertex_array);
        }
        if (framebuffer != 0) {
            rgl->glDeleteFramebuffers(1, &framebuffer);
        }
        if (renderbuffers[0] != 0) {
            rgl->glDeleteRenderbuffers(2, renderbuffers.data());
        }
    }
};

Status link_program(const gpu::GlApi& gl, GlObjects& objects) {
    std::string log;
    const GLuint vs = gpu::compile_shader(gl, GL_VERTEX_SHADER, VERTEX_SHADER, log);
    if (vs == 0) {
        return {StatusCode::internal, "snapshot: vertex shader did not compile: " + log};
    }
    const GLuint fs = gpu::compile_shader(gl, GL_FRAGMENT_SHADER, FRAGMENT_SHADER, log);
    if (fs == 0) {
        gl.glDeleteShader(vs);
        return {StatusCode::internal, "snapshot: fragment shader did not compile: " + log};
    }
    objects.program = gpu::link_program(gl, {vs, fs}, log);
    if (objects.program == 0) {
        return {StatusCode::internal, "snapshot: program did not link: " + log};
    }
    return Status::ok_status();
}

Status gl_error(const gpu::GlApi& gl, const char* stage) {
    const GLenum e = gl.glGetError();
    if (e == GL_NO_ERROR) {
        return Status::ok_status();
    }
    while (gl.glGetError() != GL_NO_ERROR) {
    }
    const StatusCode code =
        e == GL_OUT_OF_MEMORY ? StatusCode::resource_exhausted : StatusCode::internal;
    return {code, std::string("snapshot: ") + stage + " failed (" + gpu::gl_error_name(e) + ")"};
}

// On the render thread, with `context` current.
Status draw(const gpu::EglContext& context, const std::vector<Vertex>& triangles,
            const std::vector<Vertex>& lines, const Camera& camera, double near_plane,
            double far_plane, const RenderOptions& options, Image& image) {
    const gpu::GlApi& gl = context.gl();
    RenderGl rgl;
    if (Status s = load_render_gl(rgl); !s.ok()) {
        return s;
    }
    GLint max_renderbuffer = 0;
    gl.glGetIntegerv(GL_MAX_RENDERBUFFER_SIZE, &max_renderbuffer);
    if (options.width > max_renderbuffer || options.height > max_renderbuffer) {
        return invalid_argument("snapshot: " + std::to_string(options.width) + "x" +
                                std::to_string(options.height) + " exceeds " + context.renderer() +
                                "'s GL_MAX_RENDERBUFFER_SIZE (" + std::to_string(max_renderbuffer) +
                                ")");
    }
    GlObjects objects;
    objects.gl = &gl;
    objects.rgl = &rgl;

    rgl.glGenRenderbuffers(2, objects.renderbuffers.data());
    rgl.glBindRenderbuffer(GL_RENDERBUFFER, objects.renderbuffers[0]);
    rgl.glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, options.width, options.height);
    rgl.glBindRenderbuffer(GL_RENDERBUFFER, objects.renderbuffers[1]);
    rgl.glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, options.width, options.height);
    rgl.glGenFramebuffers(1, &objects.framebuffer);
    rgl.glBindFramebuffer(GL_FRAMEBUFFER, objects.framebuffer);
    rgl.glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER,
                                  objects.renderbuffers[0]);
    rgl.glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER,
                                  objects.renderbuffers[1]);
    if (Status s = gl_error(gl, "creating the framebuffer"); !s.ok()) {
        return s;
    }
    if (const GLenum fb = rgl.glCheckFramebufferStatus(GL_FRAMEBUFFER);
        fb != GL_FRAMEBUFFER_COMPLETE) {
        return {StatusCode::internal,
                "snapshot: framebuffer incomplete (status " + std::to_string(fb) + ")"};
    }
    if (Status s = link_program(gl, objects); !s.ok()) {
        return s;
    }

    rgl.glViewport(0, 0, options.width, options.height);
    rgl.glClearColor(static_cast<float>(options.background.r) / 255.0f,
                     static_cast<float>(options.background.g) / 255.0f,
                     static_cast<float>(options.background.b) / 255.0f, 1.0f);
    rgl.glClearDepth(1.0);
    rgl.glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);

    rgl.glGenVertexArrays(1, &objects.vertex_array);
    rgl.glBindVertexArray(objects.vertex_array);
    gl.glGenBuffers(1, &objects.buffer);
    gl.glBindBuffer(GL_ARRAY_BUFFER, objects.buffer);
    const auto stride = static_cast<GLsizei>(sizeof(Vertex));
    for (GLuint attribute = 0; attribute < 3; ++attribute) {
        rgl.glEnableVertexAttribArray(attribute);
        // A buffer offset, as GL passes it: a pointer-typed integer.
        const std::uintptr_t offset = static_cast<std::uintptr_t>(attribute) * 3 * sizeof(float);
        // NOLINTNEXTLINE(performance-no-int-to-ptr)
        const auto* pointer = reinterpret_cast<const void*>(offset);
        rgl.glVertexAttribPointer(attribute, 3, GL_FLOAT, GL_FALSE, stride, pointer);
    }
    gl.glUseProgram(objects.program);
    const double aspect = static_cast<double>(options.width) / options.height;
    const std::array<float, 16> m = view_projection(camera, aspect, near_plane, far_plane);
    rgl.glUniformMatrix4fv(gl.glGetUniformLocation(objects.program, "u_view_projection"), 1,
                           GL_FALSE, m.data());
    const auto eye = to_float(camera.eye - camera.target);
    rgl.glUniform3f(gl.glGetUniformLocation(objects.program, "u_eye"), eye[0], eye[1], eye[2]);
    const GLint lit = gl.glGetUniformLocation(objects.program, "u_lit");

    auto upload_and_draw = [&](const std::vector<Vertex>& vertices, GLenum mode) {
        if (vertices.empty()) {
            return;
        }
        gl.glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(vertices.size() * sizeof(Vertex)),
                        vertices.data(), GL_STREAM_DRAW);
        rgl.glDrawArrays(mode, 0, static_cast<GLsizei>(vertices.size()));
    };
    rgl.glEnable(GL_DEPTH_TEST);
    rgl.glDepthFunc(GL_LESS);
    rgl.glUniform1i(lit, 1);
    upload_and_draw(triangles, GL_TRIANGLES);
    // Segments on top: a closest pair between objects is often hidden by one of them.
    rgl.glDisable(GL_DEPTH_TEST);
    rgl.glUniform1i(lit, 0);
    upload_and_draw(lines, GL_LINES);
    if (Status s = gl_error(gl, "drawing"); !s.ok()) {
        return s;
    }

    const auto w = static_cast<std::size_t>(options.width);
    const auto h = static_cast<std::size_t>(options.height);
    std::vector<std::uint8_t> rgba(w * h * 4);
    rgl.glPixelStorei(GL_PACK_ALIGNMENT, 1);
    rgl.glReadPixels(0, 0, options.width, options.height, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
    if (Status s = gl_error(gl, "reading the pixels"); !s.ok()) {
        return s;
    }
    gl.glUseProgram(0);
    rgl.glBindFramebuffer(GL_FRAMEBUFFER, 0);
    image.width = options.width;
    image.height = options.height;
    image.rgb.resize(w * h * 3);
    // GL's rows start at the bottom; the image's at the top.
    for (std::size_t y = 0; y < h; ++y) {
        const std::uint8_t* src = rgba.data() + (h - 1 - y) * w * 4;
        std::uint8_t* dst = image.rgb.data() + y * w * 3;
        for (std::size_t x = 0; x < w; ++x) {
            dst[3 * x] = src[4 * x];
            dst[3 * x + 1] = src[4 * x + 1];
            dst[3 * x + 2] = src[4 * x + 2];
        }
    }
    return Status::ok_status();
}

std::mutex g_render_mutex;

}  // namespace

Status validate_camera(const Camera& camera) {
    if (!is_finite(camera.eye) || !is_finite(camera.target) || !is_finite(camera.up) ||
        !std::isfinite(camera.fov_degrees)) {
        return invalid_argument("camera: every value must be finite");
    }
    if (!(camera.fov_degrees > 0 && camera.fov_degrees < 180)) {
        return invalid_argument("camera: the field of view must be in (0, 180) degrees, not " +
                                std::to_string(camera.fov_degrees));
    }
    const Vec3 f = camera.target - camera.eye;
    if (squared_norm(f) == 0) {
        return invalid_argument("camera: eye and target are the same point");
    }
    const Vec3 side = cross(f, camera.up);
    if (squared_norm(side) <= 1e-12 * squared_norm(f) * squared_norm(camera.up)) {
        return invalid_argument("camera: the up vector is zero or parallel to the view direction");
    }
    return Status::ok_status();
}

Status validate_size(int width, int height) {
    if (width < 1 || height < 1 || width > MAX_SNAPSHOT_SIDE || height > MAX_SNAPSHOT_SIDE) {
        return invalid_argument("snapshot: width and height must be in [1, " +
                                std::to_string(MAX_SNAPSHOT_SIDE) + "], not " +
                                std::to_string(width) + "x" + std::to_string(height));
    }
    if (static_cast<std::int64_t>(width) * height > MAX_SNAPSHOT_PIXELS) {
        return invalid_argument("snapshot: " + std::to_string(width) + "x" +
                                std::to_string(height) + " is more than " +
                                std::to_string(MAX_SNAPSHOT_PIXELS) + " pixels");
    }
    return Status::ok_status();
}

Camera fit_camera(const Aabb& box, int width, int height, double fov_degrees) {
    Camera camera;
    camera.fov_degrees = fov_degrees;
    Vec3 centre{0, 0, 0};
    double radius = 1.0;
    if (!box.empty()) {
        centre = 0.5 * (box.lo + box.hi);
        radius = std::max(0.5 * norm(box.hi - box.lo), 1e-9);
    }
    const double aspect = width > 0 && height > 0 ? static_cast<double>(width) / height : 1.0;
    const double half_v = fov_degrees * PI / 360.0;
    const double half_h = std::atan(std::tan(half_v) * aspect);
    const double distance = 1.05 * radius / std::sin(std::min(half_v, half_h));
    camera.target = centre;
    camera.eye = centre + distance * normalized(Vec3{1, -1.5, 1});
    camera.up = {0, 0, 1};
    return camera;
}

Colouring colour_results(const Scene& scene, const QueryResult& result,
                         const ColourOptions& options) {
    Colouring colouring;
    colouring.triangles.resize(scene.size());
    auto paint = [&](std::uint32_t object, std::uint32_t triangle, const Rgb& colour) {
        if (object >= scene.size() || triangle >= scene[object].triangle_count()) {
            return;
        }
        auto& colours = colouring.triangles[object];
        if (colours.empty()) {
            colours.assign(scene[object].triangle_count(), BASE_GREY);
        }
        if (colours[triangle] != COLLISION_RED) {
            colours[triangle] = colour;
        }
    };
    if (options.tolerance) {
        for (const FeaturePair& p : result.tolerance) {
            paint(p.object, p.triangle, TOLERANCE_AMBER);
            paint(p.other, p.other_triangle, TOLERANCE_AMBER);
        }
    }
    if (options.collisions) {
        for (const FeaturePair& p : result.collisions) {
            paint(p.object, p.triangle, COLLISION_RED);
            paint(p.other, p.other_triangle, COLLISION_RED);
        }
    }
    if (options.segments) {
        const auto& separation = result.separation;
        for (std::size_t i = 0; i < separation.size(); ++i) {
            const Separation& s = separation[i];
            if (s.other == NO_OBJECT) {
                continue;
            }
            // A mutual closest pair once.
            const auto other = static_cast<std::size_t>(s.other);
            const bool mutual = other < separation.size() &&
                                separation[other].other == static_cast<std::int64_t>(i);
            if (mutual && other < i) {
                continue;
            }
            colouring.segments.push_back({s.point, s.other_point});
        }
    }
    return colouring;
}

StatusOr<RenderResult> render(const Scene& scene, const Colouring& colouring,
                              const RenderOptions& options) {
    if (Status s = validate_size(options.width, options.height); !s.ok()) {
        return s;
    }
    const Aabb box = scene_box(scene);
    const Camera camera =
        options.camera ? *options.camera : fit_camera(box, options.width, options.height);
    if (Status s = validate_camera(camera); !s.ok()) {
        return s;
    }
    if (!colouring.triangles.empty() && colouring.triangles.size() != scene.size()) {
        return invalid_argument("snapshot: colours for " +
                                std::to_string(colouring.triangles.size()) +
                                " objects, the scene has " + std::to_string(scene.size()));
    }
    for (std::size_t i = 0; i < colouring.triangles.size(); ++i) {
        const auto n = colouring.triangles[i].size();
        if (n != 0 && n != scene[i].triangle_count()) {
            return invalid_argument("snapshot: object " + std::to_string(i) + " has " +
                                    std::to_string(scene[i].triangle_count()) +
                                    " triangles, its colours " + std::to_string(n));
        }
    }
    if (scene.triangle_count() > MAX_SNAPSHOT_TRIANGLES) {
        return Status(StatusCode::resource_exhausted, "snapshot: the scene has " +
                                                          std::to_string(scene.triangle_count()) +
                                                          " triangles; snapshots draw at most " +
                                                          std::to_string(MAX_SNAPSHOT_TRIANGLES));
    }
    if (egl_disabled()) {
        return Status(StatusCode::unavailable, "snapshot: EGL disabled by PROXIMA_DISABLE_EGL=" +
                                                   std::string(std::getenv("PROXIMA_DISABLE_EGL")));
    }

    // Depth range: the scene's bounding sphere seen from the eye.
    const Vec3 centre = box.empty() ? camera.target : 0.5 * (box.lo + box.hi);
    const double radius = box.empty() ? 1.0 : 0.5 * norm(box.hi - box.lo) * 1.01 + 1e-9;
    const double d = norm(centre - camera.eye);
    const double far_plane = std::max(d + radius, 1e-6);
    const double near_plane = std::max(d - radius, far_plane * 1e-4);

    std::vector<Vertex> triangles;
    std::vector<Vertex> lines;
    try {
        triangles.reserve(scene.triangle_count() * 3);
        for (std::size_t i = 0; i < scene.size(); ++i) {
            const SceneObject& object = scene[i];
            const std::vector<Rgb>* colours =
                i < colouring.triangles.size() && !colouring.triangles[i].empty()
                    ? &colouring.triangles[i]
                    : nullptr;
            for (std::uint32_t t = 0; t < object.triangle_count(); ++t) {
                const auto& tri = object.triangle(t);
                const Vec3 a = object.vertices[tri[0]] - camera.target;
                const Vec3 b = object.vertices[tri[1]] - camera.target;
                const Vec3 c = object.vertices[tri[2]] - camera.target;
                const auto normal = to_float(normalized(cross(b - a, c - a)));
                const auto colour = to_float(colours != nullptr ? (*colours)[t] : BASE_GREY);
                for (const Vec3& p : {a, b, c}) {
                    triangles.push_back({to_float(p), normal, colour});
                }
            }
        }
        for (const Segment& s : colouring.segments) {
            const auto colour = to_float(SEGMENT_BLUE);
            lines.push_back({to_float(s.a - camera.target), {0, 0, 1}, colour});
            lines.push_back({to_float(s.b - camera.target), {0, 0, 1}, colour});
        }
    } catch (const std::bad_alloc&) {
        return Status(StatusCode::resource_exhausted, "snapshot: out of memory for the vertices");
    }

    std::lock_guard lock(g_render_mutex);
    RenderResult result;
    result.camera = camera;
    Status status;
    // A thread of its own: the context is made current there and nowhere else, whatever thread
    // (a gRPC worker, a test) asked.
    std::thread thread([&] {
        try {
            auto context = gpu::EglContext::create();
            if (!context.ok()) {
                status = Status(context.status().code(),
                                "snapshot: no EGL context: " + context.status().message());
            } else {
                result.renderer = (*context)->renderer();
                status = draw(**context, triangles, lines, camera, near_plane, far_plane, options,
                              result.image);
                context.value().reset();
            }
        } catch (const std::bad_alloc&) {
            status = Status(StatusCode::resource_exhausted, "snapshot: out of memory");
        } catch (const std::exception& e) {
            status = Status(StatusCode::internal, std::string("snapshot: ") + e.what());
        }
        eglReleaseThread();
    });
    thread.join();
    if (!status.ok()) {
        return status;
    }
    return result;
}

Status validate_snapshot_request(const SnapshotRequest& request) {
    if (Status s = validate_size(request.render.width, request.render.height); !s.ok()) {
        return s;
    }
    if (request.render.camera) {
        if (Status s = validate_camera(*request.render.camera); !s.ok()) {
            return s;
        }
    }
    if (request.tolerance && !(std::isfinite(*request.tolerance) && *request.tolerance >= 0)) {
        return invalid_argument("snapshot: the tolerance must be a finite number >= 0");
    }
    return Status::ok_status();
}

StatusOr<Snapshot> take_snapshot(ProximityEngine& engine, const SnapshotRequest& request,
                                 const CancelToken* cancel) {
    if (Status s = validate_snapshot_request(request); !s.ok()) {
        return s;
    }
    QueryRequest query;
    query.separation = request.segments;
    query.collisions = request.collisions;
    query.tolerance = request.tolerance;
    QueryResult result;
    if (query.separation || query.collisions || query.tolerance) {
        auto answer = engine.query(query, cancel);
        if (!answer.ok()) {
            return answer.status();
        }
        result = std::move(answer).value();
    }
    ColourOptions colour_options;
    colour_options.collisions = request.collisions;
    colour_options.tolerance = request.tolerance.has_value();
    colour_options.segments = request.segments;
    const Colouring colouring = colour_results(engine.scene(), result, colour_options);
    auto rendered = render(engine.scene(), colouring, request.render);
    if (!rendered.ok()) {
        return rendered.status();
    }
    auto png = encode_png(rendered->image);
    if (!png.ok()) {
        return png.status();
    }
    Snapshot out;
    out.png = std::move(png).value();
    out.camera = rendered->camera;
    out.width = rendered->image.width;
    out.height = rendered->image.height;
    out.renderer = rendered->renderer;
    out.collision_count = result.collisions.size();
    out.tolerance_count = result.tolerance.size();
    out.segment_count = colouring.segments.size();
    return out;
}

StatusOr<std::string> encode_png(const Image& image) {
    if (image.width < 1 || image.height < 1 ||
        image.rgb.size() !=
            static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height) * 3) {
        return invalid_argument("encode_png: the image's size does not match its pixels");
    }
    png_image png{};
    png.version = PNG_IMAGE_VERSION;
    png.width = static_cast<png_uint_32>(image.width);
    png.height = static_cast<png_uint_32>(image.height);
    png.format = PNG_FORMAT_RGB;
    png_alloc_size_t size = 0;
    if (png_image_write_to_memory(&png, nullptr, &size, 0, image.rgb.data(), 0, nullptr) == 0) {
        const std::string message = png.message;
        png_image_free(&png);
        return Status(StatusCode::internal, "encode_png: " + message);
    }
    std::string out(size, '\0');
    if (png_image_write_to_memory(&png, out.data(), &size, 0, image.rgb.data(), 0, nullptr) == 0) {
        const std::string message = png.message;
        png_image_free(&png);
        return Status(StatusCode::internal, "encode_png: " + message);
    }
    out.resize(size);
    return out;
}

StatusOr<Image> decode_png(std::string_view bytes) {
    png_image png{};
    png.version = PNG_IMAGE_VERSION;
    if (png_image_begin_read_from_memory(&png, bytes.data(), bytes.size()) == 0) {
        const std::string message = png.message;
        png_image_free(&png);
        return invalid_argument("decode_png: " + message);
    }
    png.format = PNG_FORMAT_RGB;
    Image image;
    image.width = static_cast<int>(png.width);
    image.height = static_cast<int>(png.height);
    image.rgb.resize(PNG_IMAGE_SIZE(png));
    if (png_image_finish_read(&png, nullptr, image.rgb.data(), 0, nullptr) == 0) {
        const std::string message = png.message;
        png_image_free(&png);
        return invalid_argument("decode_png: " + message);
    }
    return image;
}

}  // namespace proxima::render
