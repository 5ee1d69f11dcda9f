
#include "proxima/query/query.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <mutex>
#include <span>
#include <unordered_map>

#include <tbb/blocked_range.h>
#include <tbb/cache_aligned_allocator.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/spin_mutex.h>

#include "overwrite_array.hpp"
#include "proxima/culling/dvd.hpp"
#include "proxima/distance/bounds.hpp"
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

// Largest coordinate magnitude in the scene: sets the rounding slack of every comparison.
double scene_scale(const Scene& scene) {
    double s = 0.0;
    for (const auto& o : scene.objects()) {
        s = std::max(s, coordinate_scale(o.box));
    }
    return s;
}

// A found closest pair, ordered so that ties in distance resolve the same way on every run and
// with any thread count: smaller distance, then smaller other object, then smaller triangles.
bool better(double d_sq, std::int64_t other, std::uint32_t t, std::uint32_t u, double best_sq,
            const Separation& best) {
    if (d_sq != best_sq) {
        return d_sq < best_sq;
    }
    return std::tie(other, t, u) < std::tie(best.other, best.triangle, best.other_triangle);
}

// Closest pair of triangles between objects i and j among pairs closer than sqrt(bound_sq), in the
// culler's deterministic traversal order (first pair reaching the minimum). `found` is false when
// no pair is closer than the bound.
struct PairSearch {
    bool found = false;
    double squared_distance = std::numeric_limits<double>::infinity();
    std::uint32_t triangle = 0;
    std::uint32_t other_triangle = 0;
    Vec3 point;
    Vec3 other_point;
    std::uint64_t exact_tests = 0;
};

PairSearch search_pair(const Scene& scene, const Culler& culler, std::size_t i, std::size_t j,
                       double bound_sq, double slack) {
    PairSearch r;
    const SceneObject& a = scene[i];
    const SceneObject& b = scene[j];
    CullThreshold threshold(bound_sq, slack);
    culler.nearest_between(scene, i, j, bound_sq, [&](std::uint32_t ta, std::uint32_t tb) {
        const Triangle x = corners(a, ta);
        const Triangle y = corners(b, tb);
        if (std::isfinite(bound_sq)) {
            const double lb = triangle_lower_bound(x, y, slack);
            if (lb * lb >= threshold.get()) {
                return;
            }
        }
        ++r.exact_tests;
        const auto cp = triangle_triangle(x, y);
        if (cp.squared_distance < bound_sq) {
            bound_sq = cp.squared_distance;
            r.found = true;
            r.squared_distance = cp.squared_distance;
            r.triangle = ta;
            r.other_triangle = tb;
            r.point = cp.point_a;
            r.other_point = cp.point_b;
        }
    });
    return r;
}

// The brute-force reference: every object against every other, every triangle pair.
// Separation by brute force: every unordered object pair once, every triangle pair of it once
// (the brute-force count of the separation query, stats.brute_force_tests), each result offered to
// both objects as the culled path does, so a scene's exact tests never exceed brute force.
void run_separation_brute(const Scene& scene, const Culler& culler, Work& work,
                          QueryResult& result) {
    const std::size_t n = scene.size();
    std::vector<std::pair<std::uint32_t, std::uint32_t>> pairs;
    pairs.reserve(n * (n - 1) / 2);
    for (std::size_t i = 0; i < n; ++i) {
        for (std::size_t j = i + 1; j < n; ++j) {
            pairs.emplace_back(static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(j));
        }
    }
    std::vector<double> best_sq(n, std::numeric_limits<double>::infinity());
    std::vector<std::mutex> locks(n);
    auto offer = [&](std::size_t i, std::int64_t other, std::uint32_t t, std::uint32_t u,
                     double d_sq, const Vec3& p, const Vec3& q) {
        std::lock_guard<std::mutex> lock(locks[i]);
        if (better(d_sq, other, t, u, best_sq[i], result.separation[i])) {
            best_sq[i] = d_sq;
            result.separation[i] = {other, t, u, 0.0, p, q};
        }
    };
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pairs.size(), 1), [&](const auto& range) {
        for (std::size_t k = range.begin(); k != range.end(); ++k) {
            if (work.should_stop()) {
                return;
            }
            const std::uint32_t i = pairs[k].first;  // (no structured binding: captured below)
            const std::uint32_t j = pairs[k].second;
            const SceneObject& a = scene[i];
            const SceneObject& b = scene[j];
            // The pair's best for each side: the tie-break orders (other, own, other's triangle).
            Separation for_i;
            Separation for_j;
            double sq_i = std::numeric_limits<double>::infinity();
            double sq_j = sq_i;
            double stop = sq_i;  // negative: stopped (the culler ends after this triangle of a)
            std::uint64_t tests = 0;
            culler.nearest_between(scene, i, j, stop, [&](std::uint32_t ta, std::uint32_t tb) {
                if (stop < 0.0) {
                    return;
                }
                // Two large objects are one long loop: look at the token every 1024 tests.
                if ((++tests & 1023U) == 0 && work.should_stop()) {
                    stop = -1.0;
                    return;
                }
                const auto cp = triangle_triangle(corners(a, ta), corners(b, tb));
                if (better(cp.squared_distance, j, ta, tb, sq_i, for_i)) {
                    sq_i = cp.squared_distance;
                    for_i = {static_cast<std::int64_t>(j), ta, tb, 0.0, cp.point_a, cp.point_b};
                }
                if (better(cp.squared_distance, i, tb, ta, sq_j, for_j)) {
                    sq_j = cp.squared_distance;
                    for_j = {static_cast<std::int64_t>(i), tb, ta, 0.0, cp.point_b, cp.point_a};
                }
            });
            work.exact_tests += tests;
            if (stop < 0.0) {
                return;  // stopped; the query reports its stop status, no partial answer
            }
            if (for_i.other != NO_OBJECT) {
                offer(i, j, for_i.triangle, for_i.other_triangle, sq_i, for_i.point,
                      for_i.other_point);
                offer(j, i, for_j.triangle, for_j.other_triangle, sq_j, for_j.point,
                      for_j.other_point);
            }
        }
    });
    for (std::size_t i = 0; i < n; ++i) {
        if (result.separation[i].other != NO_OBJECT) {
            result.separation[i].distance = std::sqrt(best_sq[i]);
        }
    }
    result.stats.object_pairs_tested += pairs.size();
}

// Separation with object-level culling. Stage I gives each object an upper bound (closest box's
// farthest corners) and the objects whose boxes lie within it; each unordered candidate pair is
// searched once, bounded by the larger of its two objects' current bests, and improves both.
// Pairs tied with an object's best are still searched (thresholds are widened, the search bound
// is the next double up), so the tie-break in `better` sees every tied pair and the answer does
// not depend on scheduling.
// With the discrete-Voronoi culler, Stage II (refine_separation) lowers the upper bounds before
// the object pairs are chosen, and its per-triangle lower bounds cull inside nearest_between.
Status run_separation(const Scene& scene, Culler& culler, const SweepAndPrune& sap, Work& work,
                      QueryResult& result) {
    const std::size_t n = scene.size();
    result.separation.assign(n, Separation{});
    if (!culler.object_culling()) {
        run_separation_brute(scene, culler, work, result);
        return {};
    }
    const double slack = rounding_slack(scene_scale(scene));
    std::vector<double> upper(n);
    std::vector<std::vector<std::size_t>> near(n);
    tbb::parallel_for(std::size_t{0}, n,
                      [&](std::size_t i) { upper[i] = sap.separation_upper_bound(scene, i); });
    if (Status s = culler.refine_separation(scene, upper); !s.ok()) {
        return s;
    }
    tbb::parallel_for(std::size_t{0}, n, [&](std::size_t i) {
        if (std::isfinite(upper[i])) {
            sap.within(scene, i, upper[i], near[i]);
        }
    });
    struct Candidate {
        double box_sq;
        std::uint32_t i, j;
    };
    std::vector<Candidate> pairs;
    for (std::size_t i = 0; i < n; ++i) {
        for (auto j : near[i]) {
            const auto lo = static_cast<std::uint32_t>(std::min(i, j));
            const auto hi = static_cast<std::uint32_t>(std::max(i, j));
            pairs.push_back({box_squared_distance(scene[lo].box, scene[hi].box), lo, hi});
        }
    }
    std::sort(pairs.begin(), pairs.end(), [](const Candidate& x, const Candidate& y) {
        return std::tie(x.box_sq, x.i, x.j) < std::tie(y.box_sq, y.i, y.j);
    });
    pairs.erase(std::unique(pairs.begin(), pairs.end(),
                            [](const Candidate& x, const Candidate& y) {
                                return x.i == y.i && x.j == y.j;
                            }),
                pairs.end());

    std::vector<std::atomic<double>> best_sq(n);
    for (std::size_t i = 0; i < n; ++i) {
        best_sq[i].store(seed_bound_sq(upper[i]), std::memory_order_relaxed);
    }
    std::vector<double> exact_sq(n, std::numeric_limits<double>::infinity());
    std::vector<std::mutex> locks(n);
    std::atomic<std::uint64_t> searched{0};
    auto offer = [&](std::size_t i, std::int64_t other, std::uint32_t t, std::uint32_t u,
                     double d_sq, const Vec3& p, const Vec3& q) {
        std::lock_guard<std::mutex> lock(locks[i]);
        if (better(d_sq, other, t, u, exact_sq[i], result.separation[i])) {
            exact_sq[i] = d_sq;
            result.separation[i] = {other, t, u, 0.0, p, q};
            if (d_sq < best_sq[i].load(std::memory_order_relaxed)) {
                best_sq[i].store(d_sq, std::memory_order_relaxed);
            }
        }
    };
    // Pairs in increasing box distance: near pairs first tighten the bounds that cull the rest.
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pairs.size(), 1), [&](const auto& range) {
        std::uint64_t tests = 0;
        for (std::size_t k = range.begin(); k != range.end(); ++k) {
            if (work.should_stop()) {
                break;
            }
            const auto [box_sq, i, j] = pairs[k];
            const double bound = std::max(best_sq[i].load(std::memory_order_relaxed),
                                          best_sq[j].load(std::memory_order_relaxed));
            if (box_sq >= cull_threshold_sq(bound, slack)) {
                continue;
            }
            ++searched;
            const auto r =
                search_pair(scene, culler, i, j,
                            std::nextafter(bound, std::numeric_limits<double>::infinity()), slack);
            tests += r.exact_tests;
            if (r.found) {
                offer(i, j, r.triangle, r.other_triangle, r.squared_distance, r.point,
                      r.other_point);
                offer(j, i, r.other_triangle, r.triangle, r.squared_distance, r.other_point,
                      r.point);
            }
        }
        work.exact_tests += tests;
    });
    for (std::size_t i = 0; i < n; ++i) {
        if (result.separation[i].other != NO_OBJECT) {
            result.separation[i].distance = std::sqrt(exact_sq[i]);
        }
    }
    result.stats.object_pairs_tested += searched;
    return {};
}

// The skin of a rigid-reuse list (run_self): for a triangle whose closest distance is d, its list
// holds every triangle within d + rel d + abs.
struct Skin {
    double rel = 0.0;
    double abs = 0.0;
    double of(double d) const { return rel * d + abs; }
    bool none() const { return rel == 0.0 && abs == 0.0; }
};

// Per-triangle best of the intra-object query, shared by the threads of one object's search.
// The squared bound is readable without a lock (culling only needs a valid upper bound); the
// best pair is updated under its own lock with a deterministic tie-break (smaller distance,
// then smaller triangle index), so the answer does not depend on scheduling.
class SelfBests {
  public:
    // A `skin` widens every bound the culling reads (bounds() and threshold()) from the best
    // distance d to d + skin.of(d), so that every pair a search leaves untested is at least that
    // far (run_self's rigid-reuse list); the answers are the same.
    SelfBests(std::vector<SelfDistance>& out, double slack, Skin skin = {})
        : m_out(out),
          m_slack(slack),
          m_skin(skin),
          m_bound(out.size()),
          m_threshold(out.size()),
          m_touching(out.size()),
          m_exact(out.size(), std::numeric_limits<double>::infinity()),
          m_locks(out.size()) {
        for (auto& b : m_bound) {
            b.store(std::numeric_limits<double>::infinity(), std::memory_order_relaxed);
        }
        for (auto& b : m_threshold) {
            b.store(std::numeric_limits<double>::infinity(), std::memory_order_relaxed);
        }
        for (auto& c : m_touching) {
            c.store(UINT32_MAX, std::memory_order_relaxed);
        }
    }
    double bound(std::uint32_t t) const { return m_bound[t].load(std::memory_order_relaxed); }
    // The best squared distance found so far, unwidened; only between passes (no lock).
    double best_sq(std::uint32_t t) const { return m_exact[t]; }
    // The bounds as the culler reads them (BoundLookup).
    const std::atomic<double>* bounds() const { return m_bound.data(); }
    // cull_threshold_sq of the bound, kept beside it (a square root per improvement, not per
    // candidate pair). Read without the lock it may be an earlier bound's: larger, so still valid.
    double threshold(std::uint32_t t) const {
        return m_threshold[t].load(std::memory_order_relaxed);
    }
    // Whether pair (t, u) can no longer change t's answer, whatever its distance: t already
    // touches a triangle (distance exactly 0) whose index is at most u, and the tie-break keeps
    // the smaller index. Touching triangles (self-intersecting cloth) otherwise meet many pairs
    // that no bound can prune, each an exact test with its intersection search. The index only
    // decreases once set, so a value read without the lock (an earlier one, or none) is at least
    // the current one: never a wrong skip.
    bool settled(std::uint32_t t, std::uint32_t u) const {
        return u >= m_touching[t].load(std::memory_order_relaxed);
    }

    void offer(std::uint32_t t, std::uint32_t u, double d_sq, const Vec3& p, const Vec3& q) {
        if (d_sq > bound(t)) {
            return;
        }
        const tbb::spin_mutex::scoped_lock lock(m_locks[t]);
        SelfDistance& best = m_out[t];
        if (d_sq < m_exact[t] ||
            (d_sq == m_exact[t] && static_cast<std::int64_t>(u) < best.closest)) {
            m_exact[t] = d_sq;
            best.closest = u;
            best.point = p;
            best.other_point = q;
            double widened = d_sq;
            if (!m_skin.none()) {
                const double d = std::sqrt(d_sq);
                const double w = d + m_skin.of(d);
                widened = w * w;
            }
            m_bound[t].store(widened, std::memory_order_relaxed);
            m_threshold[t].store(cull_threshold_sq(widened, m_slack), std::memory_order_relaxed);
            if (d_sq == 0.0) {
                m_touching[t].store(u, std::memory_order_relaxed);
            }
        }
    }

    void finish() {
        for (std::size_t t = 0; t < m_out.size(); ++t) {
            if (m_out[t].closest != NO_OBJECT) {
                m_out[t].distance = std::sqrt(m_exact[t]);
            }
        }
    }

  private:
    std::vector<SelfDistance>& m_out;
    double m_slack;
    Skin m_skin;
    std::vector<std::atomic<double>> m_bound;
    std::vector<std::atomic<double>> m_threshold;
    std::vector<std::atomic<std::uint32_t>> m_touching;  // UINT32_MAX: not touching yet
    std::vector<double> m_exact;
    // One lock per triangle, a byte each: held for a few stores, so an uncontended lock is one
    // atomic exchange (a striped std::mutex cost 5 % of n-body's self query in lock and unlock
    // calls; its many exact ties each take the lock).
    std::vector<tbb::spin_mutex> m_locks;
};

// A rigid-reuse list's skin relative to each triangle's closest distance (Skin::rel). On n-body's
// balls (closest distances ~0.04, a rigid residual of ~1e-6 per step from single-precision
// positions) 0.5 % lists little more than the exact ties at shared vertices, which the answer
// tests anyway, and lasts about a hundred steps (docs/benchmarks.md: 2 % listed more and was
// slower).
constexpr double SELF_SKIN = 0.005;

// An upper bound E on how far any vertex of `to` lies from an exact rigid image of `from` (the
// same vertices, another frame): then every point of every triangle does too (a triangle's points
// are convex combinations of its corners), so each pair's distance differs from its distance at
// `from` by at most 2E (a rigid motion keeps distances). The motion maps three spread vertices'
// orthonormal frame at `from` onto theirs at `to` (the first vertex, then among up to 64 evenly
// spaced ones the farthest from it and the farthest from their line; any rigid motion gives a
// valid bound, this one is exact for a rigid body); the bound adds the rounding of that rotation
// (its distance from an orthogonal matrix, at most 3 x the largest entry of R^T R - I, times the
// lever arm) and of the residuals' own evaluation, both far above their actual size. Infinity
// when a vertex is already more than `limit` from its image (a deforming object: the caller only
// uses bounds below its limit, and the scan stops there), when the three vertices do not span a
// plane, or when the positions are not finite.
double rigid_residual_bound(const std::vector<Vec3>& from, std::span<const Vec3> to, double limit) {
    const double inf = std::numeric_limits<double>::infinity();
    if (from.size() != to.size() || from.size() < 3 || !(limit > 0.0)) {
        return inf;
    }
    const std::size_t stride = std::max<std::size_t>(1, from.size() / 64);
    const Vec3& p0 = from[0];
    std::size_t i1 = 0;
    double far = -1.0;
    for (std::size_t v = 0; v < from.size(); v += stride) {
        const double d = squared_norm(from[v] - p0);
        if (d > far) {
            far = d;
            i1 = v;
        }
    }
    const Vec3 axis = from[i1] - p0;
    std::size_t i2 = 0;
    double off = -1.0;
    for (std::size_t v = 0; v < from.size(); v += stride) {
        const double d = squared_norm(cross(axis, from[v] - p0));
        if (d > off) {
            off = d;
            i2 = v;
        }
    }
    // Orthonormal frames (rows) from the same three vertices at both frames.
    auto frame = [](const Vec3& a, const Vec3& b, const Vec3& c, Vec3 out[3]) {
        const Vec3 e0 = b - a;
        const Vec3 n = cross(e0, c - a);
        const double l0 = norm(e0);
        const double ln = norm(n);
        if (!(l0 > 0.0) || !(ln > 0.0)) {
            return false;
        }
        out[0] = (1.0 / l0) * e0;
        out[2] = (1.0 / ln) * n;
        out[1] = cross(out[2], out[0]);
        return true;
    };
    Vec3 f0[3];
    Vec3 f1[3];
    if (!frame(p0, from[i1], from[i2], f0) || !frame(to[0], to[i1], to[i2], f1)) {
        return inf;
    }
    // R = F1^T F0: maps f0's rows onto f1's.
    double r[3][3];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            r[i][j] = f1[0][i] * f0[0][j] + f1[1][i] * f0[1][j] + f1[2][i] * f0[2][j];
        }
    }
    double skew = 0.0;  // largest entry of R^T R - I
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            const double g = r[0][i] * r[0][j] + r[1][i] * r[1][j] + r[2][i] * r[2][j];
            skew = std::max(skew, std::abs(g - (i == j ? 1.0 : 0.0)));
        }
    }
    // Squared residuals and lever arms (one square root each at the end).
    const double limit_sq = limit * limit;
    double residual_sq = 0.0;
    double lever_sq = 0.0;
    double magnitude = 0.0;
    for (std::size_t v = 0; v < from.size(); ++v) {
        const Vec3 d = from[v] - p0;
        const Vec3 image{r[0][0] * d.x + r[0][1] * d.y + r[0][2] * d.z + to[0].x,
                         r[1][0] * d.x + r[1][1] * d.y + r[1][2] * d.z + to[0].y,
                         r[2][0] * d.x + r[2][1] * d.y + r[2][2] * d.z + to[0].z};
        residual_sq = std::max(residual_sq, squared_norm(to[v] - image));
        if (!(residual_sq <= limit_sq)) {
            return inf;  // also NaN
        }
        lever_sq = std::max(lever_sq, squared_norm(d));
        magnitude = std::max({magnitude, std::abs(to[v].x), std::abs(to[v].y), std::abs(to[v].z)});
    }
    const double bound =
        std::sqrt(residual_sq) + (3.0 * skew + 1e-12) * std::sqrt(lever_sq) + 1e-12 * magnitude;
    return std::isfinite(bound) ? bound : inf;
}

// Every pair run_self's search tested exactly while recording a rigid-reuse list (t < u), per
// thread.
struct TestedPair {
    std::uint32_t t, u;
    double d_sq;
};
using TestedPairs =
    tbb::enumerable_thread_specific<std::vector<TestedPair>,
                                    tbb::cache_aligned_allocator<std::vector<TestedPair>>,
                                    tbb::ets_key_per_instance>;

// The self traversal's exact tests, counted per thread.
using TraversalTests =
    tbb::enumerable_thread_specific<std::uint64_t, tbb::cache_aligned_allocator<std::uint64_t>,
                                    tbb::ets_key_per_instance>;

// Rigid reuse, recording (docs/algorithms.md): one object answered by a search whose bounds were
// widened by `skin` (SelfBests), so every pair it did not test exactly is at least the widened
// bound apart, i.e. closest distance d + skin.of(d) (a lower bound or a box distance reached it).
// Its list holds every tested pair within either triangle's widened distance, in both triangles'
// lists; a tested pair left out is at least that far by its computed distance, so reach[t] =
// d + skin.of(d) - slack (the slack covers the exact test's rounding). `margin` is the smallest
// reach[t] - d.
void record_list(const std::vector<SelfDistance>& answers, TestedPairs& tested, Skin skin,
                 double slack, detail::SelfMemory& next) {
    const std::size_t nt = answers.size();
    next.reach.resize(nt);
    next.margin = std::numeric_limits<double>::infinity();
    for (std::size_t t = 0; t < nt; ++t) {
        if (answers[t].closest == NO_OBJECT) {
            next.reach[t] = std::numeric_limits<double>::infinity();
            continue;
        }
        const double d = answers[t].distance;
        next.reach[t] = d + skin.of(d) - slack;
        next.margin = std::min(next.margin, next.reach[t] - d);
    }
    auto kept = [&](const TestedPair& p) {
        const double d = std::sqrt(p.d_sq);
        const double dt = answers[p.t].distance;
        const double du = answers[p.u].distance;
        return d < dt + skin.of(dt) || d < du + skin.of(du);
    };
    next.offsets.assign(nt + 1, 0);
    for (const auto& part : tested) {
        for (const auto& p : part) {
            if (kept(p)) {
                ++next.offsets[p.t + 1];
                ++next.offsets[p.u + 1];
            }
        }
    }
    for (std::size_t t = 0; t < nt; ++t) {
        next.offsets[t + 1] += next.offsets[t];
    }
    next.list.resize(next.offsets[nt]);
    std::vector<std::uint32_t> cursor(next.offsets.begin(), next.offsets.end() - 1);
    for (const auto& part : tested) {
        for (const auto& p : part) {
            if (kept(p)) {
                next.list[cursor[p.t]++] = p.u;
                next.list[cursor[p.u]++] = p.t;
            }
        }
    }
    next.listed = true;
}

// Rigid reuse, answering: every pair of the remembered list tested exactly at the current
// positions (smaller index first, as brute force; the list is symmetric, so from the smaller
// side only). True when every triangle's answer is proven: its closest distance plus the slack is
// below its reach less twice `moved` (rigid_residual_bound), so every unlisted triangle, at least
// that far now, is strictly farther than the answer and cannot tie it. False: `out` is partial
// and the caller searches.
bool reuse_list(const detail::OverwriteArray<Triangle>& tri, const detail::SelfMemory& mem,
                double moved, double slack, Work& work, std::vector<SelfDistance>& out) {
    const auto nt = static_cast<std::uint32_t>(out.size());
    SelfBests bests(out, slack);
    std::atomic<std::uint64_t> tests{0};
    tbb::parallel_for(tbb::blocked_range<std::uint32_t>(0, nt, 1024), [&](const auto& range) {
        std::uint64_t count = 0;
        for (std::uint32_t t = range.begin(); t != range.end(); ++t) {
            for (auto k = mem.offsets[t]; k < mem.offsets[t + 1]; ++k) {
                const std::uint32_t u = mem.list[k];
                if (u <= t || u >= nt) {
                    continue;
                }
                const auto cp = triangle_triangle(tri[t], tri[u]);
                bests.offer(t, u, cp.squared_distance, cp.point_a, cp.point_b);
                bests.offer(u, t, cp.squared_distance, cp.point_b, cp.point_a);
                ++count;
            }
        }
        tests += count;
    });
    bests.finish();
    work.exact_tests += tests.load();
    for (std::uint32_t t = 0; t < nt; ++t) {
        if (std::isinf(mem.reach[t])) {
            continue;  // no non-adjacent triangle at all: no answer, nothing outside the list
        }
        if (out[t].closest == NO_OBJECT ||
            !(out[t].distance + slack < mem.reach[t] - 2.0 * moved)) {
            return false;
        }
    }
    return true;
}

// Intra-object query (seed §5.2.2): for every triangle, its closest triangle sharing no vertex.
// With culling, one 2-ring neighbour per triangle seeds its bound (and its partner's), then the
// culler's dual traversal proposes every pair that may still beat either triangle's bound (a pair
// a seed names is skipped there: it was tested while seeding). Brute force tests every
// non-adjacent pair.
// With the discrete-Voronoi culler, the kernel's partner of each triangle (Lemma 1: the
// second-order governor of its best sample) replaces the 2-ring seed where it has one.
// `hints[a]` (null, or of another size: none) is object a's previous answer: closest triangle and
// distance per triangle (see ProximityEngine::forget_coherence). A warm frame tests each
// triangle's remembered partner first; where that pair is still about as close as it was (at most
// twice the distance), the 2-ring seed is not searched for: the remembered pair's bound is as
// tight as a seed's. A hint is only a candidate: it is checked (in range, not adjacent) and
// tested exactly at the current positions, so it gives an upper bound whatever happened since.
// `memory[a]` (null: none) is also where an object that moved rigidly finds its candidate list
// (rigid reuse: reuse_list, record_list); `fresh[a]` receives what object a's next frame needs
// (positions, list), the caller adds the answers.
Status run_self(const Scene& scene, Culler& culler, Work& work, QueryResult& result,
                const std::vector<detail::SelfMemory*>& memory,
                std::vector<detail::SelfMemory>& fresh) {
    const std::size_t n = scene.size();
    // Each object's answers are sized by its own task, not all first on one thread (n-body's
    // 146,480 answers are 9.4 MB).
    result.self.assign(n, {});
    fresh.assign(n, {});
    const bool cull = culler.object_culling();
    std::vector<Status> failures(n);
    std::atomic<std::uint64_t> reused{0};
    tbb::parallel_for(std::size_t{0}, n, [&](std::size_t a) {
        result.self[a].assign(scene[a].triangle_count(), SelfDistance{});
        if (work.should_stop()) {
            return;
        }
        const SceneObject& obj = scene[a];
        const MeshTopology& topo = *obj.topology;
        const auto nt = static_cast<std::uint32_t>(obj.triangle_count());
        const double slack = rounding_slack(coordinate_scale(obj.box));
        const double touching_threshold = cull_threshold_sq(0.0, slack);
        // Each triangle's corners, gathered once per query: a candidate pair reads two runs of
        // 72 bytes instead of six vertex lookups through the topology.
        detail::OverwriteArray<Triangle> tri(nt);
        tbb::parallel_for(tbb::blocked_range<std::uint32_t>(0, nt, 4096), [&](const auto& range) {
            for (std::uint32_t t = range.begin(); t != range.end(); ++t) {
                tri[t] = corners(obj, t);
            }
        });
        detail::SelfMemory* const mem = a < memory.size() ? memory[a] : nullptr;
        detail::SelfMemory& next = fresh[a];
        // Rigid reuse (docs/algorithms.md): how far the object is from a rigid image of the
        // remembered positions (infinity: nothing remembered, no culling, or farther than any
        // use below allows: a list's half margin, or a rigid step's 1/64 of the relative skin of
        // the mean closest distance).
        double moved = std::numeric_limits<double>::infinity();
        double rigid_limit = 0.0;
        if (cull && mem != nullptr && mem->distance.size() == nt) {
            double sum = 0.0;
            std::size_t count = 0;
            for (const double x : mem->distance) {
                if (std::isfinite(x)) {
                    sum += x;
                    ++count;
                }
            }
            rigid_limit = count == 0 ? 0.0 : SELF_SKIN * sum / (64.0 * static_cast<double>(count));
            const double limit = std::max(rigid_limit, mem->listed ? 0.5 * mem->margin : 0.0);
            moved = rigid_residual_bound(mem->positions, obj.vertices, limit);
        }
        if (mem != nullptr && mem->listed && mem->offsets.size() == std::size_t{nt} + 1 &&
            mem->reach.size() == nt && 2.0 * moved < mem->margin) {
            if (reuse_list(tri, *mem, moved, slack, work, result.self[a])) {
                next.positions = obj.vertices;
                next.listed = true;
                next.offsets = std::move(mem->offsets);
                next.list = std::move(mem->list);
                next.reach = std::move(mem->reach);
                for (auto& r : next.reach) {
                    r -= 2.0 * moved;
                }
                next.margin = mem->margin - 2.0 * moved;
                next.rigid_steps = mem->rigid_steps + 1;
                next.last_moved = moved;
                ++reused;
                return;
            }
            result.self[a].assign(nt, SelfDistance{});
        }
        next.positions = obj.vertices;
        // A rigid step: the object moved by at most 1/64 of the relative skin of its mean
        // closest distance since the last answer. After two in a row (one alone may be a frame
        // queried twice) this answer records its list for the next frame, with a skin that also
        // covers 16 steps as large as the last two for triangles whose closest distance is tiny.
        const bool rigid = moved <= rigid_limit;
        next.rigid_steps = rigid ? mem->rigid_steps + 1 : 0;
        next.last_moved = moved;
        const bool record = rigid && mem->rigid_steps >= 1;
        const Skin skin{SELF_SKIN,
                        record ? 32.0 * std::max(moved, mem->last_moved) + 4.0 * slack : 0.0};
        std::vector<std::uint32_t> partner;
        if (cull) {
            failures[a] = culler.refine_self(scene, a, partner);
            if (!failures[a].ok()) {
                return;
            }
        }
        SelfBests bests(result.self[a], slack, record ? skin : Skin{});
        std::atomic<std::uint64_t> tests{0};
        TestedPairs tested;
        // Each triangle's edge-bound frame, once per query (filled below when culling).
        detail::OverwriteArray<EdgeFrame> frames;
        // Each triangle's seed candidates (filled below when culling): its 2-ring (or Voronoi)
        // seed, and on a warm frame its previous answer. Every pair they name is tested exactly
        // while seeding, so the traversal skips it (testing it again gives the same value, and
        // offering it again changes nothing).
        std::vector<std::uint32_t> seed;
        std::vector<std::uint32_t> warm;
        auto named_by = [&](std::uint32_t u, std::uint32_t t) {
            return !seed.empty() && (seed[u] == t || (!warm.empty() && warm[u] == t));
        };

        // Exact test of one pair, skipped when a cheap lower bound shows it cannot beat (or tie)
        // either triangle's current best. A positive bound also proves the pair disjoint, which
        // spares the exact test its intersection search (same result, bit for bit).
        // The distance is computed with the smaller index first, as brute force does, so the
        // value is bit-identical whichever way a seed or a traversal proposes the pair.
        auto test = [&](std::uint32_t t, std::uint32_t u, std::uint64_t& count) {
            if (t > u) {
                std::swap(t, u);
            }
            const Triangle& x = tri[t];
            const Triangle& y = tri[u];
            double lb = 0.0;
            if (cull) {
                // = cull_threshold_sq of the larger bound (the function is non-decreasing).
                const double th = std::max(bests.threshold(t), bests.threshold(u));
                // Both bounds 0 (the threshold of a zero bound): skipped if neither answer can
                // change, before any bound is computed (brute force tests every pair).
                if (th <= touching_threshold && bests.settled(t, u) && bests.settled(u, t)) {
                    return;
                }
                if (std::isfinite(th)) {
                    lb = lower_bound_until(x, frames[t], y, frames[u], slack, th);
                    if (lb * lb >= th) {
                        return;
                    }
                } else {
                    // No bound on either side yet (mostly the warm and seed passes' first tests):
                    // nothing to skip against, but the bound's first positive stage still
                    // proves the pair disjoint and spares the exact test its intersection search
                    // (rod-twist's warm frame: 58k of 63k such tests; about 480 instructions
                    // each, more than the bound's stages before the first positive one).
                    lb = lower_bound_until(x, frames[t], y, frames[u], slack,
                                           std::numeric_limits<double>::min());
                }
            }
            ++count;
            const auto cp = triangle_triangle(x, y, lb > 0.0);
            bests.offer(t, u, cp.squared_distance, cp.point_a, cp.point_b);
            bests.offer(u, t, cp.squared_distance, cp.point_b, cp.point_a);
            if (record) {
                tested.local().push_back({t, u, cp.squared_distance});
            }
        };

        if (cull) {
            // Seed §5.2.2, reduced to its best candidate: the 2-ring triangle with the nearest
            // centroid is almost always the closest or near it, so one exact test gives each
            // triangle a tight bound; the traversal below finds the rest. (Measured: testing the
            // whole 2-ring took 2-3x the exact tests.) Every triangle picks its own seed among its
            // whole 2-ring (not only larger indices: a triangle left without a bound is what makes
            // the traversal expensive), and a pair two triangles picked for each other is tested
            // once.
            seed.assign(nt, UINT32_MAX);
            frames = detail::OverwriteArray<EdgeFrame>(nt);
            // Four at a time (edge_frames), the last few of a range one by one: the same frames.
            auto fill_frames = [&](const tbb::blocked_range<std::uint32_t>& range) {
                std::uint32_t t = range.begin();
                for (; t + 4 <= range.end(); t += 4) {
                    const Triangle* const in[4] = {&tri[t], &tri[t + 1], &tri[t + 2], &tri[t + 3]};
                    EdgeFrame* const out[4] = {&frames[t], &frames[t + 1], &frames[t + 2],
                                               &frames[t + 3]};
                    edge_frames(in, out);
                }
                for (; t != range.end(); ++t) {
                    frames[t] = edge_frame(tri[t]);
                }
            };
            tbb::parallel_for(tbb::blocked_range<std::uint32_t>(0, nt, 1024), fill_frames);
            // Each pass tests one candidate per triangle; a pair both sides name, or that an
            // earlier pass named, is tested once (from the smaller index within a pass).
            auto seed_pass = [&](const std::vector<std::uint32_t>& pick, auto&& skip) {
                tbb::parallel_for(tbb::blocked_range<std::uint32_t>(0, nt, 512),
                                  [&](const auto& range) {
                                      if (work.should_stop()) {
                                          return;
                                      }
                                      std::uint64_t count = 0;
                                      for (std::uint32_t t = range.begin(); t != range.end(); ++t) {
                                          const std::uint32_t u = pick[t];
                                          if (u == UINT32_MAX || skip(t, u)) {
                                              continue;
                                          }
                                          test(t, u, count);
                                      }
                                      tests += count;
                                  });
            };
            // Warm frame: first the previous answer's triangle, where it is still a valid partner
            // (same topology, so in range and non-adjacent; checked anyway). It was the closest at
            // the last positions, so under coherent motion it still is or nearly is: near-final
            // bounds before any node threshold is computed.
            if (mem != nullptr && mem->closest.size() == nt && mem->distance.size() == nt) {
                warm.assign(nt, UINT32_MAX);
                for (std::uint32_t t = 0; t < nt; ++t) {
                    const std::uint32_t u = mem->closest[t];
                    if (u < nt && u != t && !topo.adjacent(t, u)) {
                        warm[t] = u;
                    }
                }
                seed_pass(warm,
                          [&](std::uint32_t t, std::uint32_t u) { return u < t && warm[u] == t; });
            }
            // Seed §5.2.2, reduced to its best candidate: the 2-ring triangle with the nearest
            // centroid is almost always the closest or near it, so one exact test gives each
            // triangle a tight bound; the traversal below finds the rest. (Measured: testing the
            // whole 2-ring took 2-3x the exact tests.) Every triangle picks its own seed among its
            // whole 2-ring (not only larger indices: a triangle left without a bound is what makes
            // the traversal expensive). On a warm frame only where the remembered pair did not
            // give a bound within twice its last distance (after a large move the old answer can
            // be far worse than the 2-ring's), so a warm bound is then as good as a cold one.
            tbb::parallel_for(
                tbb::blocked_range<std::uint32_t>(0, nt, 512), [&](const auto& range) {
                    for (std::uint32_t t = range.begin(); t != range.end(); ++t) {
                        if (!partner.empty() && partner[t] != UINT32_MAX) {
                            seed[t] = partner[t];
                            continue;
                        }
                        if (!warm.empty() && warm[t] != UINT32_MAX) {
                            const double last = 2.0 * mem->distance[t];
                            if (bests.best_sq(t) <= last * last) {
                                continue;
                            }
                        }
                        double nearest = std::numeric_limits<double>::infinity();
                        for (auto u : topo.cached_two_ring(t)) {
                            const double d = squared_norm(frames[u].centroid - frames[t].centroid);
                            if (d < nearest) {
                                nearest = d;
                                seed[t] = u;
                            }
                        }
                    }
                });
            // Then the 2-ring seeds: after a warm first pass they meet finite bounds on both
            // sides, and lower_bound_until prunes most of them instead of testing them.
            seed_pass(seed, [&](std::uint32_t t, std::uint32_t u) {
                return (!warm.empty() && (warm[t] == u || warm[u] == t)) || (u < t && seed[u] == t);
            });
        }
        if (work.should_stop()) {
            return;
        }
        // The visitor runs on several threads and counts its exact tests per thread (one shared
        // atomic, its cache line bouncing between the cores on every test, cost up to 4 % of the
        // query: docs/benchmarks.md, "Edge pairs in vector lanes").
        // A stopped query reads as a negative bound: the culler stops its traversal.
        TraversalTests traversal_tests(std::uint64_t{0});
        culler.self_pairs(scene, a, BoundLookup(bests.bounds(), &work.stopped),
                          [&](std::uint32_t t, std::uint32_t u) {
                              if (work.stopped.load(std::memory_order_relaxed) || named_by(t, u) ||
                                  named_by(u, t)) {
                                  return;
                              }
                              std::uint64_t count = 0;
                              test(t, u, count);
                              if (count != 0) {
                                  // One object is one long traversal: each thread looks at
                                  // the token every 4096 of its tests.
                                  std::uint64_t& mine = traversal_tests.local();
                                  mine += count;
                                  if ((mine & 4095U) == 0) {
                                      work.should_stop();
                                  }
                              }
                          });
        bests.finish();
        work.exact_tests += tests.load() + traversal_tests.combine(std::plus<>());
        if (record && cull && !work.stopped.load()) {
            record_list(result.self[a], tested, skin, slack, next);
        }
    });
    result.stats.self_objects_reused = reused.load();
    for (auto& f : failures) {
        if (!f.ok()) {
            return f;
        }
    }
    return {};
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
Status run_pairs(const Scene& scene, Culler& culler, const SweepAndPrune& sap, double radius,
                 PairTest test, Work& work, std::vector<FeaturePair>& hits,
                 std::vector<FeaturePair>* pns, QueryStats& stats) {
    if (Status s = culler.refine_within(scene, radius); !s.ok()) {
        return s;
    }
    const auto object_pairs = object_pairs_within(scene, culler, sap, radius);
    stats.object_pairs_tested += object_pairs.size();
    const double radius_sq = radius * radius;
    std::vector<std::vector<FeaturePair>> found(object_pairs.size());
    std::vector<std::vector<FeaturePair>> candidates(pns != nullptr ? object_pairs.size() : 0);
    tbb::parallel_for(std::size_t{0}, object_pairs.size(), [&](std::size_t k) {
        if (work.should_stop()) {
            return;
        }
        // Plain variables, not a structured binding: a lambda below captures them, which clang
        // before 16 (Debian 12's clang 14 builds the fuzz targets) refuses for bindings.
        const auto i = std::get<0>(object_pairs[k]);
        const auto j = std::get<1>(object_pairs[k]);
        std::vector<TrianglePair> cands;
        culler.pairs_within(scene, i, j, radius, cands);
        if (pns != nullptr) {
            auto& out = candidates[k];
            out.reserve(cands.size());
            for (auto [ta, tb] : cands) {
                out.push_back(
                    {static_cast<std::uint32_t>(i), ta, static_cast<std::uint32_t>(j), tb, 0.0});
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
    return {};
}

// The exact tests the brute-force culler makes for `request`: each query asked tests its pairs
// once (separation: every triangle pair of every object pair; self: every non-adjacent pair inside
// each object; collisions, tolerance and a PNS-only request: both). No culler tests more
// (tests/engine/query: Stats.*), and the brute-force culler tests exactly this many.
std::uint64_t brute_force_tests(const Scene& scene, const QueryRequest& request) {
    std::uint64_t between = 0;
    std::uint64_t within = 0;
    std::uint64_t before = 0;
    for (const auto& obj : scene.objects()) {
        between += before * obj.triangle_count();
        within += non_adjacent_pair_count(*obj.topology);
        before += obj.triangle_count();
    }
    const bool pns_only = request.pns && !request.collisions && !request.tolerance;
    const std::uint64_t pair_queries =
        (request.collisions ? 1U : 0U) + (request.tolerance ? 1U : 0U) + (pns_only ? 1U : 0U);
    return (request.separation ? between : 0) + (request.self ? within : 0) +
           pair_queries * (between + within);
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

void ProximityEngine::set_gpu_backend(std::shared_ptr<dvd::Backend> backend) {
    m_gpu_backend = std::move(backend);
    m_voronoi_gpu.reset();
    m_auto = {};
}

StatusOr<Culler*> ProximityEngine::culler_for(CullerKind kind) {
    switch (kind) {
        case CullerKind::brute:
            if (!m_brute) {
                m_brute = make_culler(CullerKind::brute);
            }
            return m_brute.get();
        case CullerKind::voronoi_cpu:
            if (!m_voronoi_cpu) {
                m_voronoi_cpu = make_voronoi_culler(kind, dvd::make_cpu_backend());
            }
            return m_voronoi_cpu.get();
        case CullerKind::voronoi_gpu:
            if (!m_gpu_backend) {
                return failed_precondition("culler voronoi-gpu: no GPU backend (" + m_gpu_reason +
                                           ")");
            }
            if (!m_voronoi_gpu) {
                m_voronoi_gpu = make_voronoi_culler(kind, m_gpu_backend);
            }
            return m_voronoi_gpu.get();
        case CullerKind::automatic:
        case CullerKind::bvh:
            break;
    }
    if (!m_bvh) {
        m_bvh = make_culler(CullerKind::bvh);
    }
    return m_bvh.get();
}

namespace {
std::size_t request_shape(const QueryRequest& r) {
    return (r.separation ? 1u : 0u) | (r.self ? 2u : 0u) | (r.collisions ? 4u : 0u) |
           (r.tolerance ? 8u : 0u) | (r.pns ? 16u : 0u);
}
}  // namespace

// The automatic choice (issue #14, "no spikes"): it decides from what it has measured and never
// runs a culler only to measure it. The BVH culler is the default: on every scene measured (see
// docs/benchmarks.md) the Voronoi culler costs 4-77x more on the CPU, and more on an H200 too,
// so measuring it on a client's frame costs that frame a stall of that size. A Voronoi culler is
// chosen only when a query that asked for it by name (the client's own exploration) measured it
// cheaper than the BVH culler's last measurement for the same kind of request; each frame it then
// runs re-measures it, so it is dropped again as soon as it gets slower.
CullerKind ProximityEngine::choose_automatic(const QueryRequest& request) {
    const AutoModel& m = m_auto[request_shape(request)];
    CullerKind best = CullerKind::bvh;
    double best_seconds = m.bvh_seconds;
    auto consider = [&](CullerKind kind, double seconds) {
        if (seconds >= 0 && best_seconds >= 0 && seconds < best_seconds) {
            best = kind;
            best_seconds = seconds;
        }
    };
    consider(CullerKind::voronoi_cpu, m.voronoi_cpu_seconds);
    if (m_gpu_backend) {
        consider(CullerKind::voronoi_gpu, m.voronoi_gpu_seconds);
    }
    return best;
}

void ProximityEngine::record_automatic(const QueryRequest& request, CullerKind kind,
                                       double seconds) {
    AutoModel& m = m_auto[request_shape(request)];
    switch (kind) {
        case CullerKind::bvh:
            m.bvh_seconds = seconds;
            break;
        case CullerKind::voronoi_cpu:
            m.voronoi_cpu_seconds = seconds;
            break;
        case CullerKind::voronoi_gpu:
            m.voronoi_gpu_seconds = seconds;
            break;
        case CullerKind::automatic:
        case CullerKind::brute:
            break;
    }
}

StatusOr<QueryResult> ProximityEngine::query(const QueryRequest& request,
                                             const CancelToken* cancel) {
    if (request.tolerance && (!std::isfinite(*request.tolerance) || *request.tolerance < 0.0)) {
        return invalid_argument("tolerance must be a finite distance >= 0, got " +
                                std::to_string(*request.tolerance));
    }
    if (request.voronoi_cell &&
        (!std::isfinite(*request.voronoi_cell) || *request.voronoi_cell <= 0.0)) {
        return invalid_argument("voronoi cell size must be a finite distance > 0, got " +
                                std::to_string(*request.voronoi_cell));
    }
    if (request.culler == CullerKind::automatic) {
        // The cost model picks; a Voronoi culler that fails (a GPU error) falls back to the BVH
        // culler for this query and counts as infinitely slow until asked for by name again.
        QueryRequest forced = request;
        forced.culler = choose_automatic(request);
        auto r = query(forced, cancel);
        if (!r.ok() && forced.culler != CullerKind::bvh &&
            r.status().code() != StatusCode::cancelled &&
            r.status().code() != StatusCode::deadline_exceeded) {
            record_automatic(request, forced.culler, std::numeric_limits<double>::infinity());
            forced.culler = CullerKind::bvh;
            r = query(forced, cancel);
        }
        return r;  // the query that ran recorded its time
    }
    const auto t_start = Clock::now();
    QueryResult result;
    auto& stats = result.stats;
    auto culler_or = culler_for(request.culler);
    if (!culler_or.ok()) {
        return culler_or.status();
    }
    Culler& culler = *culler_or.value();
    culler.set_cell(request.voronoi_cell);
    stats.culler = culler_name(culler.kind());
    if (!request.separation && !request.self && !request.collisions && !request.tolerance &&
        !request.pns) {
        // Nothing asked: a frame that only moves vertices. Refitting now would be wasted (the
        // next query refits for the positions it sees).
        stats.brute_force_tests = 0;
        stats.total_seconds = seconds_since(t_start);
        return result;
    }

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
        if (Status s = run_separation(m_scene, culler, m_sap, work, result); !s.ok()) {
            return s;
        }
        stats.separation_seconds = seconds_since(t0);
    }
    if (request.self) {
        t0 = Clock::now();
        std::vector<detail::SelfMemory*> memory_in(m_scene.size(), nullptr);
        for (std::size_t a = 0; a < m_scene.size(); ++a) {
            const auto it = m_self_memory.find(m_scene[a].id);
            if (it != m_self_memory.end() &&
                it->second.topology_version == m_scene[a].topology_version) {
                memory_in[a] = &it->second;
            }
        }
        std::vector<detail::SelfMemory> fresh;
        if (Status s = run_self(m_scene, culler, work, result, memory_in, fresh); !s.ok()) {
            // A list run_self moved out is gone: forget the memory rather than keep half of it.
            m_self_memory.clear();
            return s;
        }
        if (!work.stopped.load()) {
            // Remember this answer for the next frame; objects no longer in the scene are dropped.
            // An object's previous arrays are reused (no allocation on a stream of frames), and
            // the objects are copied in parallel.
            std::unordered_map<ObjectId, detail::SelfMemory> memory;
            memory.reserve(m_scene.size());
            std::vector<detail::SelfMemory*> slots(m_scene.size());
            for (std::size_t a = 0; a < m_scene.size(); ++a) {
                detail::SelfMemory& m = memory[m_scene[a].id];
                m = std::move(fresh[a]);
                if (auto old = m_self_memory.find(m_scene[a].id); old != m_self_memory.end()) {
                    m.closest.swap(old->second.closest);  // reused as buffers
                    m.distance.swap(old->second.distance);
                }
                m.topology_version = m_scene[a].topology_version;
                slots[a] = &m;
            }
            tbb::parallel_for(std::size_t{0}, m_scene.size(), [&](std::size_t a) {
                detail::SelfMemory& m = *slots[a];
                const auto& answers = result.self[a];
                m.closest.resize(answers.size());
                m.distance.resize(answers.size());
                for (std::size_t t = 0; t < answers.size(); ++t) {
                    const auto c = answers[t].closest;
                    m.closest[t] = c == NO_OBJECT ? UINT32_MAX : static_cast<std::uint32_t>(c);
                    m.distance[t] = answers[t].distance;
                }
            });
            m_self_memory = std::move(memory);
        }
        stats.self_seconds = seconds_since(t0);
    }
    const bool pns_on_tolerance = request.pns && request.tolerance.has_value();
    if (request.collisions) {
        t0 = Clock::now();
        if (Status s =
                run_pairs(m_scene, culler, m_sap, 0.0, PairTest::intersect, work, result.collisions,
                          request.pns && !pns_on_tolerance ? &result.pns : nullptr, stats);
            !s.ok()) {
            return s;
        }
        stats.collision_seconds = seconds_since(t0);
    }
    if (request.tolerance) {
        t0 = Clock::now();
        if (Status s = run_pairs(m_scene, culler, m_sap, *request.tolerance, PairTest::within, work,
                                 result.tolerance, pns_on_tolerance ? &result.pns : nullptr, stats);
            !s.ok()) {
            return s;
        }
        stats.tolerance_seconds = seconds_since(t0);
    }
    if (request.pns && !request.collisions && !request.tolerance) {
        // Candidates only: no exact test is counted for a PNS-only request.
        if (Status s = culler.refine_within(m_scene, 0.0); !s.ok()) {
            return s;
        }
        std::vector<TrianglePair> cands;
        for (auto [i, j] : object_pairs_within(m_scene, culler, m_sap, 0.0)) {
            cands.clear();
            culler.pairs_within(m_scene, i, j, 0.0, cands);
            for (auto [ta, tb] : cands) {
                result.pns.push_back(
                    {static_cast<std::uint32_t>(i), ta, static_cast<std::uint32_t>(j), tb, 0.0});
            }
        }
        std::sort(result.pns.begin(), result.pns.end());
        stats.pns_pairs = result.pns.size();
    }
    if (work.stopped.load()) {
        return stop_status(*cancel, "query");  // only a token sets `stopped`
    }
    stats.exact_tests = work.exact_tests.load();
    stats.brute_force_tests = brute_force_tests(m_scene, request);
    const VoronoiStats vs = culler.take_voronoi_stats();
    stats.voronoi_seconds = vs.seconds;
    stats.dvd_seconds = vs.dvd_seconds;
    stats.dvd_samples = vs.samples;
    stats.dvd_cell = vs.cell;
    stats.voronoi_culled = vs.culled;
    stats.dvd_epsilon = vs.epsilon;
    stats.total_seconds = seconds_since(t_start);
    // Every culler's measured time feeds the automatic choice (no query runs only to measure).
    record_automatic(request, request.culler, stats.total_seconds);
    return result;
}

}  // namespace proxima
