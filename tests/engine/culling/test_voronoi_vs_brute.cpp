// Property tests of the discrete-Voronoi culler: on random scenes (closed and open, touching,
// crossing, nested, degenerate) and folded sheets, every query through voronoi-cpu (and
// voronoi-gpu when a headless EGL context starts) equals brute force, at automatic and random
// grid resolutions; the CPU and GPU backends give the same PNS; no pair brute force finds within
// the tolerance is missing from the PNS.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <limits>

#include "proxima/culling/dvd.hpp"
#include "proxima/distance/primitives.hpp"
#include "proxima/gpu/egl_backend.hpp"
#include "proxima/query/query.hpp"
#include "support/random_scenes.hpp"

#include <tbb/task_arena.h>

namespace proxima {
namespace {

using test::Rng;

constexpr double REL = 1e-12;

bool same_distance(double a, double b) {
    if (std::isinf(a) || std::isinf(b)) {
        return a == b;
    }
    return std::abs(a - b) <= REL * std::max(1.0, std::max(std::abs(a), std::abs(b)));
}

Triangle corners(const SceneObject& o, std::uint32_t t) {
    const auto& i = o.triangle(t);
    return {o.vertices[i[0]], o.vertices[i[1]], o.vertices[i[2]]};
}

bool same_pairs(std::vector<FeaturePair> a, std::vector<FeaturePair> b) {
    std::sort(a.begin(), a.end());
    std::sort(b.begin(), b.end());
    if (a.size() != b.size()) {
        return false;
    }
    for (std::size_t k = 0; k < a.size(); ++k) {
        if (a[k] < b[k] || b[k] < a[k]) {
            return false;
        }
    }
    return true;
}

QueryRequest full_request(CullerKind culler, double tolerance, std::optional<double> cell = {}) {
    QueryRequest r;
    r.separation = true;
    r.self = true;
    r.collisions = true;
    r.tolerance = tolerance;
    r.pns = true;
    r.culler = culler;
    r.voronoi_cell = cell;
    return r;
}

// The culled answer against brute force for the same scene state.
void expect_equal_answers(const Scene& scene, const QueryResult& got, const QueryResult& brute,
                          const std::string& where) {
    ASSERT_EQ(got.separation.size(), brute.separation.size()) << where;
    for (std::size_t i = 0; i < scene.size(); ++i) {
        const auto& x = got.separation[i];
        const auto& y = brute.separation[i];
        EXPECT_TRUE(same_distance(x.distance, y.distance))
            << where << " object " << i << ": " << got.stats.culler << " " << x.distance
            << " brute " << y.distance;
        if (x.other != NO_OBJECT) {
            const auto j = static_cast<std::size_t>(x.other);
            ASSERT_NE(j, i) << where;
            const auto cp = triangle_triangle(corners(scene[i], x.triangle),
                                              corners(scene[j], x.other_triangle));
            EXPECT_TRUE(same_distance(std::sqrt(cp.squared_distance), x.distance)) << where;
        }
    }
    ASSERT_EQ(got.self.size(), brute.self.size()) << where;
    for (std::size_t i = 0; i < scene.size(); ++i) {
        for (std::size_t t = 0; t < got.self[i].size(); ++t) {
            const auto& x = got.self[i][t];
            const auto& y = brute.self[i][t];
            ASSERT_TRUE(same_distance(x.distance, y.distance))
                << where << " object " << i << " triangle " << t << ": " << got.stats.culler << " "
                << x.distance << " brute " << y.distance;
            if (x.closest != NO_OBJECT) {
                EXPECT_FALSE(scene[i].topology->adjacent(static_cast<std::uint32_t>(t),
                                                         static_cast<std::uint32_t>(x.closest)))
                    << where;
            }
        }
    }
    EXPECT_TRUE(same_pairs(got.collisions, brute.collisions))
        << where << ": " << got.collisions.size() << " vs " << brute.collisions.size();
    EXPECT_TRUE(same_pairs(got.tolerance, brute.tolerance))
        << where << ": " << got.tolerance.size() << " vs " << brute.tolerance.size();
    // No pair brute force finds within the tolerance (or touching) is culled from the PNS.
    for (const auto& p : brute.tolerance) {
        ASSERT_TRUE(std::binary_search(got.pns.begin(), got.pns.end(), p))
            << where << ": pair " << p.object << ":" << p.triangle << " - " << p.other << ":"
            << p.other_triangle << " at " << p.distance << " culled";
    }
    EXPECT_LE(got.stats.exact_tests, brute.stats.exact_tests + scene.triangle_count()) << where;
}

// The GPU backend, once per process: in CI (env CI set) it must start (llvmpipe); elsewhere a
// failure skips the GPU checks with the reason.
std::shared_ptr<dvd::Backend> gpu_backend(std::string* reason) {
    static std::string why;
    static std::shared_ptr<dvd::Backend> backend = [] {
        auto b = gpu::make_egl_backend();
        if (!b.ok()) {
            why = b.status().to_string();
            return std::shared_ptr<dvd::Backend>();
        }
        return b.value();
    }();
    if (reason != nullptr) {
        *reason = why;
    }
    return backend;
}

bool in_ci() {
    const char* ci = std::getenv("CI");
    return ci != nullptr && *ci != '\0';
}

void add_scene(ProximityEngine& engine, const std::vector<NamedMesh>& meshes) {
    for (const auto& m : meshes) {
        ASSERT_TRUE(engine.scene().add_object(m).ok());
    }
}

// Random scenes in shards (separate ctest entries). Half the scenes use the automatic cell, half
// a random cell from very fine to coarser than the objects.
class VoronoiRandomScenes : public ::testing::TestWithParam<int> {};
constexpr int SCENES_PER_SHARD = 60;

TEST_P(VoronoiRandomScenes, CpuEqualsBruteForce) {
    const auto first = static_cast<std::uint64_t>(40000 + GetParam() * SCENES_PER_SHARD);
    std::uint64_t samples = 0;
    for (std::uint64_t seed = first; seed < first + SCENES_PER_SHARD; ++seed) {
        Rng rng(seed);
        const auto meshes = test::random_scene(rng);
        const double tol = test::uniform(rng, 0.0, 0.2);
        std::optional<double> cell;
        if (seed % 2 == 1) {
            cell = std::pow(10.0, test::uniform(rng, -1.7, 0.0));
        }
        ProximityEngine vor;
        ProximityEngine brute;
        add_scene(vor, meshes);
        add_scene(brute, meshes);
        auto a = vor.query(full_request(CullerKind::voronoi_cpu, tol, cell));
        auto b = brute.query(full_request(CullerKind::brute, tol));
        ASSERT_TRUE(a.ok()) << a.status().to_string();
        ASSERT_TRUE(b.ok());
        EXPECT_EQ(a->stats.culler, "voronoi-cpu");
        samples += a->stats.dvd_samples;
        expect_equal_answers(vor.scene(), a.value(), b.value(),
                             "seed " + std::to_string(seed) +
                                 (cell ? " cell " + std::to_string(*cell) : std::string()));
        if (HasFatalFailure()) {
            return;
        }
    }
    EXPECT_GT(samples, 0u);
}
INSTANTIATE_TEST_SUITE_P(VoronoiVsBrute, VoronoiRandomScenes, ::testing::Range(0, 4));

// GPU backend: the same answers, and bit-identical PNS and statistics of the kernel's work
// as the CPU backend (the cull count on one thread: see below).
TEST(VoronoiVsBrute, GpuEqualsCpuAndBruteForce) {
    std::string reason;
    auto gpu = gpu_backend(&reason);
    if (!gpu) {
        if (in_ci()) {
            FAIL() << "CI must run the GPU backend (llvmpipe): " << reason;
        }
        GTEST_SKIP() << "no GPU backend here: " << reason;
    }
    std::cout << "GPU backend: " << gpu->name() << "\n";
    for (std::uint64_t seed = 50000; seed < 50030; ++seed) {
        Rng rng(seed);
        const auto meshes = test::random_scene(rng);
        const double tol = test::uniform(rng, 0.0, 0.2);
        std::optional<double> cell;
        if (seed % 2 == 1) {
            cell = std::pow(10.0, test::uniform(rng, -1.5, 0.0));
        }
        ProximityEngine g;
        ProximityEngine c;
        ProximityEngine brute;
        g.set_gpu_backend(gpu);
        add_scene(g, meshes);
        add_scene(c, meshes);
        add_scene(brute, meshes);
        // One thread: how many pairs the lower bounds cull depends on how far the shared
        // per-object bests have tightened when a pair is reached, which depends on scheduling
        // under several threads (the answers do not). On one thread the order is fixed, so the
        // count compares the two backends' bounds and nothing else.
        tbb::task_arena serial(1);
        auto x = serial.execute(
            [&] { return g.query(full_request(CullerKind::voronoi_gpu, tol, cell)); });
        auto y = serial.execute(
            [&] { return c.query(full_request(CullerKind::voronoi_cpu, tol, cell)); });
        auto z = brute.query(full_request(CullerKind::brute, tol));
        ASSERT_TRUE(x.ok()) << x.status().to_string();
        ASSERT_TRUE(y.ok() && z.ok());
        EXPECT_EQ(x->stats.culler, "voronoi-gpu");
        const std::string where = "seed " + std::to_string(seed);
        expect_equal_answers(g.scene(), x.value(), z.value(), where + " gpu");
        EXPECT_TRUE(same_pairs(x->pns, y->pns))
            << where << ": gpu pns " << x->pns.size() << " cpu pns " << y->pns.size();
        EXPECT_EQ(x->stats.dvd_samples, y->stats.dvd_samples) << where;
        EXPECT_EQ(x->stats.voronoi_culled, y->stats.voronoi_culled) << where;
        if (HasFatalFailure()) {
            return;
        }
    }
}

// Deforming frames through one engine (bounds recomputed every frame), one topology change.
TEST(VoronoiVsBrute, DeformingFramesAndTopologyChange) {
    for (std::uint64_t seed = 60000; seed < 60020; ++seed) {
        Rng rng(seed);
        ProximityEngine vor;
        add_scene(vor, test::random_scene(rng));
        for (int frame = 0; frame <= 3; ++frame) {
            if (frame > 0) {
                SceneUpdate update;
                if (frame == 2 && vor.scene()[0].triangle_count() > 1) {
                    const SceneObject& o = vor.scene()[0];
                    TriangleMesh whole{o.vertices, o.topology->triangles()};
                    TriangleMesh first{whole.vertices, {}};
                    TriangleMesh second{whole.vertices, {}};
                    for (std::size_t t = 0; t < whole.triangles.size(); ++t) {
                        (t % 2 == 0 ? first : second).triangles.push_back(whole.triangles[t]);
                    }
                    update.replacements.push_back({o.id, {{"frag-a", first}, {"frag-b", second}}});
                }
                for (const auto& o : vor.scene().objects()) {
                    if (!update.replacements.empty() && o.id == update.replacements[0].object) {
                        continue;
                    }
                    update.positions.push_back({o.id, test::jitter(rng, o.vertices, 0.05)});
                }
                ASSERT_TRUE(vor.scene().apply(std::move(update)).ok());
            }
            ProximityEngine brute;
            for (const auto& o : vor.scene().objects()) {
                ASSERT_TRUE(
                    brute.scene().add_object({o.name, {o.vertices, o.topology->triangles()}}).ok());
            }
            auto a = vor.query(full_request(CullerKind::voronoi_cpu, 0.05));
            auto b = brute.query(full_request(CullerKind::brute, 0.05));
            ASSERT_TRUE(a.ok() && b.ok());
            expect_equal_answers(
                vor.scene(), a.value(), b.value(),
                "seed " + std::to_string(seed) + " frame " + std::to_string(frame));
            if (HasFatalFailure()) {
                return;
            }
        }
    }
}

// Folded sheets close to each other (the cloth case): the Voronoi bounds remove candidate pairs
// and the answers still equal brute force, at several resolutions.
TEST(VoronoiVsBrute, FoldedSheetsCullAndAgree) {
    std::uint64_t culled = 0;
    for (std::uint64_t seed = 70000; seed < 70004; ++seed) {
        Rng rng(seed);
        std::vector<NamedMesh> meshes;
        for (int k = 0; k < 2; ++k) {
            auto m = test::sheet(rng, 16, 12, test::uniform(rng, 0.005, 0.05));
            test::transform(m, 1.0, {0.3 * k, 0.1 * k, 0.02 * k}, 0.1 * k);
            meshes.push_back({"s", m});
        }
        ProximityEngine brute;
        add_scene(brute, meshes);
        auto b = brute.query(full_request(CullerKind::brute, 0.02));
        ASSERT_TRUE(b.ok());
        for (std::optional<double> cell :
             {std::optional<double>(), std::optional<double>(0.01), std::optional<double>(0.2)}) {
            ProximityEngine vor;
            add_scene(vor, meshes);
            auto a = vor.query(full_request(CullerKind::voronoi_cpu, 0.02, cell));
            ASSERT_TRUE(a.ok());
            culled += a->stats.voronoi_culled;
            expect_equal_answers(vor.scene(), a.value(), b.value(),
                                 "seed " + std::to_string(seed) +
                                     (cell ? " cell " + std::to_string(*cell) : " auto"));
        }
    }
    EXPECT_GT(culled, 0u);
}

// Selection: names, the GPU precondition, a bad cell size, and `automatic` choosing the BVH
// culler on a fresh engine and answering like brute force.
// Found by fuzz_frames (tests/fuzz/regressions/frames/): a tolerance near the largest double
// overflowed the band's boxes to infinity and the bucket coordinates to NaN (SIGSEGV), and one far
// vertex with a small cell made the sampling visit ~10^8 grid points (22 s under ASan, no deadline
// check). Both now skip the Voronoi stage (VoronoiStats::skipped) and cull with the BVH alone:
// the answers stay brute force's.
TEST(VoronoiVsBrute, OverflowingBandsAndFarVerticesSkipSamplingAndStayExact) {
    Rng rng(80100);
    auto meshes = test::random_scene(rng);
    for (const double tol : {1.7e308, std::numeric_limits<double>::max(), 1e300}) {
        ProximityEngine vor;
        ProximityEngine brute;
        add_scene(vor, meshes);
        add_scene(brute, meshes);
        auto a = vor.query(full_request(CullerKind::voronoi_cpu, tol));
        auto b = brute.query(full_request(CullerKind::brute, tol));
        ASSERT_TRUE(a.ok()) << a.status().to_string();
        ASSERT_TRUE(b.ok()) << b.status().to_string();
        expect_equal_answers(vor.scene(), a.value(), b.value(), "tolerance " + std::to_string(tol));
    }
    // One vertex far away, a cell of 0.25: the grid coarsens to fit its 21-bit coordinates, and
    // the slivers reaching the vertex span 2^20 cells of it, millions of grid points each.
    ASSERT_FALSE(meshes.empty());
    meshes[0].mesh.vertices[0].x = -9.3e61;
    ProximityEngine vor;
    ProximityEngine brute;
    add_scene(vor, meshes);
    add_scene(brute, meshes);
    auto a = vor.query(full_request(CullerKind::voronoi_cpu, 0.2, 0.25));
    auto b = brute.query(full_request(CullerKind::brute, 0.2));
    ASSERT_TRUE(a.ok()) << a.status().to_string();
    ASSERT_TRUE(b.ok()) << b.status().to_string();
    expect_equal_answers(vor.scene(), a.value(), b.value(), "far vertex");
}

TEST(VoronoiVsBrute, SelectionAndErrors) {
    EXPECT_EQ(parse_culler("voronoi-cpu").value(), CullerKind::voronoi_cpu);
    EXPECT_EQ(parse_culler("voronoi-gpu").value(), CullerKind::voronoi_gpu);
    EXPECT_STREQ(culler_name(CullerKind::voronoi_gpu), "voronoi-gpu");
    EXPECT_FALSE(parse_culler("voronoi").ok());

    Rng rng(80000);
    const auto meshes = test::random_scene(rng);
    ProximityEngine engine;
    add_scene(engine, meshes);
    auto g = engine.query(full_request(CullerKind::voronoi_gpu, 0.1));
    ASSERT_FALSE(g.ok());
    EXPECT_EQ(g.status().code(), StatusCode::failed_precondition);
    EXPECT_NE(g.status().message().find("no GPU backend"), std::string::npos);
    for (double bad : {0.0, -1.0, std::nan("")}) {
        auto r = engine.query(full_request(CullerKind::voronoi_cpu, 0.1, bad));
        ASSERT_FALSE(r.ok());
        EXPECT_EQ(r.status().code(), StatusCode::invalid_argument);
    }
    ProximityEngine brute;
    add_scene(brute, meshes);
    auto b = brute.query(full_request(CullerKind::brute, 0.1));
    ASSERT_TRUE(b.ok());
    for (int q = 0; q < 3; ++q) {
        auto r = engine.query(full_request(CullerKind::automatic, 0.1));
        ASSERT_TRUE(r.ok());
        EXPECT_EQ(r->stats.culler, "bvh");
        expect_equal_answers(engine.scene(), r.value(), b.value(),
                             "auto query " + std::to_string(q));
    }
}

// Issue #14 ("no spikes"): `automatic` used to run the Voronoi culler on the second query and
// every 32nd to measure it, a 10-70x stall on those frames. It now never runs a Voronoi culler
// nobody asked for: 70 queries with moving vertices, every one BVH with no Stage II, every one
// equal to brute force; with a GPU backend set (the daemon's case) too.
TEST(VoronoiVsBrute, AutomaticNeverExploresUnasked) {
    Rng rng(80200);
    const auto meshes = test::random_scene(rng);
    std::string reason;
    auto gpu = gpu_backend(&reason);
    for (const bool with_gpu : {false, true}) {
        if (with_gpu && !gpu) {
            std::cout << "no GPU backend (" << reason << "): CPU engine only\n";
            continue;
        }
        ProximityEngine engine;
        ProximityEngine brute;
        if (with_gpu) {
            engine.set_gpu_backend(gpu);
        }
        add_scene(engine, meshes);
        add_scene(brute, meshes);
        for (int q = 0; q < 70; ++q) {
            const std::string where =
                (with_gpu ? "gpu engine, auto query " : "cpu engine, auto query ") +
                std::to_string(q);
            if (q > 0) {
                // A small rigid shift of one object each query: a stream of changing frames.
                SceneUpdate u;
                const std::size_t i = static_cast<std::size_t>(q) % engine.scene().size();
                auto moved = engine.scene()[i].vertices;
                for (auto& v : moved) {
                    v.x += (q % 2 == 0 ? 1e-3 : -1e-3);
                }
                u.positions.push_back({engine.scene()[i].id, moved});
                SceneUpdate ub;
                ub.positions.push_back({brute.scene()[i].id, moved});
                ASSERT_TRUE(engine.scene().apply(std::move(u)).ok());
                ASSERT_TRUE(brute.scene().apply(std::move(ub)).ok());
            }
            auto r = engine.query(full_request(CullerKind::automatic, 0.1));
            auto b = brute.query(full_request(CullerKind::brute, 0.1));
            ASSERT_TRUE(r.ok()) << r.status().to_string();
            ASSERT_TRUE(b.ok()) << b.status().to_string();
            EXPECT_EQ(r->stats.culler, "bvh") << where;
            EXPECT_EQ(r->stats.dvd_samples, 0u) << where;
            EXPECT_EQ(r->stats.voronoi_seconds, 0.0) << where;
            expect_equal_answers(engine.scene(), r.value(), b.value(), where);
        }
    }
}

// A client asks for the Voronoi culler by name (its own exploration, on its own frame): from then
// on `automatic` keeps whichever of the two was measured cheaper for this kind of request, each
// frame's run re-measuring the culler it used. The choice is predicted here from the times the
// queries report, and every answer equals brute force.
TEST(VoronoiVsBrute, AutomaticChoosesVoronoiOnlyFromMeasurementsAskedFor) {
    Rng rng(80300);
    const auto meshes = test::random_scene(rng);
    ProximityEngine engine;
    ProximityEngine brute;
    add_scene(engine, meshes);
    add_scene(brute, meshes);
    auto b = brute.query(full_request(CullerKind::brute, 0.1));
    ASSERT_TRUE(b.ok());
    double bvh = -1;
    double voronoi = -1;
    auto expect_auto = [&](const std::string& where) {
        auto r = engine.query(full_request(CullerKind::automatic, 0.1));
        ASSERT_TRUE(r.ok()) << r.status().to_string();
        const bool want_voronoi = voronoi >= 0 && bvh >= 0 && voronoi < bvh;
        EXPECT_EQ(r->stats.culler, want_voronoi ? "voronoi-cpu" : "bvh")
            << where << ": bvh " << bvh << " s, voronoi " << voronoi << " s";
        (r->stats.culler == "bvh" ? bvh : voronoi) = r->stats.total_seconds;
        expect_equal_answers(engine.scene(), r.value(), b.value(), where);
    };
    expect_auto("first auto query");
    expect_auto("second auto query");
    // Brute force asked for by name is never a candidate of `automatic`.
    auto forced = engine.query(full_request(CullerKind::brute, 0.1));
    ASSERT_TRUE(forced.ok());
    expect_auto("after a brute query");
    auto asked = engine.query(full_request(CullerKind::voronoi_cpu, 0.1));
    ASSERT_TRUE(asked.ok()) << asked.status().to_string();
    EXPECT_EQ(asked->stats.culler, "voronoi-cpu");
    expect_equal_answers(engine.scene(), asked.value(), b.value(), "asked voronoi-cpu");
    voronoi = asked->stats.total_seconds;
    for (int q = 0; q < 6; ++q) {
        expect_auto("auto query " + std::to_string(q) + " after asking for voronoi-cpu");
    }
}

}  // namespace
}  // namespace proxima
