#include "proxima/massive/cache.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <tuple>

#include "proxima/distance/bounds.hpp"

namespace proxima::massive {

// ---------------------------------------------------------------------------------------------
// LazyBvh

LazyBvh::LazyBvh(std::span<const Vec3> vertices, std::span<const TriangleIndices> triangles,
                 std::atomic<std::int64_t>* bytes, std::span<const std::uint32_t> source)
    : m_vertices(vertices),
      m_triangles(triangles),
      m_source(source),
      m_order(triangles.size()),
      m_bytes(bytes) {
    for (std::uint32_t t = 0; t < m_order.size(); ++t) {
        m_order[t] = t;
    }
    // A binary tree with leaves of >= 1 triangle has < 2n nodes: the block table is sized once, so
    // readers never see it reallocate.
    const std::size_t max_nodes = std::max<std::size_t>(1, 2 * triangles.size());
    m_blocks.resize((max_nodes + BLOCK - 1) / BLOCK + 1);
    const std::uint32_t r = allocate_two();  // nodes 0 (root) and 1 (spare, keeps pairs aligned)
    Node& root = mutable_node(r);
    root.first = 0;
    root.count = static_cast<std::uint32_t>(triangles.size());
    set_box(root);
    if (m_bytes != nullptr) {
        m_bytes->fetch_add(static_cast<std::int64_t>(m_order.size() * sizeof(std::uint32_t)),
                           std::memory_order_relaxed);
    }
}

void LazyBvh::expand_above(std::uint32_t count) {
    std::vector<const Node*> stack{&root()};
    while (!stack.empty()) {
        const Node* n = stack.back();
        stack.pop_back();
        if (n->leaf() || n->count <= count) {
            continue;
        }
        auto [l, r] = children(*n);
        stack.push_back(l);
        stack.push_back(r);
    }
}

std::uint64_t LazyBvh::memory_bytes() const {
    std::uint64_t blocks = 0;
    for (const auto& b : m_blocks) {
        blocks += b ? BLOCK * sizeof(Node) : 0;
    }
    return blocks + m_order.size() * sizeof(std::uint32_t) +
           m_blocks.size() * sizeof(std::unique_ptr<Node[]>);
}

std::uint32_t LazyBvh::allocate_two() {
    const std::uint32_t i = m_count.load(std::memory_order_relaxed);
    for (std::uint32_t k = i; k < i + 2; ++k) {
        auto& block = m_blocks[k / BLOCK];
        if (!block) {
            block = std::make_unique<Node[]>(BLOCK);
            if (m_bytes != nullptr) {
                m_bytes->fetch_add(static_cast<std::int64_t>(BLOCK * sizeof(Node)),
                                   std::memory_order_relaxed);
            }
        }
    }
    m_count.store(i + 2, std::memory_order_relaxed);
    return i;
}

void LazyBvh::set_box(Node& n) {
    Aabb box;
    std::uint32_t min_source = UINT32_MAX;
    for (std::uint32_t s = n.first; s < n.first + n.count; ++s) {
        const std::uint32_t t = m_order[s];
        min_source = std::min(min_source, m_source.empty() ? t : m_source[t]);
        const auto& tri = m_triangles[t];
        box.extend(m_vertices[tri[0]]);
        box.extend(m_vertices[tri[1]]);
        box.extend(m_vertices[tri[2]]);
    }
    n.box = box;
    n.min_source = min_source;
}

std::pair<const LazyBvh::Node*, const LazyBvh::Node*> LazyBvh::children(const Node& n) {
    std::uint32_t left = n.left.load(std::memory_order_acquire);
    if (left == NONE) {
        std::lock_guard lock(m_mutex);
        left = n.left.load(std::memory_order_relaxed);
        if (left == NONE) {
            // Split at the median of triangle centres along the longest axis of the centres'
            // box (ties by triangle index: deterministic whatever thread expands first).
            Aabb centres;
            auto centre = [&](std::uint32_t t) {
                const auto& tri = m_triangles[t];
                return (m_vertices[tri[0]] + m_vertices[tri[1]] + m_vertices[tri[2]]) / 3.0;
            };
            for (std::uint32_t s = n.first; s < n.first + n.count; ++s) {
                centres.extend(centre(m_order[s]));
            }
            const Vec3 e = centres.extent();
            const int axis = (e.x >= e.y && e.x >= e.z) ? 0 : (e.y >= e.z ? 1 : 2);
            const std::uint32_t half = n.count / 2;
            auto begin = m_order.begin() + n.first;
            std::nth_element(begin, begin + half, begin + n.count,
                             [&](std::uint32_t a, std::uint32_t b) {
                                 const double ca = centre(a)[axis];
                                 const double cb = centre(b)[axis];
                                 return ca < cb || (ca == cb && a < b);
                             });
            left = allocate_two();
            Node& l = mutable_node(left);
            Node& r = mutable_node(left + 1);
            l.first = n.first;
            l.count = half;
            r.first = n.first + half;
            r.count = n.count - half;
            set_box(l);
            set_box(r);
            const_cast<Node&>(n).left.store(left, std::memory_order_release);
        }
    }
    return {&node(left), &node(left + 1)};
}

ResidentPiece::ResidentPiece(std::uint32_t piece_index, std::uint32_t object_index, PieceGeometry g,
                             std::atomic<std::int64_t>* bytes)
    : piece(piece_index),
      object(object_index),
      geometry(std::move(g)),
      bvh(geometry.vertices, geometry.triangles, bytes, geometry.source_triangles) {}

std::uint64_t ResidentPiece::geometry_bytes() const {
    return geometry.vertices.size() * sizeof(Vec3) +
           geometry.triangles.size() * sizeof(TriangleIndices) +
           geometry.source_triangles.size() * sizeof(std::uint32_t) + sizeof(ResidentPiece);
}

// ---------------------------------------------------------------------------------------------
// closest_pair: dual traversal, nearer child pairs first, tied pairs never pruned.

namespace {

// The box of a node of `t`: its own, or under the avatar's pose the box of its mapped box
// (centre mapped, half-extent through |A|), grown by a few ulps of the result so rounding never
// makes it smaller than the posed triangles it holds.
Aabb node_box(const TreeRef& t, const LazyBvh::Node& n) {
    if (t.pose == nullptr) {
        return n.box;
    }
    const auto& m = t.pose->m;
    const Vec3 c = t.pose->apply(n.box.center());
    const Vec3 h = 0.5 * n.box.extent();
    Vec3 e{std::abs(m[0]) * h.x + std::abs(m[1]) * h.y + std::abs(m[2]) * h.z,
           std::abs(m[4]) * h.x + std::abs(m[5]) * h.y + std::abs(m[6]) * h.z,
           std::abs(m[8]) * h.x + std::abs(m[9]) * h.y + std::abs(m[10]) * h.z};
    const double scale = std::max({std::abs(c.x), std::abs(c.y), std::abs(c.z), e.x, e.y, e.z});
    const double grow = 1e-14 * scale;
    e = e + Vec3{grow, grow, grow};
    return {c - e, c + e};
}

Triangle tree_corners(const TreeRef& t, std::uint32_t tri) {
    if (t.posed == nullptr) {
        return t.bvh->corners(tri);
    }
    const auto& idx = t.bvh->indices(tri);
    return {t.posed[idx[0]], t.posed[idx[1]], t.posed[idx[2]]};
}

struct PairSearch {
    TreeRef a;
    TreeRef b;
    double bound_sq;  // accept pairs with squared distance <= this
    double slack;
    bool ties_b_first;
    PairHit hit;

    std::uint32_t source(const TreeRef& t, std::uint32_t tri) const {
        return t.source != nullptr ? (*t.source)[tri] : tri;
    }
    double threshold() const {
        const double best = hit.found ? std::min(hit.squared_distance, bound_sq) : bound_sq;
        return cull_threshold_sq(best, slack);
    }
    void leaves(const LazyBvh::Node& na, const LazyBvh::Node& nb) {
        for (std::uint32_t i = na.first; i < na.first + na.count; ++i) {
            const std::uint32_t ta = a.bvh->triangle(i);
            const Triangle x = tree_corners(a, ta);
            for (std::uint32_t j = nb.first; j < nb.first + nb.count; ++j) {
                const std::uint32_t tb = b.bvh->triangle(j);
                const Triangle y = tree_corners(b, tb);
                // The triangles' boxes first (a lower bound up to rounding, which the widened
                // threshold covers): a pair beyond it can be neither closer nor tied.
                const double t = threshold();
                if (std::isfinite(t)) {
                    if (box_squared_distance(triangle_box(x[0], x[1], x[2]),
                                             triangle_box(y[0], y[1], y[2])) > t) {
                        continue;
                    }
                    // Then the separating-plane and centroid-axis bounds (each accounts for its
                    // own rounding): tight where boxes are loose, small triangles facing each
                    // other from afar.
                    const double lb = triangle_lower_bound(x, y, slack);
                    if (lb * lb > t) {
                        continue;
                    }
                }
                ++hit.exact_tests;
                const auto cp = triangle_triangle(x, y);
                if (cp.squared_distance > bound_sq) {
                    continue;
                }
                const std::uint32_t sa = source(a, ta);
                const std::uint32_t sb = source(b, tb);
                bool better = !hit.found || cp.squared_distance < hit.squared_distance;
                if (hit.found && cp.squared_distance == hit.squared_distance) {
                    better = ties_b_first
                                 ? std::tie(sb, sa) < std::tie(hit.triangle_b, hit.triangle_a)
                                 : std::tie(sa, sb) < std::tie(hit.triangle_a, hit.triangle_b);
                }
                if (better) {
                    hit.found = true;
                    hit.squared_distance = cp.squared_distance;
                    hit.triangle_a = sa;
                    hit.triangle_b = sb;
                    hit.local_a = ta;
                    hit.local_b = tb;
                    hit.point_a = cp.point_a;
                    hit.point_b = cp.point_b;
                }
            }
        }
    }
    // With a best distance of 0 nothing is strictly closer: only a tied pair of smaller indices
    // (in the tie order) could still win, and a subtree pair whose smallest indices are not
    // smaller cannot hold one.
    bool cannot_beat_tie(const LazyBvh::Node& na, const LazyBvh::Node& nb) const {
        if (!hit.found || hit.squared_distance != 0.0) {
            return false;
        }
        const auto [first, second, best_first, best_second] =
            ties_b_first ? std::tuple{nb.min_source, na.min_source, hit.triangle_b, hit.triangle_a}
                         : std::tuple{na.min_source, nb.min_source, hit.triangle_a, hit.triangle_b};
        return first > best_first || (first == best_first && second >= best_second);
    }
    void visit(const LazyBvh::Node& na, const Aabb& ba, const LazyBvh::Node& nb, const Aabb& bb) {
        if (box_squared_distance(ba, bb) > threshold() || cannot_beat_tie(na, nb)) {
            return;
        }
        const bool la = na.leaf();
        const bool lb = nb.leaf();
        if (la && lb) {
            leaves(na, nb);
            return;
        }
        // Descend the larger node (by triangle count), nearer child first.
        if (lb || (!la && na.count >= nb.count)) {
            auto [c0, c1] = a.bvh->children(na);
            Aabb b0 = node_box(a, *c0);
            Aabb b1 = node_box(a, *c1);
            if (box_squared_distance(b1, bb) < box_squared_distance(b0, bb)) {
                std::swap(c0, c1);
                std::swap(b0, b1);
            }
            visit(*c0, b0, nb, bb);
            visit(*c1, b1, nb, bb);
        } else {
            auto [c0, c1] = b.bvh->children(nb);
            Aabb b0 = node_box(b, *c0);
            Aabb b1 = node_box(b, *c1);
            if (box_squared_distance(ba, b1) < box_squared_distance(ba, b0)) {
                std::swap(c0, c1);
                std::swap(b0, b1);
            }
            visit(na, ba, *c0, b0);
            visit(na, ba, *c1, b1);
        }
    }
};

}  // namespace

PairHit closest_pair(TreeRef a, TreeRef b, double bound_sq, double slack, bool ties_b_first) {
    PairSearch s{a, b, bound_sq, slack, ties_b_first, {}};
    if (a.bvh->root().count > 0 && b.bvh->root().count > 0) {
        s.visit(a.bvh->root(), node_box(a, a.bvh->root()), b.bvh->root(),
                node_box(b, b.bvh->root()));
    }
    return s.hit;
}

// ---------------------------------------------------------------------------------------------
// GeometryCache

struct GeometryCache::Entry {
    PieceHandle piece;  // null while loading
    bool loading = false;
    Status error;  // of the last failed load (entry then removed)
    std::list<Key>::iterator lru;
    std::int64_t charged = 0;  // geometry bytes charged at load
    std::shared_ptr<std::atomic<std::int64_t>> tree_bytes;
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
std::int64_t entry_bytes(const std::shared_ptr<std::atomic<std::int64_t>>& tree,
                         std::int64_t charged) {
    return charged + (tree ? tree->load(std::memory_order_relaxed) : 0);
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
    std::shared_ptr<std::atomic<std::int64_t>> tree_bytes;
    PieceHandle resident;
    const auto& info = store->pieces()[piece];
    if (geometry.ok()) {
        tree_bytes = std::make_shared<std::atomic<std::int64_t>>(0);
        resident = std::make_shared<ResidentPiece>(piece, info.object, std::move(*geometry),
                                                   tree_bytes.get());
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
    entry->tree_bytes = std::move(tree_bytes);
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
        // levels; the last ones stay lazy), after publishing the piece: a query that needs it
        // meanwhile uses it at once (the tree is safe to expand from several threads).
        handle->bvh.expand_above(PREFETCH_EXPAND_ABOVE);
    }
    return handle;
}

std::int64_t GeometryCache::resident_locked() const {
    // Summed on demand: hierarchies grow without taking the cache lock.
    std::int64_t total = 0;
    for (const auto& [k, e] : m_entries) {
        total += entry_bytes(e->tree_bytes, e->charged);
    }
    return total;
}

void GeometryCache::evict_locked() {
    // Recompute the resident total (hierarchies grow without taking the cache lock).
    std::int64_t total = resident_locked();
    auto it = m_lru.end();
    while (total > static_cast<std::int64_t>(m_budget) && it != m_lru.begin()) {
        --it;
        auto e = m_entries.find(*it);
        auto& entry = e->second;
        // Pinned (a handle outside the cache) or loading: skip.
        if (entry->loading || entry->piece.use_count() > 1) {
            continue;
        }
        total -= entry_bytes(entry->tree_bytes, entry->charged);
        ++m_stats.evictions;
        m_entries.erase(e);
        it = m_lru.erase(it);
    }
    m_stats.peak_bytes = std::max(m_stats.peak_bytes, total);
}

void GeometryCache::prefetch(const std::shared_ptr<const Store>& store,
                             std::vector<std::uint32_t> pieces, std::uint64_t stream) {
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
