#pragma once
// The discrete-Voronoi kernel (seed 000 §4.3-4.4, §5.2, §6.1): for a list of grid sample points,
// each sampled on an "owner" triangle f, the distance from the point to the closest *eligible*
// triangle, where eligible means
//   inter_object mode: a triangle of another object than f's;
//   intra_object mode: a triangle of f's object that is not f and shares no vertex with f
//                      (f's 1-ring is excluded, seed §5.2.2).
// This is the second-order discrete Voronoi diagram evaluated where the culler needs it: at the
// grid points on a site, the closest site other than the site itself. Only triangles within
// `radius` of a sample are searched (the band of seed §5.2); a sample with none gets +infinity.
//
// Two backends compute it: CPU (parallel, the reference) and GPU (OpenGL compute shaders on a
// headless EGL context; Mesa llvmpipe where there is no GPU). Both run the same single-precision
// arithmetic in the same order, without fused multiply-add (CPU: the kernel file is compiled with
// -ffp-contract=off; GLSL: `precise`), and break ties by the smallest triangle index, so on
// llvmpipe they return bit-identical results. The culler never trusts the single-precision values
// beyond their error bound: it widens every bound by `kernel_error_bound` (docs/algorithms.md).

#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "proxima/status.hpp"

namespace proxima::dvd {

enum class Mode : std::uint32_t { inter_object = 0, intra_object = 1 };

inline constexpr std::uint32_t NO_TRIANGLE = std::numeric_limits<std::uint32_t>::max();

// Everything is in single precision, in coordinates relative to a common origin chosen by the
// caller (the grid origin), so magnitudes stay small.
struct KernelInput {
    Mode mode = Mode::inter_object;
    float radius = 0.0f;  // search radius (band width), > 0

    // Triangles: 9 floats each (corner 0 xyz, corner 1 xyz, corner 2 xyz).
    std::vector<float> triangle_vertices;
    // 3 per triangle: vertex ids; two triangles are adjacent when they share one (intra mode).
    std::vector<std::uint32_t> triangle_indices;
    // Per triangle: object number (inter mode compares them; intra mode: all triangles are of one
    // object, and this may hold anything).
    std::vector<std::uint32_t> triangle_object;

    // Uniform bucket grid over space: bucket (i, j, k) covers
    // bucket_origin + bucket_size * [i, i+1) x [j, j+1) x [k, k+1). Bucket b's list is
    // bucket_triangles[bucket_offsets[b] .. bucket_offsets[b + 1]), ascending, and holds every
    // triangle whose box grown by `radius` overlaps the bucket. A sample searches only its own
    // bucket, so every triangle within `radius` of it is seen.
    std::array<float, 3> bucket_origin{};
    float bucket_size = 1.0f;
    std::array<std::uint32_t, 3> bucket_dims{};
    std::vector<std::uint32_t> bucket_offsets;  // size = bucket count + 1
    std::vector<std::uint32_t> bucket_triangles;

    // Samples: 3 floats each, and the owner triangle of each.
    std::vector<float> sample_points;
    std::vector<std::uint32_t> sample_owner;
    // Bucket of each sample (flattened i + dims[0] * (j + dims[1] * k)), computed by the caller
    // so both backends agree on it.
    std::vector<std::uint32_t> sample_bucket;
};

struct KernelOutput {
    // Per sample: distance to the closest eligible triangle within `radius` (+infinity if none),
    // and that triangle (NO_TRIANGLE if none; ties go to the smallest index).
    std::vector<float> distance;
    std::vector<std::uint32_t> nearest;
};

// Checks sizes and index ranges (every index below its array's size, offsets monotone); the
// backends call it first, so a malformed input is an invalid_argument status, never a crash.
Status validate(const KernelInput& input);

// Squared distance from point p to triangle (a, b, c), in single precision, the exact operation
// sequence both backends use (the GLSL source spells the same steps).
float point_triangle_distance_squared(const float p[3], const float a[3], const float b[3],
                                      const float c[3]);

// An upper bound on |computed - exact| for the distance the kernel returns (not squared), for
// coordinates (relative to the origin) of magnitude at most `max_abs_coordinate` and the
// rounding of double inputs to float. The culler adds it to every discrete distance.
//
// The sequence is spelled out in engine/src/culling/dvd_cpu.cpp (comment block at the top): three
// edge candidates, and the supporting-plane distance when a generous inside test passes.
// The bound covers every well-shaped triangle; a triangle whose normal is ill-conditioned (a
// "cap", nearly collinear corners) adds triangle_error_term below. The culler's epsilon is
// kernel_error_bound(M) + the largest triangle_error_term over the kernel's triangles.
double kernel_error_bound(double max_abs_coordinate);

// Extra error allowance of one triangle (corners a, b, c in double, relative to the kernel's
// origin, in the kernel's corner order): min(2 * inradius, 128 * kappa * u * M) with
// kappa = |ab| |ac| / |ab x ac| and u = 2^-24. 0 for an exactly degenerate triangle.
double triangle_error_term(const double a[3], const double b[3], const double c[3],
                           double max_abs_coordinate);

class Backend {
  public:
    virtual ~Backend() = default;
    // "cpu", or "gpu (<GL renderer string>)".
    virtual std::string name() const = 0;
    virtual bool is_gpu() const = 0;
    // Thread-safe: a GPU backend serializes work on the one thread that owns its context.
    virtual Status run(const KernelInput& input, KernelOutput& output) = 0;
    // "" while the backend can run jobs. Once it never can again (a GPU whose context was lost,
    // or left in an undefined state by a failed job), why; every later run() then fails. A run()
    // that fails while this stays "" refused that one job only (e.g. an input over a GPU limit).
    virtual std::string lost_reason() const { return {}; }
};

// What a backend that falls back from the GPU to the CPU (gpu::FailoverBackend) has done, for
// server info and metrics.
struct BackendStats {
    bool gpu_active = false;      // the GPU runs the jobs (false after a loss, or without a GPU)
    std::string fallback_reason;  // why the GPU does not ("" while it does)
    std::uint64_t gpu_jobs = 0;   // jobs the GPU answered
    std::uint64_t cpu_jobs = 0;   // jobs the CPU kernel ran in the GPU's place
    double gpu_seconds = 0.0;     // time in the GPU backend's run(), failed attempts included
    double cpu_seconds = 0.0;     // time in the CPU kernel for those jobs
};

// The parallel CPU backend (oneTBB).
std::shared_ptr<Backend> make_cpu_backend();

}  // namespace proxima::dvd
