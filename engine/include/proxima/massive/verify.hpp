#pragma once
// Static verification of a massive model (seed 001 §4.2–§4.3, §6.5): every pair of objects whose
// surfaces come within a tolerance (0: every collision), found by traversing the localized
// subgraphs of the overlap graph in order, with pieces streaming through the shared cache and a
// prefetch thread reading ahead along the same order. The answer equals the brute-force reference
// (every object pair, everything in memory) exactly: same pairs, same distances bit for bit, same
// closest triangles (ties go to the smaller triangle indices).

#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "proxima/massive/cache.hpp"
#include "proxima/massive/partition.hpp"
#include "proxima/massive/store.hpp"
#include "proxima/query/query.hpp"

namespace proxima::massive {

struct ObjectPairResult {
    std::uint32_t object_a = 0;  // object_a < object_b (indices in Store::objects())
    std::uint32_t object_b = 0;
    double distance = 0.0;
    std::uint32_t triangle_a = 0;  // triangle indices within each object
    std::uint32_t triangle_b = 0;
    Vec3 point_a;
    Vec3 point_b;
    friend bool operator==(const ObjectPairResult&, const ObjectPairResult&) = default;
};

struct VerifyStats {
    std::uint64_t objects = 0;
    std::uint64_t pieces = 0;
    std::uint64_t model_triangles = 0;
    // Triangles of the pieces some edge needs: each must be loaded at least once, the rest never
    // (cache.triangles_loaded / edge_triangles is the re-load factor of the schedule).
    std::uint64_t edge_triangles = 0;
    std::uint64_t subgraphs = 0;
    std::uint64_t edges = 0;         // piece pairs tested
    std::uint64_t object_pairs = 0;  // object pairs with at least one edge
    std::uint64_t pairs_found = 0;   // within tolerance
    std::uint64_t exact_tests = 0;
    double plan_seconds = 0;  // 0 when the schedule was read from the store
    double seconds = 0;       // traversal
    bool schedule_from_store = false;
    CacheStats cache;  // counters of this run (loads, triangles loaded, waits, peak)
};

struct VerifyOptions {
    double tolerance = 0.0;
    // Pieces the prefetch thread may read ahead of the traversal, at most this share of the cache
    // (the rest holds the current subgraph).
    double prefetch_share = 0.25;
    // Persist the schedule with the store (and reuse a persisted one for the same tolerance and
    // cache budget).
    bool persist_schedule = true;
};

// Streams each object pair within tolerance to `on_pair` as soon as all its piece pairs are done
// (from one thread at a time), and reports progress ("verifying", edges done, edges). Returns the
// statistics; the pairs are also returned sorted by (object_a, object_b) through `all` if given.
StatusOr<VerifyStats> verify_static(const std::shared_ptr<const Store>& store, GeometryCache& cache,
                                    const VerifyOptions& options,
                                    const std::function<void(const ObjectPairResult&)>& on_pair,
                                    std::vector<ObjectPairResult>* all = nullptr,
                                    const ProgressFn& progress = {},
                                    const CancelToken* cancel = nullptr);

// --- Shards: one verification split over several processes or machines ----------------------
//
// Shard i of n takes the i-th of n groups of the schedule's localized subgraphs, balanced by
// estimated work (the triangles of both pieces of each piece pair, summed per subgraph; the
// heaviest subgraph first goes to the lightest group, ties to the lower index: deterministic for
// a given store generation, tolerance and cache budget). An object pair's piece pairs may fall in
// several shards, so a shard reports each object pair's best hit among its own piece pairs, with
// the exact squared distance; merge_shard_pairs keeps the best of them in the same canonical
// order as a single run (squared distance, then triangle indices), which is the single run's
// answer exactly.

struct ShardPair {
    ObjectPairResult pair;
    double squared_distance = 0.0;
};

struct ShardStats {
    std::uint32_t index = 0;
    std::uint32_t count = 1;
    std::uint64_t subgraphs = 0;  // this shard's
    std::uint64_t edges = 0;      // this shard's piece pairs
    std::uint64_t work = 0;       // this shard's estimated work (triangles)
};

// The indices (in processing order) of the subgraphs of shard `index` of `count`.
std::vector<std::size_t> shard_subgraphs(const Schedule& schedule,
                                         const std::vector<PieceInfo>& pieces, std::uint32_t index,
                                         std::uint32_t count);

// Runs shard `index` of `count` (INVALID_ARGUMENT unless index < count). The statistics are those
// of the whole model and schedule (objects, pieces, subgraphs, edges, object_pairs), except
// exact_tests, pairs_found, seconds and cache, which are this shard's; `pairs` gets this shard's
// object pairs within tolerance, sorted by (object_a, object_b).
StatusOr<VerifyStats> verify_shard(const std::shared_ptr<const Store>& store, GeometryCache& cache,
                                   const VerifyOptions& options, std::uint32_t index,
                                   std::uint32_t count, std::vector<ShardPair>* pairs,
                                   ShardStats* shard = nullptr, const ProgressFn& progress = {},
                                   const CancelToken* cancel = nullptr);

// The shards' pairs combined: per object pair the best hit, sorted by (object_a, object_b).
std::vector<ObjectPairResult> merge_shard_pairs(const std::vector<std::vector<ShardPair>>& shards);

// The schedule for (tolerance, cache budget): read from the store's sidecar when present, else
// planned (and written when `persist`).
StatusOr<Schedule> schedule_for(const Store& store, double tolerance, std::uint64_t cache_bytes,
                                bool persist, bool* from_store = nullptr,
                                const ProgressFn& progress = {});

// Every object of the store in memory (pieces reassembled into whole objects), a full hierarchy
// per object (culling/bvh.hpp), every object pair tested: the reference verify_static must equal.
StatusOr<std::vector<ObjectPairResult>> verify_brute_force(const Store& store, double tolerance,
                                                           const CancelToken* cancel = nullptr);

// The rounding slack of comparisons on the store's coordinates (distance/bounds.hpp), from the
// largest coordinate magnitude of its objects' boxes.
double model_slack(const Store& store);

// Reassembles object `object` from its pieces (exact coordinates, original triangle order).
StatusOr<TriangleMesh> read_object(const Store& store, std::uint32_t object);

}  // namespace proxima::massive
