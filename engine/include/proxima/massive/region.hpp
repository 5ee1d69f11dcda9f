#pragma once
// A region of a massive model for viewers (the FetchRegion call, the review page): the stored
// pieces whose boxes come within a radius of a point, nearest first, read one at a time through
// the shared GeometryCache. With a review room's view (ModelView::Snapshot), objects the room
// moved or added are its overlay pieces (one piece per object, transform applied) and deleted
// ones are left out. The daemon streams what this plans; proto/wire converts the types below.

#include <cstdint>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "proxima/massive/avatar.hpp"
#include "proxima/massive/cache.hpp"
#include "proxima/massive/store.hpp"

namespace proxima::massive {

struct RegionRequest {
    std::string model;
    Vec3 center;
    double radius = 0.0;                 // finite, >= 0; 0: every piece (distances reported 0)
    std::string room;                    // "": the stored model
    std::vector<std::uint32_t> objects;  // empty: every object
    std::uint64_t max_triangles = 0;     // 0: no limit
    bool float64 = false;                // the answer's vertices (float32 otherwise)
};

// One selected piece: a stored piece, or (with a room) one overlay object.
struct RegionPieceRef {
    std::uint32_t object = 0;
    std::uint32_t piece = 0;  // the store's piece index; 0 for an overlay object
    bool overlay = false;
    std::size_t overlay_index = 0;  // into Snapshot::overlay when `overlay`
    Aabb box;
    double distance = 0.0;
    std::uint32_t triangles = 0;
};

struct RegionPlan {
    std::vector<RegionPieceRef> pieces;  // in sending order, cut at max_triangles
    std::uint64_t triangles = 0;         // of `pieces`
    bool truncated = false;              // max_triangles left selected pieces out
};

// Euclidean distance from `p` to the box (0 inside or on it).
double box_distance(const Aabb& box, const Vec3& p);

// INVALID_ARGUMENT naming the field: a non-finite center, a negative or non-finite radius, an
// object index >= object_count ("objects[2]: object 17 is out of range ...").
Status check_region_request(const RegionRequest& request, std::uint32_t object_count);

// The pieces to send, in order: boxes within `radius` of `center` (every piece for radius 0),
// nearest first, ties by object then piece; only `objects` when given; then the longest prefix
// whose triangles stay within max_triangles. `snapshot` null: the stored model; otherwise a
// room's view (masked stored objects skipped, overlay objects one piece each). Assumes
// check_region_request passed.
RegionPlan plan_region(const Store& store, const ModelView::Snapshot* snapshot,
                       const RegionRequest& request);

// One piece's geometry, as sent: vertices in model coordinates, triangles indexing them, and each
// triangle's id in its whole object (AvatarHit::object_triangle's numbering).
struct RegionPiece {
    std::uint32_t object = 0;
    std::string object_name;
    std::vector<Vec3> vertices;
    std::vector<TriangleIndices> triangles;
    std::vector<std::uint32_t> triangle_ids;
    Aabb box;
    double distance = 0.0;
};

struct RegionProgress {
    std::uint64_t pieces_sent = 0;
    std::uint64_t pieces_total = 0;
    std::uint64_t triangles_sent = 0;
    std::uint64_t triangles_total = 0;
};

struct RegionSummary {
    std::uint64_t pieces = 0;
    std::uint64_t triangles = 0;
    bool truncated = false;
    std::uint64_t model_version = 0;  // the room's version seen (0 without a room)
    std::string generation;
    double server_seconds = 0.0;
};

using RegionEvent = std::variant<RegionPiece, RegionProgress, RegionSummary>;

// Reads one planned piece: a stored piece through `cache` (the handle is released before this
// returns, so a caller holds at most one piece at a time), an overlay object from the snapshot.
// DATA_LOSS / UNAVAILABLE from the store.
StatusOr<RegionPiece> read_region_piece(const std::shared_ptr<const Store>& store,
                                        GeometryCache& cache, const ModelView::Snapshot* snapshot,
                                        const RegionPieceRef& ref);

}  // namespace proxima::massive
