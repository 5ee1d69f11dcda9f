// The GPU backend of the discrete-Voronoi kernel (proxima/culling/dvd.hpp): OpenGL compute
// shaders on a headless EGL context owned by one thread.
//
// Why compute shaders and not rasterization of distance functions (the seed's §6.1 approach):
// the kernel evaluates the distance at a sparse set of sample points (the grid points on the
// sites, each with its own owner triangle and eligibility rule), not on every pixel of dense
// slices. Rasterizing distance meshes would compute whole slices and throw most of them away,
// needs one pass per slice, loses the per-sample eligibility (1-ring exclusion, other object)
// unless encoded in extra passes, and its result goes through depth-buffer precision and
// interpolation of the distance function that the CPU cannot reproduce bit-for-bit. A compute
// shader runs exactly the CPU's per-sample loop: one invocation per sample, the same
// single-precision operation sequence (`precise`, no fused multiply-add), the same ascending
// triangle order and tie rule, so on llvmpipe the two backends agree bit-for-bit and on a GPU the
// only difference is the documented precision of the few operations GLSL does not round
// correctly (see dvd_shader.cpp). Sparse buckets also cost nothing where there are no samples.
//
// Threading: an EGL/GL context is current on at most one thread, and GL calls on a context are
// not thread-safe. One thread, started by make_egl_backend, creates the context, compiles the
// kernel, and then runs jobs from a queue in arrival order; run() from any thread validates and
// packs its input on the caller's thread, posts the GPU part and waits for it. The destructor
// closes the queue, lets the jobs already queued finish, deletes the GL objects, destroys the
// context on that thread and joins it.
//
// Context loss: after every job the context thread checks the reset status and that the context
// is still current (EglContext::lost_reason), and the job's GL error flags. Any failure there
// fails the job, and the context is destroyed at once: after a reset, or a GL error in the
// middle of a job, its state is undefined, and a backend that kept using it could return wrong
// distances the culler would trust. The thread then stays up, failing every job with the reason,
// until the backend is destroyed; the failover backend has run them on the CPU since the loss.

#include "proxima/gpu/egl_backend.hpp"

#include <EGL/egl.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <functional>
#include <future>
#include <mutex>
#include <new>
#include <optional>
#include <thread>

#include "gpu/dvd_shader.hpp"
#include "gpu/egl_context.hpp"
#include "gpu/gl_api.hpp"

namespace proxima::gpu {

namespace {

Status unavailable(std::string message) {
    return {StatusCode::unavailable, std::move(message)};
}

// Buffer binding points of the kernel's std430 blocks (dvd_shader.cpp). Eight blocks: the
// minimum GL_MAX_COMPUTE_SHADER_STORAGE_BLOCKS of OpenGL 4.3, so any 4.3 driver runs it.
enum Binding : GLuint {
    TRIANGLE_VERTICES = 0,
    TRIANGLE_INDICES = 1,
    TRIANGLE_OBJECT = 2,
    BUCKET_OFFSETS = 3,
    BUCKET_TRIANGLES = 4,
    SAMPLES = 5,
    OUT_DISTANCE = 6,
    OUT_NEAREST = 7,
    BINDING_COUNT = 8,
};

const char* binding_name(GLuint b) {
    static const char* const NAMES[] = {"triangle_vertices", "triangle_indices", "triangle_object",
                                        "bucket_offsets",    "bucket_triangles", "samples",
                                        "distance",          "nearest"};
    return NAMES[b];
}

// One sample as the shader reads it (std430 struct of five 4-byte scalars: stride 20 bytes).
// Packing point, owner and bucket together keeps the block count at 8 and gives each invocation
// one contiguous read.
struct PackedSample {
    float x;
    float y;
    float z;
    std::uint32_t owner;
    std::uint32_t bucket;
};
static_assert(sizeof(PackedSample) == 20);

// A FIFO of jobs served by one thread.
class JobQueue {
  public:
    using Job = std::function<void()>;

    // False when the queue is closed (the backend is being destroyed).
    bool push(Job job) {
        {
            std::lock_guard lock(m_mutex);
            if (m_closed) {
                return false;
            }
            m_jobs.push_back(std::move(job));
        }
        m_cv.notify_one();
        return true;
    }

    // Runs jobs in order until the queue is closed and empty.
    void serve() {
        for (;;) {
            Job job;
            {
                std::unique_lock lock(m_mutex);
                m_cv.wait(lock, [&] { return m_closed || !m_jobs.empty(); });
                if (m_jobs.empty()) {
                    return;
                }
                job = std::move(m_jobs.front());
                m_jobs.pop_front();
            }
            job();
        }
    }

    void close() {
        {
            std::lock_guard lock(m_mutex);
            m_closed = true;
        }
        m_cv.notify_all();
    }

  private:
    std::mutex m_mutex;
    std::condition_variable m_cv;
    std::deque<Job> m_jobs;
    bool m_closed = false;
};

class EglDvdBackend final : public dvd::Backend {
  public:
    // `lose_after`: the test hook of EglOptions::lose_context_after_jobs, `lose_after_source`
    // how it was set (for the reason).
    EglDvdBackend(std::size_t max_dispatch_samples, std::optional<std::uint64_t> lose_after,
                  std::string lose_after_source)
        : m_requested_chunk(max_dispatch_samples),
          m_lose_after(lose_after),
          m_lose_after_source(std::move(lose_after_source)) {}

    // Starts the context thread and waits until the context and the kernel are ready.
    Status start() {
        std::promise<Status> started;
        auto ready = started.get_future();
        m_thread =
            std::thread([this, started = std::move(started)]() mutable { thread_main(started); });
        Status s = ready.get();
        if (!s.ok()) {
            m_queue.close();
            m_thread.join();
        }
        return s;
    }

    ~EglDvdBackend() override {
        m_queue.close();
        if (m_thread.joinable()) {
            m_thread.join();
        }
    }

    std::string name() const override { return m_name; }
    bool is_gpu() const override { return true; }

    std::string lost_reason() const override {
        std::lock_guard lock(m_lost_mutex);
        return m_lost_reason;
    }

    Status run(const dvd::KernelInput& input, dvd::KernelOutput& output) override {
        if (Status s = dvd::validate(input); !s.ok()) {
            return s;
        }
        if (m_lost.load(std::memory_order_acquire)) {
            return lost_status();
        }
        if (Status s = check_block_limits(input); !s.ok()) {
            return s;
        }
        // CPU-side preparation on the caller's thread, so that callers overlap it.
        const std::size_t n = input.sample_owner.size();
        std::vector<PackedSample> samples;
        try {
            output.distance.resize(n);
            output.nearest.resize(n);
            samples.resize(n);
        } catch (const std::bad_alloc&) {
            return {StatusCode::resource_exhausted,
                    "GPU kernel: out of memory for " + std::to_string(n) + " samples"};
        }
        if (n == 0) {
            return Status::ok_status();
        }
        for (std::size_t i = 0; i < n; ++i) {
            samples[i] = {input.sample_points[3 * i], input.sample_points[3 * i + 1],
                          input.sample_points[3 * i + 2], input.sample_owner[i],
                          input.sample_bucket[i]};
        }
        return call([&] { return run_job(input, samples, output); });
    }

  private:
    Status lost_status() const { return unavailable("GPU context lost earlier: " + lost_reason()); }

    // The arrays every invocation may index whole must each fit one storage block. Checked on
    // the caller's thread, before any GL call: a job over the limit is refused, and the context
    // is untouched (lost_reason() stays ""), so the GPU keeps serving smaller jobs. The limits
    // are written by the context thread before start() returns and constant after.
    Status check_block_limits(const dvd::KernelInput& in) const {
        const std::array<std::size_t, 5> whole_bytes = whole_array_bytes(in);
        for (GLuint b = 0; b < whole_bytes.size(); ++b) {
            if (whole_bytes[b] > static_cast<std::size_t>(m_max_block_bytes)) {
                return {StatusCode::resource_exhausted,
                        "GPU kernel: " + std::string(binding_name(b)) + " takes " +
                            std::to_string(whole_bytes[b]) +
                            " bytes, more than GL_MAX_SHADER_STORAGE_BLOCK_SIZE (" +
                            std::to_string(m_max_block_bytes) + ") on " + m_renderer +
                            "; use the CPU backend or a coarser bucket grid"};
            }
        }
        return Status::ok_status();
    }

    static std::array<std::size_t, 5> whole_array_bytes(const dvd::KernelInput& in) {
        return {in.triangle_vertices.size() * sizeof(float),
                in.triangle_indices.size() * sizeof(std::uint32_t),
                in.triangle_object.size() * sizeof(std::uint32_t),
                in.bucket_offsets.size() * sizeof(std::uint32_t),
                in.bucket_triangles.size() * sizeof(std::uint32_t)};
    }

    // On the context thread: one job, and the checks that say whether the context survived it.
    Status run_job(const dvd::KernelInput& in, const std::vector<PackedSample>& samples,
                   dvd::KernelOutput& out) {
        if (!m_context) {  // queued before the loss
            return lost_status();
        }
        if (std::string before = m_context->lost_reason(); !before.empty()) {
            lose(before);
            return unavailable("GPU kernel: " + before);
        }
        Status s = execute(in, samples, out);
        // The test hook ends the job exactly where a real reset would be noticed.
        const bool simulate = m_lose_after && m_jobs_done >= *m_lose_after;
        std::string reason =
            m_context->lost_reason(simulate ? GL_UNKNOWN_CONTEXT_RESET : GL_NO_ERROR);
        if (!reason.empty()) {
            if (simulate) {
                reason += ", simulated after " + std::to_string(m_jobs_done) + " jobs (" +
                          m_lose_after_source + ")";
            }
            lose(reason);
            return unavailable("GPU kernel: " + reason);
        }
        if (!s.ok()) {
            lose(s.message() + " on " + m_renderer);
            return s;
        }
        ++m_jobs_done;
        return Status::ok_status();
    }

    // On the context thread: the context is gone or undefined. Deletes what it can (GL calls on
    // a lost context do nothing) and destroys the context; later jobs fail with `reason`.
    void lose(const std::string& reason) {
        {
            std::lock_guard lock(m_lost_mutex);
            m_lost_reason = reason;
        }
        m_lost.store(true, std::memory_order_release);
        release_gl();
        m_program = 0;
        m_buffers = {};
        m_capacity = {};
    }

    // Posts `job` to the context thread and waits for its status.
    Status call(const std::function<Status()>& job) {
        auto done = std::make_shared<std::promise<Status>>();
        auto result = done->get_future();
        const bool queued = m_queue.push([&job, done] {
            Status s;
            try {
                s = job();
            } catch (const std::bad_alloc&) {
                s = {StatusCode::resource_exhausted, "GPU kernel: out of host memory"};
            } catch (const std::exception& e) {
                s = {StatusCode::internal, std::string("GPU kernel: ") + e.what()};
            }
            done->set_value(std::move(s));
        });
        if (!queued) {
            return unavailable("GPU backend is shutting down");
        }
        return result.get();
    }

    void thread_main(std::promise<Status>& started) {
        Status s;
        try {
            s = init_gl();
        } catch (const std::exception& e) {
            s = unavailable(std::string("EGL: ") + e.what());
        }
        started.set_value(s);
        if (s.ok()) {
            m_queue.serve();
        }
        release_gl();
        eglReleaseThread();
    }

    // On the context thread: context, kernel, limits, buffers.
    Status init_gl() {
        auto context = EglContext::create();
        if (!context.ok()) {
            return context.status();
        }
        m_context = std::move(context).value();
        const GlApi& gl = m_context->gl();
        const std::string where = " (" + m_context->renderer() + ")";

        GLint blocks = 0;
        gl.glGetIntegerv(GL_MAX_COMPUTE_SHADER_STORAGE_BLOCKS, &blocks);
        GLint bindings = 0;
        gl.glGetIntegerv(GL_MAX_SHADER_STORAGE_BUFFER_BINDINGS, &bindings);
        if (blocks < static_cast<GLint>(BINDING_COUNT) ||
            bindings < static_cast<GLint>(BINDING_COUNT)) {
            return unavailable("OpenGL: the kernel needs 8 shader storage blocks, the driver has " +
                               std::to_string(std::min(blocks, bindings)) + where);
        }
        gl.glGetInteger64v(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &m_max_block_bytes);
        GLint groups = 0;
        gl.glGetIntegeri_v(GL_MAX_COMPUTE_WORK_GROUP_COUNT, 0, &groups);
        GLint alignment = 0;
        gl.glGetIntegerv(GL_SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT, &alignment);
        if (const GLenum e = gl.glGetError();
            e != GL_NO_ERROR || m_max_block_bytes <= 0 || groups <= 0 || alignment <= 0) {
            return unavailable("OpenGL: cannot read the compute limits (" + gl_error_name(e) + ")" +
                               where);
        }

        // Samples per dispatch: bounded by the work-group count limit and by the largest
        // per-sample block (the packed samples, 20 bytes each). Chunk starts are multiples of
        // `granule` samples, a multiple of the offset alignment (a power of two), so every
        // bound range offset (start * 4 or start * 20 bytes) is aligned.
        const std::size_t granule =
            std::max<std::size_t>(DVD_LOCAL_SIZE, static_cast<std::size_t>(alignment));
        std::size_t chunk = static_cast<std::size_t>(groups) * DVD_LOCAL_SIZE;
        chunk = std::min<std::size_t>(
            chunk, static_cast<std::size_t>(m_max_block_bytes) / sizeof(PackedSample));
        if (m_requested_chunk > 0) {
            chunk = std::min(chunk, m_requested_chunk);
        }
        m_chunk_samples = std::max(granule, chunk / granule * granule);

        if (Status s = compile_kernel(); !s.ok()) {
            return s;
        }
        gl.glGenBuffers(BINDING_COUNT, m_buffers.data());
        if (const GLenum e = gl.glGetError(); e != GL_NO_ERROR) {
            return unavailable("OpenGL: glGenBuffers failed (" + gl_error_name(e) + ")" + where);
        }
        m_renderer = m_context->renderer();
        m_name = "gpu (" + m_renderer + ")";
        return Status::ok_status();
    }

    Status compile_kernel() {
        const GlApi& gl = m_context->gl();
        std::string log;
        const GLuint shader = compile_shader(gl, GL_COMPUTE_SHADER, dvd_shader_source(), log);
        if (shader == 0) {
            return unavailable("OpenGL: the kernel's compute shader did not compile on " +
                               m_context->renderer() + ": " + log);
        }
        m_program = link_program(gl, {shader}, log);
        if (m_program == 0) {
            return unavailable("OpenGL: the kernel's program did not link on " +
                               m_context->renderer() + ": " + log);
        }
        m_loc_count = gl.glGetUniformLocation(m_program, "u_sample_count");
        m_loc_mode = gl.glGetUniformLocation(m_program, "u_mode");
        m_loc_radius = gl.glGetUniformLocation(m_program, "u_radius");
        if (m_loc_count < 0 || m_loc_mode < 0 || m_loc_radius < 0) {
            return unavailable("OpenGL: the kernel's uniforms are missing after linking on " +
                               m_context->renderer());
        }
        return Status::ok_status();
    }

    // On the context thread, after the queue closed (or when start failed).
    void release_gl() {
        if (!m_context) {
            return;
        }
        const GlApi& gl = m_context->gl();
        if (m_buffers[0] != 0) {
            gl.glDeleteBuffers(BINDING_COUNT, m_buffers.data());
        }
        if (m_program != 0) {
            gl.glDeleteProgram(m_program);
        }
        m_context.reset();
    }

    // Status for a GL error raised during `stage`, or ok. Clears the error flags. run_job then
    // destroys the context: a GL error in the middle of a job leaves it undefined.
    Status check_gl(const char* stage) {
        const GlApi& gl = m_context->gl();
        GLenum first = GL_NO_ERROR;
        for (GLenum e = gl.glGetError(); e != GL_NO_ERROR; e = gl.glGetError()) {
            if (first == GL_NO_ERROR) {
                first = e;
            }
            if (e == GL_CONTEXT_LOST) {
                break;
            }
        }
        if (first == GL_NO_ERROR) {
            return Status::ok_status();
        }
        const std::string message =
            std::string("GPU kernel: ") + stage + " failed (" + gl_error_name(first) + ")";
        if (first == GL_OUT_OF_MEMORY) {
            return {StatusCode::resource_exhausted, message};
        }
        if (first == GL_CONTEXT_LOST) {
            return unavailable(message);
        }
        return {StatusCode::internal, message};
    }

    // Grow-only: reallocates buffer `b` only when `bytes` exceed its capacity (by at least half
    // again, so a slowly growing input reallocates rarely). Never smaller than 16 bytes, so an
    // empty array still has a valid (unused) binding.
    void reserve(GLuint b, std::size_t bytes) {
        bytes = std::max<std::size_t>(bytes, 16);
        if (bytes <= m_capacity[b]) {
            return;
        }
        const std::size_t grown = std::max(bytes, m_capacity[b] + m_capacity[b] / 2);
        const GlApi& gl = m_context->gl();
        gl.glBindBuffer(GL_SHADER_STORAGE_BUFFER, m_buffers[b]);
        gl.glBufferData(GL_SHADER_STORAGE_BUFFER, static_cast<GLsizeiptr>(grown), nullptr,
                        GL_DYNAMIC_DRAW);
        m_capacity[b] = grown;
    }

    template <class T>
    void upload(GLuint b, const T* data, std::size_t count) {
        const std::size_t bytes = count * sizeof(T);
        reserve(b, bytes);
        if (bytes > 0) {
            const GlApi& gl = m_context->gl();
            gl.glBindBuffer(GL_SHADER_STORAGE_BUFFER, m_buffers[b]);
            gl.glBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, static_cast<GLsizeiptr>(bytes), data);
        }
    }

    // Binds the first `bytes` of buffer `b` (the whole array the shader may index).
    void bind_whole(GLuint b, std::size_t bytes) {
        m_context->gl().glBindBufferRange(
            GL_SHADER_STORAGE_BUFFER, b, m_buffers[b], 0,
            static_cast<GLsizeiptr>(std::max<std::size_t>(bytes, 16)));
    }

    // On the context thread: upload, dispatch in chunks, read back.
    Status execute(const dvd::KernelInput& in, const std::vector<PackedSample>& samples,
                   dvd::KernelOutput& out) {
        const GlApi& gl = m_context->gl();
        // Every GL error so far ended its job and the context, so none is stale; the check
        // only keeps a driver's stray flag (e.g. from the start-up queries) off this job.
        (void)check_gl("an earlier call");
        const std::array<std::size_t, 5> whole_bytes = whole_array_bytes(in);

        const std::size_t n = samples.size();
        upload(TRIANGLE_VERTICES, in.triangle_vertices.data(), in.triangle_vertices.size());
        upload(TRIANGLE_INDICES, in.triangle_indices.data(), in.triangle_indices.size());
        upload(TRIANGLE_OBJECT, in.triangle_object.data(), in.triangle_object.size());
        upload(BUCKET_OFFSETS, in.bucket_offsets.data(), in.bucket_offsets.size());
        upload(BUCKET_TRIANGLES, in.bucket_triangles.data(), in.bucket_triangles.size());
        upload(SAMPLES, samples.data(), n);
        reserve(OUT_DISTANCE, n * sizeof(float));
        reserve(OUT_NEAREST, n * sizeof(std::uint32_t));
        if (Status s = check_gl("uploading the input"); !s.ok()) {
            return s;
        }

        gl.glUseProgram(m_program);
        gl.glUniform1ui(m_loc_mode, static_cast<GLuint>(in.mode));
        gl.glUniform1f(m_loc_radius, in.radius);
        for (GLuint b = 0; b < whole_bytes.size(); ++b) {
            bind_whole(b, whole_bytes[b]);
        }
        for (std::size_t start = 0; start < n; start += m_chunk_samples) {
            const std::size_t count = std::min(m_chunk_samples, n - start);
            gl.glBindBufferRange(GL_SHADER_STORAGE_BUFFER, SAMPLES, m_buffers[SAMPLES],
                                 static_cast<GLintptr>(start * sizeof(PackedSample)),
                                 static_cast<GLsizeiptr>(count * sizeof(PackedSample)));
            gl.glBindBufferRange(GL_SHADER_STORAGE_BUFFER, OUT_DISTANCE, m_buffers[OUT_DISTANCE],
                                 static_cast<GLintptr>(start * sizeof(float)),
                                 static_cast<GLsizeiptr>(count * sizeof(float)));
            gl.glBindBufferRange(GL_SHADER_STORAGE_BUFFER, OUT_NEAREST, m_buffers[OUT_NEAREST],
                                 static_cast<GLintptr>(start * sizeof(std::uint32_t)),
                                 static_cast<GLsizeiptr>(count * sizeof(std::uint32_t)));
            gl.glUniform1ui(m_loc_count, static_cast<GLuint>(count));
            gl.glDispatchCompute(static_cast<GLuint>((count + DVD_LOCAL_SIZE - 1) / DVD_LOCAL_SIZE),
                                 1, 1);
        }
        if (Status s = check_gl("dispatching the kernel"); !s.ok()) {
            return s;
        }

        // Make the shader's writes visible to glGetBufferSubData, then read back (this waits).
        gl.glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        gl.glBindBuffer(GL_SHADER_STORAGE_BUFFER, m_buffers[OUT_DISTANCE]);
        gl.glGetBufferSubData(GL_SHADER_STORAGE_BUFFER, 0,
                              static_cast<GLsizeiptr>(n * sizeof(float)), out.distance.data());
        gl.glBindBuffer(GL_SHADER_STORAGE_BUFFER, m_buffers[OUT_NEAREST]);
        gl.glGetBufferSubData(GL_SHADER_STORAGE_BUFFER, 0,
                              static_cast<GLsizeiptr>(n * sizeof(std::uint32_t)),
                              out.nearest.data());
        gl.glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
        gl.glUseProgram(0);
        return check_gl("reading back the result");
    }

    std::size_t m_requested_chunk = 0;  // 0: as the limits allow
    const std::optional<std::uint64_t> m_lose_after;
    const std::string m_lose_after_source;
    std::thread m_thread;
    JobQueue m_queue;
    // Written by the context thread before start() returns; const after.
    std::string m_name;
    std::string m_renderer;
    GLint64 m_max_block_bytes = 0;

    // Set once, by the context thread, when the context is lost.
    std::atomic<bool> m_lost{false};
    mutable std::mutex m_lost_mutex;
    std::string m_lost_reason;

    // Owned by the context thread.
    std::unique_ptr<EglContext> m_context;
    GLuint m_program = 0;
    GLint m_loc_count = -1;
    GLint m_loc_mode = -1;
    GLint m_loc_radius = -1;
    std::array<GLuint, BINDING_COUNT> m_buffers{};
    std::array<std::size_t, BINDING_COUNT> m_capacity{};
    std::size_t m_chunk_samples = 0;
    std::uint64_t m_jobs_done = 0;  // jobs the GPU answered
};

bool env_is_set(const char* name) {
    const char* v = std::getenv(name);
    return v != nullptr && *v != '\0' && std::strcmp(v, "0") != 0;
}

}  // namespace

StatusOr<std::shared_ptr<dvd::Backend>> make_egl_backend(const EglOptions& options) {
    if (options.force_failure) {
        return unavailable("EGL disabled (EglOptions::force_failure)");
    }
    if (env_is_set("PROXIMA_DISABLE_EGL")) {
        return unavailable("EGL disabled by PROXIMA_DISABLE_EGL=" +
                           std::string(std::getenv("PROXIMA_DISABLE_EGL")));
    }
    // For tests and benchmarks: at most this many samples per dispatch (rounded down to the
    // work-group and alignment granule), to exercise chunking on small inputs.
    std::size_t max_dispatch = 0;
    if (const char* v = std::getenv("PROXIMA_EGL_MAX_DISPATCH_SAMPLES"); v != nullptr) {
        max_dispatch = static_cast<std::size_t>(std::strtoull(v, nullptr, 10));
    }
    std::optional<std::uint64_t> lose_after = options.lose_context_after_jobs;
    std::string lose_after_source;
    if (lose_after) {
        lose_after_source = "EglOptions::lose_context_after_jobs=" + std::to_string(*lose_after);
    } else if (const char* v = std::getenv("PROXIMA_EGL_LOSE_CONTEXT_AFTER");
               v != nullptr && *v != '\0') {
        // A typo here must not pass for "never": the daemon would then test nothing.
        char* end = nullptr;
        errno = 0;
        const unsigned long long n = std::strtoull(v, &end, 10);
        if (*end != '\0' || errno != 0 || *v == '-') {
            return Status(
                StatusCode::invalid_argument,
                "PROXIMA_EGL_LOSE_CONTEXT_AFTER='" + std::string(v) + "' is not a job count");
        }
        lose_after = n;
        lose_after_source = "PROXIMA_EGL_LOSE_CONTEXT_AFTER=" + std::to_string(n);
    }
    try {
        auto backend =
            std::make_shared<EglDvdBackend>(max_dispatch, lose_after, std::move(lose_after_source));
        if (Status s = backend->start(); !s.ok()) {
            return s;
        }
        return std::shared_ptr<dvd::Backend>(std::move(backend));
    } catch (const std::system_error& e) {  // no thread could be started
        return unavailable(std::string("EGL: cannot start the GPU context thread: ") + e.what());
    }
}

}  // namespace proxima::gpu
