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
#include "proxima/massive/lazy_bvh.hpp"
#include "proxima/massive/store.hpp"

namespace proxima::massive {

// A piece in memory: its geometry and its lazy hierarchy. Immutable geometry; the hierarchy grows.
// The piece shares the counter its hierarchy adds its bytes to (`tree_bytes`, may be null) with
// whoever reads it: a handle can outlive the cache entry that counted it (a get() that waited on
// a load returns the piece even when the entry was evicted meanwhile), and its tree still grows.
struct ResidentPiece {
    ResidentPiece(std::uint32_t piece_index, std::uint32_t object_index, PieceGeometry g,
                  std::shared_ptr<std::atomic<std::int64_t>> bytes);
    std::uint32_t piece = 0;
    std::uint32_t object = 0;
    PieceGeometry geometry;
    std::shared_ptr<std::atomic<std::int64_t>> tree_bytes;  // before bvh: outlives it
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
    // Hierarchy nodes built by the prefetch thread (GeometryCache::PREFETCH_EXPAND_ABOVE).
    std::uint64_t prefetch_nodes_built = 0;
    std::uint64_t triangles_loaded = 0;
    std::uint64_t bytes_loaded = 0;  // piece record bytes read
    std::uint64_t evictions = 0;
    double blocked_seconds = 0;  // time get() spent waiting for disk
    // Memory outside the cache charged to its budget (GeometryCache::charge): the review rooms'
    // moved and added objects, with their hierarchies. Pieces are evicted to keep resident_bytes +
    // charged_bytes within the budget.
    std::int64_t charged_bytes = 0;
};
// Counters accumulated between two snapshots of a shared cache (budget, resident and peak are
// taken from `after`).
CacheStats counters_since(const CacheStats& before, const CacheStats& after);

// LRU cache of pieces of any number of stores under one byte budget. Pinned pieces (a handle is
// held) are never evicted; when everything resident is pinned the cache may exceed the budget
// until handles are released (peak_bytes shows by how much).
class GeometryCache {
  public:
    // Prefetched pieces get the upper levels of their hierarchy built by the prefetch thread
    // (every node of more than this many triangles); the levels below are built by the queries
    // that visit them, as for pieces a query loads itself. Building whole trees here cost half
    // the daemon's CPU under the review load (many pieces are evicted before a query walks most
    // of their tree) and charged M for nodes no query used (docs/massive.md, docs/load.md).
    static constexpr std::uint32_t PREFETCH_EXPAND_ABOVE = 1024;
    explicit GeometryCache(std::uint64_t budget_bytes);
    ~GeometryCache();
    GeometryCache(const GeometryCache&) = delete;
    GeometryCache& operator=(const GeometryCache&) = delete;

    // The resident piece, loading it (and waiting for a load in progress) when needed. DATA_LOSS
    // or UNAVAILABLE from the store are returned (and not cached: a later get tries again).
    StatusOr<PieceHandle> get(const std::shared_ptr<const Store>& store, std::uint32_t piece);
    // Hints: the prefetch thread loads these (in order) unless resident; a newer hint list from
    // the same `stream` replaces the older one's remaining entries.
    void prefetch(const std::shared_ptr<const Store>& store,
                  const std::vector<std::uint32_t>& pieces, std::uint64_t stream = 0);
    bool resident(const Store& store, std::uint32_t piece) const;

    // Memory held outside the cache that counts against its budget: a review room's moved and
    // added objects (ModelView's overlay). `fixed` bytes plus what `growing` counts (a lazy
    // hierarchy's nodes) stay charged while the returned handle lives; charging evicts unpinned
    // pieces to make room. RESOURCE_EXHAUSTED, and nothing charged, when the charges alone would
    // exceed the budget with this one (less `replaces`, a charge this one takes the place of).
    using Charge = std::shared_ptr<const void>;
    StatusOr<Charge> charge(std::int64_t fixed,
                            std::shared_ptr<const std::atomic<std::int64_t>> growing,
                            const Charge& replaces = nullptr);

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
    std::int64_t charged_locked();             // drops the charges whose handles are gone
    std::int64_t live_charges_locked() const;  // sums the live charges, drops none
    void prefetch_loop();

    const std::uint64_t m_budget;
    mutable std::mutex m_mutex;
    std::condition_variable m_loaded;
    std::unordered_map<Key, std::shared_ptr<Entry>, KeyHash> m_entries;
    std::list<Key> m_lru;  // front: most recently used
    CacheStats m_stats;
    struct ChargeRecord;
    std::vector<std::weak_ptr<const ChargeRecord>> m_charges;

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

}  // namespace proxima::massive
