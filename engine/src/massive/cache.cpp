#include "proxima/massive/cache.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <tuple>

#include "proxima/distance/bounds.hpp"

namespace proxima::massive {

ResidentPiece::ResidentPiece(std::uint32_t piece_index, std::uint32_t object_index, PieceGeometry g,
                             std::shared_ptr<std::atomic<std::int64_t>> bytes)
    : piece(piece_index),
      object(object_index),
      geometry(std::move(g)),
      tree_bytes(std::move(bytes)),
      bvh(geometry.vertices, geometry.triangles, tree_bytes.get(), geometry.source_triangles) {}

std::uint64_t ResidentPiece::geometry_bytes() const {
    return geometry.vertices.size() * sizeof(Vec3) +
           geometry.triangles.size() * sizeof(TriangleIndices) +
           geometry.source_triangles.size() * sizeof(std::uint32_t) + sizeof(ResidentPiece);
}

struct GeometryCache::Entry {
    PieceHandle piece;  // null while loading
    bool loading = false;
    Status error;  // of the last failed load (entry then removed)
    std::list<Key>::iterator lru;
    std::int64_t charged = 0;            // geometry bytes charged at load
    std::shared_ptr<const Store> store;  // keeps the store open while its pieces are resident
};

GeometryCache::GeometryCache(std::uint64_t budget_bytes) : m_budget(budget_bytes) {
    m_stats.budget_bytes = budget_bytes;
    m_prefetcher = std::thread([this] { prefetch_loop(); });
}

GeometryCache::~GeometryCache() {
    {
        std::lock_guard lock(m_mutex);
        m_stop = true;
    }
    m_hint_cv.notify_all();
    m_prefetcher.join();
}

namespace {
// The geometry charged at load plus the piece's hierarchy so far (none while loading).
std::int64_t entry_bytes(const PieceHandle& piece, std::int64_t charged) {
    return charged + (piece ? piece->tree_bytes->load(std::memory_order_relaxed) : 0);
}
}  // namespace

StatusOr<PieceHandle> GeometryCache::get(const std::shared_ptr<const Store>& store,
                                         std::uint32_t piece) {
    const Key key{store.get(), piece};
    {
        std::unique_lock lock(m_mutex);
        auto it = m_entries.find(key);
        if (it != m_entries.end()) {
            auto entry = it->second;
            if (entry->loading) {
                ++m_stats.waits;
                const auto t0 = std::chrono::steady_clock::now();
                m_loaded.wait(lock, [&] { return !entry->loading; });
                m_stats.blocked_seconds +=
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
                if (!entry->piece) {
                    return entry->error;
                }
            } else {
                ++m_stats.hits;
            }
            // The entry may have been evicted (or failed) while this call waited: touch the LRU
            // only if it is still the cached one.
            auto again = m_entries.find(key);
            if (again != m_entries.end() && again->second == entry) {
                m_lru.splice(m_lru.begin(), m_lru, entry->lru);
            }
            return entry->piece;
        }
        ++m_stats.misses;
    }
    const auto t0 = std::chrono::steady_clock::now();
    auto r = load(store, piece, false);
    std::lock_guard lock(m_mutex);
    m_stats.blocked_seconds +=
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return r;
}

StatusOr<PieceHandle> GeometryCache::load(const std::shared_ptr<const Store>& store,
                                          std::uint32_t piece, bool by_prefetch) {
    const Key key{store.get(), piece};
    std::shared_ptr<Entry> entry;
    {
        std::lock_guard lock(m_mutex);
        auto it = m_entries.find(key);
        if (it != m_entries.end()) {
            // Someone else is loading or has loaded it meanwhile.
            if (by_prefetch) {
                return PieceHandle{};
            }
            // get() raced with prefetch: wait through get's path.
        } else {
            entry = std::make_shared<Entry>();
            entry->loading = true;
            entry->store = store;
            m_lru.push_front(key);
            entry->lru = m_lru.begin();
            m_entries.emplace(key, entry);
        }
    }
    if (!entry) {
        return get(store, piece);
    }
    auto geometry = store->read_piece(piece);
    PieceHandle resident;
    const auto& info = store->pieces()[piece];
    if (geometry.ok()) {
        resident = std::make_shared<ResidentPiece>(piece, info.object, std::move(*geometry),
                                                   std::make_shared<std::atomic<std::int64_t>>(0));
    }
    std::unique_lock lock(m_mutex);
    entry->loading = false;
    if (!geometry.ok()) {
        entry->error = geometry.status();
        m_lru.erase(entry->lru);
        m_entries.erase(key);
        m_loaded.notify_all();
        return geometry.status();
    }
    entry->piece = std::move(resident);
    entry->charged = static_cast<std::int64_t>(entry->piece->geometry_bytes());
    ++m_stats.loads;
    if (by_prefetch) {
        ++m_stats.prefetch_loads;
    }
    m_stats.triangles_loaded += info.triangle_count;
    m_stats.bytes_loaded += info.bytes;
    // Pinned before evicting, so the piece just read is not the one thrown out.
    PieceHandle handle = entry->piece;
    evict_locked();
    m_loaded.notify_all();
    lock.unlock();
    if (by_prefetch) {
        // §4.3: the prefetch phase also builds hierarchies ahead of the queries (the upper
        // levels only; the rest stays lazy), after publishing the piece: a query that needs it
        // meanwhile uses it at once (the tree is safe to expand from several threads).
        const std::uint32_t built = handle->bvh.expand_above(PREFETCH_EXPAND_ABOVE);
        std::lock_guard relock(m_mutex);
        m_stats.prefetch_nodes_built += built;
    }
    return handle;
}

struct GeometryCache::ChargeRecord {
    std::int64_t fixed = 0;
    std::shared_ptr<const std::atomic<std::int64_t>> growing;
    std::int64_t bytes() const {
        return fixed + (growing ? growing->load(std::memory_order_relaxed) : 0);
    }
};

std::int64_t GeometryCache::live_charges_locked() const {
    std::int64_t total = 0;
    for (const auto& w : m_charges) {
        if (auto c = w.lock()) {
            total += c->bytes();
        }
    }
    return total;
}

std::int64_t GeometryCache::charged_locked() {
    std::erase_if(m_charges,
                  [](const std::weak_ptr<const ChargeRecord>& w) { return w.expired(); });
    return live_charges_locked();
}

StatusOr<GeometryCache::Charge> GeometryCache::charge(
    std::int64_t fixed, std::shared_ptr<const std::atomic<std::int64_t>> growing,
    const Charge& replaces) {
    auto record = std::make_shared<ChargeRecord>();
    record->fixed = fixed;
    record->growing = std::move(growing);
    std::lock_guard lock(m_mutex);
    std::int64_t after = charged_locked() + record->bytes();
    if (replaces) {
        after -= static_cast<const ChargeRecord*>(replaces.get())->bytes();
    }
    if (after > static_cast<std::int64_t>(m_budget)) {
        return Status(StatusCode::resource_exhausted,
                      "edited objects would hold " + std::to_string(after) +
                          " bytes in memory, over the geometry cache's budget of " +
                          std::to_string(m_budget) +
                          " bytes (--cache-bytes): delete added objects or move objects back "
                          "to their stored placement first");
    }
    m_charges.push_back(record);
    evict_locked();
    return Charge(record);
}

std::int64_t GeometryCache::resident_locked() const {
    // Summed on demand: hierarchies grow without taking the cache lock.
    std::int64_t total = 0;
    for (const auto& [k, e] : m_entries) {
        total += entry_bytes(e->piece, e->charged);
    }
    return total;
}

void GeometryCache::evict_locked() {
    // Recompute the resident total (hierarchies grow without taking the cache lock); the charges
    // from outside count against the same budget.
    std::int64_t total = resident_locked();
    const std::int64_t budget = static_cast<std::int64_t>(m_budget) - charged_locked();
    auto it = m_lru.end();
    while (total > budget && it != m_lru.begin()) {
        --it;
        auto e = m_entries.find(*it);
        auto& entry = e->second;
        // Pinned (a handle outside the cache) or loading: skip.
        if (entry->loading || entry->piece.use_count() > 1) {
            continue;
        }
        total -= entry_bytes(entry->piece, entry->charged);
        ++m_stats.evictions;
        m_entries.erase(e);
        it = m_lru.erase(it);
    }
    m_stats.peak_bytes = std::max(m_stats.peak_bytes, total);
}

void GeometryCache::prefetch(const std::shared_ptr<const Store>& store,
                             const std::vector<std::uint32_t>& pieces, std::uint64_t stream) {
    {
        std::lock_guard lock(m_mutex);
        std::erase_if(m_hints, [&](const Hint& h) { return h.stream == stream; });
        for (auto p : pieces) {
            if (m_entries.find(Key{store.get(), p}) == m_entries.end()) {
                m_hints.push_back({store, p, stream});
            }
        }
    }
    m_hint_cv.notify_all();
}

void GeometryCache::prefetch_loop() {
    for (;;) {
        Hint h;
        {
            std::unique_lock lock(m_mutex);
            m_hint_cv.wait(lock, [&] { return m_stop || !m_hints.empty(); });
            if (m_stop) {
                return;
            }
            h = std::move(m_hints.front());
            m_hints.pop_front();
            if (m_entries.count(Key{h.store.get(), h.piece}) != 0) {
                continue;
            }
        }
        (void)load(h.store, h.piece, true);  // a failure resurfaces at get()
    }
}

bool GeometryCache::resident(const Store& store, std::uint32_t piece) const {
    std::lock_guard lock(m_mutex);
    auto it = m_entries.find(Key{&store, piece});
    return it != m_entries.end() && !it->second->loading;
}

CacheStats GeometryCache::stats() const {
    std::lock_guard lock(m_mutex);
    CacheStats s = m_stats;
    std::int64_t total = resident_locked();
    s.resident_bytes = total;
    s.charged_bytes = live_charges_locked();
    s.peak_bytes = std::max(s.peak_bytes, total);
    return s;
}

CacheStats counters_since(const CacheStats& before, const CacheStats& after) {
    CacheStats d = after;
    d.hits -= before.hits;
    d.misses -= before.misses;
    d.waits -= before.waits;
    d.loads -= before.loads;
    d.prefetch_loads -= before.prefetch_loads;
    d.prefetch_nodes_built -= before.prefetch_nodes_built;
    d.triangles_loaded -= before.triangles_loaded;
    d.bytes_loaded -= before.bytes_loaded;
    d.evictions -= before.evictions;
    d.blocked_seconds -= before.blocked_seconds;
    return d;
}

void GeometryCache::clear() {
    std::lock_guard lock(m_mutex);
    m_hints.clear();
    for (auto it = m_lru.begin(); it != m_lru.end();) {
        auto e = m_entries.find(*it);
        if (e->second->loading || e->second->piece.use_count() > 1) {
            ++it;
            continue;
        }
        m_entries.erase(e);
        it = m_lru.erase(it);
    }
}

}  // namespace proxima::massive
