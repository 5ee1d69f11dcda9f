// Property tests: on random scenes (closed and open, touching, crossing, nested, degenerate),
// every query through the BVH culler equals brute force, and brute force through the query code
// equals a naive loop written here independently of it.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "proxima/distance/primitives.hpp"
#include "proxima/query/query.hpp"
#include "support/random_scenes.hpp"
#include "support/sanitized.hpp"

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

// Naive references, independent of cullers and of the query code.
double naive_object_distance(const SceneObject& a, const SceneObject& b) {
    double best = std::numeric_limits<double>::infinity();
    for (std::uint32_t i = 0; i < a.triangle_count(); ++i) {
        for (std::uint32_t j = 0; j < b.triangle_count(); ++j) {
            best = std::min(best, triangle_triangle(corners(a, i), corners(b, j)).squared_distance);
        }
    }
    return std::sqrt(best);
}

double naive_self_distance(const SceneObject& a, std::uint32_t t) {
    double best = std::numeric_limits<double>::infinity();
    for (std::uint32_t u = 0; u < a.triangle_count(); ++u) {
        if (!a.topology->adjacent(t, u)) {
            best = std::min(best, triangle_triangle(corners(a, t), corners(a, u)).squared_distance);
        }
    }
    return std::sqrt(best);
}

std::vector<FeaturePair> naive_pairs(const Scene& s, double radius, bool intersect) {
    std::vector<FeaturePair> out;
    for (std::uint32_t i = 0; i < s.size(); ++i) {
        for (std::uint32_t j = i; j < s.size(); ++j) {
            for (std::uint32_t ta = 0; ta < s[i].triangle_count(); ++ta) {
                for (std::uint32_t tb = (i == j ? ta + 1 : 0); tb < s[j].triangle_count(); ++tb) {
                    if (i == j && s[i].topology->adjacent(ta, tb)) {
                        continue;
                    }
                    const Triangle x = corners(s[i], ta);
                    const Triangle y = corners(s[j], tb);
                    if (intersect ? triangles_intersect(x, y)
                                  : triangle_triangle(x, y).squared_distance <= radius * radius) {
                        out.push_back({i, ta, j, tb, 0.0});
                    }
                }
            }
        }
    }
    return out;
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

QueryRequest full_request(CullerKind culler, double tolerance) {
    QueryRequest r;
    r.separation = true;
    r.self = true;
    r.collisions = true;
    r.tolerance = tolerance;
    r.pns = true;
    r.culler = culler;
    return r;
}

// Checks the BVH answer against the brute-force answer for the same scene state.
void expect_equal_answers(const Scene& scene, const QueryResult& bvh, const QueryResult& brute,
                          const std::string& where) {
    ASSERT_EQ(bvh.separation.size(), brute.separation.size()) << where;
    for (std::size_t i = 0; i < scene.size(); ++i) {
        const auto& x = bvh.separation[i];
        const auto& y = brute.separation[i];
        // Within rounding: a pair of objects may be measured as (a, b) or (b, a).
        EXPECT_TRUE(same_distance(x.distance, y.distance))
            << where << " object " << i << ": bvh " << x.distance << " brute " << y.distance;
        if (x.other != NO_OBJECT) {
            // The reported pair realizes the reported distance (ties may pick another pair).
            const auto j = static_cast<std::size_t>(x.other);
            ASSERT_NE(j, i) << where;
            const auto cp = triangle_triangle(corners(scene[i], x.triangle),
                                              corners(scene[j], x.other_triangle));
            EXPECT_TRUE(same_distance(std::sqrt(cp.squared_distance), x.distance)) << where;
            EXPECT_TRUE(same_distance(norm(x.point - x.other_point), x.distance)) << where;
        }
    }
    ASSERT_EQ(bvh.self.size(), brute.self.size()) << where;
    for (std::size_t i = 0; i < scene.size(); ++i) {
        for (std::size_t t = 0; t < bvh.self[i].size(); ++t) {
            const auto& x = bvh.self[i][t];
            const auto& y = brute.self[i][t];
            // Bit for bit: the same exact primitive on the same pair, smaller index first.
            ASSERT_EQ(x.distance, y.distance) << where << " object " << i << " triangle " << t
                                              << ": bvh " << x.distance << " brute " << y.distance;
            if (x.closest != NO_OBJECT) {
                EXPECT_FALSE(scene[i].topology->adjacent(static_cast<std::uint32_t>(t),
                                                         static_cast<std::uint32_t>(x.closest)))
                    << where;
            }
        }
    }
    EXPECT_TRUE(same_pairs(bvh.collisions, brute.collisions))
        << where << ": " << bvh.collisions.size() << " vs " << brute.collisions.size();
    EXPECT_TRUE(same_pairs(bvh.tolerance, brute.tolerance))
        << where << ": " << bvh.tolerance.size() << " vs " << brute.tolerance.size();
    // The BVH's candidates must contain every pair brute force finds within the bound.
    for (const auto& p : brute.tolerance) {
        EXPECT_TRUE(std::binary_search(bvh.pns.begin(), bvh.pns.end(), p)) << where;
    }
    // Culling never tests more pairs than brute force, except that a pair tested while seeding a
    // triangle's self bound may be tested again (at most one per triangle).
    EXPECT_LE(bvh.stats.exact_tests, brute.stats.exact_tests + scene.triangle_count()) << where;
    // The brute-force count is the brute-force culler's own count, whatever culler ran.
    EXPECT_EQ(brute.stats.exact_tests, brute.stats.brute_force_tests) << where;
    EXPECT_EQ(bvh.stats.brute_force_tests, brute.stats.brute_force_tests) << where;
}

// 2,000 random scenes in four shards (separate ctest entries, so they run in parallel). Under a
// sanitizer (brute force ~3x slower, 90 s of the ASan stage for the four) the first 125 of each
// shard: the same code paths with the same kinds of scenes; the release stage checks all 2,000
// answers.
class RandomScenes : public ::testing::TestWithParam<int> {};
constexpr int SCENES_PER_SHARD = 500;
constexpr int SCENES_RUN_PER_SHARD = test::SANITIZED ? 125 : SCENES_PER_SHARD;

TEST_P(RandomScenes, AllQueriesEqualBruteForce) {
    int scenes = 0;
    const auto first = static_cast<std::uint64_t>(1 + GetParam() * SCENES_PER_SHARD);
    for (std::uint64_t seed = first; seed < first + SCENES_RUN_PER_SHARD; ++seed) {
        Rng rng(seed);
        ProximityEngine bvh;
        ProximityEngine brute;
        const auto meshes = test::random_scene(rng);
        for (const auto& m : meshes) {
            ASSERT_TRUE(bvh.scene().add_object(m).ok());
            ASSERT_TRUE(brute.scene().add_object(m).ok());
        }
        const double tol = test::uniform(rng, 0.0, 0.2);
        auto a = bvh.query(full_request(CullerKind::bvh, tol));
        auto b = brute.query(full_request(CullerKind::brute, tol));
        ASSERT_TRUE(a.ok() && b.ok());
        const std::string where = "seed " + std::to_string(seed);
        expect_equal_answers(bvh.scene(), a.value(), b.value(), where);
        ++scenes;
        if (HasFatalFailure()) {
            return;
        }
    }
    EXPECT_EQ(scenes, SCENES_RUN_PER_SHARD);
}
INSTANTIATE_TEST_SUITE_P(QueriesVsBrute, RandomScenes, ::testing::Range(0, 4));

TEST(QueriesVsBrute, BruteForceMatchesNaiveLoops) {
    for (std::uint64_t seed = 10000; seed < 10150; ++seed) {
        Rng rng(seed);
        ProximityEngine engine;
        for (const auto& m : test::random_scene(rng)) {
            ASSERT_TRUE(engine.scene().add_object(m).ok());
        }
        const double tol = test::uniform(rng, 0.0, 0.2);
        auto r = engine.query(full_request(CullerKind::brute, tol));
        ASSERT_TRUE(r.ok());
        const Scene& s = engine.scene();
        for (std::size_t i = 0; i < s.size(); ++i) {
            double best = std::numeric_limits<double>::infinity();
            for (std::size_t j = 0; j < s.size(); ++j) {
                if (j != i) {
                    best = std::min(best, naive_object_distance(s[i], s[j]));
                }
            }
            EXPECT_TRUE(same_distance(r->separation[i].distance, best)) << "seed " << seed;
            for (std::uint32_t t = 0; t < s[i].triangle_count(); ++t) {
                ASSERT_TRUE(same_distance(r->self[i][t].distance, naive_self_distance(s[i], t)))
                    << "seed " << seed << " object " << i << " triangle " << t;
            }
        }
        EXPECT_TRUE(same_pairs(r->collisions, naive_pairs(s, 0.0, true))) << "seed " << seed;
        EXPECT_TRUE(same_pairs(r->tolerance, naive_pairs(s, tol, false))) << "seed " << seed;
    }
}

// stats.brute_force_tests is what the brute-force culler tests for the queries asked (issue #18:
// with the brute culler it once counted each object pair of the separation query twice, so
// exact_tests exceeded it): equal with the brute culler for every combination of queries, never
// exceeded by another culler beyond the self query's seeding allowance (one test per triangle).
// 40 scenes; under a sanitizer (45 s of the ASan stage) 10: every culler and every combination
// of queries still runs on each, only fewer random scenes.
TEST(QueriesVsBrute, TheBruteForceCountIsWhatBruteForceTests) {
    const CullerKind cullers[] = {CullerKind::brute, CullerKind::bvh, CullerKind::voronoi_cpu};
    const std::uint64_t scenes = test::SANITIZED ? 10 : 40;
    for (std::uint64_t seed = 20000; seed < 20000 + scenes; ++seed) {
        Rng rng(seed);
        const auto meshes = test::random_scene(rng);
        const double tol = test::uniform(rng, 0.0, 0.2);
        for (unsigned mask = 1; mask < 32; ++mask) {
            QueryRequest request;
            request.separation = (mask & 1U) != 0;
            request.self = (mask & 2U) != 0;
            request.collisions = (mask & 4U) != 0;
            if ((mask & 8U) != 0) {
                request.tolerance = tol;
            }
            request.pns = (mask & 16U) != 0;
            const bool pns_only = request.pns && !request.collisions && !request.tolerance;
            std::uint64_t brute_count = 0;
            for (CullerKind culler : cullers) {
                ProximityEngine engine;
                for (const auto& m : meshes) {
                    ASSERT_TRUE(engine.scene().add_object(m).ok());
                }
                request.culler = culler;
                auto r = engine.query(request);
                ASSERT_TRUE(r.ok()) << r.status().to_string();
                const auto& st = r->stats;
                const std::string where = "seed " + std::to_string(seed) + " queries " +
                                          std::to_string(mask) + " culler " + culler_name(culler);
                if (culler == CullerKind::brute) {
                    brute_count = st.brute_force_tests;
                    if (pns_only) {
                        // PNS alone counts candidates, no exact test: brute force's count for it
                        // is the pairs it would examine.
                        EXPECT_LT(st.exact_tests, st.brute_force_tests) << where;
                    } else {
                        EXPECT_EQ(st.exact_tests, st.brute_force_tests) << where;
                    }
                } else {
                    EXPECT_EQ(st.brute_force_tests, brute_count) << where;
                    const std::uint64_t seeding =
                        request.self ? engine.scene().triangle_count() : 0;
                    EXPECT_LE(st.exact_tests, st.brute_force_tests + seeding) << where;
                }
            }
        }
    }
}

// Several frames of deformation through one engine (refitted hierarchies, coherent sort),
// against a fresh brute force every frame; one frame replaces an object by two fragments.
// 150 scenes; under a sanitizer (27 s of the ASan stage) 50, each with every kind of frame.
TEST(QueriesVsBrute, DeformingFramesAndTopologyChange) {
    const std::uint64_t scenes = test::SANITIZED ? 50 : 150;
    for (std::uint64_t seed = 20000; seed < 20000 + scenes; ++seed) {
        Rng rng(seed);
        ProximityEngine bvh;
        for (const auto& m : test::random_scene(rng)) {
            ASSERT_TRUE(bvh.scene().add_object(m).ok());
        }
        ASSERT_TRUE(bvh.query(full_request(CullerKind::bvh, 0.05)).ok());  // builds
        for (int frame = 1; frame <= 4; ++frame) {
            SceneUpdate update;
            if (frame == 2) {
                // Topology change: the first object becomes two fragments (its two halves of
                // triangles, each a new mesh), with no preprocessing step in between.
                const SceneObject& o = bvh.scene()[0];
                TriangleMesh whole{o.vertices, o.topology->triangles()};
                TriangleMesh first{whole.vertices, {}};
                TriangleMesh second{whole.vertices, {}};
                for (std::size_t t = 0; t < whole.triangles.size(); ++t) {
                    (t % 2 == 0 ? first : second).triangles.push_back(whole.triangles[t]);
                }
                SceneUpdate::Replacement rep{o.id, {{"frag-a", first}}};
                if (!second.triangles.empty()) {
                    rep.fragments.push_back({"frag-b", second});
                }
                update.replacements.push_back(std::move(rep));
            }
            for (const auto& o : bvh.scene().objects()) {
                if (frame == 2 && o.id == bvh.scene()[0].id) {
                    continue;
                }
                update.positions.push_back({o.id, test::jitter(rng, o.vertices, 0.05)});
            }
            ASSERT_TRUE(bvh.scene().apply(std::move(update)).ok());
            ProximityEngine brute;
            for (const auto& o : bvh.scene().objects()) {
                ASSERT_TRUE(
                    brute.scene().add_object({o.name, {o.vertices, o.topology->triangles()}}).ok());
            }
            auto a = bvh.query(full_request(CullerKind::bvh, 0.05));
            auto b = brute.query(full_request(CullerKind::brute, 0.05));
            ASSERT_TRUE(a.ok() && b.ok());
            expect_equal_answers(
                bvh.scene(), a.value(), b.value(),
                "seed " + std::to_string(seed) + " frame " + std::to_string(frame));
            if (HasFatalFailure()) {
                return;
            }
        }
    }
}

// Larger single objects where culling matters: the BVH must do far fewer exact tests than brute
// force and still agree.
TEST(QueriesVsBrute, FoldedSheetsCullAndAgree) {
    for (std::uint64_t seed = 30000; seed < 30010; ++seed) {
        Rng rng(seed);
        ProximityEngine bvh;
        ProximityEngine brute;
        for (int k = 0; k < 2; ++k) {
            auto m = test::sheet(rng, 16, 12, test::uniform(rng, 0.005, 0.05));
            test::transform(m, 1.0, {0.3 * k, 0.1 * k, 0.02 * k}, 0.1 * k);
            ASSERT_TRUE(bvh.scene().add_object({"s", m}).ok());
            ASSERT_TRUE(brute.scene().add_object({"s", m}).ok());
        }
        auto a = bvh.query(full_request(CullerKind::bvh, 0.02));
        auto b = brute.query(full_request(CullerKind::brute, 0.02));
        ASSERT_TRUE(a.ok() && b.ok());
        expect_equal_answers(bvh.scene(), a.value(), b.value(), "seed " + std::to_string(seed));
        EXPECT_LT(a->stats.exact_tests * 5, b->stats.exact_tests) << "seed " << seed;
    }
}

// One object made of many disjoint components (as a simulation file read without
// --split-components): closed spheres near and far from each other, open sheets, tetrahedra (whose
// four triangles are all adjacent, so they have no partner inside their component) and lone
// triangles. Many triangles start the self search without a seed, which is what made the traversal
// slow on such objects; the answer must still equal brute force's, tie-breaks included.
TriangleMesh many_components(Rng& rng, int count) {
    TriangleMesh all;
    auto append = [&](const TriangleMesh& m) {
        const auto base = static_cast<std::uint32_t>(all.vertices.size());
        all.vertices.insert(all.vertices.end(), m.vertices.begin(), m.vertices.end());
        for (const auto& t : m.triangles) {
            all.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
        }
    };
    for (int k = 0; k < count; ++k) {
        // Clustered in a few places, so some components nearly touch and some are far apart.
        const double spread = k % 3 == 0 ? 8.0 : 2.0;
        const Vec3 at{test::uniform(rng, 0, spread), test::uniform(rng, 0, spread),
                      test::uniform(rng, 0, spread)};
        TriangleMesh m;
        switch (std::uniform_int_distribution<int>(0, 5)(rng)) {
            case 0:
            case 1:
                m = test::sphere(rng, std::uniform_int_distribution<int>(3, 6)(rng),
                                 std::uniform_int_distribution<int>(3, 8)(rng), 1.0, 0.1);
                break;
            case 2:
                m = test::sheet(rng, std::uniform_int_distribution<int>(1, 5)(rng),
                                std::uniform_int_distribution<int>(1, 4)(rng),
                                test::uniform(rng, 0.01, 0.3));
                break;
            case 3:
                m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
                m.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
                break;
            case 4:
                m = test::box({0, 0, 0}, {1, 1, 1});
                break;
            default:
                m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
                m.triangles = {{0, 1, 2}};
        }
        test::transform(m, test::uniform(rng, 0.1, 0.5), at, test::uniform(rng, 0, 6));
        append(m);
    }
    return all;
}

TEST(QueriesVsBrute, ManyComponentsInOneObject) {
    for (std::uint64_t seed = 40000; seed < 40024; ++seed) {
        Rng rng(seed);
        ProximityEngine bvh;
        ProximityEngine brute;
        const auto m = many_components(rng, std::uniform_int_distribution<int>(2, 40)(rng));
        ASSERT_TRUE(bvh.scene().add_object({"many", m}).ok());
        ASSERT_TRUE(brute.scene().add_object({"many", m}).ok());
        if (seed % 2 == 0) {
            // A second object, also of several components, so separation is checked too.
            const auto o = many_components(rng, 5);
            ASSERT_TRUE(bvh.scene().add_object({"other", o}).ok());
            ASSERT_TRUE(brute.scene().add_object({"other", o}).ok());
        }
        auto a = bvh.query(full_request(CullerKind::bvh, 0.05));
        auto b = brute.query(full_request(CullerKind::brute, 0.05));
        ASSERT_TRUE(a.ok() && b.ok());
        const std::string where = "seed " + std::to_string(seed);
        expect_equal_answers(bvh.scene(), a.value(), b.value(), where);
        // And on moved positions (a refit, the seeds from the previous answer do not carry over).
        const auto moved = test::jitter(rng, m.vertices, 0.05);
        for (ProximityEngine* e : {&bvh, &brute}) {
            SceneUpdate update;
            update.positions.push_back({e->scene()[0].id, moved});
            ASSERT_TRUE(e->scene().apply(std::move(update)).ok());
        }
        a = bvh.query(full_request(CullerKind::bvh, 0.05));
        b = brute.query(full_request(CullerKind::brute, 0.05));
        ASSERT_TRUE(a.ok() && b.ok());
        expect_equal_answers(bvh.scene(), a.value(), b.value(), where + " moved");
        if (HasFatalFailure()) {
            return;
        }
    }
}

// Two self answers for the same scene state, bit for bit: the same closest triangle (ties go to
// the smaller index), distance and points for every triangle.
void expect_same_self(const QueryResult& a, const char* a_name, const QueryResult& b,
                      const char* b_name, const std::string& where) {
    ASSERT_EQ(a.self.size(), b.self.size()) << where;
    for (std::size_t i = 0; i < a.self.size(); ++i) {
        ASSERT_EQ(a.self[i].size(), b.self[i].size()) << where;
        for (std::size_t t = 0; t < a.self[i].size(); ++t) {
            const auto& x = a.self[i][t];
            const auto& y = b.self[i][t];
            EXPECT_TRUE(x.closest == y.closest && x.distance == y.distance && x.point == y.point &&
                        x.other_point == y.other_point)
                << where << " object " << i << " triangle " << t << ": " << a_name << " "
                << x.closest << " " << x.distance << ", " << b_name << " " << y.closest << " "
                << y.distance;
        }
    }
}

// Frame-to-frame coherence (warm self queries seed each triangle with its previous closest
// triangle): through one engine, every frame's self answer equals brute force and, bit for bit,
// the same engine's cold answer (forget_coherence). The frames cover what can make a remembered
// answer wrong or stale: small motion, a large move that scrambles every position (the previous
// closest is now anywhere), a topology change (replacement), objects removed and added, a frame
// without a self query (the memory is two frames old) and many components in one object.
TEST(QueriesVsBrute, WarmSelfFramesEqualBruteForceAndCold) {
    QueryRequest self_only;
    self_only.separation = false;
    self_only.self = true;
    self_only.culler = CullerKind::bvh;
    // 20 scenes (about 15 s); under a sanitizer, which runs the brute force ~10x slower, 5.
    const std::uint64_t scenes = test::SANITIZED ? 5 : 20;
    for (std::uint64_t seed = 50000; seed < 50000 + scenes; ++seed) {
        Rng rng(seed);
        ProximityEngine bvh;
        for (const auto& m : test::random_scene(rng)) {
            ASSERT_TRUE(bvh.scene().add_object(m).ok());
        }
        ASSERT_TRUE(bvh.scene().add_object({"many", many_components(rng, 12)}).ok());
        ASSERT_TRUE(bvh.query(self_only).ok());  // builds, remembers the first answer
        for (int frame = 1; frame <= 7; ++frame) {
            SceneUpdate update;
            const SceneObject& first = bvh.scene()[0];
            if (frame == 3) {
                TriangleMesh whole{first.vertices, first.topology->triangles()};
                TriangleMesh half{whole.vertices, {}};
                for (std::size_t t = 0; t < whole.triangles.size(); t += 2) {
                    half.triangles.push_back(whole.triangles[t]);
                }
                update.replacements.push_back({first.id, {{"half", half}}});
            }
            if (frame == 5 && bvh.scene().size() > 2) {
                update.removals.push_back(bvh.scene()[1].id);
                update.additions.push_back({"new", many_components(rng, 6)});
            }
            for (const auto& o : bvh.scene().objects()) {
                if ((frame == 3 && o.id == first.id) ||
                    (frame == 5 && !update.removals.empty() && o.id == update.removals[0])) {
                    continue;
                }
                std::vector<Vec3> v = test::jitter(rng, o.vertices, 0.05);
                if (frame == 2 || frame == 6) {
                    std::shuffle(v.begin(), v.end(), rng);  // a large move: stale closest pairs
                }
                update.positions.push_back({o.id, std::move(v)});
            }
            ASSERT_TRUE(bvh.scene().apply(std::move(update)).ok());
            const std::string where =
                "seed " + std::to_string(seed) + " frame " + std::to_string(frame);
            if (frame == 4) {
                // Positions only: the next self query seeds from an answer two frames old.
                QueryRequest separation;
                separation.culler = CullerKind::bvh;
                ASSERT_TRUE(bvh.query(separation).ok());
                continue;
            }
            auto warm = bvh.query(full_request(CullerKind::bvh, 0.05));
            ASSERT_TRUE(warm.ok());
            ProximityEngine brute;
            for (const auto& o : bvh.scene().objects()) {
                ASSERT_TRUE(
                    brute.scene().add_object({o.name, {o.vertices, o.topology->triangles()}}).ok());
            }
            auto b = brute.query(full_request(CullerKind::brute, 0.05));
            ASSERT_TRUE(b.ok());
            expect_equal_answers(bvh.scene(), warm.value(), b.value(), where + " warm");
            bvh.forget_coherence();
            auto cold = bvh.query(self_only);
            ASSERT_TRUE(cold.ok());
            expect_same_self(warm.value(), "warm", cold.value(), "cold", where);
            if (HasFailure()) {
                return;
            }
        }
    }
}

// Rigid reuse (docs/algorithms.md): an object that moved rigidly answers its self query from a
// candidate list recorded by an earlier answer, guarded by a bound on how far it is from a rigid
// image of the positions the list was made at. Through one engine, objects move rigidly (a fresh
// rotation and translation of their first positions every frame, rounded to single precision as
// a simulator's positions are, so the motion is rigid only up to ~1e-7), then one is deformed a
// little, one has a single vertex pulled across the object (a fold no list can foresee), and
// they keep moving rigidly up to frame 30. Every frame's self answer
// must equal brute force bit for bit, and most frames must have answered objects from their
// lists (else this would test nothing new).
TEST(QueriesVsBrute, RigidFramesReuseTheirListsAndEqualBruteForce) {
    QueryRequest self_only;
    self_only.separation = false;
    self_only.self = true;
    self_only.culler = CullerKind::bvh;
    const std::uint64_t scenes = test::SANITIZED ? 2 : 6;
    const int frames = test::SANITIZED ? 14 : 30;
    for (std::uint64_t seed = 70000; seed < 70000 + scenes; ++seed) {
        Rng rng(seed);
        ProximityEngine bvh;
        std::vector<NamedMesh> meshes = test::random_scene(rng);
        meshes.push_back({"many", many_components(rng, 8)});
        meshes.push_back({"grid", test::sheet(rng, 12, 12, 0.0)});  // a regular lattice: ties
        for (const auto& m : meshes) {
            ASSERT_TRUE(bvh.scene().add_object(m).ok());
        }
        std::vector<std::vector<Vec3>> rest;
        for (const auto& o : bvh.scene().objects()) {
            rest.push_back(o.vertices);
        }
        std::uint64_t reused = 0;
        for (int frame = 0; frame < frames; ++frame) {
            SceneUpdate update;
            for (std::size_t i = 0; i < bvh.scene().size(); ++i) {
                const SceneObject& o = bvh.scene()[i];
                // A rotation about a random axis through the origin, then a translation.
                Vec3 axis{test::uniform(rng, -1, 1), test::uniform(rng, -1, 1),
                          test::uniform(rng, -1, 1)};
                axis = (1.0 / std::max(norm(axis), 1e-9)) * axis;
                const double angle = test::uniform(rng, -3.0, 3.0);
                const Vec3 shift{test::uniform(rng, -5, 5), test::uniform(rng, -5, 5),
                                 test::uniform(rng, -5, 5)};
                const double c = std::cos(angle);
                const double sn = std::sin(angle);
                std::vector<Vec3> v(rest[i].size());
                for (std::size_t k = 0; k < v.size(); ++k) {
                    const Vec3& p = rest[i][k];
                    // Rodrigues' formula.
                    const Vec3 r = c * p + sn * cross(axis, p) + (1.0 - c) * dot(axis, p) * axis;
                    const Vec3 moved = r + shift;
                    v[k] = {static_cast<float>(moved.x), static_cast<float>(moved.y),
                            static_cast<float>(moved.z)};
                }
                if (frame == 10 && i == 0) {
                    v = test::jitter(rng, v, 1e-3);  // a small deformation
                }
                if (frame == 12 && i + 1 == bvh.scene().size() && v.size() > 2) {
                    v[0] = v[v.size() / 2] + Vec3{1e-4, 1e-4, 1e-4};  // a fold
                }
                update.positions.push_back({o.id, std::move(v)});
            }
            ASSERT_TRUE(bvh.scene().apply(std::move(update)).ok());
            const std::string where =
                "seed " + std::to_string(seed) + " frame " + std::to_string(frame);
            auto warm = bvh.query(self_only);
            ASSERT_TRUE(warm.ok());
            reused += warm->stats.self_objects_reused;
            ProximityEngine brute;
            for (const auto& o : bvh.scene().objects()) {
                ASSERT_TRUE(
                    brute.scene().add_object({o.name, {o.vertices, o.topology->triangles()}}).ok());
            }
            QueryRequest brute_self = self_only;
            brute_self.culler = CullerKind::brute;
            auto b = brute.query(brute_self);
            ASSERT_TRUE(b.ok());
            expect_same_self(warm.value(), "warm", b.value(), "brute", where);
            EXPECT_LE(warm->stats.exact_tests, b->stats.exact_tests + bvh.scene().triangle_count())
                << where;
            if (HasFailure()) {
                return;
            }
        }
        // Lists are recorded on the second rigid step and used from the third on, except after
        // the deformation and the fold: at least half of all object-frames.
        EXPECT_GE(reused, bvh.scene().size() * static_cast<std::size_t>(frames) / 2)
            << "seed " << seed;
    }
}

}  // namespace
}  // namespace proxima
