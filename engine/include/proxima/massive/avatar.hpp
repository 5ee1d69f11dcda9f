#pragma once
// Dynamic queries on a massive model (seed 001 §4.4, §4.5, §6.5): rigid avatars moving through a
// resident model, and objects of the model moved, added or deleted. Avatars and edited objects are
// the *floating nodes* of the dynamic overlap graph: each pose queries the sorted intervals of the
// static pieces' boxes (grown by the tolerance, or by the current distance bound for the nearest
// object), and only the pieces found there are loaded and tested, through the shared cache. After
// each pose the avatar's box is extended along its velocity and the pieces it will reach are
// prefetched.
//
// Answers equal the in-memory engine's on the same objects (query/query.hpp, the avatar added as
// the last object): the same objects, the same distances bit for bit.

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <vector>

#include "proxima/culling/sorted_intervals.hpp"
#include "proxima/massive/cache.hpp"
#include "proxima/massive/store.hpp"
#include "proxima/query/query.hpp"

namespace proxima::massive {

// Static pieces sorted by box.lo.x: the sorted intervals a floating node sweeps against.
class PieceIndex {
  public:
    explicit PieceIndex(const std::vector<PieceInfo>& pieces);
    // Pieces whose box may lie within `radius` of `box` (radius widened by `slack`), appended.
    void within(const Aabb& box, double radius, double slack,
                std::vector<std::uint32_t>& out) const;

  private:
    SortedIntervals m_intervals;  // pieces by lo.x
    std::vector<Aabb> m_boxes;    // by piece
};

// A model as the queries see it: the store's objects plus a shared overlay of edits (objects moved
// by an affine map of their stored coordinates, added, or deleted). Thread-safe; every query sees
// one consistent version. Object indices: the store's first, then added objects in order.
class ModelView {
  public:
    ModelView(std::shared_ptr<const Store> store, std::shared_ptr<GeometryCache> cache);

    const std::shared_ptr<const Store>& store() const { return m_store; }
    const std::shared_ptr<GeometryCache>& cache() const { return m_cache; }
    const PieceIndex& index() const { return m_index; }

    // Each edit is validated whole (unknown or deleted object, non-finite transform, invalid
    // mesh) and then applied; a failed edit changes nothing. A moved stored object is held in
    // memory (an overlay object) until it is deleted or moved back to its stored placement (the
    // identity transform), which drops the copy. Moved and added objects are charged to the
    // cache's budget M (GeometryCache::charge) for as long as any query or snapshot holds them:
    // the cache evicts pieces to make room, and an edit whose copies alone would exceed M fails
    // with RESOURCE_EXHAUSTED.
    Status move_object(std::uint32_t object, const Affine& transform);
    StatusOr<std::uint32_t> add_object(ModelObject object);
    Status delete_object(std::uint32_t object);

    // move_object in two steps, for a caller that serialises its edits under its own lock: the
    // slow step (a stored object read from disk, transformed and checked) takes no lock and can
    // run outside the caller's; commit_move charges the copy and publishes the new version (and
    // fails NOT_FOUND when the object was deleted meanwhile). Edits commit one at a time.
    struct PreparedMove {
        std::uint32_t object = 0;
        bool back = false;  // to the stored placement: no copy
        std::string name;
        TriangleMesh mesh;  // the moved coordinates (empty when `back`)
    };
    StatusOr<PreparedMove> prepare_move(std::uint32_t object, const Affine& transform) const;
    Status commit_move(PreparedMove move);

    std::uint32_t object_count() const;
    StatusOr<std::string> object_name(std::uint32_t object) const;
    bool deleted(std::uint32_t object) const;
    std::uint64_t version() const;  // incremented by every edit

    // Overlay objects (moved or added) in memory, each one piece with its own lazy hierarchy.
    struct OverlayObject {
        std::uint32_t object = 0;
        std::string name;
        Aabb box;
        std::shared_ptr<ResidentPiece> piece;  // owns its charge to the cache's budget
        GeometryCache::Charge charge;          // (the same charge, for an edit replacing it)
    };
    struct Snapshot {
        std::vector<std::uint8_t> masked;  // per store object: deleted or moved (not from disk)
        std::vector<OverlayObject> overlay;
        std::uint64_t version = 0;
    };
    // The current version: queries on it see exactly its edits, however many edits follow.
    std::shared_ptr<const Snapshot> snapshot() const;
    // An object's name as of version `at` (an object added then deleted later still has one).
    StatusOr<std::string> object_name(const Snapshot& at, std::uint32_t object) const;
    double slack() const { return m_slack; }

  private:
    std::shared_ptr<const Store> m_store;
    std::shared_ptr<GeometryCache> m_cache;
    PieceIndex m_index;
    double m_slack = 0.0;
    std::mutex m_commit_mutex;  // edits publish one at a time (charge, then swap the snapshot)
    mutable std::shared_mutex m_mutex;  // guards m_snapshot (held only to read or swap it)
    std::shared_ptr<const Snapshot> m_snapshot;
    std::uint32_t m_next_added = 0;  // guarded by m_commit_mutex: added ids are never reused
};

struct AvatarQueryOptions {
    double tolerance = 0.0;  // report objects within this distance (>= 0)
    bool nearest = true;     // the closest object
    // ... among objects at most this far (the search stops there; no nearest when none is):
    // design review rarely cares about the closest object five metres away, and the exact
    // search's cost grows with the distance (more near-tied triangle pairs).
    double nearest_max_distance = std::numeric_limits<double>::infinity();
    // Prefetch along the velocity: the box swept over this many future poses.
    double prefetch_poses = 4.0;
};

struct AvatarHit {
    std::uint32_t object = 0;
    double distance = 0.0;
    std::uint32_t object_triangle = 0;
    std::uint32_t avatar_triangle = 0;
    Vec3 object_point;
    Vec3 avatar_point;
};

struct AvatarResult {
    std::vector<AvatarHit> collisions;  // objects touching or intersecting the avatar, by object
    std::vector<AvatarHit> within;      // objects within the tolerance, by object
    std::optional<AvatarHit> nearest;   // ties: smaller object index
    // Statistics of this pose.
    std::uint64_t candidate_pieces = 0;
    std::uint64_t pieces_tested = 0;
    std::uint64_t exact_tests = 0;
    std::uint64_t prefetch_hints = 0;
    double seconds = 0;
};

// One avatar: a rigid mesh posed by an affine map of its own coordinates. Not thread-safe (one
// stream drives one avatar); many avatars share one ModelView.
class AvatarTracker {
  public:
    static StatusOr<std::unique_ptr<AvatarTracker>> create(std::shared_ptr<ModelView> view,
                                                           TriangleMesh avatar,
                                                           std::uint64_t id = 0);
    // `at`: the model version to query (a snapshot of the view; null: the current one). A caller
    // that names the version in its answer takes the snapshot first and queries at it: edits
    // committed meanwhile do not change what this query sees.
    StatusOr<AvatarResult> query(const Affine& pose, const AvatarQueryOptions& options,
                                 const CancelToken* cancel = nullptr,
                                 std::shared_ptr<const ModelView::Snapshot> at = nullptr);
    const std::vector<Vec3>& posed_vertices() const { return m_posed; }

  private:
    struct Query;  // one query's state and steps (avatar.cpp)

    AvatarTracker() = default;
    std::shared_ptr<ModelView> m_view;
    TriangleMesh m_mesh;
    std::vector<Vec3> m_posed;
    std::unique_ptr<LazyBvh> m_tree;  // on the avatar's own coordinates, built once, lazily
    std::uint64_t m_id = 0;
    bool m_has_previous = false;
    Aabb m_previous_box;
    double m_previous_nearest = 0.0;
    // The previous pose's closest pair: re-evaluated first at the next pose, it gives the nearest
    // search a tight upper bound from the start (temporal coherence).
    struct Seed {
        bool valid = false;
        std::uint32_t piece = 0;  // UINT32_MAX: an overlay object
        std::uint32_t object = 0;
        std::uint32_t local = 0;   // triangle of the piece (tree index)
        std::uint32_t avatar = 0;  // avatar triangle
    } m_seed;
};

}  // namespace proxima::massive
