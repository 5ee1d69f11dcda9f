// The discrete-Voronoi culler (seed 000 §4-5.2) in our terms.
//
// Grid and samples. A uniform grid of cell size h (points (i h, j h, k h)). For a triangle f,
// Q_f = the grid points within rho = h*sqrt(3)/2 of f (computed in double, rho widened by the
// rounding slack): every point x of f lies in some cell, within half its diagonal of one of the
// cell's corners, and that corner is then within rho of f, so it is in Q_f (seed §4.4: sampling
// the site grown by a cell, the Minkowski sum). Q_f is the site's sampling.
//
// Kernel (proxima/culling/dvd.hpp). For each sample q of f, D(q) = the single-precision distance
// from q to the closest *eligible* triangle within the band radius R (the second-order discrete
// Voronoi diagram at q: the closest site other than f's own), or R when there is none. With
// eps = kernel_error_bound + the largest triangle_error_term, dist(q, S_f) >= D(q) - eps for the
// eligible set S_f (when nothing is within R, nothing is closer than R - eps either).
//
// Lemma 2 in our terms. Distance to a set is 1-Lipschitz, so for every x on f and its corner q:
// dist(x, S_f) >= dist(q, S_f) - rho. Hence the lower bound
//     L(f) = min_{q in Q_f} D(q) - rho - eps  <=  dist(f, S_f),
// and the upper bound (no float involved: recomputed in double for the best sample q* and the
// triangle g the kernel found there)
//     U(f) = d(q*, f) + d(q*, g)  >=  dist(f, S_f).
// Lemma 1 (the closest site of f is among the second-order governors of its points) is why g is
// the partner to try first for f: it is exactly f's closest triangle when the grid is fine enough.
//
// How the bounds are used (the culler only ever removes pairs; the query's exact tests decide):
//   separation: eligible = other objects' triangles. U(O) = min_f U(f) lowers Stage I's upper
//     bound of object O (so fewer objects are searched); in nearest_between a triangle pair is
//     dropped when L of either triangle reaches the current pair bound (the seed's feature-level
//     PNS: a triangle farther from every other object than the bound cannot be the closest).
//   tolerance / collisions / PNS with radius r: eligible = every non-adjacent triangle of any
//     object (one intra-mode run with scene-wide vertex ids): a pair (t, u) is dropped when
//     L(t) or L(u) exceeds r (both are lower bounds on dist(t, u)).
//   self: eligible = non-adjacent triangles of the same object; the kernel's g for the best
//     sample of each triangle seeds that triangle's bound with one exact test (Lemma 1), and the
//     BVH traversal then finds every pair that can still beat or tie it. (L cannot cull a self
//     pair: a triangle's own bound is never below its lower bound.)
// Everything downstream of the kernel is a deterministic function of its output and of the
// double-precision geometry, so two backends with equal output give equal PNS.
//
// Band radius: separation uses the largest Stage I upper bound, capped at SEPARATION_BAND cells
// (a larger band only makes L larger where it is already above every bound); within-radius
// queries use r + 2 rho (L can then exceed r); self uses SELF_BAND cells.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "culling/cullers.hpp"
#include "proxima/distance/bounds.hpp"
#include "proxima/distance/primitives.hpp"

namespace proxima::detail {

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Cell size = factor * median edge length (tuned with proxima_dvd_bench; docs/algorithms.md).
constexpr double SEPARATION_CELL_FACTOR = 1.0;
constexpr double SELF_CELL_FACTOR = 0.5;
constexpr double WITHIN_CELL_FACTOR = 0.25;
// Band radii in cells.
constexpr double SEPARATION_BAND = 2.0;
constexpr double SELF_BAND = 2.0;
// Limits that keep one kernel run's memory bounded.
constexpr std::uint64_t MAX_BUCKETS = std::uint64_t{1} << 22;
constexpr std::int64_t GRID_HALF_RANGE = std::int64_t{1} << 20;  // 21-bit grid coordinates

struct Job {
    dvd::Mode mode = dvd::Mode::inter_object;
    std::vector<std::size_t> objects;  // scene indices; triangles numbered in this order
    double cell = 1.0;
    double radius = 1.0;
};

// Sampling visits every grid point of every triangle's grown box. Far-apart coordinates with a
// small cell (fuzz_frames: one vertex at -9.3e61) make those boxes hundreds of thousands of cells
// long, and the sampling loop ran for 22 s under ASan against a 100 ms deadline. A job whose boxes
// hold more grid points than this (a base plus an average per triangle; meshes at the median-edge
// cell use tens to hundreds per triangle) is skipped: the culler then leaves every bound to the
// BVH, which gives the same answers. Small scenes asked for a fine cell are skipped too: for them
// the BVH alone is faster than sampling a quarter of a million points.
constexpr std::uint64_t MAX_GRID_POINTS_BASE = std::uint64_t{1} << 18;
constexpr std::uint64_t MAX_GRID_POINTS_PER_TRIANGLE = 1024;

struct JobResult {
    bool skipped = false;                // the sampling bound was exceeded; nothing else is set
    std::vector<std::size_t> offsets;    // first job triangle of each job object
    std::vector<double> lower;           // L(f)
    std::vector<double> upper;           // U(f), +inf when no sample found an eligible triangle
    std::vector<std::uint32_t> partner;  // job triangle index, or NO_TRIANGLE
    VoronoiStats stats;
};

struct Entry {
    std::uint64_t key;     // packed grid point
    std::uint32_t owner;   // job triangle
    std::uint32_t object;  // job object
    double dist;           // d(q, owner) in double
};

std::uint64_t pack(std::int64_t i, std::int64_t j, std::int64_t k) {
    return (static_cast<std::uint64_t>(i + GRID_HALF_RANGE) << 42) |
           (static_cast<std::uint64_t>(j + GRID_HALF_RANGE) << 21) |
           static_cast<std::uint64_t>(k + GRID_HALF_RANGE);
}

Vec3 unpack(std::uint64_t key, double h) {
    const auto mask = (std::uint64_t{1} << 21) - 1;
    const auto i = static_cast<std::int64_t>(key >> 42) - GRID_HALF_RANGE;
    const auto j = static_cast<std::int64_t>((key >> 21) & mask) - GRID_HALF_RANGE;
    const auto k = static_cast<std::int64_t>(key & mask) - GRID_HALF_RANGE;
    return {static_cast<double>(i) * h, static_cast<double>(j) * h, static_cast<double>(k) * h};
}

// The grid of one run: cell h, sampling radius rho, band radius and the rounding slack.
struct Grid {
    double h = 1.0;
    double rho = 0.0;
    double radius = 1.0;
    double slack = 0.0;
};

// The best sample of each triangle so far (for U(f) and its partner).
struct BestSamples {
    std::vector<double> score;
    std::vector<std::uint32_t> sample;
    std::vector<double> dist;
};

// The bucket grid over the sampled region: its origin, bucket size and dimensions.
struct Buckets {
    Aabb sampled;
    double size = 1.0;
    std::array<std::uint32_t, 3> dims{};

    // The bucket coordinate of x along axis a, clamped to the grid.
    std::uint32_t coord(double x, int a) const {
        const double c = std::floor((x - sampled.lo[a]) / size);
        if (std::isnan(c)) {
            return std::uint32_t{0};  // unreachable with the finite boxes checked in step 0
        }
        return static_cast<std::uint32_t>(std::clamp(c, 0.0, static_cast<double>(dims[a] - 1)));
    }
    // The flattened bucket number of (i, j, k).
    std::uint64_t flat(std::uint32_t i, std::uint32_t j, std::uint32_t k) const {
        return i + dims[0] * (std::uint64_t{j} + std::uint64_t{dims[1]} * k);
    }
    // The number of buckets.
    std::uint64_t count() const { return std::uint64_t{dims[0]} * dims[1] * dims[2]; }
};

// Numbers the job's triangles (each object's first one) and resets the bounds; returns the count.
std::size_t reset_result(const Scene& scene, const Job& job, JobResult& out) {
    const std::size_t nobj = job.objects.size();
    out.offsets.assign(nobj + 1, 0);
    for (std::size_t k = 0; k < nobj; ++k) {
        out.offsets[k + 1] = out.offsets[k] + scene[job.objects[k]].triangle_count();
    }
    const std::size_t nt = out.offsets[nobj];
    out.lower.assign(nt, -std::numeric_limits<double>::infinity());
    out.upper.assign(nt, std::numeric_limits<double>::infinity());
    out.partner.assign(nt, dvd::NO_TRIANGLE);
    return nt;
}

// Copies the job's triangles (and each one's job object) in job order; returns the region's box.
Aabb gather_triangles(const Scene& scene, const Job& job, const std::vector<std::size_t>& offsets,
                      std::vector<Triangle>& tris, std::vector<std::uint32_t>& tri_object) {
    const std::size_t nobj = job.objects.size();
    Aabb region;
    for (std::size_t k = 0; k < nobj; ++k) {
        region.extend(scene[job.objects[k]].box);
    }
    tbb::parallel_for(std::size_t{0}, nobj, [&](std::size_t k) {
        const SceneObject& obj = scene[job.objects[k]];
        for (std::uint32_t t = 0; t < obj.triangle_count(); ++t) {
            const auto& idx = obj.triangle(t);
            tris[offsets[k] + t] = {obj.vertices[idx[0]], obj.vertices[idx[1]],
                                    obj.vertices[idx[2]]};
            tri_object[offsets[k] + t] = static_cast<std::uint32_t>(k);
        }
    });
    return region;
}

// Step 0, the work bound: true when the job must be skipped (boxes beyond float's range or more
// grid points in the triangles' boxes than the limit), decided before any point is visited.
bool exceeds_work_bound(const Job& job, const Aabb& region, const std::vector<Triangle>& tris,
                        const Grid& g) {
    // A band radius whose boxes overflow (a tolerance near the largest double: fuzz_frames)
    // culls nothing either: skipped too, before the bucket coordinates would turn NaN, and so is
    // geometry beyond float's range. The kernel works in float, relative to the region's centre:
    // the radius and the region's extent must stay well inside float's range too.
    constexpr double FLOAT_SAFE = 1e36;
    const Aabb reach = region.grown(job.radius * (1.0 + 1e-9) + 4.0 * g.slack);
    bool finite = std::isfinite(job.radius) && job.radius < FLOAT_SAFE;
    for (int a = 0; a < 3; ++a) {
        finite = finite && std::isfinite(reach.lo[a]) && std::isfinite(reach.hi[a]) &&
                 reach.hi[a] - reach.lo[a] < FLOAT_SAFE;
    }
    if (!finite) {
        return true;
    }
    const std::size_t nt = tris.size();
    const double limit =
        static_cast<double>(MAX_GRID_POINTS_BASE) +
        static_cast<double>(MAX_GRID_POINTS_PER_TRIANGLE) * static_cast<double>(nt);
    double points = 0;
    for (std::size_t f = 0; f < nt && points <= limit; ++f) {
        const Aabb box = triangle_box(tris[f][0], tris[f][1], tris[f][2]).grown(g.rho);
        double in_box = 1;
        for (int a = 0; a < 3; ++a) {
            in_box *= std::max(0.0, std::floor(box.hi[a] / g.h) - std::ceil(box.lo[a] / g.h) + 1);
        }
        points += in_box;
    }
    return !(points <= limit);
}

// Step 1, the samples: Q_f for every triangle, in triangle order (deterministic).
std::vector<Entry> collect_samples(const std::vector<Triangle>& tris,
                                   const std::vector<std::uint32_t>& tri_object, const Grid& g) {
    const std::size_t nt = tris.size();
    const double h = g.h;
    const double rho = g.rho;
    const std::size_t chunk = 256;
    std::vector<std::vector<Entry>> parts((nt + chunk - 1) / chunk);
    tbb::parallel_for(std::size_t{0}, parts.size(), [&](std::size_t c) {
        auto& part = parts[c];
        for (std::size_t f = c * chunk; f < std::min(nt, (c + 1) * chunk); ++f) {
            const Triangle& tr = tris[f];
            const Aabb box = triangle_box(tr[0], tr[1], tr[2]).grown(rho);
            // Points farther than rho from the supporting plane are farther from the triangle:
            // skip them before the exact point-triangle distance (the test is widened so that
            // rounding only keeps extra points, and extra samples only lower L).
            // With |ab x ac| >= 1e-6 max(|ab|, |ac|)^2 the unit normal's direction is off by
            // less than 1e-10 rad, so |n.(q - a)| errs by less than 1e-8 (edge + rho).
            const Vec3 normal = cross(tr[1] - tr[0], tr[2] - tr[0]);
            const double nlen = norm(normal);
            const double edge_sq =
                std::max(squared_norm(tr[1] - tr[0]), squared_norm(tr[2] - tr[0]));
            const bool plane_filter = nlen > 1e-6 * edge_sq && nlen > 0.0;
            const Vec3 unit = plane_filter ? normal / nlen : Vec3{};
            const double plane_limit =
                rho * (1.0 + 1e-9) + 1e-8 * (std::sqrt(edge_sq) + rho) + 4.0 * g.slack;
            std::int64_t lo[3], hi[3];
            for (int a = 0; a < 3; ++a) {
                lo[a] = static_cast<std::int64_t>(std::ceil(box.lo[a] / h));
                hi[a] = static_cast<std::int64_t>(std::floor(box.hi[a] / h));
            }
            for (auto i = lo[0]; i <= hi[0]; ++i) {
                for (auto j = lo[1]; j <= hi[1]; ++j) {
                    for (auto k = lo[2]; k <= hi[2]; ++k) {
                        const Vec3 q{static_cast<double>(i) * h, static_cast<double>(j) * h,
                                     static_cast<double>(k) * h};
                        if (plane_filter && std::abs(dot(unit, q - tr[0])) > plane_limit) {
                            continue;
                        }
                        const double d2 = point_triangle(q, tr[0], tr[1], tr[2]).squared_distance;
                        if (d2 <= rho * rho) {
                            part.push_back({pack(i, j, k), static_cast<std::uint32_t>(f),
                                            tri_object[f], std::sqrt(d2)});
                        }
                    }
                }
            }
        }
    });
    std::vector<Entry> entries;
    std::size_t total = 0;
    for (const auto& p : parts) {
        total += p.size();
    }
    entries.reserve(total);
    for (auto& p : parts) {
        entries.insert(entries.end(), p.begin(), p.end());
        std::vector<Entry>().swap(p);
    }
    return entries;
}

// Groups the entries into kernel samples: in inter-object mode the kernel's answer depends only
// on the owner's object, so one sample per (object, grid point), owned by its smallest triangle;
// in intra-object mode every entry is a sample.
void group_samples(dvd::Mode mode, std::vector<Entry>& entries,
                   std::vector<std::uint32_t>& entry_sample,
                   std::vector<std::size_t>& sample_entry) {
    entry_sample.resize(entries.size());
    if (mode == dvd::Mode::inter_object) {
        tbb::parallel_sort(entries.begin(), entries.end(), [](const Entry& x, const Entry& y) {
            return std::tie(x.object, x.key, x.owner) < std::tie(y.object, y.key, y.owner);
        });
        for (std::size_t e = 0; e < entries.size(); ++e) {
            if (e == 0 || entries[e].key != entries[e - 1].key ||
                entries[e].object != entries[e - 1].object) {
                sample_entry.push_back(e);
            }
            entry_sample[e] = static_cast<std::uint32_t>(sample_entry.size() - 1);
        }
    } else {
        sample_entry.resize(entries.size());
        for (std::size_t e = 0; e < entries.size(); ++e) {
            sample_entry[e] = e;
            entry_sample[e] = static_cast<std::uint32_t>(e);
        }
    }
}

// Step 2a: the bucket grid over the sampled region, coarsened until it has at most MAX_BUCKETS.
Buckets choose_buckets(const Aabb& region, const Grid& g) {
    Buckets b;
    b.sampled = region.grown(g.rho + g.h);
    b.size = std::max(2.0 * g.h, 0.5 * g.radius);
    for (;;) {
        std::uint64_t count = 1;
        for (int a = 0; a < 3; ++a) {
            const double n = std::floor((b.sampled.hi[a] - b.sampled.lo[a]) / b.size) + 1.0;
            b.dims[a] = static_cast<std::uint32_t>(std::min(n, 4e9));
            count *= b.dims[a];
            count = std::min(count, MAX_BUCKETS + 1);
        }
        if (count <= MAX_BUCKETS) {
            break;
        }
        b.size *= 1.25;
    }
    return b;
}

// Step 2b: each bucket's list of the triangles whose box grown by the band radius reaches it
// (decided in double, so a sample's bucket holds every triangle within the radius of it).
Status list_bucket_triangles(const Buckets& b, const std::vector<Triangle>& tris, const Grid& g,
                             dvd::KernelInput& in) {
    const std::size_t nt = tris.size();
    std::vector<std::array<std::uint32_t, 6>> ranges(nt);
    tbb::parallel_for(std::size_t{0}, nt, [&](std::size_t f) {
        const Triangle& tr = tris[f];
        const Aabb box =
            triangle_box(tr[0], tr[1], tr[2]).grown(g.radius * (1.0 + 1e-9) + 4.0 * g.slack);
        for (int a = 0; a < 3; ++a) {
            ranges[f][a] = b.coord(box.lo[a], a);
            ranges[f][3 + a] = b.coord(box.hi[a], a);
        }
    });
    const std::uint64_t nb = b.count();
    in.bucket_offsets.assign(nb + 1, 0);
    std::uint64_t listed = 0;
    for (std::size_t f = 0; f < nt; ++f) {
        const auto& r = ranges[f];
        for (auto k = r[2]; k <= r[5]; ++k) {
            for (auto j = r[1]; j <= r[4]; ++j) {
                for (auto i = r[0]; i <= r[3]; ++i) {
                    ++in.bucket_offsets[b.flat(i, j, k) + 1];
                    ++listed;
                }
            }
        }
    }
    if (listed >= dvd::NO_TRIANGLE) {
        return {StatusCode::resource_exhausted,
                "voronoi culler: bucket lists too long (band radius too large for the cell)"};
    }
    for (std::uint64_t i = 0; i < nb; ++i) {
        in.bucket_offsets[i + 1] += in.bucket_offsets[i];
    }
    in.bucket_triangles.resize(listed);
    std::vector<std::uint32_t> fill(in.bucket_offsets.begin(), in.bucket_offsets.end() - 1);
    for (std::size_t f = 0; f < nt; ++f) {
        const auto& r = ranges[f];
        for (auto k = r[2]; k <= r[5]; ++k) {
            for (auto j = r[1]; j <= r[4]; ++j) {
                for (auto i = r[0]; i <= r[3]; ++i) {
                    in.bucket_triangles[fill[b.flat(i, j, k)]++] = static_cast<std::uint32_t>(f);
                }
            }
        }
    }
    return {};
}

// Step 3a: the triangles in single precision relative to origin, with scene-wide vertex ids;
// returns the largest absolute coordinate written.
double fill_triangle_input(const Scene& scene, const Job& job,
                           const std::vector<std::size_t>& offsets,
                           const std::vector<Triangle>& tris,
                           const std::vector<std::uint32_t>& tri_object, const Vec3& origin,
                           dvd::KernelInput& in) {
    const std::size_t nt = tris.size();
    double max_abs = 0.0;
    in.triangle_vertices.resize(9 * nt);
    in.triangle_indices.resize(3 * nt);
    in.triangle_object = tri_object;
    std::uint32_t vertex_base = 0;
    for (std::size_t k = 0; k < job.objects.size(); ++k) {
        const SceneObject& obj = scene[job.objects[k]];
        for (std::uint32_t t = 0; t < obj.triangle_count(); ++t) {
            const auto& idx = obj.triangle(t);
            for (int c = 0; c < 3; ++c) {
                in.triangle_indices[3 * (offsets[k] + t) + c] = vertex_base + idx[c];
            }
        }
        vertex_base += static_cast<std::uint32_t>(obj.vertices.size());
    }
    for (std::size_t f = 0; f < nt; ++f) {
        for (std::size_t c = 0; c < 3; ++c) {
            for (int a = 0; a < 3; ++a) {
                const double x = tris[f][c][a] - origin[a];
                max_abs = std::max(max_abs, std::abs(x));
                in.triangle_vertices[9 * f + 3 * c + static_cast<std::size_t>(a)] =
                    static_cast<float>(x);
            }
        }
    }
    return max_abs;
}

// Step 3b: the samples in single precision relative to origin, with owner and bucket (and their
// double positions in sample_pos); returns max_abs raised to the largest coordinate written.
double fill_sample_input(const std::vector<Entry>& entries,
                         const std::vector<std::size_t>& sample_entry, const Buckets& b, double h,
                         const Vec3& origin, double max_abs, dvd::KernelInput& in,
                         std::vector<Vec3>& sample_pos) {
    const std::size_t ns = sample_entry.size();
    in.sample_points.resize(3 * ns);
    in.sample_owner.resize(ns);
    in.sample_bucket.resize(ns);
    sample_pos.resize(ns);
    for (std::size_t s = 0; s < ns; ++s) {
        const Entry& e = entries[sample_entry[s]];
        const Vec3 q = unpack(e.key, h);
        sample_pos[s] = q;
        for (int a = 0; a < 3; ++a) {
            const double x = q[a] - origin[a];
            max_abs = std::max(max_abs, std::abs(x));
            in.sample_points[3 * s + a] = static_cast<float>(x);
        }
        in.sample_owner[s] = e.owner;
        in.sample_bucket[s] =
            static_cast<std::uint32_t>(b.flat(b.coord(q.x, 0), b.coord(q.y, 1), b.coord(q.z, 2)));
    }
    return max_abs;
}

// Step 4: runs the kernel and checks that it answered every sample.
Status run_kernel(dvd::Backend& backend, const dvd::KernelInput& in, std::size_t ns,
                  dvd::KernelOutput& kout, VoronoiStats& stats) {
    const auto t_kernel = Clock::now();
    if (Status s = backend.run(in, kout); !s.ok()) {
        return s;
    }
    stats.dvd_seconds = seconds_since(t_kernel);
    if (kout.distance.size() != ns || kout.nearest.size() != ns) {
        return {StatusCode::internal, "voronoi culler: kernel returned " +
                                          std::to_string(kout.distance.size()) + " results for " +
                                          std::to_string(ns) + " samples"};
    }
    return {};
}

// Step 5, the error allowance: the generic bound plus the worst triangle's shape term, for float
// coordinates of magnitude at most m.
double error_allowance(const std::vector<Triangle>& tris, const Vec3& origin, double m) {
    const double shape = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, tris.size(), 1024), 0.0,
        [&](const auto& range, double acc) {
            for (std::size_t f = range.begin(); f != range.end(); ++f) {
                double c[3][3];
                for (int v = 0; v < 3; ++v) {
                    for (int a = 0; a < 3; ++a) {
                        c[v][a] = tris[f][v][a] - origin[a];
                    }
                }
                acc = std::max(acc, dvd::triangle_error_term(c[0], c[1], c[2], m));
            }
            return acc;
        },
        [](double x, double y) { return std::max(x, y); });
    return dvd::kernel_error_bound(m) + shape;
}

// Step 6a: L(f) per triangle (Lemma 2) and each triangle's best sample for U(f), sequential over
// the entries in a fixed order.
Status accumulate_bounds(const std::vector<Entry>& entries,
                         const std::vector<std::uint32_t>& entry_sample,
                         const dvd::KernelOutput& kout, const Grid& g, double eps, JobResult& out,
                         BestSamples& best) {
    const std::size_t nt = out.lower.size();
    const double R = g.radius;
    best.score.assign(nt, std::numeric_limits<double>::infinity());
    best.sample.assign(nt, dvd::NO_TRIANGLE);
    best.dist.assign(nt, 0.0);
    for (std::size_t e = 0; e < entries.size(); ++e) {
        const Entry& en = entries[e];
        const std::uint32_t s = entry_sample[e];
        const bool found = kout.nearest[s] != dvd::NO_TRIANGLE;
        if (found && kout.nearest[s] >= nt) {
            return {StatusCode::internal, "voronoi culler: kernel returned triangle " +
                                              std::to_string(kout.nearest[s]) + " of " +
                                              std::to_string(nt)};
        }
        const double d = found ? std::min(static_cast<double>(kout.distance[s]), R) : R;
        const double lower = d - g.rho - eps;
        const std::uint32_t f = en.owner;
        if (out.lower[f] == -std::numeric_limits<double>::infinity() || lower < out.lower[f]) {
            out.lower[f] = lower;
        }
        if (found) {
            const double score = en.dist + d;
            if (score < best.score[f] || (score == best.score[f] && s < best.sample[f])) {
                best.score[f] = score;
                best.sample[f] = s;
                best.dist[f] = en.dist;
            }
        }
    }
    return {};
}

// Step 6b: U(f) and the partner g of each triangle with a best sample q*, recomputed in double:
// d(q*, f) + d(q*, g).
void resolve_partners(const BestSamples& best, const dvd::KernelOutput& kout,
                      const std::vector<Triangle>& tris, const std::vector<Vec3>& sample_pos,
                      double slack, JobResult& out) {
    tbb::parallel_for(std::size_t{0}, tris.size(), [&](std::size_t f) {
        const std::uint32_t s = best.sample[f];
        if (s == dvd::NO_TRIANGLE) {
            return;
        }
        const std::uint32_t g = kout.nearest[s];
        const Triangle& tg = tris[g];
        const double dg =
            std::sqrt(point_triangle(sample_pos[s], tg[0], tg[1], tg[2]).squared_distance);
        out.upper[f] = (best.dist[f] + dg) * (1.0 + 1e-12) + 4.0 * slack;
        out.partner[f] = g;
    });
}

// Runs one job: samples, buckets, kernel, then L(f), U(f) and the partner of every job triangle.
Status run_job(const Scene& scene, dvd::Backend& backend, const Job& job, JobResult& out) {
    const auto t_start = Clock::now();
    const std::size_t nt = reset_result(scene, job, out);
    if (nt == 0) {
        return {};
    }
    if (nt >= dvd::NO_TRIANGLE) {
        return {StatusCode::resource_exhausted, "voronoi culler: too many triangles"};
    }
    std::vector<std::uint32_t> tri_object(nt);
    std::vector<Triangle> tris(nt);
    const Aabb region = gather_triangles(scene, job, out.offsets, tris, tri_object);
    const double scale = coordinate_scale(region);
    Grid g;
    g.slack = rounding_slack(scale);
    // Grid coordinates must fit the packed key.
    g.h = std::max(job.cell, scale / static_cast<double>(GRID_HALF_RANGE >> 1));
    g.rho = g.h * std::sqrt(3.0) / 2.0 * (1.0 + 1e-12) + 4.0 * g.slack;
    g.radius = job.radius;
    out.stats.cell = g.h;

    if (exceeds_work_bound(job, region, tris, g)) {
        out.skipped = true;
        out.stats.skipped = 1;
        out.stats.seconds = seconds_since(t_start);
        return {};
    }

    std::vector<Entry> entries = collect_samples(tris, tri_object, g);
    std::vector<std::uint32_t> entry_sample;
    std::vector<std::size_t> sample_entry;  // first entry of each sample
    group_samples(job.mode, entries, entry_sample, sample_entry);
    const std::size_t ns = sample_entry.size();
    if (ns >= dvd::NO_TRIANGLE) {
        return {StatusCode::resource_exhausted, "voronoi culler: too many samples"};
    }
    out.stats.samples = ns;

    const Buckets buckets = choose_buckets(region, g);
    dvd::KernelInput in;
    in.mode = job.mode;
    in.radius = static_cast<float>(g.radius);
    in.bucket_dims = buckets.dims;
    in.bucket_size = static_cast<float>(buckets.size);
    const Vec3 origin = region.center();
    for (int a = 0; a < 3; ++a) {
        in.bucket_origin[a] = static_cast<float>(buckets.sampled.lo[a] - origin[a]);
    }
    if (Status s = list_bucket_triangles(buckets, tris, g, in); !s.ok()) {
        return s;
    }

    double max_abs = fill_triangle_input(scene, job, out.offsets, tris, tri_object, origin, in);
    std::vector<Vec3> sample_pos;
    max_abs =
        fill_sample_input(entries, sample_entry, buckets, g.h, origin, max_abs, in, sample_pos);
    // The float coordinates are at most max_abs rounded: widen by one float ulp.
    const double m = max_abs * (1.0 + 1.0 / 8388608.0);

    dvd::KernelOutput kout;
    if (Status s = run_kernel(backend, in, ns, kout, out.stats); !s.ok()) {
        return s;
    }
    const double eps = error_allowance(tris, origin, m);
    out.stats.epsilon = eps;

    BestSamples best;
    if (Status s = accumulate_bounds(entries, entry_sample, kout, g, eps, out, best); !s.ok()) {
        return s;
    }
    resolve_partners(best, kout, tris, sample_pos, g.slack, out);
    out.stats.seconds = seconds_since(t_start);
    return {};
}

// A triangle whose lower bound reaches the (widened) pair threshold cannot be in a pair that
// matters: same comparison as the BVH's box test.
bool lower_culls(double lower, double threshold_sq) {
    return lower > 0.0 && lower * lower >= threshold_sq;
}

double pair_slack(const Scene& scene, std::size_t a, std::size_t b) {
    return rounding_slack(std::max(coordinate_scale(scene[a].box), coordinate_scale(scene[b].box)));
}

}  // namespace

VoronoiCuller::VoronoiCuller(CullerKind kind, std::shared_ptr<dvd::Backend> backend)
    : m_kind(kind), m_backend(std::move(backend)) {}

VoronoiCuller::~VoronoiCuller() = default;

void VoronoiCuller::prepare(const Scene& scene) {
    m_bvh.prepare(scene);
    if (m_scene == &scene && m_generation == scene.generation()) {
        return;
    }
    m_scene = &scene;
    m_generation = scene.generation();
    m_separation = {};
    m_within = {};
    m_offsets.assign(scene.size() + 1, 0);
    // The scale of the grid: the median edge length (the mean is dominated by a few large
    // triangles in scenes that mix resolutions, e.g. a coarse ball under a fine cloth).
    std::vector<double> lengths;
    lengths.reserve(3 * scene.triangle_count());
    for (std::size_t i = 0; i < scene.size(); ++i) {
        const SceneObject& obj = scene[i];
        m_offsets[i + 1] = m_offsets[i] + obj.triangle_count();
        for (std::uint32_t t = 0; t < obj.triangle_count(); ++t) {
            const auto& idx = obj.triangle(t);
            for (int c = 0; c < 3; ++c) {
                lengths.push_back(norm(obj.vertices[idx[(c + 1) % 3]] - obj.vertices[idx[c]]));
            }
        }
    }
    m_edge_scale = 0.0;
    if (!lengths.empty()) {
        auto mid = lengths.begin() + static_cast<std::ptrdiff_t>(lengths.size() / 2);
        std::nth_element(lengths.begin(), mid, lengths.end());
        m_edge_scale = *mid;
    }
}

double VoronoiCuller::cell_for(const Scene& scene, double factor) const {
    if (m_cell && *m_cell > 0.0) {
        return *m_cell;
    }
    double h = m_edge_scale * factor;
    if (!(h > 0.0)) {
        // Every triangle degenerate to a point: any positive cell is valid.
        double s = 0.0;
        for (const auto& o : scene.objects()) {
            s = std::max(s, coordinate_scale(o.box));
        }
        h = s > 0.0 ? s * 1e-3 : 1.0;
    }
    return h;
}

void VoronoiCuller::add_stats(const VoronoiStats& s) {
    std::lock_guard<std::mutex> lock(m_stats_lock);
    m_stats.seconds += s.seconds;
    m_stats.dvd_seconds += s.dvd_seconds;
    m_stats.samples += s.samples;
    m_stats.cell = s.cell;
    m_stats.epsilon = std::max(m_stats.epsilon, s.epsilon);
    m_stats.skipped += s.skipped;
}

VoronoiStats VoronoiCuller::take_voronoi_stats() {
    std::lock_guard<std::mutex> lock(m_stats_lock);
    VoronoiStats s = m_stats;
    s.culled = m_culled.exchange(0);
    m_stats = {};
    return s;
}

Status VoronoiCuller::refine_separation(const Scene& scene, std::vector<double>& object_upper) {
    m_separation = {};
    if (scene.size() < 2) {
        return {};
    }
    double widest = 0.0;
    for (double u : object_upper) {
        if (std::isfinite(u)) {
            widest = std::max(widest, u);
        }
    }
    const double h = cell_for(scene, SEPARATION_CELL_FACTOR);
    Job job;
    job.mode = dvd::Mode::inter_object;
    job.cell = h;
    job.radius = std::max(std::min(widest, SEPARATION_BAND * h), h);
    job.objects.resize(scene.size());
    for (std::size_t i = 0; i < scene.size(); ++i) {
        job.objects[i] = i;
    }
    JobResult r;
    if (Status s = run_job(scene, *m_backend, job, r); !s.ok()) {
        return s;
    }
    add_stats(r.stats);
    if (r.skipped) {
        return {};  // m_separation stays invalid: nearest_between uses the BVH alone
    }
    for (std::size_t i = 0; i < scene.size(); ++i) {
        for (std::size_t f = r.offsets[i]; f < r.offsets[i + 1]; ++f) {
            object_upper[i] = std::min(object_upper[i], r.upper[f]);
        }
    }
    m_separation.lower = std::move(r.lower);
    m_separation.valid = true;
    return {};
}

Status VoronoiCuller::refine_within(const Scene& scene, double radius) {
    m_within = {};
    const double h = cell_for(scene, WITHIN_CELL_FACTOR);
    Job job;
    job.mode = dvd::Mode::intra_object;  // scene-wide vertex ids: every non-adjacent triangle
    job.cell = h;
    job.radius = radius + h * std::sqrt(3.0) + h * 0.25;
    job.objects.resize(scene.size());
    for (std::size_t i = 0; i < scene.size(); ++i) {
        job.objects[i] = i;
    }
    JobResult r;
    if (Status s = run_job(scene, *m_backend, job, r); !s.ok()) {
        return s;
    }
    add_stats(r.stats);
    if (r.skipped) {
        return {};  // m_within stays invalid: pairs_within keeps the BVH's pairs
    }
    m_within.lower = std::move(r.lower);
    m_within.radius = radius;
    m_within.valid = true;
    return {};
}

Status VoronoiCuller::refine_self(const Scene& scene, std::size_t a,
                                  std::vector<std::uint32_t>& partner) {
    // The hierarchy's own step first (a rebuild after a large deformation); it proposes no
    // partners.
    if (Status s = m_bvh.refine_self(scene, a, partner); !s.ok()) {
        return s;
    }
    partner.clear();
    const double h = cell_for(scene, SELF_CELL_FACTOR);
    Job job;
    job.mode = dvd::Mode::intra_object;
    job.cell = h;
    job.radius = SELF_BAND * h;
    job.objects = {a};
    JobResult r;
    if (Status s = run_job(scene, *m_backend, job, r); !s.ok()) {
        return s;
    }
    add_stats(r.stats);
    if (r.skipped) {
        return {};  // no partners: the self query tests the BVH's pairs alone
    }
    partner = std::move(r.partner);
    return {};
}

void VoronoiCuller::nearest_between(const Scene& scene, std::size_t a, std::size_t b,
                                    double& bound_sq, PairVisitor visit) const {
    if (!m_separation.valid) {
        m_bvh.nearest_between(scene, a, b, bound_sq, visit);
        return;
    }
    const double* la = m_separation.lower.data() + m_offsets[a];
    const double* lb = m_separation.lower.data() + m_offsets[b];
    CullThreshold threshold(bound_sq, pair_slack(scene, a, b));
    std::uint64_t culled = 0;
    m_bvh.nearest_between(scene, a, b, bound_sq, [&](std::uint32_t ta, std::uint32_t tb) {
        const double th = threshold.get();
        if (lower_culls(la[ta], th) || lower_culls(lb[tb], th)) {
            ++culled;
            return;
        }
        visit(ta, tb);
    });
    if (culled != 0) {
        m_culled.fetch_add(culled, std::memory_order_relaxed);
    }
}

void VoronoiCuller::self_pairs(const Scene& scene, std::size_t a, BoundLookup bound_sq,
                               PairVisitor visit) const {
    m_bvh.self_pairs(scene, a, bound_sq, visit);
}

void VoronoiCuller::pairs_within(const Scene& scene, std::size_t a, std::size_t b, double radius,
                                 std::vector<TrianglePair>& out) const {
    const std::size_t start = out.size();
    m_bvh.pairs_within(scene, a, b, radius, out);
    if (!m_within.valid || m_within.radius != radius) {
        return;
    }
    const double* la = m_within.lower.data() + m_offsets[a];
    const double* lb = m_within.lower.data() + m_offsets[b];
    const double th = cull_threshold_sq(radius * radius, pair_slack(scene, a, b));
    auto keep_end = std::remove_if(
        out.begin() + static_cast<std::ptrdiff_t>(start), out.end(), [&](const TrianglePair& p) {
            return lower_culls(la[p.first], th) || lower_culls(lb[p.second], th);
        });
    const auto culled = static_cast<std::uint64_t>(out.end() - keep_end);
    out.erase(keep_end, out.end());
    if (culled != 0) {
        m_culled.fetch_add(culled, std::memory_order_relaxed);
    }
}

}  // namespace proxima::detail
