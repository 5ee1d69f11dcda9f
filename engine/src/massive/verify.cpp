#include "proxima/massive/verify.hpp"

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cstdio>
#include <mutex>
#include <thread>
#include <unordered_map>

#include "proxima/culling/bvh.hpp"
#include "proxima/distance/bounds.hpp"
#include "proxima/scene.hpp"

namespace proxima::massive {

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

std::uint64_t pair_key(std::uint32_t a, std::uint32_t b) {
    return (static_cast<std::uint64_t>(a) << 32) | b;
}

// The canonical order of candidates for one object pair: distance, then triangle indices.
bool better_hit(double d_sq, std::uint32_t ta, std::uint32_t tb, const ObjectPairResult& best,
                double best_sq, bool have) {
    if (!have || d_sq != best_sq) {
        return !have || d_sq < best_sq;
    }
    return std::tie(ta, tb) < std::tie(best.triangle_a, best.triangle_b);
}

std::string schedule_name(double tolerance, std::uint64_t cache_bytes) {
    char name[96];
    std::snprintf(name, sizeof(name), "schedule-t%016llx-m%llu.bin",
                  static_cast<unsigned long long>(std::bit_cast<std::uint64_t>(tolerance)),
                  static_cast<unsigned long long>(cache_bytes));
    return name;
}

}  // namespace

StatusOr<Schedule> schedule_for(const Store& store, double tolerance, std::uint64_t cache_bytes,
                                bool persist, bool* from_store, const ProgressFn& progress) {
    if (from_store != nullptr) {
        *from_store = false;
    }
    const std::string name = schedule_name(tolerance, cache_bytes);
    if (auto bytes = store.read_sidecar(name); bytes.ok()) {
        auto s = deserialize_schedule(*bytes);
        if (s.ok() && s->node_count == store.pieces().size()) {
            if (from_store != nullptr) {
                *from_store = true;
            }
            return s;
        }
        // A stale or unreadable schedule is planned again (and overwritten) below.
    } else if (bytes.status().code() == StatusCode::unavailable) {
        return bytes.status();
    }
    std::vector<GraphNode> nodes;
    nodes.reserve(store.pieces().size());
    for (const auto& p : store.pieces()) {
        nodes.push_back({p.box, p.weight(), p.object});
    }
    auto schedule = plan_schedule(nodes, tolerance, cache_bytes, progress);
    if (!schedule.ok()) {
        return schedule.status();
    }
    if (persist) {
        // Best effort: a read-only store still verifies, it just plans every time.
        (void)store.write_sidecar(name, serialize_schedule(*schedule));
    }
    return schedule;
}

namespace {

// The edges in processing order (the schedule's subgraphs one after the other).
std::vector<std::pair<std::uint32_t, std::uint32_t>> edges_in_order(const Schedule& schedule) {
    std::vector<std::pair<std::uint32_t, std::uint32_t>> edges;
    edges.reserve(schedule.edge_count);
    for (const auto& sg : schedule.subgraphs) {
        edges.insert(edges.end(), sg.edges.begin(), sg.edges.end());
    }
    return edges;
}

// Triangles of the pieces that take part in at least one edge.
std::uint64_t edge_triangles(const std::vector<std::pair<std::uint32_t, std::uint32_t>>& edges,
                             const std::vector<PieceInfo>& pieces) {
    std::vector<std::uint8_t> used(pieces.size(), 0);
    for (const auto& [a, b] : edges) {
        used[a] = used[b] = 1;
    }
    std::uint64_t triangles = 0;
    for (std::size_t p = 0; p < pieces.size(); ++p) {
        triangles += used[p] != 0 ? pieces[p].triangle_count : 0;
    }
    return triangles;
}

// One object pair's best hit so far, and how many of its piece pairs are still to test.
struct Aggregate {
    std::uint32_t remaining = 0;
    bool found = false;
    double best_sq = 0.0;
    ObjectPairResult result;
};

std::unordered_map<std::uint64_t, Aggregate> object_pairs(
    const std::vector<std::pair<std::uint32_t, std::uint32_t>>& edges,
    const std::vector<PieceInfo>& pieces) {
    std::unordered_map<std::uint64_t, Aggregate> pairs;
    for (const auto& [a, b] : edges) {
        auto oa = pieces[a].object;
        auto ob = pieces[b].object;
        if (oa > ob) {
            std::swap(oa, ob);
        }
        auto& agg = pairs[pair_key(oa, ob)];
        agg.result.object_a = oa;
        agg.result.object_b = ob;
        ++agg.remaining;
    }
    return pairs;
}

// The piece pairs' tests, run by a pool of workers taking edges in order: the shared state, the
// prefetch hints ahead of the workers and the streaming of every object pair whose last piece
// pair is done.
struct VerifyRun {
    VerifyRun(const std::shared_ptr<const Store>& s, GeometryCache& c,
              const std::vector<std::pair<std::uint32_t, std::uint32_t>>& e,
              std::unordered_map<std::uint64_t, Aggregate>& p,
              const std::function<void(const ObjectPairResult&)>& on_pair_done,
              const ProgressFn& progress_fn, const CancelToken* cancel_token)
        : store(s),
          cache(c),
          edges(e),
          pairs(p),
          on_pair(on_pair_done),
          progress(progress_fn),
          cancel(cancel_token) {}

    const std::shared_ptr<const Store>& store;
    GeometryCache& cache;
    const std::vector<std::pair<std::uint32_t, std::uint32_t>>& edges;
    std::unordered_map<std::uint64_t, Aggregate>& pairs;
    const std::function<void(const ObjectPairResult&)>& on_pair;
    const ProgressFn& progress;
    const CancelToken* cancel;
    double tol_sq = 0.0;
    double slack = 0.0;
    std::uint64_t prefetch_budget = 0;
    std::uint64_t stream = 0;

    std::atomic<std::size_t> next{0};
    std::atomic<std::size_t> done{0};
    std::atomic<std::uint64_t> exact_tests{0};
    std::mutex result_mutex;    // aggregates and on_pair
    std::mutex prefetch_mutex;  // hint issuing
    std::size_t hinted_until = 0;
    Status failure;
    std::atomic<bool> failed{false};
    std::vector<ObjectPairResult> found;
    std::vector<double> found_sq;  // the exact squared distance of each of `found`

    // Hints the pieces of the edges after `from`, up to the prefetch budget, in order.
    void issue_hints(std::size_t from) {
        std::lock_guard lock(prefetch_mutex);
        if (from + 16 < hinted_until) {
            return;
        }
        const auto& pieces = store->pieces();
        std::vector<std::uint32_t> list;
        std::uint64_t bytes = 0;
        std::size_t k = from;
        for (; k < edges.size() && bytes < prefetch_budget; ++k) {
            for (auto p : {edges[k].first, edges[k].second}) {
                if (!cache.resident(*store, p) &&
                    std::find(list.begin(), list.end(), p) == list.end()) {
                    list.push_back(p);
                    bytes += pieces[p].weight();
                }
            }
        }
        hinted_until = k;
        cache.prefetch(store, list, stream);
    }

    // Records the first failure (later ones are dropped); the workers then stop.
    void fail(const Status& status) {
        std::lock_guard lock(result_mutex);
        if (!failed.exchange(true)) {
            failure = status;
        }
    }

    // Folds one piece pair's hit into its object pair; streams the object pair when complete.
    void merge(const ResidentPiece& a, const ResidentPiece& b, const PairHit& hit) {
        std::lock_guard lock(result_mutex);
        auto& agg = pairs[pair_key(a.object, b.object)];
        if (hit.found && better_hit(hit.squared_distance, hit.triangle_a, hit.triangle_b,
                                    agg.result, agg.best_sq, agg.found)) {
            agg.found = true;
            agg.best_sq = hit.squared_distance;
            agg.result.distance = std::sqrt(hit.squared_distance);
            agg.result.triangle_a = hit.triangle_a;
            agg.result.triangle_b = hit.triangle_b;
            agg.result.point_a = hit.point_a;
            agg.result.point_b = hit.point_b;
        }
        if (--agg.remaining == 0 && agg.found) {
            found.push_back(agg.result);
            found_sq.push_back(agg.best_sq);
            if (on_pair) {
                on_pair(agg.result);
            }
        }
    }

    // Tests edge k; false when the run must stop.
    bool test_edge(std::size_t k) {
        const auto& pieces = store->pieces();
        auto [pa, pb] = edges[k];
        if (pieces[pa].object > pieces[pb].object) {
            std::swap(pa, pb);
        }
        auto ha = cache.get(store, pa);
        auto hb = ha.ok() ? cache.get(store, pb) : StatusOr<PieceHandle>(ha.status());
        if (!ha.ok() || !hb.ok()) {
            fail(ha.ok() ? hb.status() : ha.status());
            return false;
        }
        ResidentPiece& a = **ha;
        ResidentPiece& b = **hb;
        const PairHit hit = closest_pair({&a.bvh, a.geometry.source_map()},
                                         {&b.bvh, b.geometry.source_map()}, tol_sq, slack);
        exact_tests += hit.exact_tests;
        merge(a, b, hit);
        return true;
    }

    void worker() {
        const std::size_t report_every = std::max<std::size_t>(1, edges.size() / 100);
        for (;;) {
            const std::size_t k = next.fetch_add(1);
            if (k >= edges.size() || failed.load()) {
                return;
            }
            if (cancel != nullptr && cancel->should_stop()) {
                fail(stop_status(*cancel, "verification"));
                return;
            }
            if (k % 32 == 0) {
                issue_hints(k + 1);
            }
            if (!test_edge(k)) {
                return;
            }
            const std::size_t d = done.fetch_add(1) + 1;
            if (progress && (d % report_every == 0 || d == edges.size())) {
                std::lock_guard lock(result_mutex);
                progress({"verifying", d, edges.size(), "piece pairs"});
            }
        }
    }

    // Runs the workers (this thread and one per further arena slot) to the end.
    void run() {
        issue_hints(0);
        const int threads = std::max(1, tbb::this_task_arena::max_concurrency());
        std::vector<std::thread> pool;
        for (int t = 1; t < threads; ++t) {
            pool.emplace_back([this] { worker(); });
        }
        worker();
        for (auto& t : pool) {
            t.join();
        }
        cache.prefetch(store, {}, stream);
    }
};

}  // namespace

namespace {

// Estimated work of a subgraph: the triangles of both pieces of each of its piece pairs.
std::uint64_t subgraph_work(const LocalizedSubgraph& sg, const std::vector<PieceInfo>& pieces) {
    std::uint64_t work = 0;
    for (const auto& [a, b] : sg.edges) {
        work += static_cast<std::uint64_t>(pieces[a].triangle_count) + pieces[b].triangle_count;
    }
    return work;
}

// One run over the schedule's subgraphs, or over one shard's (shard_count > 1).
StatusOr<VerifyStats> verify_run(const std::shared_ptr<const Store>& store, GeometryCache& cache,
                                 const VerifyOptions& options, std::uint32_t shard_index,
                                 std::uint32_t shard_count,
                                 const std::function<void(const ObjectPairResult&)>& on_pair,
                                 std::vector<ObjectPairResult>* all, std::vector<double>* all_sq,
                                 ShardStats* shard, const ProgressFn& progress,
                                 const CancelToken* cancel) {
    if (!std::isfinite(options.tolerance) || options.tolerance < 0.0) {
        return invalid_argument("tolerance must be a finite distance >= 0");
    }
    if (shard_count == 0 || shard_index >= shard_count) {
        return invalid_argument("shard " + std::to_string(shard_index) + "/" +
                                std::to_string(shard_count) +
                                ": the index must be below the count (0 <= I < N)");
    }
    VerifyStats stats;
    stats.objects = store->objects().size();
    stats.pieces = store->pieces().size();
    stats.model_triangles = store->summary().triangles;

    const auto t_plan = std::chrono::steady_clock::now();
    auto schedule = schedule_for(*store, options.tolerance, cache.budget(),
                                 options.persist_schedule, &stats.schedule_from_store, progress);
    if (!schedule.ok()) {
        return schedule.status();
    }
    stats.plan_seconds = stats.schedule_from_store ? 0.0 : seconds_since(t_plan);
    stats.subgraphs = schedule->subgraphs.size();

    // The edges in processing order, and how many piece pairs each object pair has: an object
    // pair's result is final (and streamed) when its last piece pair is done.
    const auto all_edges = edges_in_order(*schedule);
    stats.edges = all_edges.size();
    stats.edge_triangles = edge_triangles(all_edges, store->pieces());
    stats.object_pairs = object_pairs(all_edges, store->pieces()).size();
    std::vector<std::pair<std::uint32_t, std::uint32_t>> edges;
    if (shard_count == 1) {
        edges = all_edges;
    } else {
        ShardStats s;
        s.index = shard_index;
        s.count = shard_count;
        for (auto k : shard_subgraphs(*schedule, store->pieces(), shard_index, shard_count)) {
            const auto& sg = schedule->subgraphs[k];
            edges.insert(edges.end(), sg.edges.begin(), sg.edges.end());
            s.work += subgraph_work(sg, store->pieces());
            ++s.subgraphs;
        }
        s.edges = edges.size();
        if (shard != nullptr) {
            *shard = s;
        }
    }
    auto pairs = object_pairs(edges, store->pieces());

    VerifyRun run(store, cache, edges, pairs, on_pair, progress, cancel);
    run.tol_sq = options.tolerance * options.tolerance;
    run.slack = model_slack(*store);
    run.prefetch_budget =
        static_cast<std::uint64_t>(options.prefetch_share * static_cast<double>(cache.budget()));
    run.stream = reinterpret_cast<std::uintptr_t>(&stats);

    // The cache may be shared (the daemon's): this run's counters are the difference.
    const CacheStats before = cache.stats();
    const auto t0 = std::chrono::steady_clock::now();
    run.run();
    if (run.failed.load()) {
        return run.failure;
    }
    stats.seconds = seconds_since(t0);
    stats.exact_tests = run.exact_tests.load();
    stats.pairs_found = run.found.size();
    stats.cache = counters_since(before, cache.stats());
    if (all != nullptr) {
        std::vector<std::size_t> order(run.found.size());
        for (std::size_t k = 0; k < order.size(); ++k) {
            order[k] = k;
        }
        std::sort(order.begin(), order.end(), [&](std::size_t x, std::size_t y) {
            return std::tie(run.found[x].object_a, run.found[x].object_b) <
                   std::tie(run.found[y].object_a, run.found[y].object_b);
        });
        all->clear();
        if (all_sq != nullptr) {
            all_sq->clear();
        }
        for (auto k : order) {
            all->push_back(run.found[k]);
            if (all_sq != nullptr) {
                all_sq->push_back(run.found_sq[k]);
            }
        }
    }
    return stats;
}

}  // namespace

StatusOr<VerifyStats> verify_static(const std::shared_ptr<const Store>& store, GeometryCache& cache,
                                    const VerifyOptions& options,
                                    const std::function<void(const ObjectPairResult&)>& on_pair,
                                    std::vector<ObjectPairResult>* all, const ProgressFn& progress,
                                    const CancelToken* cancel) {
    return verify_run(store, cache, options, 0, 1, on_pair, all, nullptr, nullptr, progress,
                      cancel);
}

std::vector<std::size_t> shard_subgraphs(const Schedule& schedule,
                                         const std::vector<PieceInfo>& pieces, std::uint32_t index,
                                         std::uint32_t count) {
    std::vector<std::size_t> out;
    if (count == 0 || index >= count) {
        return out;
    }
    const std::size_t n = schedule.subgraphs.size();
    std::vector<std::uint64_t> work(n);
    std::vector<std::size_t> order(n);
    for (std::size_t k = 0; k < n; ++k) {
        work[k] = subgraph_work(schedule.subgraphs[k], pieces);
        order[k] = k;
    }
    // Longest processing time first: the heaviest subgraph to the lightest group.
    std::stable_sort(order.begin(), order.end(),
                     [&](std::size_t x, std::size_t y) { return work[x] > work[y]; });
    std::vector<std::uint64_t> load(count, 0);
    std::vector<std::uint32_t> group(n, 0);
    for (auto k : order) {
        const auto lightest =
            static_cast<std::uint32_t>(std::min_element(load.begin(), load.end()) - load.begin());
        group[k] = lightest;
        load[lightest] += work[k];
    }
    for (std::size_t k = 0; k < n; ++k) {
        if (group[k] == index) {
            out.push_back(k);  // processing order within the shard
        }
    }
    return out;
}

StatusOr<VerifyStats> verify_shard(const std::shared_ptr<const Store>& store, GeometryCache& cache,
                                   const VerifyOptions& options, std::uint32_t index,
                                   std::uint32_t count, std::vector<ShardPair>* pairs,
                                   ShardStats* shard, const ProgressFn& progress,
                                   const CancelToken* cancel) {
    std::vector<ObjectPairResult> found;
    std::vector<double> found_sq;
    ShardStats s;
    s.index = index;
    s.count = count;
    auto stats = verify_run(store, cache, options, index, count, {}, &found, &found_sq, &s,
                            progress, cancel);
    if (!stats.ok()) {
        return stats;
    }
    if (count == 1) {
        s.subgraphs = stats->subgraphs;
        s.edges = stats->edges;
    }
    if (shard != nullptr) {
        *shard = s;
    }
    if (pairs != nullptr) {
        pairs->clear();
        for (std::size_t k = 0; k < found.size(); ++k) {
            pairs->push_back({found[k], found_sq[k]});
        }
    }
    return stats;
}

std::vector<ObjectPairResult> merge_shard_pairs(const std::vector<std::vector<ShardPair>>& shards) {
    std::unordered_map<std::uint64_t, ShardPair> best;
    for (const auto& shard : shards) {
        for (const auto& p : shard) {
            auto [it, fresh] = best.try_emplace(pair_key(p.pair.object_a, p.pair.object_b), p);
            if (!fresh && better_hit(p.squared_distance, p.pair.triangle_a, p.pair.triangle_b,
                                     it->second.pair, it->second.squared_distance, true)) {
                it->second = p;
            }
        }
    }
    std::vector<ObjectPairResult> out;
    out.reserve(best.size());
    for (const auto& [key, p] : best) {
        out.push_back(p.pair);
    }
    std::sort(out.begin(), out.end(), [](const auto& x, const auto& y) {
        return std::tie(x.object_a, x.object_b) < std::tie(y.object_a, y.object_b);
    });
    return out;
}

double model_slack(const Store& store) {
    double scale = 0.0;
    for (const auto& o : store.objects()) {
        scale = std::max(scale, coordinate_scale(o.box));
    }
    return rounding_slack(scale);
}

StatusOr<TriangleMesh> read_object(const Store& store, std::uint32_t object) {
    if (object >= store.objects().size()) {
        return not_found("object " + std::to_string(object) + " not in the store");
    }
    const auto& info = store.objects()[object];
    TriangleMesh mesh;
    mesh.triangles.resize(info.triangle_count);
    for (std::uint32_t p = info.first_piece; p < info.first_piece + info.piece_count; ++p) {
        auto g = store.read_piece(p);
        if (!g.ok()) {
            return g.status();
        }
        const auto base = static_cast<std::uint32_t>(mesh.vertices.size());
        mesh.vertices.insert(mesh.vertices.end(), g->vertices.begin(), g->vertices.end());
        for (std::size_t t = 0; t < g->triangles.size(); ++t) {
            const auto& tri = g->triangles[t];
            mesh.triangles.at(g->source(t)) = {tri[0] + base, tri[1] + base, tri[2] + base};
        }
    }
    return mesh;
}

namespace {

// Dual traversal of two full hierarchies (culling/bvh.hpp), an implementation independent of the
// lazy one above: the brute-force reference must not share the code it checks.
struct FullPairSearch {
    const TriangleMesh& ma;
    const Bvh& ba;
    const TriangleMesh& mb;
    const Bvh& bb;
    double bound_sq;
    double slack;
    bool found = false;
    double best_sq = 0.0;
    ObjectPairResult best{};
    std::uint64_t tests = 0;

    Triangle corners(const TriangleMesh& m, std::uint32_t t) const {
        const auto& tri = m.triangles[t];
        return {m.vertices[tri[0]], m.vertices[tri[1]], m.vertices[tri[2]]};
    }
    void visit(std::uint32_t na, std::uint32_t nb) {
        const auto& A = ba.nodes()[na];
        const auto& B = bb.nodes()[nb];
        const double threshold = cull_threshold_sq(found ? best_sq : bound_sq, slack);
        if (box_squared_distance(A.box, B.box) > threshold) {
            return;
        }
        if (A.leaf() && B.leaf()) {
            for (std::uint32_t i = A.first; i < A.first + A.count; ++i) {
                const std::uint32_t ta = ba.order()[i];
                for (std::uint32_t j = B.first; j < B.first + B.count; ++j) {
                    const std::uint32_t tb = bb.order()[j];
                    ++tests;
                    const auto cp = triangle_triangle(corners(ma, ta), corners(mb, tb));
                    if (cp.squared_distance <= bound_sq &&
                        better_hit(cp.squared_distance, ta, tb, best, best_sq, found)) {
                        found = true;
                        best_sq = cp.squared_distance;
                        best.triangle_a = ta;
                        best.triangle_b = tb;
                        best.point_a = cp.point_a;
                        best.point_b = cp.point_b;
                    }
                }
            }
            return;
        }
        if (!A.leaf()) {
            visit(na + 1, nb);
            visit(A.first, nb);
        } else {
            visit(na, nb + 1);
            visit(na, B.first);
        }
    }
};

}  // namespace

StatusOr<std::vector<ObjectPairResult>> verify_brute_force(const Store& store, double tolerance,
                                                           const CancelToken* cancel) {
    if (!std::isfinite(tolerance) || tolerance < 0.0) {
        return invalid_argument("tolerance must be a finite distance >= 0");
    }
    const std::size_t n = store.objects().size();
    std::vector<TriangleMesh> meshes(n);
    std::vector<Bvh> trees(n);
    std::vector<Aabb> boxes(n);
    for (std::uint32_t i = 0; i < n; ++i) {
        auto m = read_object(store, i);
        if (!m.ok()) {
            return m.status();
        }
        meshes[i] = std::move(*m);
        boxes[i] = compute_box(meshes[i].vertices);
    }
    tbb::parallel_for(std::size_t{0}, n, [&](std::size_t i) {
        MeshTopology topology(meshes[i].triangles, meshes[i].vertices.size());
        trees[i].build(meshes[i].vertices, topology);
    });
    const double tol_sq = tolerance * tolerance;
    const double slack = model_slack(store);
    std::vector<std::vector<ObjectPairResult>> per(n);
    std::atomic<bool> stopped{false};
    tbb::parallel_for(std::size_t{0}, n, [&](std::size_t i) {
        for (std::size_t j = i + 1; j < n; ++j) {
            if (cancel != nullptr && cancel->should_stop()) {
                stopped = true;
                return;
            }
            // The roots' test (every pair goes through it).
            if (box_squared_distance(boxes[i], boxes[j]) > cull_threshold_sq(tol_sq, slack)) {
                continue;
            }
            FullPairSearch s{meshes[i], trees[i], meshes[j], trees[j], tol_sq,
                             slack,     false,    0.0,       {},       0};
            s.visit(0, 0);
            if (s.found) {
                s.best.object_a = static_cast<std::uint32_t>(i);
                s.best.object_b = static_cast<std::uint32_t>(j);
                s.best.distance = std::sqrt(s.best_sq);
                per[i].push_back(s.best);
            }
        }
    });
    if (stopped) {
        return stop_status(*cancel, "verification");
    }
    std::vector<ObjectPairResult> out;
    for (auto& v : per) {
        out.insert(out.end(), v.begin(), v.end());
    }
    return out;
}

}  // namespace proxima::massive
