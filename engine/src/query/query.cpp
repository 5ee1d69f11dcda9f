#include "proxima/query/query.hpp"

#include <algorithm>
#include <cmath>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "proxima/distance/primitives.hpp"

namespace proxima {

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

Triangle corners(const SceneObject& obj, std::uint32_t t) {
    const auto& tri = obj.triangle(t);
    return {obj.vertices[tri[0]], obj.vertices[tri[1]], obj.vertices[tri[2]]};
}

// Shared by the parallel loops of one query: the exact-test count and the stop flag.
struct Work {
    const CancelToken* cancel = nullptr;
    std::atomic<std::uint64_t> exact_tests{0};
    std::atomic<bool> stopped{false};

    bool should_stop() {
        if (stopped.load(std::memory_order_relaxed)) {
            return true;
        }
        if (cancel != nullptr && cancel->should_stop()) {
            stopped.store(true, std::memory_order_relaxed);
            return true;
        }
        return false;
    }
};

// Inflates an upper bound so that a strict "<" search seeded with it still accepts a pair whose
// computed distance equals the bound up to rounding.
double seed_bound_sq(double upper) {
    if (!std::isfinite(upper)) {
        return std::numeric_limits<double>::infinity();
    }
    return upper * upper * (1.0 + 1e-9) + std::numeric_limits<double>::min();
}

void run_separation(const Scene& scene, const Culler& culler, const SweepAndPrune& sap,
                    Work& work, QueryResult& result) {
    const std::size_t n = scene.size();
    result.separation.assign(n, Separation{});
    std::atomic<std::uint64_t> object_pairs{0};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1), [&](const auto& range) {
        std::uint64_t tests = 0;
        std::uint64_t pairs = 0;
        std::vector<std::size_t> candidates;
        for (std::size_t i = range.begin(); i != range.end(); ++i) {
            if (work.should_stop()) {
                break;
            }
            Separation best;
            double bound_sq = std::numeric_limits<double>::infinity();
            candidates.clear();
            if (culler.object_culling()) {
                const double upper = sap.separation_upper_bound(scene, i);
                bound_sq = seed_bound_sq(upper);
                sap.within(scene, i, std::isfinite(upper) ? upper : 0.0, candidates);
            } else {
                for (std::size_t j = 0; j < n; ++j) {
                    if (j != i) {
                        candidates.push_back(j);
                    }
                }
            }
            const SceneObject& a = scene[i];
            for (auto j : candidates) {
                // Candidates come in increasing box distance: once one is beyond the bound, all
                // the rest are too.
                if (culler.object_culling() &&
                    box_squared_distance(a.box, scene[j].box) * CULL_SAFETY >= bound_sq) {
                    break;
                }
                ++pairs;
                const SceneObject& b = scene[j];
                culler.nearest_between(scene, i, j, bound_sq,
                                       [&](std::uint32_t ta, std::uint32_t tb) {
                                           ++tests;
                                           const auto cp = triangle_triangle(corners(a, ta),
                                                                             corners(b, tb));
                                           if (cp.squared_distance < bound_sq) {
                                               bound_sq = cp.squared_distance;
                                               best.other = static_cast<std::int64_t>(j);
                                               best.triangle = ta;
                                               best.other_triangle = tb;
                                               best.point = cp.point_a;
                                               best.other_point = cp.point_b;
                                           }
                                       });
            }
            if (best.other != NO_OBJECT) {
                best.distance = std::sqrt(bound_sq);
            }
            result.separation[i] = best;
        }
        work.exact_tests += tests;
        object_pairs += pairs;
    });
    result.stats.object_pairs_tested += object_pairs;
}

void run_self(const Scene& scene, const Culler& culler, Work& work, QueryResult& result) {
    const std::size_t n = scene.size();
    result.self.assign(n, {});
    for (std::size_t a = 0; a < n; ++a) {
        result.self[a].assign(scene[a].triangle_count(), SelfDistance{});
    }
    tbb::parallel_for(std::size_t{0}, n, [&](std::size_t a) {
        const SceneObject& obj = scene[a];
        const MeshTopology& topo = *obj.topology;
        const auto nt = static_cast<std::uint32_t>(obj.triangle_count());
        tbb::parallel_for(
            tbb::blocked_range<std::uint32_t>(0, nt, 256), [&](const auto& range) {
                if (work.should_stop()) {
                    return;
                }
                std::uint64_t tests = 0;
                std::vector<std::uint32_t> ring;
                for (std::uint32_t t = range.begin(); t != range.end(); ++t) {
                    SelfDistance best;
                    double bound_sq = std::numeric_limits<double>::infinity();
                    const Triangle tt = corners(obj, t);
                    auto test = [&](std::uint32_t u) {
                        ++tests;
                        const auto cp = triangle_triangle(tt, corners(obj, u));
                        if (cp.squared_distance < bound_sq) {
                            bound_sq = cp.squared_distance;
                            best.closest = u;
                            best.point = cp.point_a;
                            best.other_point = cp.point_b;
                        }
                    };
                    if (culler.object_culling()) {
                        // Seed §5.2.2: the 2-ring's closest triangle is an upper bound that is
                        // usually tight on meshes, so the hierarchy search below prunes early.
                        topo.two_ring(t, ring);
                        for (auto u : ring) {
                            test(u);
                        }
                        culler.nearest_within(scene, a, t, bound_sq,
                                              [&](std::uint32_t, std::uint32_t u) {
                                                  if (!std::binary_search(ring.begin(), ring.end(), u)) {
                                                      test(u);
                                                  }
                                              });
                    } else {
                        culler.nearest_within(scene, a, t, bound_sq,
                                              [&](std::uint32_t, std::uint32_t u) { test(u); });
                    }
                    if (best.closest != NO_OBJECT) {
                        best.distance = std::sqrt(bound_sq);
                    }
                    result.self[a][t] = best;
                }
                work.exact_tests += tests;
            });
    });
}

// Object pairs (i <= j; i == j for the intra-object part) whose boxes come within `radius`.
std::vector<std::pair<std::size_t, std::size_t>> object_pairs_within(const Scene& scene,
                                                                     const Culler& culler,
                                                                     const SweepAndPrune& sap,
                                                                     double radius) {
    std::vector<std::pair<std::size_t, std::size_t>> pairs;
    std::vector<std::size_t> near;
    for (std::size_t i = 0; i < scene.size(); ++i) {
        pairs.emplace_back(i, i);
        if (culler.object_culling()) {
            near.clear();
            sap.within(scene, i, radius, near);
            for (auto j : near) {
                if (j > i) {
                    pairs.emplace_back(i, j);
                }
            }
        } else {
            for (std::size_t j = i + 1; j < scene.size(); ++j) {
                pairs.emplace_back(i, j);
            }
        }
    }
    return pairs;
}

enum class PairTest { intersect, within };

// Runs the exact test on every candidate pair of every object pair within `radius`; appends the
// pairs that pass to `hits` (sorted) and, when `pns` is given, every candidate to it.
void run_pairs(const Scene& scene, const Culler& culler, const SweepAndPrune& sap, double radius,
               PairTest test, Work& work, std::vector<FeaturePair>& hits,
               std::vector<FeaturePair>* pns, QueryStats& stats) {
    const auto object_pairs = object_pairs_within(scene, culler, sap, radius);
    stats.object_pairs_tested += object_pairs.size();
    const double radius_sq = radius * radius;
    std::vector<std::vector<FeaturePair>> found(object_pairs.size());
    std::vector<std::vector<FeaturePair>> candidates(pns != nullptr ? object_pairs.size() : 0);
    tbb::parallel_for(std::size_t{0}, object_pairs.size(), [&](std::size_t k) {
        if (work.should_stop()) {
            return;
        }
        const auto [i, j] = object_pairs[k];
        std::vector<TrianglePair> cands;
        culler.pairs_within(scene, i, j, radius, cands);
        if (pns != nullptr) {
            auto& out = candidates[k];
            out.reserve(cands.size());
            for (auto [ta, tb] : cands) {
                out.push_back({static_cast<std::uint32_t>(i), ta, static_cast<std::uint32_t>(j),
                               tb, 0.0});
            }
        }
        const SceneObject& a = scene[i];
        const SceneObject& b = scene[j];
        // Exact tests in parallel chunks: one object pair (a large self pair) can hold most of
        // the work.
        std::vector<std::vector<FeaturePair>> parts((cands.size() + 1023) / 1024);
        tbb::parallel_for(std::size_t{0}, parts.size(), [&](std::size_t c) {
            const auto begin = c * 1024;
            const auto end = std::min(cands.size(), begin + 1024);
            for (auto p = begin; p < end; ++p) {
                const auto [ta, tb] = cands[p];
                const Triangle x = corners(a, ta);
                const Triangle y = corners(b, tb);
                if (test == PairTest::intersect) {
                    if (triangles_intersect(x, y)) {
                        parts[c].push_back({static_cast<std::uint32_t>(i), ta,
                                            static_cast<std::uint32_t>(j), tb, 0.0});
                    }
                } else {
                    const auto cp = triangle_triangle(x, y);
                    if (cp.squared_distance <= radius_sq) {
                        parts[c].push_back({static_cast<std::uint32_t>(i), ta,
                                            static_cast<std::uint32_t>(j), tb,
                                            std::sqrt(cp.squared_distance)});
                    }
                }
            }
            work.exact_tests += end - begin;
        });
        for (auto& part : parts) {
            found[k].insert(found[k].end(), part.begin(), part.end());
        }
    });
    for (auto& f : found) {
        hits.insert(hits.end(), f.begin(), f.end());
    }
    std::sort(hits.begin(), hits.end());
    if (pns != nullptr) {
        for (auto& c : candidates) {
            pns->insert(pns->end(), c.begin(), c.end());
        }
        std::sort(pns->begin(), pns->end());
        stats.pns_pairs = pns->size();
    }
}

std::uint64_t brute_force_pairs(const Scene& scene) {
    std::uint64_t total = 0;
    std::uint64_t before = 0;
    for (const auto& obj : scene.objects()) {
        total += before * obj.triangle_count() + non_adjacent_pair_count(*obj.topology);
        before += obj.triangle_count();
    }
    return total;
}

}  // namespace

std::uint64_t non_adjacent_pair_count(const MeshTopology& topology) {
    const std::uint64_t n = topology.triangle_count();
    std::uint64_t ring = 0;
    for (std::uint32_t t = 0; t < n; ++t) {
        ring += topology.one_ring(t).size();
    }
    return n * (n - 1) / 2 - ring / 2;
}

ProximityEngine::ProximityEngine() = default;
ProximityEngine::~ProximityEngine() = default;

Culler& ProximityEngine::culler_for(CullerKind kind) {
    if (kind == CullerKind::brute) {
        if (!m_brute) {
            m_brute = make_culler(CullerKind::brute);
        }
        return *m_brute;
    }
    if (!m_bvh) {
        m_bvh = make_culler(CullerKind::bvh);
    }
    return *m_bvh;
}

StatusOr<QueryResult> ProximityEngine::query(const QueryRequest& request,
                                             const CancelToken* cancel) {
    if (request.tolerance && (!std::isfinite(*request.tolerance) || *request.tolerance < 0.0)) {
        return invalid_argument("tolerance must be a finite distance >= 0, got " +
                                std::to_string(*request.tolerance));
    }
    const auto t_start = Clock::now();
    QueryResult result;
    auto& stats = result.stats;
    Culler& culler = culler_for(request.culler);
    stats.culler = culler_name(culler.kind());

    auto t0 = Clock::now();
    culler.prepare(m_scene);
    stats.prepare_seconds = seconds_since(t0);

    t0 = Clock::now();
    if (culler.object_culling() && m_sap_generation != m_scene.generation()) {
        m_sap.update(m_scene);
        m_sap_generation = m_scene.generation();
    }
    stats.broad_phase_seconds = seconds_since(t0);

    Work work;
    work.cancel = cancel;
    work.should_stop();  // a request cancelled (or past its deadline) before it starts does nothing
    if (request.separation) {
        t0 = Clock::now();
        run_separation(m_scene, culler, m_sap, work, result);
        stats.separation_seconds = seconds_since(t0);
    }
    if (request.self) {
        t0 = Clock::now();
        run_self(m_scene, culler, work, result);
        stats.self_seconds = seconds_since(t0);
    }
    const bool pns_on_tolerance = request.pns && request.tolerance.has_value();
    if (request.collisions) {
        t0 = Clock::now();
        run_pairs(m_scene, culler, m_sap, 0.0, PairTest::intersect, work, result.collisions,
                  request.pns && !pns_on_tolerance ? &result.pns : nullptr, stats);
        stats.collision_seconds = seconds_since(t0);
    }
    if (request.tolerance) {
        t0 = Clock::now();
        run_pairs(m_scene, culler, m_sap, *request.tolerance, PairTest::within, work,
                  result.tolerance, pns_on_tolerance ? &result.pns : nullptr, stats);
        stats.tolerance_seconds = seconds_since(t0);
    }
    if (request.pns && !request.collisions && !request.tolerance) {
        // Candidates only: no exact test is counted for a PNS-only request.
        std::vector<TrianglePair> cands;
        for (auto [i, j] : object_pairs_within(m_scene, culler, m_sap, 0.0)) {
            cands.clear();
            culler.pairs_within(m_scene, i, j, 0.0, cands);
            for (auto [ta, tb] : cands) {
                result.pns.push_back({static_cast<std::uint32_t>(i), ta,
                                      static_cast<std::uint32_t>(j), tb, 0.0});
            }
        }
        std::sort(result.pns.begin(), result.pns.end());
        stats.pns_pairs = result.pns.size();
    }
    if (work.stopped.load()) {
        if (cancel != nullptr && cancel->cancelled()) {
            return Status(StatusCode::cancelled, "query cancelled by the caller");
        }
        return Status(StatusCode::deadline_exceeded, "query stopped: deadline exceeded");
    }
    stats.exact_tests = work.exact_tests.load();
    stats.brute_force_tests = brute_force_pairs(m_scene);
    stats.total_seconds = seconds_since(t_start);
    return result;
}

}  // namespace proxima
