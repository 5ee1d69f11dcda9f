#pragma once
// Proximity queries on a scene: separation (closest other object per object), self (closest
// non-adjacent triangle per triangle), collisions, tolerance and PNS. Every answer is exact: it is
// what brute force over all (non-adjacent) triangle pairs gives, with the same exact primitives;
// the culler only decides which pairs are tested.
//
// Conventions: objects are scene indices (order of Scene::objects()); triangles are indices in the
// object's topology; distances are Euclidean, in scene units; two triangles are adjacent when they
// share a vertex index, and adjacent pairs are excluded from intra-object queries.

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <tuple>
#include <unordered_map>
#include <vector>

#include "proxima/cancel.hpp"
#include "proxima/culling/culler.hpp"
#include "proxima/culling/sweep_and_prune.hpp"
#include "proxima/scene.hpp"

namespace proxima {

struct QueryRequest {
    bool separation = true;
    bool self = false;
    bool collisions = false;
    std::optional<double> tolerance;  // report pairs with distance <= tolerance (>= 0)
    bool pns = false;                 // report the culler's candidates for the tolerance (or 0)
    // `automatic`: the BVH culler, unless a Voronoi culler was asked for by name on this scene
    // (same kind of request) and measured cheaper than the BVH culler's last frame. It never runs
    // a culler just to measure it, so no frame pays for exploration it did not ask for.
    CullerKind culler = CullerKind::automatic;
    // Grid cell size of the discrete-Voronoi cullers (> 0, scene units); unset: automatic
    // (a multiple of the mean edge length).
    std::optional<double> voronoi_cell;
};

inline constexpr std::int64_t NO_OBJECT = -1;

struct Separation {
    std::int64_t other = NO_OBJECT;    // scene index of the closest other object
    std::uint32_t triangle = 0;        // in this object
    std::uint32_t other_triangle = 0;  // in `other`
    double distance = std::numeric_limits<double>::infinity();
    Vec3 point;        // on this object
    Vec3 other_point;  // on `other`
};

struct SelfDistance {
    std::int64_t closest = NO_OBJECT;  // triangle of the same object, -1 when all are adjacent
    double distance = std::numeric_limits<double>::infinity();
    Vec3 point;
    Vec3 other_point;
};

struct FeaturePair {
    std::uint32_t object = 0;
    std::uint32_t triangle = 0;
    std::uint32_t other = 0;  // == object for intra-object pairs (then triangle < other_triangle)
    std::uint32_t other_triangle = 0;
    double distance = 0.0;  // for tolerance pairs; 0 for collisions and PNS
    friend bool operator<(const FeaturePair& a, const FeaturePair& b) {
        return std::tie(a.object, a.triangle, a.other, a.other_triangle) <
               std::tie(b.object, b.triangle, b.other, b.other_triangle);
    }
};

struct QueryStats {
    std::string culler;  // which culler ran
    // Wall-clock seconds per stage.
    double prepare_seconds = 0;      // refit / rebuild of culling structures
    double broad_phase_seconds = 0;  // Stage I: object boxes, sweep and prune
    double separation_seconds = 0;
    double self_seconds = 0;
    double collision_seconds = 0;
    double tolerance_seconds = 0;
    double total_seconds = 0;
    // Exact primitive tests performed (triangle-triangle distance or intersection).
    std::uint64_t exact_tests = 0;
    // Tests the brute-force culler performs for the same queries, each query once over its pairs
    // (separation: every triangle pair of every object pair; self: every non-adjacent pair in each
    // object; collisions, tolerance, PNS alone: both): the denominator of the culling efficiency.
    // No culler exceeds it but for the self query's bound seeding (at most one test per triangle).
    std::uint64_t brute_force_tests = 0;
    std::uint64_t object_pairs_tested = 0;
    std::uint64_t pns_pairs = 0;
    // Objects whose self answer came from their candidate list because they moved rigidly
    // (docs/algorithms.md, "Rigid reuse"), not from a search.
    std::uint64_t self_objects_reused = 0;
    // Discrete-Voronoi culler (zero for the others): Stage II seconds (sampling, buckets, kernel,
    // bounds), the kernel alone, kernel samples, grid cell size, candidate pairs removed by the
    // Voronoi lower bounds, and the largest kernel error allowance used.
    double voronoi_seconds = 0;
    double dvd_seconds = 0;
    std::uint64_t dvd_samples = 0;
    double dvd_cell = 0;
    std::uint64_t voronoi_culled = 0;
    double dvd_epsilon = 0;
};

struct QueryResult {
    std::vector<Separation> separation;           // per object, when requested
    std::vector<std::vector<SelfDistance>> self;  // per object, per triangle, when requested
    std::vector<FeaturePair> collisions;          // sorted
    std::vector<FeaturePair> tolerance;           // sorted, with distances
    std::vector<FeaturePair> pns;                 // sorted
    QueryStats stats;
};

namespace detail {
// One object's last self answer (closest triangle per triangle, UINT32_MAX for none), with the
// topology it was computed on, and what a rigidly moving object needs to answer its next frame
// from a list instead of a search (run_self in query.cpp, docs/algorithms.md "Rigid reuse"):
// the positions the answer was computed at and, when `listed`, each triangle t's candidates
// list[offsets[t], offsets[t + 1]) with a reach: every non-adjacent triangle outside t's list is
// at least reach[t] from t at `positions` (infinity: t has no non-adjacent triangle).
struct SelfMemory {
    std::uint64_t topology_version = 0;
    std::vector<std::uint32_t> closest;  // per triangle; UINT32_MAX: none
    std::vector<double> distance;        // to it
    std::vector<Vec3> positions;
    bool listed = false;
    std::vector<std::uint32_t> offsets;  // triangle_count + 1
    std::vector<std::uint32_t> list;     // symmetric: u in t's list exactly when t is in u's
    std::vector<double> reach;
    double margin = 0.0;  // the smallest reach[t] - distance[t]
    // Rigid steps in a row up to this answer, and the last step's rigid_residual_bound.
    std::uint32_t rigid_steps = 0;
    double last_moved = std::numeric_limits<double>::infinity();
};
}  // namespace detail

// Owns a scene and the culling state that persists between frames (refitted hierarchies, the
// sorted intervals of Stage I), so a simulator's frames reuse work.
class ProximityEngine {
  public:
    ProximityEngine();
    ~ProximityEngine();
    ProximityEngine(const ProximityEngine&) = delete;
    ProximityEngine& operator=(const ProximityEngine&) = delete;

    Scene& scene() { return m_scene; }
    const Scene& scene() const { return m_scene; }

    // Runs the requested queries on the current scene. Fails with invalid_argument for a bad
    // request (negative or non-finite tolerance), cancelled / deadline_exceeded when the token says
    // so (partial results are discarded).
    // Culler `voronoi_gpu` without a GPU backend fails with failed_precondition.
    StatusOr<QueryResult> query(const QueryRequest& request, const CancelToken* cancel = nullptr);

    // The GPU backend of the discrete-Voronoi kernel (gpu::make_egl_backend), or null for none.
    // Without one, `voronoi_gpu` is refused (and `automatic` never chooses it).
    void set_gpu_backend(std::shared_ptr<dvd::Backend> backend);
    // Why there is no GPU backend (shown in the failed_precondition message), e.g. the EGL error.
    void set_gpu_unavailable_reason(std::string reason) { m_gpu_reason = std::move(reason); }
    bool has_gpu_backend() const { return m_gpu_backend != nullptr; }

    // Frame-to-frame coherence: a self query remembers each object's answer (every triangle's
    // closest triangle and distance), and the next self query on an object of the same topology
    // first seeds each triangle's bound with an exact test against that triangle at the new
    // positions (an upper bound whatever the motion, so answers never depend on it), and skips
    // the 2-ring seed search where that pair is still within twice its last distance. This
    // forgets it: the next query runs cold (benchmarks compare warm and cold frames with it).
    void forget_coherence() { m_self_memory.clear(); }

  private:
    StatusOr<Culler*> culler_for(CullerKind kind);
    CullerKind choose_automatic(const QueryRequest& request);
    void record_automatic(const QueryRequest& request, CullerKind kind, double seconds);

    Scene m_scene;
    std::unique_ptr<Culler> m_brute;
    std::unique_ptr<Culler> m_bvh;
    std::unique_ptr<Culler> m_voronoi_cpu;
    std::unique_ptr<Culler> m_voronoi_gpu;
    std::shared_ptr<dvd::Backend> m_gpu_backend;
    std::string m_gpu_reason = "no GPU backend was set";
    // The automatic choice's cost model, per kind of request (which queries it asks): the last
    // measured total of each culler on this scene, from queries that ran it anyway (chosen by
    // `automatic` or asked for by name). `automatic` never runs a culler only to measure it.
    struct AutoModel {
        double bvh_seconds = -1;          // < 0: not measured
        double voronoi_cpu_seconds = -1;  // infinity: failed when `automatic` chose it
        double voronoi_gpu_seconds = -1;
    };
    std::array<AutoModel, 32> m_auto{};
    SweepAndPrune m_sap;
    std::uint64_t m_sap_generation = ~0ull;
    // The last self answer per object (detail::SelfMemory): hints and a candidate list, every one
    // checked and tested again.
    std::unordered_map<ObjectId, detail::SelfMemory> m_self_memory;
};

// Number of unordered non-adjacent triangle pairs within one object (brute-force work of a
// self-collision query).
std::uint64_t non_adjacent_pair_count(const MeshTopology& topology);

}  // namespace proxima
