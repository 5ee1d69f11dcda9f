// proxima_dvd_gpu_bench: the discrete-Voronoi kernel (proxima/culling/dvd.hpp) on the GPU backend
// (whatever gpu::make_egl_backend() gives: Mesa llvmpipe on a machine without a GPU, the NVIDIA
// driver on an NVIDIA machine) against the CPU backend, on kernel inputs built like the culler's
// from the skirt scene (seed 000's skirt: a 200 x 175 x 45 grid). Times include everything a
// run() does: validation, packing, upload, dispatch and readback (GPU); the whole parallel loop
// (CPU). It also says whether the two outputs are identical bit-for-bit (they must be on
// llvmpipe; on a GPU, sqrt and division may differ by a few ulp, see docs/algorithms.md).
//
//   proxima_dvd_gpu_bench [--dims X,Y,Z] [--reps N] [--radius-cells R] [--bucket-cells B]
//                         [--scene NAME] [--quick]
//
// Samples: for every triangle f, the grid points within half a cell diagonal of f (the culler's
// Q_f), owner f. Inter-object mode over all objects of the scene, then intra-object mode on the
// largest object (the cloth).

#include <sched.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <string>
#include <vector>

#include "proxima/culling/dvd.hpp"
#include "proxima/distance/primitives.hpp"
#include "proxima/gpu/egl_backend.hpp"
#include "proxima/scenes/procedural.hpp"

#include "bench_util.hpp"

namespace {

using namespace proxima;

struct Options {
    std::array<std::uint32_t, 3> dims = {200, 175, 45};
    int reps = 5;
    double radius_cells = 4.0;
    double bucket_cells = 4.0;
    std::string scene = "skirt";
};

int usage(const char* argv0, int code) {
    std::fprintf(code == 0 ? stdout : stderr,
                 "usage: %s [--dims X,Y,Z] [--reps N] [--radius-cells R] [--bucket-cells B]\n"
                 "          [--scene NAME] [--quick]\n"
                 "  --dims          grid points per axis over the scene box (default 200,175,45)\n"
                 "  --reps          timed runs per backend after one warm-up (default 5)\n"
                 "  --radius-cells  search radius in grid cells (default 4)\n"
                 "  --bucket-cells  bucket edge in grid cells (default 4)\n"
                 "  --scene         procedural scene (default skirt)\n"
                 "  --quick         a 100,88,23 grid, radius and buckets 2 cells, 1 rep (smoke)\n",
                 argv0);
    return code;
}

std::string machine() {
    cpu_set_t set;
    CPU_ZERO(&set);
    const int cpus = sched_getaffinity(0, sizeof set, &set) == 0 ? CPU_COUNT(&set) : 0;
    const std::string model = bench::cpu_model();
    const std::string load = bench::load_average();
    const std::time_t now = std::time(nullptr);
    char date[64];
    std::strftime(date, sizeof date, "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
    return std::to_string(cpus) + " CPUs (affinity), " + model + ", load " + load + ", " + date;
}

struct Geometry {
    std::vector<Triangle> triangles;
    std::vector<std::array<std::uint32_t, 3>> indices;  // vertex ids, unique per object
    std::vector<std::uint32_t> object;
};

// Kernel input from `g` on a grid of `dims` points over its box, coordinates relative to the grid
// origin; every triangle owns the grid points within half a cell diagonal of it.
dvd::KernelInput build_input(const Geometry& g, const Options& opt, dvd::Mode mode,
                             double* cell_out) {
    Vec3 lo{1e300, 1e300, 1e300};
    Vec3 hi{-1e300, -1e300, -1e300};
    for (const auto& t : g.triangles) {
        for (const auto& v : t) {
            lo = {std::min(lo.x, v.x), std::min(lo.y, v.y), std::min(lo.z, v.z)};
            hi = {std::max(hi.x, v.x), std::max(hi.y, v.y), std::max(hi.z, v.z)};
        }
    }
    // Cell size: the grid of dims points covers the box on every axis.
    double h = 0.0;
    for (int k = 0; k < 3; ++k) {
        h = std::max(h, (hi[k] - lo[k]) / static_cast<double>(opt.dims[k] - 1));
    }
    *cell_out = h;
    const double radius = opt.radius_cells * h;
    const double bucket = opt.bucket_cells * h;

    dvd::KernelInput in;
    in.mode = mode;
    in.radius = static_cast<float>(radius);
    in.bucket_origin = {0.0f, 0.0f, 0.0f};  // coordinates are relative to the grid origin `lo`
    in.bucket_size = static_cast<float>(bucket);
    for (int k = 0; k < 3; ++k) {
        in.bucket_dims[k] = static_cast<std::uint32_t>(std::ceil((hi[k] - lo[k]) / bucket)) + 1;
    }
    const auto& bd = in.bucket_dims;
    std::vector<std::vector<std::uint32_t>> lists(std::size_t{bd[0]} * bd[1] * bd[2]);
    auto bucket_of = [&](double x, int k) {
        const double f = std::floor(x / bucket);
        return static_cast<std::uint32_t>(std::clamp(f, 0.0, static_cast<double>(bd[k] - 1)));
    };
    for (std::uint32_t t = 0; t < g.triangles.size(); ++t) {
        const auto& tri = g.triangles[t];
        for (const auto& v : tri) {
            for (int k = 0; k < 3; ++k) {
                in.triangle_vertices.push_back(static_cast<float>(v[k] - lo[k]));
            }
        }
        in.triangle_indices.insert(in.triangle_indices.end(), g.indices[t].begin(),
                                   g.indices[t].end());
        in.triangle_object.push_back(g.object[t]);
        std::array<std::uint32_t, 3> b0{};
        std::array<std::uint32_t, 3> b1{};
        for (int k = 0; k < 3; ++k) {
            const double mn = std::min({tri[0][k], tri[1][k], tri[2][k]}) - lo[k];
            const double mx = std::max({tri[0][k], tri[1][k], tri[2][k]}) - lo[k];
            b0[k] = bucket_of(mn - radius, k);
            b1[k] = bucket_of(mx + radius, k);
        }
        for (std::uint32_t z = b0[2]; z <= b1[2]; ++z) {
            for (std::uint32_t y = b0[1]; y <= b1[1]; ++y) {
                for (std::uint32_t x = b0[0]; x <= b1[0]; ++x) {
                    lists[x + bd[0] * (y + bd[1] * z)].push_back(t);
                }
            }
        }
    }
    in.bucket_offsets.push_back(0);
    for (const auto& l : lists) {
        in.bucket_triangles.insert(in.bucket_triangles.end(), l.begin(), l.end());
        in.bucket_offsets.push_back(static_cast<std::uint32_t>(in.bucket_triangles.size()));
    }

    // Q_f: grid points within half a cell diagonal of f.
    const double reach = 0.5 * std::sqrt(3.0) * h;
    for (std::uint32_t t = 0; t < g.triangles.size(); ++t) {
        const auto& tri = g.triangles[t];
        std::array<long, 3> g0{};
        std::array<long, 3> g1{};
        for (int k = 0; k < 3; ++k) {
            const double mn = std::min({tri[0][k], tri[1][k], tri[2][k]}) - lo[k] - reach;
            const double mx = std::max({tri[0][k], tri[1][k], tri[2][k]}) - lo[k] + reach;
            g0[k] = std::max(0L, static_cast<long>(std::ceil(mn / h)));
            g1[k] = std::min(static_cast<long>(opt.dims[k] - 1), static_cast<long>(mx / h));
        }
        for (long z = g0[2]; z <= g1[2]; ++z) {
            for (long y = g0[1]; y <= g1[1]; ++y) {
                for (long x = g0[0]; x <= g1[0]; ++x) {
                    const Vec3 q{lo.x + static_cast<double>(x) * h,
                                 lo.y + static_cast<double>(y) * h,
                                 lo.z + static_cast<double>(z) * h};
                    if (point_triangle(q, tri[0], tri[1], tri[2]).squared_distance >
                        reach * reach) {
                        continue;
                    }
                    const double rel[3] = {static_cast<double>(x) * h, static_cast<double>(y) * h,
                                           static_cast<double>(z) * h};
                    for (double r : rel) {
                        in.sample_points.push_back(static_cast<float>(r));
                    }
                    in.sample_owner.push_back(t);
                    in.sample_bucket.push_back(
                        bucket_of(rel[0], 0) +
                        bd[0] * (bucket_of(rel[1], 1) + bd[1] * bucket_of(rel[2], 2)));
                }
            }
        }
    }
    return in;
}

struct Timing {
    double median_ms = 0.0;
    double min_ms = 0.0;
    Status status;
};

Timing time_backend(dvd::Backend& backend, const dvd::KernelInput& in, dvd::KernelOutput& out,
                    int reps) {
    Timing t;
    t.status = backend.run(in, out);  // warm-up: buffers grow, shaders are compiled
    if (!t.status.ok()) {
        return t;
    }
    std::vector<double> ms;
    for (int r = 0; r < reps; ++r) {
        const auto start = std::chrono::steady_clock::now();
        t.status = backend.run(in, out);
        ms.push_back(
            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                .count());
        if (!t.status.ok()) {
            return t;
        }
    }
    std::sort(ms.begin(), ms.end());
    t.median_ms = ms[ms.size() / 2];
    t.min_ms = ms.front();
    return t;
}

void compare(const dvd::KernelOutput& a, const dvd::KernelOutput& b) {
    std::size_t differ = 0;
    std::size_t nearest_differ = 0;
    double max_rel = 0.0;
    for (std::size_t i = 0; i < a.distance.size(); ++i) {
        std::uint32_t x;
        std::uint32_t y;
        std::memcpy(&x, &a.distance[i], 4);
        std::memcpy(&y, &b.distance[i], 4);
        if (x != y) {
            ++differ;
            if (std::isfinite(a.distance[i]) && std::isfinite(b.distance[i]) &&
                a.distance[i] > 0.0f) {
                max_rel =
                    std::max(max_rel, std::abs(static_cast<double>(a.distance[i]) - b.distance[i]) /
                                          a.distance[i]);
            }
        }
        nearest_differ += a.nearest[i] != b.nearest[i] ? 1 : 0;
    }
    if (differ == 0 && nearest_differ == 0) {
        std::printf("  outputs: identical bit-for-bit (%zu samples)\n", a.distance.size());
    } else {
        std::printf("  outputs: %zu distances differ (max relative %.3g), %zu nearest differ\n",
                    differ, max_rel, nearest_differ);
    }
}

}  // namespace

int main(int argc, char** argv) {
    Options opt;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto next = [&]() -> const char* {
            if (i + 1 >= argc) {
                std::exit(usage(argv[0], 2));
            }
            return argv[++i];
        };
        if (a == "--dims") {
            unsigned x = 0;
            unsigned y = 0;
            unsigned z = 0;
            if (std::sscanf(next(), "%u,%u,%u", &x, &y, &z) != 3 || x < 2 || y < 2 || z < 2) {
                return usage(argv[0], 2);
            }
            opt.dims = {x, y, z};
        } else if (a == "--reps") {
            opt.reps = std::max(1, std::atoi(next()));
        } else if (a == "--radius-cells") {
            opt.radius_cells = std::atof(next());
        } else if (a == "--bucket-cells") {
            opt.bucket_cells = std::atof(next());
        } else if (a == "--scene") {
            opt.scene = next();
        } else if (a == "--quick") {
            opt.dims = {100, 88, 23};
            opt.radius_cells = 2.0;
            opt.bucket_cells = 2.0;
            opt.reps = 1;
        } else if (a == "--help" || a == "-h") {
            return usage(argv[0], 0);
        } else {
            return usage(argv[0], 2);
        }
    }
    if (opt.radius_cells <= 0.0 || opt.bucket_cells <= 0.0) {
        return usage(argv[0], 2);
    }
    setenv("MESA_SHADER_CACHE_DISABLE", "true", 0);

    const auto scene = scenes::by_name(opt.scene, 1);
    if (scene.name.empty()) {
        std::fprintf(stderr, "unknown scene '%s'\n", opt.scene.c_str());
        return 2;
    }
    Geometry all;
    Geometry largest;
    std::size_t largest_index = 0;
    for (std::size_t o = 0; o < scene.initial.size(); ++o) {
        if (scene.initial[o].mesh.triangles.size() >
            scene.initial[largest_index].mesh.triangles.size()) {
            largest_index = o;
        }
    }
    std::uint32_t base = 0;
    for (std::uint32_t o = 0; o < scene.initial.size(); ++o) {
        const auto& mesh = scene.initial[o].mesh;
        for (const auto& t : mesh.triangles) {
            const Triangle tri = {mesh.vertices[t[0]], mesh.vertices[t[1]], mesh.vertices[t[2]]};
            all.triangles.push_back(tri);
            all.indices.push_back({base + t[0], base + t[1], base + t[2]});
            all.object.push_back(o);
            if (o == largest_index) {
                largest.triangles.push_back(tri);
                largest.indices.push_back(t);
                largest.object.push_back(0);
            }
        }
        base += static_cast<std::uint32_t>(mesh.vertices.size());
    }

    std::printf(
        "proxima_dvd_gpu_bench: scene %s (%zu objects, %zu triangles), grid %ux%ux%u, "
        "radius %.1f cells, buckets %.1f cells, %d reps (median, min)\n",
        scene.name.c_str(), scene.initial.size(), all.triangles.size(), opt.dims[0], opt.dims[1],
        opt.dims[2], opt.radius_cells, opt.bucket_cells, opt.reps);
    std::printf("machine: %s\n", machine().c_str());

    auto cpu = dvd::make_cpu_backend();
    const auto t0 = std::chrono::steady_clock::now();
    auto gpu = gpu::make_egl_backend();
    const double start_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    if (gpu.ok()) {
        std::printf("gpu backend: %s (context + kernel compile %.0f ms)\n",
                    gpu.value()->name().c_str(), start_ms);
    } else {
        std::printf("gpu backend: unavailable: %s\n", gpu.status().to_string().c_str());
    }

    int failures = 0;
    for (dvd::Mode mode : {dvd::Mode::inter_object, dvd::Mode::intra_object}) {
        const bool inter = mode == dvd::Mode::inter_object;
        double h = 0.0;
        const auto in = build_input(inter ? all : largest, opt, mode, &h);
        double visits = 0.0;  // bucket entries each sample scans
        for (auto b : in.sample_bucket) {
            visits += in.bucket_offsets[b + 1] - in.bucket_offsets[b];
        }
        std::printf(
            "%s: %zu triangles, %zu samples, cell %.4g, %zu buckets, %zu bucket entries, "
            "%.0f triangles scanned per sample\n",
            inter ? "inter-object (all objects)" : "intra-object (largest object)",
            in.triangle_object.size(), in.sample_owner.size(), h, in.bucket_offsets.size() - 1,
            in.bucket_triangles.size(),
            in.sample_owner.empty() ? 0.0 : visits / in.sample_owner.size());
        dvd::KernelOutput cpu_out;
        const Timing c = time_backend(*cpu, in, cpu_out, opt.reps);
        if (!c.status.ok()) {
            std::printf("  cpu: %s\n", c.status.to_string().c_str());
            ++failures;
            continue;
        }
        std::printf("  %-44s %9.2f ms  (min %.2f)\n", cpu->name().c_str(), c.median_ms, c.min_ms);
        if (!gpu.ok()) {
            continue;
        }
        dvd::KernelOutput gpu_out;
        const Timing g = time_backend(*gpu.value(), in, gpu_out, opt.reps);
        if (!g.status.ok()) {
            std::printf("  gpu: %s\n", g.status.to_string().c_str());
            ++failures;
            continue;
        }
        std::printf("  %-44s %9.2f ms  (min %.2f)\n", gpu.value()->name().c_str(), g.median_ms,
                    g.min_ms);
        compare(cpu_out, gpu_out);
    }
    return failures == 0 ? 0 : 1;
}
