// The GPU backend of the discrete-Voronoi kernel (proxima/gpu/egl_backend.hpp) against the CPU
// backend: on Mesa's llvmpipe (CI) both run the same single-precision sequence without fused
// multiply-adds and with the same tie rule, so their outputs must be equal bit-for-bit. In CI
// (environment variable CI set) the EGL context must start; elsewhere the tests skip with the
// reason when it cannot.

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "proxima/culling/dvd.hpp"
#include "proxima/gpu/egl_backend.hpp"
#include "proxima/gpu/failover_backend.hpp"

namespace proxima {
namespace {

using dvd::KernelInput;
using dvd::KernelOutput;
using dvd::Mode;
using dvd::NO_TRIANGLE;

constexpr float INF = std::numeric_limits<float>::infinity();

// Mesa writes a shader cache under $HOME/.cache by default: keep tests from touching it.
void disable_mesa_shader_cache() {
    setenv("MESA_SHADER_CACHE_DISABLE", "true", /*overwrite=*/0);
}

bool in_ci() {
    const char* ci = std::getenv("CI");
    return ci != nullptr && *ci != '\0';
}

// One backend shared by the suite (each creation compiles the kernel).
std::shared_ptr<dvd::Backend>& shared_gpu() {
    static std::shared_ptr<dvd::Backend> backend;
    return backend;
}
std::string& gpu_failure() {
    static std::string reason;
    return reason;
}

class DvdGpu : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        disable_mesa_shader_cache();
        auto made = gpu::make_egl_backend();
        if (made.ok()) {
            shared_gpu() = made.value();
        } else {
            gpu_failure() = made.status().to_string();
        }
    }
    static void TearDownTestSuite() { shared_gpu().reset(); }

    void SetUp() override {
        if (!shared_gpu()) {
            if (in_ci()) {
                FAIL() << "CI is set, so EGL (llvmpipe) must start: " << gpu_failure();
            }
            GTEST_SKIP() << "no EGL context on this machine: " << gpu_failure();
        }
        m_gpu = shared_gpu();
        m_cpu = dvd::make_cpu_backend();
    }

    std::shared_ptr<dvd::Backend> m_gpu;
    std::shared_ptr<dvd::Backend> m_cpu;
};

std::uint32_t bits(float f) {
    std::uint32_t u;
    std::memcpy(&u, &f, sizeof u);
    return u;
}

// Whether the GPU backend is Mesa's llvmpipe, whose GLSL arithmetic rounds exactly like the CPU
// kernel: there the two must agree bit for bit. A hardware driver need not (measured on an NVIDIA
// H200: up to 3.6e-6 relative, subnormal intermediates flushed to zero, so near-ties may pick
// another triangle); there each distance must be within the kernel's error bound of the CPU's,
// which is all the culler relies on (docs/algorithms.md).
bool gpu_rounds_like_the_cpu() {
    return !shared_gpu() || shared_gpu()->name().find("llvmpipe") != std::string::npos;
}

// Coordinates in these tests stay below this magnitude (relative to the kernel's origin).
constexpr double TEST_COORDINATE_BOUND = 128.0;

bool within_kernel_bound(float cpu, float gpu) {
    if (std::isinf(cpu) || std::isinf(gpu)) {
        // A sample at the band's edge may fall either side of the radius.
        return true;
    }
    return std::abs(double(cpu) - double(gpu)) <= dvd::kernel_error_bound(TEST_COORDINATE_BOUND);
}

// Equal bit-for-bit (so +inf equals +inf and -0 differs from +0) on llvmpipe, within the kernel's
// error bound elsewhere; reports the first mismatches.
void expect_identical(const KernelOutput& cpu, const KernelOutput& gpu, const std::string& what) {
    ASSERT_EQ(cpu.distance.size(), gpu.distance.size()) << what;
    ASSERT_EQ(cpu.nearest.size(), gpu.nearest.size()) << what;
    const bool exact = gpu_rounds_like_the_cpu();
    int reported = 0;
    std::size_t mismatches = 0;
    for (std::size_t i = 0; i < cpu.distance.size(); ++i) {
        const bool differ = exact ? (bits(cpu.distance[i]) != bits(gpu.distance[i]) ||
                                     cpu.nearest[i] != gpu.nearest[i])
                                  : !within_kernel_bound(cpu.distance[i], gpu.distance[i]);
        if (differ) {
            ++mismatches;
            if (reported++ < 5) {
                ADD_FAILURE() << what << ": sample " << i << ": cpu " << cpu.distance[i] << " (0x"
                              << std::hex << bits(cpu.distance[i]) << std::dec << ") triangle "
                              << cpu.nearest[i] << ", gpu " << gpu.distance[i] << " (0x" << std::hex
                              << bits(gpu.distance[i]) << std::dec << ") triangle "
                              << gpu.nearest[i];
            }
        }
    }
    EXPECT_EQ(mismatches, 0u) << what << ": of " << cpu.distance.size() << " samples";
}

struct RandomSpec {
    std::uint32_t seed = 1;
    Mode mode = Mode::inter_object;
    std::size_t triangles = 200;
    std::size_t vertices = 120;  // shared pool: many triangles share vertices (intra mode)
    std::size_t objects = 3;
    std::size_t samples = 2000;
    std::uint32_t dims = 4;  // buckets per axis
    float extent = 4.0f;     // triangles live in [0, extent * occupied)^3
    float occupied = 0.5f;   // fraction of the box with triangles: the rest has empty buckets
    float triangle_size = 0.4f;
    float radius = 0.7f;
    std::size_t duplicates = 10;  // exact copies of earlier triangles (ties)
};

// A kernel input shaped like the culler's: a vertex pool, triangles over it, objects, a bucket
// grid whose lists hold every triangle whose box grown by the radius meets the bucket, and
// samples each with an owner triangle and the bucket containing it. Some samples lie on their
// owner's plane (as the culler's do, near the site); many buckets are empty.
KernelInput random_input(const RandomSpec& spec) {
    std::mt19937 rng(spec.seed);
    std::uniform_real_distribution<float> unit(0.0f, 1.0f);
    KernelInput in;
    in.mode = spec.mode;
    in.radius = spec.radius;
    const float bucket = spec.extent / static_cast<float>(spec.dims);
    in.bucket_origin = {0.0f, 0.0f, 0.0f};
    in.bucket_size = bucket;
    in.bucket_dims = {spec.dims, spec.dims, spec.dims};

    std::vector<std::array<float, 3>> pool(spec.vertices);
    for (auto& v : pool) {
        for (auto& x : v) {
            x = unit(rng) * spec.extent * spec.occupied;
        }
    }
    std::uniform_int_distribution<std::uint32_t> pick_vertex(
        0, static_cast<std::uint32_t>(spec.vertices - 1));
    std::uniform_int_distribution<std::uint32_t> pick_object(
        0, static_cast<std::uint32_t>(spec.objects - 1));
    const std::size_t total = spec.triangles + spec.duplicates;
    for (std::size_t t = 0; t < spec.triangles; ++t) {
        // Corner 0 from the pool, the other two near it (small triangles), vertex ids shared
        // with the pool for corner 0 only, fresh ids for the others half the time.
        const std::uint32_t v0 = pick_vertex(rng);
        std::array<std::uint32_t, 3> ids = {v0, pick_vertex(rng), pick_vertex(rng)};
        for (int c = 0; c < 3; ++c) {
            for (int k = 0; k < 3; ++k) {
                const float jitter = c == 0 ? 0.0f : (unit(rng) - 0.5f) * spec.triangle_size;
                in.triangle_vertices.push_back(pool[v0][k] + jitter);
            }
            in.triangle_indices.push_back(ids[c]);
        }
        in.triangle_object.push_back(pick_object(rng));
    }
    std::uniform_int_distribution<std::size_t> pick_triangle(0, spec.triangles - 1);
    for (std::size_t d = 0; d < spec.duplicates; ++d) {
        const std::size_t src = pick_triangle(rng);
        for (int k = 0; k < 9; ++k) {
            in.triangle_vertices.push_back(in.triangle_vertices[9 * src + k]);
        }
        for (int c = 0; c < 3; ++c) {  // fresh vertex ids: not adjacent to the original
            in.triangle_indices.push_back(
                static_cast<std::uint32_t>(spec.vertices + 3 * d + static_cast<std::size_t>(c)));
        }
        in.triangle_object.push_back(pick_object(rng));
    }

    // Buckets: box of each triangle grown by the radius, against each bucket's cell.
    const std::size_t bucket_count = std::size_t{spec.dims} * spec.dims * spec.dims;
    std::vector<std::vector<std::uint32_t>> lists(bucket_count);
    for (std::uint32_t t = 0; t < total; ++t) {
        std::array<std::uint32_t, 3> lo{};
        std::array<std::uint32_t, 3> hi{};
        for (int k = 0; k < 3; ++k) {
            float mn = in.triangle_vertices[9 * t + k];
            float mx = mn;
            for (int c = 1; c < 3; ++c) {
                mn = std::min(mn, in.triangle_vertices[9 * t + 3 * c + k]);
                mx = std::max(mx, in.triangle_vertices[9 * t + 3 * c + k]);
            }
            auto cell = [&](float x) {
                const float f = std::floor(x / bucket);
                return static_cast<std::uint32_t>(
                    std::clamp(f, 0.0f, static_cast<float>(spec.dims - 1)));
            };
            lo[k] = cell(mn - spec.radius);
            hi[k] = cell(mx + spec.radius);
        }
        for (std::uint32_t k = lo[2]; k <= hi[2]; ++k) {
            for (std::uint32_t j = lo[1]; j <= hi[1]; ++j) {
                for (std::uint32_t i = lo[0]; i <= hi[0]; ++i) {
                    lists[i + spec.dims * (j + spec.dims * k)].push_back(t);
                }
            }
        }
    }
    in.bucket_offsets.push_back(0);
    for (const auto& list : lists) {
        in.bucket_triangles.insert(in.bucket_triangles.end(), list.begin(), list.end());
        in.bucket_offsets.push_back(static_cast<std::uint32_t>(in.bucket_triangles.size()));
    }

    // Samples: a third on the owner triangle (barycentric), the rest anywhere in the box.
    std::uniform_int_distribution<std::size_t> pick_owner(0, total - 1);
    for (std::size_t s = 0; s < spec.samples; ++s) {
        const auto owner = static_cast<std::uint32_t>(pick_owner(rng));
        std::array<float, 3> p{};
        if (s % 3 == 0) {
            float u = unit(rng);
            float v = unit(rng);
            if (u + v > 1.0f) {
                u = 1.0f - u;
                v = 1.0f - v;
            }
            for (int k = 0; k < 3; ++k) {
                const float a = in.triangle_vertices[9 * owner + k];
                const float b = in.triangle_vertices[9 * owner + 3 + k];
                const float c = in.triangle_vertices[9 * owner + 6 + k];
                p[k] = a + u * (b - a) + v * (c - a);
            }
        } else {
            for (auto& x : p) {
                x = unit(rng) * spec.extent * 0.999f;
            }
        }
        std::array<std::uint32_t, 3> cell{};
        for (int k = 0; k < 3; ++k) {
            const float f = std::floor(p[k] / bucket);
            cell[k] =
                static_cast<std::uint32_t>(std::clamp(f, 0.0f, static_cast<float>(spec.dims - 1)));
        }
        in.sample_points.insert(in.sample_points.end(), p.begin(), p.end());
        in.sample_owner.push_back(owner);
        in.sample_bucket.push_back(cell[0] + spec.dims * (cell[1] + spec.dims * cell[2]));
    }
    return in;
}

KernelOutput run_ok(dvd::Backend& backend, const KernelInput& in) {
    KernelOutput out;
    const Status s = backend.run(in, out);
    EXPECT_TRUE(s.ok()) << backend.name() << ": " << s.to_string();
    return out;
}

TEST_F(DvdGpu, NameReportsTheRenderer) {
    EXPECT_TRUE(m_gpu->is_gpu());
    EXPECT_EQ(m_gpu->name().rfind("gpu (", 0), 0u) << m_gpu->name();
    EXPECT_EQ(m_gpu->name().back(), ')');
    EXPECT_GT(m_gpu->name().size(), 6u);
}

// Known answers on a hand-made input: distances that are exact in float.
TEST_F(DvdGpu, KnownAnswers) {
    KernelInput in;
    in.mode = Mode::inter_object;
    in.radius = 5.0f;
    // Triangle 0 (object 0) in the plane z = 0; triangle 1 (object 1) in z = 2; triangle 2
    // (object 0) in z = 3.
    in.triangle_vertices = {0, 0, 0, 4, 0, 0, 0, 4, 0,  //
                            0, 0, 2, 4, 0, 2, 0, 4, 2,  //
                            0, 0, 3, 4, 0, 3, 0, 4, 3};
    in.triangle_indices = {0, 1, 2, 3, 4, 5, 6, 7, 8};
    in.triangle_object = {0, 1, 0};
    in.bucket_dims = {1, 1, 1};
    in.bucket_size = 100.0f;
    in.bucket_origin = {-50.0f, -50.0f, -50.0f};
    in.bucket_offsets = {0, 3};
    in.bucket_triangles = {0, 1, 2};
    in.sample_points = {1, 1, 0,    // on triangle 0: triangle 1 (object 1) at 2
                        1, 1, 2,    // on triangle 1: triangle 2 at 1 (triangle 0 at 2)
                        1, 1, 3,    // on triangle 2: triangle 1 at 1
                        1, 1, 10};  // owner 1: object 0's triangles are 7 and 10 away: none
    in.sample_owner = {0, 1, 2, 1};
    in.sample_bucket = {0, 0, 0, 0};
    const KernelOutput gpu = run_ok(*m_gpu, in);
    ASSERT_EQ(gpu.distance.size(), 4u);
    EXPECT_EQ(gpu.distance[0], 2.0f);
    EXPECT_EQ(gpu.nearest[0], 1u);
    EXPECT_EQ(gpu.distance[1], 1.0f);  // triangle 2 (z = 3) is closer than triangle 0 (z = 0)
    EXPECT_EQ(gpu.nearest[1], 2u);
    EXPECT_EQ(gpu.distance[2], 1.0f);
    EXPECT_EQ(gpu.nearest[2], 1u);
    EXPECT_EQ(gpu.distance[3], INF);
    EXPECT_EQ(gpu.nearest[3], NO_TRIANGLE);
    expect_identical(run_ok(*m_cpu, in), gpu, "known answers");
}

// Exact ties: identical triangles at several indices; the smallest eligible index wins.
TEST_F(DvdGpu, TiesGoToTheSmallestIndex) {
    KernelInput in;
    in.mode = Mode::inter_object;
    in.radius = 10.0f;
    const std::vector<float> tri = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    for (int t = 0; t < 5; ++t) {
        in.triangle_vertices.insert(in.triangle_vertices.end(), tri.begin(), tri.end());
        for (int c = 0; c < 3; ++c) {
            in.triangle_indices.push_back(static_cast<std::uint32_t>(3 * t + c));
        }
    }
    in.triangle_object = {0, 0, 1, 1, 1};  // sample owner in object 0: triangles 2, 3, 4 eligible
    in.bucket_dims = {1, 1, 1};
    in.bucket_offsets = {0, 5};
    in.bucket_triangles = {0, 1, 2, 3, 4};
    in.sample_points = {0.25f, 0.25f, 3.0f, 5.0f, 5.0f, 5.0f};
    in.sample_owner = {0, 1};
    in.sample_bucket = {0, 0};
    const KernelOutput gpu = run_ok(*m_gpu, in);
    ASSERT_EQ(gpu.nearest.size(), 2u);
    EXPECT_EQ(gpu.nearest[0], 2u);
    EXPECT_EQ(gpu.distance[0], 3.0f);
    EXPECT_EQ(gpu.nearest[1], 2u);
    expect_identical(run_ok(*m_cpu, in), gpu, "ties");

    // Intra-object: triangles sharing a vertex with the owner (or the owner itself) are skipped
    // even when they are closest.
    KernelInput intra = in;
    intra.mode = Mode::intra_object;
    intra.triangle_indices[3] = 0;  // triangle 1 shares vertex 0 with triangle 0
    intra.triangle_indices[9] = 2;  // triangle 3 shares vertex 2 with triangle 0
    intra.sample_owner = {0, 2};
    const KernelOutput g2 = run_ok(*m_gpu, intra);
    ASSERT_EQ(g2.nearest.size(), 2u);
    EXPECT_EQ(g2.nearest[0], 2u);  // not 0 (itself) nor 1 (adjacent): 2 is the first eligible
    EXPECT_EQ(g2.nearest[1], 0u);  // owner 2 shares no vertex with 0
    expect_identical(run_ok(*m_cpu, intra), g2, "ties, intra");
}

TEST_F(DvdGpu, RandomInputsMatchTheCpuBitForBit) {
    std::uint32_t seed = 100;
    for (Mode mode : {Mode::inter_object, Mode::intra_object}) {
        for (std::size_t samples : {1u, 63u, 64u, 65u, 1000u, 20000u}) {
            RandomSpec spec;
            spec.seed = ++seed;
            spec.mode = mode;
            spec.samples = samples;
            spec.triangles = samples < 100 ? 20 : 300;
            spec.vertices = samples < 100 ? 15 : 150;
            spec.objects = mode == Mode::intra_object ? 1 : 4;
            const KernelInput in = random_input(spec);
            const KernelOutput cpu = run_ok(*m_cpu, in);
            expect_identical(cpu, run_ok(*m_gpu, in),
                             std::string(mode == Mode::inter_object ? "inter" : "intra") + ", " +
                                 std::to_string(samples) + " samples");
            if (samples >= 1000) {  // the comparison is not vacuous: most samples find a triangle
                const auto found = std::count_if(cpu.nearest.begin(), cpu.nearest.end(),
                                                 [](std::uint32_t t) { return t != NO_TRIANGLE; });
                EXPECT_GT(found, static_cast<std::ptrdiff_t>(samples / 4));
                EXPECT_LT(found, static_cast<std::ptrdiff_t>(samples));
            }
        }
    }
}

// Subnormal intermediates: a tiny triangle (legs 1e-6) and a sample 1e-8 above it give a plane
// distance h = 1e-20 whose square is subnormal in float. A driver that flushed subnormals to
// zero would return 0 instead of 1e-8 (llvmpipe does not flush).
TEST_F(DvdGpu, SubnormalIntermediatesMatchTheCpu) {
    KernelInput in;
    in.radius = 1.0f;
    in.triangle_vertices = {0, 0, 0, 1e-6f, 0, 0, 0, 1e-6f, 0,  //
                            5, 5, 5, 6,     5, 5, 5, 6,     5};
    in.triangle_indices = {0, 1, 2, 3, 4, 5};
    in.triangle_object = {1, 0};
    in.bucket_dims = {1, 1, 1};
    in.bucket_size = 100.0f;
    in.bucket_origin = {-50.0f, -50.0f, -50.0f};
    in.bucket_offsets = {0, 2};
    in.bucket_triangles = {0, 1};
    in.sample_points = {2.5e-7f, 2.5e-7f, 1e-8f, 2.5e-7f, 2.5e-7f, 0.0f};
    in.sample_owner = {1, 1};
    in.sample_bucket = {0, 0};
    const KernelOutput gpu = run_ok(*m_gpu, in);
    ASSERT_EQ(gpu.distance.size(), 2u);
    // llvmpipe keeps the subnormal intermediate; a hardware driver may flush it to zero.
    EXPECT_NEAR(gpu.distance[0], 1e-8f,
                gpu_rounds_like_the_cpu() ? 1e-12 : dvd::kernel_error_bound(TEST_COORDINATE_BOUND));
    EXPECT_EQ(gpu.nearest[0], 0u);
    EXPECT_EQ(gpu.distance[1], 0.0f);
    expect_identical(run_ok(*m_cpu, in), gpu, "subnormal");
}

// Degenerate geometry: zero-area triangles (collinear and coincident corners), samples on
// vertices and edges, tiny and large radii.
TEST_F(DvdGpu, DegenerateTrianglesMatchTheCpu) {
    RandomSpec spec;
    spec.seed = 7;
    spec.samples = 3000;
    spec.triangles = 100;
    KernelInput in = random_input(spec);
    for (std::size_t t = 0; t < 100; t += 3) {
        for (int k = 0; k < 3; ++k) {
            in.triangle_vertices[9 * t + 6 + k] = in.triangle_vertices[9 * t + 3 + k];  // c = b
        }
    }
    for (std::size_t t = 1; t < 100; t += 3) {
        for (int k = 0; k < 3; ++k) {  // c = (a + b) / 2: collinear
            in.triangle_vertices[9 * t + 6 + k] =
                0.5f * (in.triangle_vertices[9 * t + k] + in.triangle_vertices[9 * t + 3 + k]);
        }
    }
    for (std::size_t s = 0; s < 300; ++s) {  // samples exactly on corners of some triangle
        const std::size_t t = (s * 7) % 100;
        for (int k = 0; k < 3; ++k) {
            in.sample_points[3 * s + k] = in.triangle_vertices[9 * t + 3 * (s % 3) + k];
        }
        const float b = in.bucket_size;
        std::array<std::uint32_t, 3> cell{};
        for (int k = 0; k < 3; ++k) {
            cell[k] = static_cast<std::uint32_t>(
                std::clamp(std::floor(in.sample_points[3 * s + k] / b), 0.0f,
                           static_cast<float>(in.bucket_dims[k] - 1)));
        }
        in.sample_bucket[s] = cell[0] + in.bucket_dims[0] * (cell[1] + in.bucket_dims[1] * cell[2]);
    }
    expect_identical(run_ok(*m_cpu, in), run_ok(*m_gpu, in), "degenerate");
    for (float radius : {1e-3f, 100.0f}) {
        in.radius = radius;
        expect_identical(run_ok(*m_cpu, in), run_ok(*m_gpu, in),
                         "radius " + std::to_string(radius));
    }
}

// No triangles at all, only empty buckets, or no eligible triangle: +inf and NO_TRIANGLE.
TEST_F(DvdGpu, EmptyInputsAndNoEligibleTriangle) {
    RandomSpec spec;
    spec.seed = 9;
    spec.samples = 500;
    KernelInput in = random_input(spec);

    KernelInput no_samples = in;
    no_samples.sample_points.clear();
    no_samples.sample_owner.clear();
    no_samples.sample_bucket.clear();
    KernelOutput out;
    out.distance.assign(3, 1.0f);
    ASSERT_TRUE(m_gpu->run(no_samples, out).ok());
    EXPECT_TRUE(out.distance.empty());
    EXPECT_TRUE(out.nearest.empty());

    KernelInput empty_buckets = in;
    std::fill(empty_buckets.bucket_offsets.begin(), empty_buckets.bucket_offsets.end(), 0u);
    empty_buckets.bucket_triangles.clear();
    const KernelOutput e = run_ok(*m_gpu, empty_buckets);
    ASSERT_EQ(e.distance.size(), 500u);
    for (std::size_t i = 0; i < e.distance.size(); ++i) {
        EXPECT_EQ(e.distance[i], INF) << i;
        EXPECT_EQ(e.nearest[i], NO_TRIANGLE) << i;
    }
    expect_identical(run_ok(*m_cpu, empty_buckets), e, "empty buckets");

    // One object only, inter-object mode: nothing is eligible anywhere.
    KernelInput one_object = in;
    std::fill(one_object.triangle_object.begin(), one_object.triangle_object.end(), 2u);
    const KernelOutput o = run_ok(*m_gpu, one_object);
    EXPECT_TRUE(std::all_of(o.nearest.begin(), o.nearest.end(),
                            [](std::uint32_t t) { return t == NO_TRIANGLE; }));
    EXPECT_TRUE(
        std::all_of(o.distance.begin(), o.distance.end(), [](float d) { return d == INF; }));
    expect_identical(run_ok(*m_cpu, one_object), o, "one object");
}

TEST_F(DvdGpu, MalformedInputIsRejectedAndTheBackendStillWorks) {
    RandomSpec spec;
    spec.seed = 11;
    spec.samples = 100;
    const KernelInput good = random_input(spec);
    std::vector<std::pair<std::string, KernelInput>> bad;
    auto add = [&](const std::string& what, auto change) {
        KernelInput in = good;
        change(in);
        bad.emplace_back(what, std::move(in));
    };
    add("sample owner out of range", [](KernelInput& in) { in.sample_owner[5] = 1u << 30; });
    add("sample bucket out of range", [](KernelInput& in) { in.sample_bucket[7] = 1u << 30; });
    add("bucket triangle out of range", [](KernelInput& in) { in.bucket_triangles[0] = 1u << 30; });
    add("bucket offsets too short", [](KernelInput& in) { in.bucket_offsets.pop_back(); });
    add("bucket offset past the list",
        [](KernelInput& in) { in.bucket_offsets.back() = 1u << 30; });
    add("sample points not 3 per sample", [](KernelInput& in) { in.sample_points.pop_back(); });
    add("sample arrays of different sizes", [](KernelInput& in) { in.sample_bucket.pop_back(); });
    add("triangle arrays of different sizes",
        [](KernelInput& in) { in.triangle_object.push_back(0); });
    for (const auto& [what, in] : bad) {
        KernelOutput out;
        const Status s = m_gpu->run(in, out);
        EXPECT_EQ(s.code(), StatusCode::invalid_argument) << what << ": " << s.to_string();
        EXPECT_FALSE(s.message().empty()) << what;
    }
    expect_identical(run_ok(*m_cpu, good), run_ok(*m_gpu, good), "after malformed inputs");
}

// More samples than one dispatch takes: a backend limited (through the test knob
// PROXIMA_EGL_MAX_DISPATCH_SAMPLES) to a few hundred samples per dispatch runs dozens of chunks,
// with a partial last one; and one large run with the default (driver) limits.
TEST_F(DvdGpu, LargeInputsRunInSeveralChunks) {
    RandomSpec spec;
    spec.seed = 13;
    spec.samples = 20000 + 37;
    spec.triangles = 400;
    spec.vertices = 200;
    const KernelInput in = random_input(spec);
    const KernelOutput cpu = run_ok(*m_cpu, in);

    setenv("PROXIMA_EGL_MAX_DISPATCH_SAMPLES", "300", 1);
    auto chunked = gpu::make_egl_backend();
    unsetenv("PROXIMA_EGL_MAX_DISPATCH_SAMPLES");
    ASSERT_TRUE(chunked.ok()) << chunked.status().to_string();
    expect_identical(cpu, run_ok(*chunked.value(), in), "300 samples per dispatch");
    // The same backend again, smaller then larger (grow-only buffers keep old contents past the
    // new end: they must not leak into the result).
    RandomSpec small = spec;
    small.samples = 777;
    small.seed = 14;
    const KernelInput in_small = random_input(small);
    expect_identical(run_ok(*m_cpu, in_small), run_ok(*chunked.value(), in_small), "smaller");
    expect_identical(cpu, run_ok(*chunked.value(), in), "larger again");

    RandomSpec big = spec;
    big.seed = 15;
    big.samples = 100000;
    big.dims = 8;
    big.occupied = 0.9f;
    big.triangles = 2000;
    big.vertices = 1000;
    big.radius = 0.3f;
    const KernelInput in_big = random_input(big);
    expect_identical(run_ok(*m_cpu, in_big), run_ok(*m_gpu, in_big), "100000 samples");
}

TEST_F(DvdGpu, ConcurrentRunsAreSerializedAndCorrect) {
    constexpr int THREADS = 4;
    constexpr int RUNS = 6;
    std::vector<KernelInput> inputs;
    std::vector<KernelOutput> expected;
    for (int i = 0; i < THREADS; ++i) {
        RandomSpec spec;
        spec.seed = 200 + static_cast<std::uint32_t>(i);
        spec.mode = i % 2 == 0 ? Mode::inter_object : Mode::intra_object;
        spec.samples = 1500 + 500 * static_cast<std::size_t>(i);
        inputs.push_back(random_input(spec));
        expected.push_back(run_ok(*m_cpu, inputs.back()));
    }
    std::vector<std::vector<KernelOutput>> got(THREADS);
    std::vector<std::vector<Status>> status(THREADS);
    std::vector<std::thread> threads;
    for (int i = 0; i < THREADS; ++i) {
        threads.emplace_back([&, i] {
            for (int r = 0; r < RUNS; ++r) {
                // Each thread alternates its own input with its neighbour's.
                const int which = (i + r) % THREADS;
                KernelOutput out;
                status[i].push_back(m_gpu->run(inputs[which], out));
                got[i].push_back(std::move(out));
            }
        });
    }
    for (auto& t : threads) {
        t.join();
    }
    for (int i = 0; i < THREADS; ++i) {
        for (int r = 0; r < RUNS; ++r) {
            ASSERT_TRUE(status[i][r].ok()) << status[i][r].to_string();
            expect_identical(expected[(i + r) % THREADS], got[i][r],
                             "thread " + std::to_string(i) + " run " + std::to_string(r));
        }
    }
}

// Backends come and go independently: destroying one (with or without runs) leaves the display
// and the other contexts working.
TEST_F(DvdGpu, DestructionIsClean) {
    {
        auto idle = gpu::make_egl_backend();
        ASSERT_TRUE(idle.ok()) << idle.status().to_string();
    }
    RandomSpec spec;
    spec.seed = 17;
    spec.samples = 300;
    const KernelInput in = random_input(spec);
    const KernelOutput cpu = run_ok(*m_cpu, in);
    {
        auto used = gpu::make_egl_backend();
        ASSERT_TRUE(used.ok()) << used.status().to_string();
        expect_identical(cpu, run_ok(*used.value(), in), "second backend");
        expect_identical(cpu, run_ok(*used.value(), in), "second backend, again");
    }
    expect_identical(cpu, run_ok(*m_gpu, in), "shared backend after others were destroyed");
}

// --- Context loss (EglOptions::lose_context_after_jobs, PROXIMA_EGL_LOSE_CONTEXT_AFTER) and the
// failover backend. The hook ends a job exactly where a real reset is noticed, so these run the
// real loss path: the job fails, the context is destroyed, the backend stays lost.

std::shared_ptr<dvd::Backend> egl_losing_after(std::uint64_t jobs) {
    gpu::EglOptions options;
    options.lose_context_after_jobs = jobs;
    auto made = gpu::make_egl_backend(options);
    EXPECT_TRUE(made.ok()) << made.status().to_string();
    return made.ok() ? made.value() : nullptr;
}

// Inputs of both modes and several sizes, with their CPU outputs.
struct Cases {
    std::vector<KernelInput> inputs;
    std::vector<KernelOutput> expected;
};

Cases make_cases(dvd::Backend& cpu, int count, std::uint32_t seed) {
    Cases c;
    for (int i = 0; i < count; ++i) {
        RandomSpec spec;
        spec.seed = seed + static_cast<std::uint32_t>(i);
        spec.mode = i % 2 == 0 ? Mode::inter_object : Mode::intra_object;
        spec.objects = spec.mode == Mode::intra_object ? 1 : 3;
        spec.samples = 400 + 150 * static_cast<std::size_t>(i % 5);
        c.inputs.push_back(random_input(spec));
        c.expected.push_back(run_ok(cpu, c.inputs.back()));
    }
    return c;
}

TEST_F(DvdGpu, LostContextFailsTheJobAndStaysLost) {
    const Cases cases = make_cases(*m_cpu, 3, 300);
    auto losing = egl_losing_after(2);
    ASSERT_TRUE(losing);
    EXPECT_EQ(losing->lost_reason(), "");
    expect_identical(cases.expected[0], run_ok(*losing, cases.inputs[0]), "job 1");
    expect_identical(cases.expected[1], run_ok(*losing, cases.inputs[1]), "job 2");
    EXPECT_EQ(losing->lost_reason(), "");

    KernelOutput out;
    const Status third = losing->run(cases.inputs[2], out);
    EXPECT_EQ(third.code(), StatusCode::unavailable) << third.to_string();
    EXPECT_NE(third.message().find("GL context reset (GL_UNKNOWN_CONTEXT_RESET)"),
              std::string::npos)
        << third.message();
    const std::string reason = losing->lost_reason();
    EXPECT_NE(reason.find("GL_UNKNOWN_CONTEXT_RESET"), std::string::npos) << reason;
    EXPECT_NE(reason.find("simulated after 2 jobs (EglOptions::lose_context_after_jobs=2)"),
              std::string::npos)
        << reason;

    // Lost for good: no job runs again, not even the ones that worked before.
    for (int i = 0; i < 2; ++i) {
        const Status again = losing->run(cases.inputs[i], out);
        EXPECT_EQ(again.code(), StatusCode::unavailable) << again.to_string();
        EXPECT_NE(again.message().find("GPU context lost earlier: " + reason), std::string::npos)
            << again.message();
    }
    EXPECT_EQ(losing->lost_reason(), reason);
    // Input errors are still reported as such.
    KernelInput bad = cases.inputs[0];
    bad.sample_owner[0] = 1u << 30;
    EXPECT_EQ(losing->run(bad, out).code(), StatusCode::invalid_argument);

    // The lost backend gave its context back; the display and the suite's backend still work.
    losing.reset();
    expect_identical(cases.expected[2], run_ok(*m_gpu, cases.inputs[2]), "other backend");
}

TEST_F(DvdGpu, LosingAtTheFirstJobAndThroughTheEnvironment) {
    const Cases cases = make_cases(*m_cpu, 2, 320);
    auto at_once = egl_losing_after(0);
    ASSERT_TRUE(at_once);
    KernelOutput out;
    EXPECT_EQ(at_once->run(cases.inputs[0], out).code(), StatusCode::unavailable);
    EXPECT_NE(at_once->lost_reason().find("simulated after 0 jobs"), std::string::npos)
        << at_once->lost_reason();

    setenv("PROXIMA_EGL_LOSE_CONTEXT_AFTER", "1", 1);
    auto from_env = gpu::make_egl_backend();
    unsetenv("PROXIMA_EGL_LOSE_CONTEXT_AFTER");
    ASSERT_TRUE(from_env.ok()) << from_env.status().to_string();
    expect_identical(cases.expected[0], run_ok(*from_env.value(), cases.inputs[0]), "env job 1");
    EXPECT_EQ(from_env.value()->run(cases.inputs[1], out).code(), StatusCode::unavailable);
    EXPECT_NE(from_env.value()->lost_reason().find("(PROXIMA_EGL_LOSE_CONTEXT_AFTER=1)"),
              std::string::npos)
        << from_env.value()->lost_reason();

    for (const char* bad : {"x", "3 jobs", "-1"}) {
        setenv("PROXIMA_EGL_LOSE_CONTEXT_AFTER", bad, 1);
        auto refused = gpu::make_egl_backend();
        unsetenv("PROXIMA_EGL_LOSE_CONTEXT_AFTER");
        ASSERT_FALSE(refused.ok()) << bad;
        EXPECT_EQ(refused.status().code(), StatusCode::invalid_argument) << bad;
    }
}

TEST_F(DvdGpu, FailoverRunsEveryJobAfterTheLossOnTheCpu) {
    const Cases cases = make_cases(*m_cpu, 8, 340);
    std::vector<std::string> events;
    auto failover = gpu::make_failover_backend(
        egl_losing_after(3), m_cpu, [&](const std::string& reason) { events.push_back(reason); });
    EXPECT_TRUE(failover->is_gpu());
    EXPECT_EQ(failover->name(), m_gpu->name());
    for (int i = 0; i < 8; ++i) {
        expect_identical(cases.expected[i], run_ok(*failover, cases.inputs[i]),
                         "job " + std::to_string(i + 1));
        const dvd::BackendStats st = failover->stats();
        EXPECT_EQ(st.gpu_active, i < 3) << "after job " << i + 1;
        EXPECT_EQ(st.gpu_jobs, static_cast<std::uint64_t>(std::min(i + 1, 3)));
        EXPECT_EQ(st.cpu_jobs, static_cast<std::uint64_t>(std::max(i + 1 - 3, 0)));
    }
    const dvd::BackendStats st = failover->stats();
    EXPECT_FALSE(st.gpu_active);
    EXPECT_NE(st.fallback_reason.find("GL context reset (GL_UNKNOWN_CONTEXT_RESET)"),
              std::string::npos)
        << st.fallback_reason;
    EXPECT_GT(st.gpu_seconds, 0.0);
    EXPECT_GT(st.cpu_seconds, 0.0);
    ASSERT_EQ(events.size(), 1u);  // logged once, with the stats' reason
    EXPECT_EQ(events[0], st.fallback_reason);
    EXPECT_FALSE(failover->is_gpu());
    EXPECT_EQ(failover->name(), "cpu (gpu lost: " + st.fallback_reason + ")");

    // A malformed input is refused as before and counts nowhere.
    KernelInput bad = cases.inputs[0];
    bad.bucket_offsets.pop_back();
    KernelOutput out;
    EXPECT_EQ(failover->run(bad, out).code(), StatusCode::invalid_argument);
    EXPECT_EQ(failover->stats().cpu_jobs, st.cpu_jobs);
}

TEST_F(DvdGpu, ConcurrentJobsAcrossTheLossAllMatchTheCpu) {
    constexpr int THREADS = 4;
    constexpr int RUNS = 8;
    constexpr std::uint64_t LOSE_AFTER = 7;
    const Cases cases = make_cases(*m_cpu, THREADS, 360);
    std::atomic<int> events{0};
    auto failover = gpu::make_failover_backend(egl_losing_after(LOSE_AFTER), m_cpu,
                                               [&](const std::string&) { ++events; });
    std::vector<std::vector<KernelOutput>> got(THREADS);
    std::vector<std::vector<Status>> status(THREADS);
    std::vector<std::thread> threads;
    for (int i = 0; i < THREADS; ++i) {
        threads.emplace_back([&, i] {
            for (int r = 0; r < RUNS; ++r) {
                KernelOutput out;
                status[i].push_back(failover->run(cases.inputs[(i + r) % THREADS], out));
                got[i].push_back(std::move(out));
            }
        });
    }
    for (auto& t : threads) {
        t.join();
    }
    for (int i = 0; i < THREADS; ++i) {
        for (int r = 0; r < RUNS; ++r) {
            ASSERT_TRUE(status[i][r].ok()) << status[i][r].to_string();
            expect_identical(cases.expected[(i + r) % THREADS], got[i][r],
                             "thread " + std::to_string(i) + " run " + std::to_string(r));
        }
    }
    // The context thread runs jobs one at a time, so exactly LOSE_AFTER reached the GPU in time;
    // the others (queued behind the lost one, or posted after) ran on the CPU.
    const dvd::BackendStats st = failover->stats();
    EXPECT_FALSE(st.gpu_active);
    EXPECT_EQ(st.gpu_jobs, LOSE_AFTER);
    EXPECT_EQ(st.cpu_jobs, THREADS * RUNS - LOSE_AFTER);
    EXPECT_EQ(events.load(), 1);
}

// The failover policy on its own, with a scripted "GPU" (the CPU kernel behind a switch), so it
// is tested on machines without EGL too.
class ScriptedGpu final : public dvd::Backend {
  public:
    std::string name() const override { return "gpu (scripted)"; }
    bool is_gpu() const override { return true; }
    Status run(const KernelInput& input, KernelOutput& output) override {
        if (Status s = dvd::validate(input); !s.ok()) {
            return s;
        }
        ++m_calls;
        if (m_lost) {
            return {StatusCode::unavailable, "lost"};
        }
        if (m_decline_next) {
            m_decline_next = false;
            return {StatusCode::resource_exhausted, "over a GPU limit"};
        }
        if (m_lose_next) {
            m_lost = true;
            return {StatusCode::internal, "GPU kernel: dispatching the kernel failed"};
        }
        return m_cpu->run(input, output);
    }
    std::string lost_reason() const override { return m_lost ? "device reset (scripted)" : ""; }

    std::shared_ptr<dvd::Backend> m_cpu = dvd::make_cpu_backend();
    bool m_decline_next = false;
    bool m_lose_next = false;
    bool m_lost = false;
    int m_calls = 0;
};

TEST(DvdFailover, DeclinedJobsRunOnTheCpuAndALossSwitchesForGood) {
    auto cpu = dvd::make_cpu_backend();
    RandomSpec spec;
    spec.seed = 380;
    spec.samples = 500;
    const KernelInput in = random_input(spec);
    const KernelOutput expected = run_ok(*cpu, in);
    auto scripted = std::make_shared<ScriptedGpu>();
    int events = 0;
    auto failover =
        gpu::make_failover_backend(scripted, cpu, [&](const std::string&) { ++events; });
    EXPECT_EQ(failover->name(), "gpu (scripted)");

    expect_identical(expected, run_ok(*failover, in), "on the GPU");
    scripted->m_decline_next = true;  // one job refused, the GPU still working
    expect_identical(expected, run_ok(*failover, in), "declined");
    dvd::BackendStats st = failover->stats();
    EXPECT_TRUE(st.gpu_active);
    EXPECT_EQ(st.fallback_reason, "");
    EXPECT_EQ(st.gpu_jobs, 1u);
    EXPECT_EQ(st.cpu_jobs, 1u);
    expect_identical(expected, run_ok(*failover, in), "on the GPU again");
    EXPECT_EQ(scripted->m_calls, 3);
    EXPECT_EQ(events, 0);

    scripted->m_lose_next = true;
    expect_identical(expected, run_ok(*failover, in), "the job that lost the GPU");
    expect_identical(expected, run_ok(*failover, in), "after the loss");
    st = failover->stats();
    EXPECT_FALSE(st.gpu_active);
    EXPECT_EQ(st.fallback_reason, "device reset (scripted)");
    EXPECT_EQ(st.gpu_jobs, 2u);
    EXPECT_EQ(st.cpu_jobs, 3u);
    EXPECT_EQ(scripted->m_calls, 4);  // the job after the loss never went to the GPU
    EXPECT_EQ(events, 1);
    EXPECT_EQ(failover->name(), "cpu (gpu lost: device reset (scripted))");
    EXPECT_FALSE(failover->is_gpu());

    KernelInput bad = in;
    bad.sample_points.pop_back();
    KernelOutput out;
    EXPECT_EQ(failover->run(bad, out).code(), StatusCode::invalid_argument);
    EXPECT_EQ(failover->stats().cpu_jobs, 3u);
}

// Forced failure and the environment switch: `unavailable` with the reason, no context.
TEST(DvdGpuUnavailable, ForcedFailureAndEnvironment) {
    gpu::EglOptions options;
    options.force_failure = true;
    auto forced = gpu::make_egl_backend(options);
    ASSERT_FALSE(forced.ok());
    EXPECT_EQ(forced.status().code(), StatusCode::unavailable);
    EXPECT_NE(forced.status().message().find("EGL disabled"), std::string::npos)
        << forced.status().message();

    setenv("PROXIMA_DISABLE_EGL", "1", 1);
    auto disabled = gpu::make_egl_backend();
    unsetenv("PROXIMA_DISABLE_EGL");
    ASSERT_FALSE(disabled.ok());
    EXPECT_EQ(disabled.status().code(), StatusCode::unavailable);
    EXPECT_NE(disabled.status().message().find("PROXIMA_DISABLE_EGL"), std::string::npos)
        << disabled.status().message();
}

}  // namespace
}  // namespace proxima
