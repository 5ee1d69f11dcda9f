#include "proxima/massive/avatar.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <mutex>
#include <numeric>
#include <unordered_set>

#include "proxima/distance/bounds.hpp"
#include "proxima/massive/verify.hpp"
#include "proxima/scene.hpp"

namespace proxima::massive {

// ---------------------------------------------------------------------------------------------
// PieceIndex

PieceIndex::PieceIndex(const std::vector<PieceInfo>& pieces) {
    std::vector<double> lo(pieces.size());
    std::vector<double> hi(pieces.size());
    m_boxes.reserve(pieces.size());
    for (std::size_t i = 0; i < pieces.size(); ++i) {
        m_boxes.push_back(pieces[i].box);
        lo[i] = pieces[i].box.lo.x;
        hi[i] = pieces[i].box.hi.x;
    }
    m_intervals.build(lo, hi);
}

void PieceIndex::within(const Aabb& box, double radius, double slack,
                        std::vector<std::uint32_t>& out) const {
    // A piece can only be near if its lo.x lies in [box.lo.x - r - max extent, box.hi.x + r]
    // (the extent widened by 1e-12).
    m_intervals.within(
        box, SortedIntervals::widened(radius, slack), 1e-12,
        [&](std::uint32_t p) -> const Aabb& { return m_boxes[p]; },
        [&](std::uint32_t p, double /*d*/) { out.push_back(p); });
}

// ---------------------------------------------------------------------------------------------
// ModelView

ModelView::ModelView(std::shared_ptr<const Store> store, std::shared_ptr<GeometryCache> cache)
    : m_store(std::move(store)), m_cache(std::move(cache)), m_index(m_store->pieces()) {
    m_slack = model_slack(*m_store);
    auto s = std::make_shared<Snapshot>();
    s->masked.assign(m_store->objects().size(), 0);
    m_snapshot = std::move(s);
}

std::shared_ptr<const ModelView::Snapshot> ModelView::snapshot() const {
    std::shared_lock lock(m_mutex);
    return m_snapshot;
}

std::uint64_t ModelView::version() const {
    return snapshot()->version;
}

std::uint32_t ModelView::object_count() const {
    auto s = snapshot();
    std::uint32_t n = static_cast<std::uint32_t>(m_store->objects().size());
    for (const auto& o : s->overlay) {
        n = std::max(n, o.object + 1);
    }
    return n;
}

namespace {

// Whether `object` is absent from snapshot `s`: a store object masked with no overlay copy, or an
// id that no overlay object has.
bool deleted_in(const ModelView::Snapshot& s, std::uint32_t object) {
    const bool in_overlay = std::any_of(s.overlay.begin(), s.overlay.end(),
                                        [&](const auto& o) { return o.object == object; });
    if (object < s.masked.size()) {
        return s.masked[object] != 0 && !in_overlay;
    }
    return !in_overlay;
}

}  // namespace

bool ModelView::deleted(std::uint32_t object) const {
    return deleted_in(*snapshot(), object);
}

StatusOr<std::string> ModelView::object_name(std::uint32_t object) const {
    return object_name(*snapshot(), object);
}

StatusOr<std::string> ModelView::object_name(const Snapshot& at, std::uint32_t object) const {
    for (const auto& o : at.overlay) {
        if (o.object == object) {
            return o.name;
        }
    }
    if (object < m_store->objects().size()) {
        return m_store->objects()[object].name;
    }
    return not_found("no object " + std::to_string(object) + " in the model");
}

namespace {

// An overlay piece and its charge to the cache's budget, which so lasts exactly as long as the
// piece (whoever holds it); the piece itself holds the count of its hierarchy's bytes.
struct OverlayHolder {
    OverlayHolder(std::shared_ptr<std::atomic<std::int64_t>> bytes, GeometryCache::Charge c,
                  std::uint32_t object, PieceGeometry g)
        : charge(std::move(c)), piece(UINT32_MAX, object, std::move(g), std::move(bytes)) {}
    GeometryCache::Charge charge;
    ResidentPiece piece;
};

// A moved or added object in memory, charged to the cache (RESOURCE_EXHAUSTED when the edited
// objects would exceed its budget; `replaces`: the overlay object this one takes the place of).
StatusOr<ModelView::OverlayObject> overlay_object(GeometryCache& cache, std::uint32_t object,
                                                  std::string name, TriangleMesh mesh,
                                                  const ModelView::OverlayObject* replaces) {
    PieceGeometry g;
    g.vertices = std::move(mesh.vertices);
    g.triangles = std::move(mesh.triangles);  // the whole object: source_triangles stays empty
    const auto fixed = static_cast<std::int64_t>(g.vertices.size() * sizeof(Vec3) +
                                                 g.triangles.size() * sizeof(TriangleIndices) +
                                                 sizeof(OverlayHolder));
    auto bytes = std::make_shared<std::atomic<std::int64_t>>(0);
    auto charge = cache.charge(fixed, bytes, replaces != nullptr ? replaces->charge : nullptr);
    if (!charge.ok()) {
        return charge.status();
    }
    const Aabb box = compute_box(g.vertices);
    auto holder = std::make_shared<OverlayHolder>(bytes, *charge, object, std::move(g));
    return ModelView::OverlayObject{object, std::move(name), box,
                                    std::shared_ptr<ResidentPiece>(holder, &holder->piece),
                                    std::move(charge).value()};
}

// The overlay object of `object` in `snap`, if any.
const ModelView::OverlayObject* find_overlay(const ModelView::Snapshot& snap,
                                             std::uint32_t object) {
    for (const auto& o : snap.overlay) {
        if (o.object == object) {
            return &o;
        }
    }
    return nullptr;
}

}  // namespace

Status ModelView::move_object(std::uint32_t object, const Affine& transform) {
    auto prepared = prepare_move(object, transform);
    if (!prepared.ok()) {
        return prepared.status();
    }
    return commit_move(std::move(prepared).value());
}

StatusOr<ModelView::PreparedMove> ModelView::prepare_move(std::uint32_t object,
                                                          const Affine& transform) const {
    if (!transform.finite()) {
        return invalid_argument("move: the transform has a non-finite entry");
    }
    if (deleted(object)) {
        return not_found("move: no object " + std::to_string(object) + " in the model");
    }
    if (object >= m_store->objects().size()) {
        return failed_precondition("move: object " + std::to_string(object) +
                                   " was added in this session; delete and add it again");
    }
    PreparedMove move;
    move.object = object;
    if (transform.m == Affine{}.m) {
        // Back to the stored placement: the object reads from its stored pieces again, through
        // the cache. The same geometry bit for bit: the identity map gives each stored coordinate
        // back exactly.
        move.back = true;
        return move;
    }
    // The stored coordinates under the new map.
    auto m = read_object(*m_store, object);
    if (!m.ok()) {
        return m.status();
    }
    move.mesh = std::move(m).value();
    move.name = m_store->objects()[object].name;
    for (auto& v : move.mesh.vertices) {
        v = transform.apply(v);
    }
    if (Status s = validate_mesh(move.mesh, "moved object '" + move.name + "'"); !s.ok()) {
        return s;
    }
    return move;
}

Status ModelView::commit_move(PreparedMove move) {
    std::lock_guard commit(m_commit_mutex);
    const auto current = snapshot();
    const std::uint32_t object = move.object;
    if (deleted_in(*current, object)) {  // by an edit committed since the move was prepared
        return not_found("move: no object " + std::to_string(object) + " in the model");
    }
    auto next = std::make_shared<Snapshot>(*current);
    std::erase_if(next->overlay, [&](const auto& x) { return x.object == object; });
    if (move.back) {
        // The in-memory copy (charged to the cache's budget) goes with the snapshots that hold it.
        next->masked[object] = 0;
    } else {
        auto o = overlay_object(*m_cache, object, std::move(move.name), std::move(move.mesh),
                                find_overlay(*current, object));
        if (!o.ok()) {
            return o.status();
        }
        next->overlay.push_back(std::move(o).value());
        next->masked[object] = 1;
    }
    ++next->version;
    std::unique_lock lock(m_mutex);
    m_snapshot = std::move(next);
    return {};
}

StatusOr<std::uint32_t> ModelView::add_object(ModelObject object) {
    if (Status s = validate_mesh(object.mesh, "added object '" + object.name + "'"); !s.ok()) {
        return s;
    }
    std::lock_guard commit(m_commit_mutex);
    const auto current = snapshot();
    std::uint32_t id =
        std::max(static_cast<std::uint32_t>(m_store->objects().size()), m_next_added);
    for (const auto& o : current->overlay) {
        id = std::max(id, o.object + 1);
    }
    // A refused add (over the budget) leaves the id unused, as if it had never been asked.
    auto o = overlay_object(*m_cache, id, object.name, std::move(object.mesh), nullptr);
    if (!o.ok()) {
        return o.status();
    }
    auto next = std::make_shared<Snapshot>(*current);
    next->overlay.push_back(std::move(o).value());
    ++next->version;
    m_next_added = id + 1;
    std::unique_lock lock(m_mutex);
    m_snapshot = std::move(next);
    return id;
}

Status ModelView::delete_object(std::uint32_t object) {
    std::lock_guard commit(m_commit_mutex);
    const auto current = snapshot();
    if (deleted_in(*current, object)) {
        return not_found("delete: no object " + std::to_string(object) + " in the model");
    }
    auto next = std::make_shared<Snapshot>(*current);
    std::erase_if(next->overlay, [&](const auto& x) { return x.object == object; });
    if (object < next->masked.size()) {
        next->masked[object] = 1;
    }
    ++next->version;
    std::unique_lock lock(m_mutex);
    m_snapshot = std::move(next);
    return {};
}

// ---------------------------------------------------------------------------------------------
// AvatarTracker

StatusOr<std::unique_ptr<AvatarTracker>> AvatarTracker::create(std::shared_ptr<ModelView> view,
                                                               TriangleMesh avatar,
                                                               std::uint64_t id) {
    if (Status s = validate_mesh(avatar, "avatar"); !s.ok()) {
        return s;
    }
    std::unique_ptr<AvatarTracker> t(new AvatarTracker());
    t->m_view = std::move(view);
    t->m_mesh = std::move(avatar);
    // Single-triangle leaves (LazyBvh's constructor says why): an avatar has few triangles.
    t->m_tree = std::make_unique<LazyBvh>(t->m_mesh.vertices, t->m_mesh.triangles, nullptr,
                                          std::span<const std::uint32_t>{}, 1);
    t->m_id = id;
    return t;
}

namespace {

// Per-object best under the tolerance ordering (distance, object triangle, avatar triangle) or
// the nearest ordering (distance, object, avatar triangle, object triangle: the engine's
// separation order for the avatar's closest object).
bool tolerance_better(const PairHit& h, const AvatarHit& best) {
    if (h.squared_distance != best.distance) {
        return h.squared_distance < best.distance;
    }
    return std::tie(h.triangle_a, h.triangle_b) <
           std::tie(best.object_triangle, best.avatar_triangle);
}

AvatarHit to_hit(std::uint32_t object, const PairHit& h) {
    return {object, h.squared_distance, h.triangle_a, h.triangle_b, h.point_a, h.point_b};
}

}  // namespace

// One query's shared state and its steps: 1. the objects within the tolerance, 2. the nearest
// object, 3. prefetch along the velocity.
struct AvatarTracker::Query {
    AvatarTracker& tracker;
    const AvatarQueryOptions& options;
    const CancelToken* cancel;
    const Aabb& box;
    TreeRef avatar;
    std::shared_ptr<const ModelView::Snapshot> snap;
    const std::shared_ptr<const Store>& store;
    GeometryCache& cache;
    const std::vector<PieceInfo>& pieces;
    double slack = 0.0;
    double tol_sq = 0.0;
    AvatarResult result;

    // The nearest search's state.
    bool have = false;
    double best_sq = std::numeric_limits<double>::infinity();
    AvatarHit nearest;
    Seed next_seed;
    double seed_sq = std::numeric_limits<double>::infinity();
    double max_sq = 0.0;
    std::uint32_t current_piece = 0;

    Query(AvatarTracker& t, const Affine& pose, const AvatarQueryOptions& o, const CancelToken* c,
          const Aabb& b, std::shared_ptr<const ModelView::Snapshot> at)
        : tracker(t),
          options(o),
          cancel(c),
          box(b),
          avatar{t.m_tree.get(), nullptr, &pose, t.m_posed.data()},
          snap(at != nullptr ? std::move(at) : t.m_view->snapshot()),
          store(t.m_view->store()),
          cache(*t.m_view->cache()),
          pieces(store->pieces()),
          slack(std::max(t.m_view->slack(), rounding_slack(coordinate_scale(b)))),
          tol_sq(o.tolerance * o.tolerance) {}

    bool stopped() const { return cancel != nullptr && cancel->should_stop(); }

    // Tests one candidate (a stored piece, or an overlay object when `overlay` is given).
    StatusOr<PairHit> test(std::uint32_t piece, const ResidentPiece* overlay, double bound_sq,
                           bool ties_avatar_first, std::uint32_t& object) {
        PieceHandle handle;
        const ResidentPiece* p = overlay;
        if (p == nullptr) {
            auto h = cache.get(store, piece);
            if (!h.ok()) {
                return h.status();
            }
            handle = *h;
            p = handle.get();
        }
        object = p->object;
        ++result.pieces_tested;
        auto& rp = const_cast<ResidentPiece&>(*p);
        PairHit hit = closest_pair({&rp.bvh, rp.geometry.source_map()}, avatar, bound_sq, slack,
                                   ties_avatar_first);
        result.exact_tests += hit.exact_tests;
        return hit;
    }

    // 1. Objects within the tolerance (collisions: distance 0).
    Status within_tolerance() {
        std::vector<std::uint32_t> cands;
        tracker.m_view->index().within(box, options.tolerance, slack, cands);
        result.candidate_pieces = cands.size();
        std::vector<AvatarHit> best;  // per object, squared distance in `distance` until the end
        auto merge = [&](std::uint32_t object, const PairHit& h) {
            auto it = std::find_if(best.begin(), best.end(),
                                   [&](const AvatarHit& b) { return b.object == object; });
            if (it == best.end()) {
                best.push_back(to_hit(object, h));
            } else if (tolerance_better(h, *it)) {
                *it = to_hit(object, h);
            }
        };
        for (auto p : cands) {
            if (snap->masked[pieces[p].object] != 0) {
                continue;
            }
            if (stopped()) {
                return stop_status(*cancel, "avatar query");
            }
            std::uint32_t object = 0;
            auto hit = test(p, nullptr, tol_sq, false, object);
            if (!hit.ok()) {
                return hit.status();
            }
            if (hit->found) {
                merge(object, *hit);
            }
        }
        for (const auto& o : snap->overlay) {
            if (box_squared_distance(o.box, box) > cull_threshold_sq(tol_sq, slack)) {
                continue;
            }
            std::uint32_t object = 0;
            auto hit = test(0, o.piece.get(), tol_sq, false, object);
            if (!hit.ok()) {
                return hit.status();
            }
            if (hit->found) {
                merge(object, *hit);
            }
        }
        std::sort(best.begin(), best.end(),
                  [](const AvatarHit& a, const AvatarHit& b) { return a.object < b.object; });
        for (auto& h : best) {
            h.distance = std::sqrt(h.distance);
            if (h.distance == 0.0) {
                result.collisions.push_back(h);
            }
        }
        result.within = std::move(best);
        return {};
    }

    // The first search radius: the previous pose's distance plus how far the box moved (temporal
    // coherence), at least the tolerance results' distances.
    double start_radius() const {
        double radius = std::min(options.tolerance, options.nearest_max_distance);
        if (tracker.m_has_previous) {
            const Vec3 dlo = box.lo - tracker.m_previous_box.lo;
            const Vec3 dhi = box.hi - tracker.m_previous_box.hi;
            const double moved = std::sqrt(std::max(squared_norm(dlo), squared_norm(dhi)));
            radius = std::max(radius, tracker.m_previous_nearest + moved);
        }
        for (const auto& h : result.within) {
            radius = std::max(radius, h.distance);
        }
        return std::min(std::max(radius, 1e-3 * norm(box.extent())), options.nearest_max_distance);
    }

    // The previous closest pair at this pose: an upper bound (never a result by itself: the
    // search finds it again, or something closer or tied-and-smaller). Sets seed_sq and widens
    // `radius` to it.
    void seed_bound(double& radius) {
        const Seed& seed = tracker.m_seed;
        if (!seed.valid) {
            return;
        }
        PieceHandle handle;
        const ResidentPiece* p = nullptr;
        if (seed.piece != UINT32_MAX) {
            if (snap->masked[pieces[seed.piece].object] == 0) {
                auto h = cache.get(store, seed.piece);
                if (h.ok()) {
                    handle = *h;
                    p = handle.get();
                }
            }
        } else {
            for (const auto& o : snap->overlay) {
                if (o.object == seed.object) {
                    p = o.piece.get();
                }
            }
        }
        if (p != nullptr && seed.local < p->geometry.triangles.size()) {
            const auto& t = tracker.m_mesh.triangles[seed.avatar];
            const auto& posed = tracker.m_posed;
            const Triangle y{posed[t[0]], posed[t[1]], posed[t[2]]};
            seed_sq = triangle_triangle(p->bvh.corners(seed.local), y).squared_distance;
            radius = std::min(std::max(radius, std::sqrt(seed_sq)), options.nearest_max_distance);
        }
    }

    double bound_now() const {
        const double b = have ? best_sq : seed_sq;
        return std::min(std::isfinite(b) ? std::nextafter(b, INFINITY) : b, max_sq);
    }

    void consider(std::uint32_t object, const PairHit& h) {
        if (!h.found) {
            return;
        }
        bool better = !have || h.squared_distance < best_sq;
        if (have && h.squared_distance == best_sq) {
            better = std::tie(object, h.triangle_b, h.triangle_a) <
                     std::tie(nearest.object, nearest.avatar_triangle, nearest.object_triangle);
        }
        if (better) {
            have = true;
            best_sq = h.squared_distance;
            nearest = to_hit(object, h);
            next_seed = {true, current_piece, object, h.local_a, h.local_b};
        }
    }

    // The untested pieces within `radius`, nearest box first, until one is farther than the best.
    Status search_within(double radius, std::unordered_set<std::uint32_t>& tested) {
        std::vector<std::uint32_t> near;
        tracker.m_view->index().within(box, radius, slack, near);
        std::vector<std::pair<double, std::uint32_t>> order;
        for (auto p : near) {
            if (tested.insert(p).second && snap->masked[pieces[p].object] == 0) {
                order.emplace_back(box_squared_distance(pieces[p].box, box), p);
            }
        }
        std::sort(order.begin(), order.end());
        for (const auto& [box_sq, p] : order) {
            if (box_sq > cull_threshold_sq(have ? best_sq : seed_sq, slack)) {
                break;
            }
            if (stopped()) {
                return stop_status(*cancel, "avatar query");
            }
            std::uint32_t object = 0;
            auto hit = test(p, nullptr, bound_now(), true, object);
            if (!hit.ok()) {
                return hit.status();
            }
            current_piece = p;
            consider(object, *hit);
        }
        return {};
    }

    // 2. The nearest object: the overlay objects, then candidates in growing radii around the
    // avatar's box.
    Status nearest_object() {
        if (!result.collisions.empty()) {
            return nearest_among_collisions();
        }
        double radius = start_radius();
        std::unordered_set<std::uint32_t> tested;
        seed_bound(radius);
        const double max_d = options.nearest_max_distance;
        max_sq = max_d * max_d;
        for (const auto& o : snap->overlay) {
            std::uint32_t object = 0;
            auto hit = test(0, o.piece.get(), bound_now(), true, object);
            if (!hit.ok()) {
                return hit.status();
            }
            current_piece = UINT32_MAX;
            consider(object, *hit);
        }
        for (int round = 0;; ++round) {
            if (Status s = search_within(radius, tested); !s.ok()) {
                return s;
            }
            // Done when the best lies within the searched radius (every piece outside it is
            // farther), or when every piece has been searched.
            if ((have && best_sq <= radius * radius) || tested.size() >= pieces.size() ||
                radius >= max_d) {
                break;
            }
            radius =
                std::min(max_d, std::max(radius * 4.0, 1e-9 + (have ? std::sqrt(best_sq) : 0.0)));
        }
        if (have) {
            finish_nearest();
        }
        tracker.m_seed = next_seed;
        return {};
    }

    // The best pair found becomes the answer's nearest, and the next pose's starting radius.
    void finish_nearest() {
        nearest.distance = std::sqrt(best_sq);
        result.nearest = nearest;
        tracker.m_previous_nearest = nearest.distance;
    }

    // 2'. The avatar touches something: the nearest object is at distance 0, and among the
    // objects at distance 0 (result.collisions holds every one of them: within_tolerance tested
    // every object within the tolerance) the smallest index comes first in the nearest order
    // (distance, object, avatar triangle, object triangle). So only that object's pieces are
    // searched, at bound 0, for its first touching pair in that order: the same answer as the
    // search over every candidate, without re-traversing the other touching objects.
    Status nearest_among_collisions() {
        const std::uint32_t first = result.collisions.front().object;  // sorted by object
        for (const auto& o : snap->overlay) {
            if (o.object != first) {
                continue;
            }
            std::uint32_t object = 0;
            auto hit = test(0, o.piece.get(), 0.0, true, object);
            if (!hit.ok()) {
                return hit.status();
            }
            current_piece = UINT32_MAX;
            consider(object, *hit);
        }
        // `consider` keeps the first pair in the nearest order whatever order the pieces come
        // in. A masked (moved or deleted) store object has only its overlay copy, tested above,
        // and an added object has no store piece at all.
        std::vector<std::uint32_t> near;
        if (first < snap->masked.size() && snap->masked[first] == 0) {
            tracker.m_view->index().within(box, 0.0, slack, near);
        }
        for (auto p : near) {
            if (pieces[p].object != first) {
                continue;
            }
            if (stopped()) {
                return stop_status(*cancel, "avatar query");
            }
            std::uint32_t object = 0;
            auto hit = test(p, nullptr, 0.0, true, object);
            if (!hit.ok()) {
                return hit.status();
            }
            current_piece = p;
            consider(object, *hit);
        }
        if (!have || best_sq != 0.0) {
            return Status(StatusCode::internal,
                          "avatar query: object " + std::to_string(first) +
                              " touches the avatar, yet no touching pair was found again");
        }
        finish_nearest();
        tracker.m_seed = next_seed;
        return {};
    }

    // 3. Prefetch along the velocity: the box swept over the next poses.
    void prefetch() {
        const Vec3 velocity = box.center() - tracker.m_previous_box.center();
        Aabb ahead = box;
        ahead.extend(Aabb{box.lo + velocity * options.prefetch_poses,
                          box.hi + velocity * options.prefetch_poses});
        std::vector<std::uint32_t> near;
        // Grown by the nearest distance too: the next poses' nearest search reads that far.
        // And by half the avatar's size, so a turn or a speed-up does not outrun it.
        const double reach =
            std::max({options.tolerance, result.nearest ? result.nearest->distance : 0.0,
                      0.5 * norm(box.extent())});
        tracker.m_view->index().within(ahead, reach, slack, near);
        std::vector<std::uint32_t> hints;
        for (auto p : near) {
            if (snap->masked[pieces[p].object] == 0 && !cache.resident(*store, p)) {
                hints.push_back(p);
            }
        }
        result.prefetch_hints = hints.size();
        cache.prefetch(store, hints, tracker.m_id + 1);
    }
};

StatusOr<AvatarResult> AvatarTracker::query(const Affine& pose, const AvatarQueryOptions& options,
                                            const CancelToken* cancel,
                                            std::shared_ptr<const ModelView::Snapshot> at) {
    if (!pose.finite()) {
        return invalid_argument("avatar pose has a non-finite entry");
    }
    if (!std::isfinite(options.tolerance) || options.tolerance < 0.0) {
        return invalid_argument("tolerance must be a finite distance >= 0");
    }
    if (std::isnan(options.nearest_max_distance) || options.nearest_max_distance < 0.0) {
        return invalid_argument("nearest_max_distance must be >= 0 (or infinite)");
    }
    const auto t0 = std::chrono::steady_clock::now();
    m_posed.resize(m_mesh.vertices.size());
    for (std::size_t v = 0; v < m_posed.size(); ++v) {
        m_posed[v] = pose.apply(m_mesh.vertices[v]);
    }
    const Aabb box = compute_box(m_posed);
    Query q(*this, pose, options, cancel, box, std::move(at));
    if (Status s = q.within_tolerance(); !s.ok()) {
        return s;
    }
    if (options.nearest && (!q.pieces.empty() || !q.snap->overlay.empty())) {
        if (Status s = q.nearest_object(); !s.ok()) {
            return s;
        }
    }
    if (m_has_previous && options.prefetch_poses > 0.0) {
        q.prefetch();
    }
    m_has_previous = true;
    m_previous_box = box;
    q.result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return std::move(q.result);
}

}  // namespace proxima::massive
