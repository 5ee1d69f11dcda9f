#pragma once
// The runtime side of seed 001 (§4.3, §4.5, §5.2, §6.4): pieces resident in memory with lazily
// built hierarchies, an LRU cache under one byte budget M shared by every session and model, and
// a prefetch thread that loads what the traversal (or an avatar's motion) will need next. A query
// blocks only on a piece that is not resident yet.

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <list>
#include <memory>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <vector>

#include "proxima/distance/primitives.hpp"
#include "proxima/massive/store.hpp"

namespace proxima::massive {

// An AABB tree over a piece's triangles whose children are built the first time a traversal
// visits them (§5.2): a query that touches a small region of a large piece builds only the nodes
// on its way. Thread-safe: several traversals may expand the same tree at once (expansion takes a
// lock; reading built nodes does not).
class LazyBvh {
  public:
    static constexpr std::uint32_t LEAF_SIZE = 4;
    static constexpr std::uint32_t NONE = 0;  // `left` of a node not expanded yet (or a leaf)

    struct Node {
        Aabb box;
        std::uint32_t first = 0;  // range of order()
        std::uint32_t count = 0;
        // Smallest reported (source) triangle index below: lets a search whose best distance is
        // 0 skip subtrees that cannot hold a smaller tied pair.
        std::uint32_t min_source = 0;
        std::atomic<std::uint32_t> left{NONE};  // right child is left + 1
        bool leaf() const { return count <= LEAF_SIZE; }
    };

    // `bytes` (optional) is credited with the memory of every node built; `source` (optional)
    // maps triangles to the indices results report (identity when empty).
    LazyBvh(std::span<const Vec3> vertices, std::span<const TriangleIndices> triangles,
            std::atomic<std::int64_t>* bytes = nullptr, std::span<const std::uint32_t> source = {});
    LazyBvh(const LazyBvh&) = delete;
    LazyBvh& operator=(const LazyBvh&) = delete;

    const Node& root() const { return node(0); }
    const Node& node(std::uint32_t i) const { return m_blocks[i / BLOCK][i % BLOCK]; }
    // The children of an inner node, built on first call.
    std::pair<const Node*, const Node*> children(const Node& n);
    std::uint32_t triangle(std::uint32_t slot) const { return m_order[slot]; }
    const TriangleIndices& indices(std::uint32_t t) const { return m_triangles[t]; }
    Triangle corners(std::uint32_t t) const {
        const auto& tri = m_triangles[t];
        return {m_vertices[tri[0]], m_vertices[tri[1]], m_vertices[tri[2]]};
    }
    // Builds every node holding more than `count` triangles (the prefetch thread's head start).
    void expand_above(std::uint32_t count);
    std::uint32_t nodes_built() const { return m_count.load(std::memory_order_relaxed); }
    std::uint64_t memory_bytes() const;

  private:
    static constexpr std::uint32_t BLOCK = 1024;
    Node& mutable_node(std::uint32_t i) { return m_blocks[i / BLOCK][i % BLOCK]; }
    std::uint32_t allocate_two();  // under m_mutex
    void set_box(Node& n);

    std::span<const Vec3> m_vertices;
    std::span<const TriangleIndices> m_triangles;
    std::span<const std::uint32_t> m_source;
    std::vector<std::uint32_t> m_order;
    std::vector<std::unique_ptr<Node[]>> m_blocks;  // sized for the worst case up front
    std::atomic<std::uint32_t> m_count{0};
    std::mutex m_mutex;
    std::atomic<std::int64_t>* m_bytes;
};

// A piece in memory: its geometry and its lazy hierarchy. Immutable geometry; the hierarchy grows.
struct ResidentPiece {
    ResidentPiece(std::uint32_t piece_index, std::uint32_t object_index, PieceGeometry g,
                  std::atomic<std::int64_t>* bytes);
    std::uint32_t piece = 0;
    std::uint32_t object = 0;
    PieceGeometry geometry;
    LazyBvh bvh;
    std::uint64_t geometry_bytes() const;
};
using PieceHandle = std::shared_ptr<ResidentPiece>;  // pins the piece while held

struct CacheStats {
    std::uint64_t budget_bytes = 0;
    std::int64_t resident_bytes = 0;  // geometry + hierarchies built so far
    std::int64_t peak_bytes = 0;
    std::uint64_t hits = 0;    // get() found the piece resident (or loading by prefetch)
    std::uint64_t misses = 0;  // get() had to load it itself
    std::uint64_t waits = 0;   // get() blocked on a load in progress
    std::uint64_t loads = 0;   // pieces read from disk (by get or prefetch)
    std::uint64_t prefetch_loads = 0;
    std::uint64_t triangles_loaded = 0;
    std::uint64_t bytes_loaded = 0;  // piece record bytes read
    std::uint64_t evictions = 0;
    double blocked_seconds = 0;  // time get() spent waiting for disk
};
// Counters accumulated between two snapshots of a shared cache (budget, resident and peak are
// taken from `after`).
CacheStats counters_since(const CacheStats& before, const CacheStats& after);

// LRU cache of pieces of any number of stores under one byte budget. Pinned pieces (a handle is
// held) are never evicted; when everything resident is pinned the cache may exceed the budget
// until handles are released (peak_bytes shows by how much).
class GeometryCache {
  public:
    // Prefetched pieces get their whole hierarchy built by the prefetch thread (a query then
    // never pays for a first visit); pieces a query loads itself stay lazy.
    static constexpr std::uint32_t PREFETCH_EXPAND_ABOVE = LazyBvh::LEAF_SIZE;
    explicit GeometryCache(std::uint64_t budget_bytes);
    ~GeometryCache();
    GeometryCache(const GeometryCache&) = delete;
    GeometryCache& operator=(const GeometryCache&) = delete;

    // The resident piece, loading it (and waiting for a load in progress) when needed. DATA_LOSS
    // or UNAVAILABLE from the store are returned (and not cached: a later get tries again).
    StatusOr<PieceHandle> get(const std::shared_ptr<const Store>& store, std::uint32_t piece);
    // Hints: the prefetch thread loads these (in order) unless resident; a newer hint list from
    // the same `stream` replaces the older one's remaining entries.
    void prefetch(const std::shared_ptr<const Store>& store, std::vector<std::uint32_t> pieces,
                  std::uint64_t stream = 0);
    bool resident(const Store& store, std::uint32_t piece) const;

    CacheStats stats() const;
    std::uint64_t budget() const { return m_budget; }
    // Drops every unpinned piece (tests and benchmarks start cold).
    void clear();

  private:
    struct Entry;
    struct Key {
        const Store* store;
        std::uint32_t piece;
        bool operator==(const Key&) const = default;
    };
    struct KeyHash {
        std::size_t operator()(const Key& k) const {
            return std::hash<const void*>()(k.store) * 31 + k.piece;
        }
    };
    StatusOr<PieceHandle> load(const std::shared_ptr<const Store>& store, std::uint32_t piece,
                               bool by_prefetch);
    void evict_locked();
    std::int64_t resident_locked() const;
    void prefetch_loop();

    const std::uint64_t m_budget;
    mutable std::mutex m_mutex;
    std::condition_variable m_loaded;
    std::unordered_map<Key, std::shared_ptr<Entry>, KeyHash> m_entries;
    std::list<Key> m_lru;  // front: most recently used
    CacheStats m_stats;

    struct Hint {
        std::shared_ptr<const Store> store;
        std::uint32_t piece;
        std::uint64_t stream;
    };
    std::deque<Hint> m_hints;
    std::condition_variable m_hint_cv;
    bool m_stop = false;
    std::thread m_prefetcher;
};

// Closest pair between two resident trees among pairs at most sqrt(bound_sq) apart. Ties in
// distance go to the smaller (source triangle of a, source triangle of b): every tied pair is
// visited (thresholds are widened), so the answer does not depend on traversal order. `a` is the
// first argument of every exact test (callers put the lower object index first, so the computed
// distances equal the in-memory engine's bit for bit).
struct PairHit {
    bool found = false;
    double squared_distance = std::numeric_limits<double>::infinity();
    std::uint32_t triangle_a = 0;  // source triangle indices (object numbering)
    std::uint32_t triangle_b = 0;
    std::uint32_t local_a = 0;  // the same triangles as indices of the trees
    std::uint32_t local_b = 0;
    Vec3 point_a;
    Vec3 point_b;
    std::uint64_t exact_tests = 0;
};
struct TreeRef {
    LazyBvh* bvh;
    const std::vector<std::uint32_t>* source = nullptr;  // tree triangle -> reported; null: same
    // A rigid avatar: the tree is built once on its own coordinates and searched under `pose`
    // (node boxes mapped conservatively, exact tests on `posed`, the posed vertices, indexed
    // like the tree's).
    const Affine* pose = nullptr;
    const Vec3* posed = nullptr;
};
// `ties_b_first`: break ties by (triangle_b, triangle_a) instead (the engine's separation order
// when b is the object asking).
PairHit closest_pair(TreeRef a, TreeRef b, double bound_sq, double slack,
                     bool ties_b_first = false);

}  // namespace proxima::massive
