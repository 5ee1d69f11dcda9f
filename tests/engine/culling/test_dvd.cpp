// The discrete-Voronoi kernel's CPU backend against a brute-force double loop: the nearest
// eligible triangle and its distance, the eligibility rules of both modes, ties, the radius, the
// documented error bound (including the rounding of double inputs to float), and validate().
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "proxima/culling/dvd.hpp"
#include "proxima/distance/primitives.hpp"

namespace proxima {
namespace {

using Rng = std::mt19937_64;

double uniform(Rng& rng, double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng);
}

// One bucket holding every triangle: the kernel then scans all of them, like the brute loop.
dvd::KernelInput single_bucket(dvd::Mode mode, float radius, const std::vector<Triangle>& tris,
                               const std::vector<std::uint32_t>& objects,
                               const std::vector<std::array<std::uint32_t, 3>>& ids,
                               const std::vector<Vec3>& samples,
                               const std::vector<std::uint32_t>& owners) {
    dvd::KernelInput in;
    in.mode = mode;
    in.radius = radius;
    for (std::size_t t = 0; t < tris.size(); ++t) {
        for (const auto& v : tris[t]) {
            for (int a = 0; a < 3; ++a) {
                in.triangle_vertices.push_back(static_cast<float>(v[a]));
            }
        }
        for (auto id : ids[t]) {
            in.triangle_indices.push_back(id);
        }
        in.triangle_object.push_back(objects[t]);
        in.bucket_triangles.push_back(static_cast<std::uint32_t>(t));
    }
    in.bucket_dims = {1, 1, 1};
    in.bucket_size = 1e6f;
    in.bucket_origin = {-5e5f, -5e5f, -5e5f};
    in.bucket_offsets = {0, static_cast<std::uint32_t>(tris.size())};
    for (std::size_t s = 0; s < samples.size(); ++s) {
        for (int a = 0; a < 3; ++a) {
            in.sample_points.push_back(static_cast<float>(samples[s][a]));
        }
        in.sample_owner.push_back(owners[s]);
        in.sample_bucket.push_back(0);
    }
    return in;
}

Triangle random_triangle(Rng& rng, const Vec3& c, double size) {
    Triangle t;
    for (auto& v : t) {
        v = c +
            Vec3{uniform(rng, -size, size), uniform(rng, -size, size), uniform(rng, -size, size)};
    }
    return t;
}

// The double-precision truth for the float inputs the kernel saw.
Vec3 as_float(const Vec3& v) {
    return {static_cast<float>(v.x), static_cast<float>(v.y), static_cast<float>(v.z)};
}

TEST(DvdKernel, MatchesBruteForceInBothModes) {
    Rng rng(7);
    for (int round = 0; round < 20; ++round) {
        const int nt = 60;
        std::vector<Triangle> tris;
        std::vector<std::uint32_t> objects;
        std::vector<std::array<std::uint32_t, 3>> ids;
        for (int t = 0; t < nt; ++t) {
            tris.push_back(random_triangle(
                rng, {uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)}, 0.2));
            objects.push_back(static_cast<std::uint32_t>(t % 4));
            // Shared vertex ids between neighbours in index order (an adjacency to exclude).
            ids.push_back({static_cast<std::uint32_t>(t), static_cast<std::uint32_t>(t + 1),
                           static_cast<std::uint32_t>(1000 + t)});
        }
        std::vector<Vec3> samples;
        std::vector<std::uint32_t> owners;
        for (int s = 0; s < 300; ++s) {
            samples.push_back(
                {uniform(rng, -1.3, 1.3), uniform(rng, -1.3, 1.3), uniform(rng, -1.3, 1.3)});
            owners.push_back(static_cast<std::uint32_t>(s % nt));
        }
        const float radius = static_cast<float>(uniform(rng, 0.1, 1.5));
        for (auto mode : {dvd::Mode::inter_object, dvd::Mode::intra_object}) {
            const auto in = single_bucket(mode, radius, tris, objects, ids, samples, owners);
            dvd::KernelOutput out;
            ASSERT_TRUE(dvd::make_cpu_backend()->run(in, out).ok());
            ASSERT_EQ(out.distance.size(), samples.size());
            double m = 0;
            for (float x : in.triangle_vertices) {
                m = std::max(m, std::abs(static_cast<double>(x)));
            }
            for (float x : in.sample_points) {
                m = std::max(m, std::abs(static_cast<double>(x)));
            }
            double eps = dvd::kernel_error_bound(m);
            double shape = 0;
            for (const auto& t : tris) {
                const Triangle f{as_float(t[0]), as_float(t[1]), as_float(t[2])};
                const double a[3] = {f[0].x, f[0].y, f[0].z}, b[3] = {f[1].x, f[1].y, f[1].z},
                             c[3] = {f[2].x, f[2].y, f[2].z};
                shape = std::max(shape, dvd::triangle_error_term(a, b, c, m));
            }
            eps += shape;
            for (std::size_t s = 0; s < samples.size(); ++s) {
                const std::uint32_t o = owners[s];
                double best = std::numeric_limits<double>::infinity();
                std::uint32_t arg = dvd::NO_TRIANGLE;
                const Vec3 q = as_float(samples[s]);
                for (std::uint32_t t = 0; t < nt; ++t) {
                    const bool eligible =
                        mode == dvd::Mode::inter_object
                            ? objects[t] != objects[o]
                            : (t != o && ids[t][0] != ids[o][0] && ids[t][0] != ids[o][1] &&
                               ids[t][1] != ids[o][0] && ids[t][1] != ids[o][1]);
                    if (!eligible) {
                        continue;
                    }
                    const Triangle f{as_float(tris[t][0]), as_float(tris[t][1]),
                                     as_float(tris[t][2])};
                    const double d =
                        std::sqrt(point_triangle(q, f[0], f[1], f[2]).squared_distance);
                    if (d < best) {
                        best = d;
                        arg = t;
                    }
                }
                const std::string where =
                    "round " + std::to_string(round) + " sample " + std::to_string(s);
                if (best < radius - eps) {
                    ASSERT_NE(out.nearest[s], dvd::NO_TRIANGLE) << where;
                }
                if (out.nearest[s] == dvd::NO_TRIANGLE) {
                    EXPECT_TRUE(std::isinf(out.distance[s])) << where;
                    EXPECT_GT(best, radius - eps) << where;
                    continue;
                }
                // Well-shaped random triangles: the computed distance is within eps both ways,
                // and the triangle it names is within 2 eps of the true nearest.
                EXPECT_LE(out.distance[s], best + eps) << where;
                EXPECT_GE(out.distance[s], best - eps) << where;
                EXPECT_LE(out.distance[s], radius * (1.0 + 1e-6)) << where;
                const auto g = out.nearest[s];
                const Triangle f{as_float(tris[g][0]), as_float(tris[g][1]), as_float(tris[g][2])};
                EXPECT_LE(std::sqrt(point_triangle(q, f[0], f[1], f[2]).squared_distance),
                          best + 2 * eps)
                    << where << " arg " << arg;
            }
        }
    }
}

// The bound the culler relies on: the computed distance never exceeds the exact distance between
// the *double* inputs by more than kernel_error_bound + triangle_error_term, for points near
// vertices, edges and faces, far from the origin, and for slivers and degenerate triangles.
TEST(DvdKernel, ErrorBoundHoldsAgainstDoubleGeometry) {
    Rng rng(11);
    double worst_ratio = 0;
    for (int round = 0; round < 20000; ++round) {
        const double offset = round % 3 == 0 ? 0.0 : uniform(rng, -50, 50);
        const double size = std::pow(10.0, uniform(rng, -3, 0));
        const Vec3 c{offset, uniform(rng, -2, 2), uniform(rng, -2, 2)};
        Triangle t = random_triangle(rng, c, size);
        switch (round % 5) {
            case 1:  // cap: nearly collinear corners
                t[2] = t[0] + uniform(rng, 0.2, 0.8) * (t[1] - t[0]) +
                       Vec3{uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)} * size *
                           1e-7;
                break;
            case 2:  // needle
                t[2] = t[1] + Vec3{uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)} *
                                  size * 1e-6;
                break;
            case 3:  // exactly degenerate
                t[2] = t[0];
                break;
            default:
                break;
        }
        // A point near a random point of the triangle, off by a random small vector.
        double u = uniform(rng, -0.2, 1.2), v = uniform(rng, -0.2, 1.2);
        const Vec3 on = t[0] + u * (t[1] - t[0]) + v * (t[2] - t[0]);
        const Vec3 p = on + Vec3{uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)} *
                                (size * std::pow(10.0, uniform(rng, -6, 0)));
        float pf[3], af[3], bf[3], cf[3];
        double m = 0;
        for (int a = 0; a < 3; ++a) {
            pf[a] = static_cast<float>(p[a]);
            af[a] = static_cast<float>(t[0][a]);
            bf[a] = static_cast<float>(t[1][a]);
            cf[a] = static_cast<float>(t[2][a]);
            for (double x : {p[a], t[0][a], t[1][a], t[2][a]}) {
                m = std::max(m, std::abs(x) * (1 + 1.0 / 8388608.0));
            }
        }
        const double computed =
            std::sqrt(static_cast<double>(dvd::point_triangle_distance_squared(pf, af, bf, cf)));
        const double exact = std::sqrt(point_triangle(p, t[0], t[1], t[2]).squared_distance);
        const double a3[3] = {t[0].x, t[0].y, t[0].z}, b3[3] = {t[1].x, t[1].y, t[1].z},
                     c3[3] = {t[2].x, t[2].y, t[2].z};
        const double eps = dvd::kernel_error_bound(m) + dvd::triangle_error_term(a3, b3, c3, m);
        ASSERT_LE(computed, exact + eps) << "round " << round << " computed " << computed
                                         << " exact " << exact << " eps " << eps;
        worst_ratio = std::max(worst_ratio, (computed - exact) / dvd::kernel_error_bound(m));
    }
    // Informative: how much of the generic bound the worst case used.
    RecordProperty("worst_excess_over_generic_bound", std::to_string(worst_ratio));
}

TEST(DvdKernel, TiesGoToTheSmallestIndexAndRadiusLimits) {
    const Triangle t{Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}};
    // Triangles 1 and 2 are the same (a tie); 0 is the owner's own object.
    std::vector<Triangle> tris{t, t, t};
    std::vector<std::uint32_t> objects{0, 1, 2};
    std::vector<std::array<std::uint32_t, 3>> ids{{0, 1, 2}, {3, 4, 5}, {6, 7, 8}};
    std::vector<Vec3> samples{{0.2, 0.2, 0.5}, {0.2, 0.2, 3.0}};
    std::vector<std::uint32_t> owners{0, 0};
    const auto in =
        single_bucket(dvd::Mode::inter_object, 1.0f, tris, objects, ids, samples, owners);
    dvd::KernelOutput out;
    ASSERT_TRUE(dvd::make_cpu_backend()->run(in, out).ok());
    EXPECT_EQ(out.nearest[0], 1u);
    EXPECT_FLOAT_EQ(out.distance[0], 0.5f);
    // Beyond the radius: none.
    EXPECT_EQ(out.nearest[1], dvd::NO_TRIANGLE);
    EXPECT_TRUE(std::isinf(out.distance[1]));
    // Intra mode: triangle 1 shares vertex id 3 with the owner now, so 2 is the nearest.
    auto ids2 = ids;
    ids2[1] = {3, 4, 5};
    ids2[0] = {0, 1, 3};
    const auto in2 =
        single_bucket(dvd::Mode::intra_object, 1.0f, tris, objects, ids2, samples, owners);
    ASSERT_TRUE(dvd::make_cpu_backend()->run(in2, out).ok());
    EXPECT_EQ(out.nearest[0], 2u);
}

TEST(DvdKernel, ValidateRejectsMalformedInput) {
    const Triangle t{Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}};
    const auto good = single_bucket(dvd::Mode::inter_object, 1.0f, {t, t}, {0, 1},
                                    {{0, 1, 2}, {3, 4, 5}}, {{0.1, 0.1, 0.1}}, {0});
    ASSERT_TRUE(dvd::validate(good).ok());
    auto backend = dvd::make_cpu_backend();
    EXPECT_EQ(backend->name(), "cpu");
    EXPECT_FALSE(backend->is_gpu());
    std::vector<std::pair<std::string, dvd::KernelInput>> bad;
    auto add = [&](const std::string& what, auto&& edit) {
        dvd::KernelInput in = good;
        edit(in);
        bad.emplace_back(what, std::move(in));
    };
    add("zero radius", [](auto& in) { in.radius = 0.0f; });
    add("nan radius", [](auto& in) { in.radius = std::nanf(""); });
    add("vertex count", [](auto& in) { in.triangle_vertices.pop_back(); });
    add("indices count", [](auto& in) { in.triangle_indices.pop_back(); });
    add("object count", [](auto& in) { in.triangle_object.push_back(0); });
    add("nan vertex", [](auto& in) { in.triangle_vertices[4] = std::nanf(""); });
    add("inf sample", [](auto& in) { in.sample_points[1] = INFINITY; });
    add("bucket triangle", [](auto& in) { in.bucket_triangles[1] = 7; });
    add("not ascending",
        [](auto& in) { std::swap(in.bucket_triangles[0], in.bucket_triangles[1]); });
    add("offsets size", [](auto& in) { in.bucket_offsets.push_back(2); });
    add("offsets end", [](auto& in) { in.bucket_offsets.back() = 1; });
    add("owner range", [](auto& in) { in.sample_owner[0] = 2; });
    add("bucket range", [](auto& in) { in.sample_bucket[0] = 1; });
    add("owner count", [](auto& in) { in.sample_owner.push_back(0); });
    add("bucket size", [](auto& in) { in.bucket_size = -1.0f; });
    add("mode", [](auto& in) { in.mode = static_cast<dvd::Mode>(7); });
    for (const auto& [what, in] : bad) {
        const Status s = dvd::validate(in);
        EXPECT_EQ(s.code(), StatusCode::invalid_argument) << what;
        EXPECT_NE(s.message().find("dvd kernel"), std::string::npos) << what;
        dvd::KernelOutput out;
        EXPECT_EQ(backend->run(in, out).code(), StatusCode::invalid_argument) << what;
    }
}

}  // namespace
}  // namespace proxima
