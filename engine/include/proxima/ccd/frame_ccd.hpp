#pragma once
// Full-frame continuous collision detection between two frames of a scene (seed 000 §3.2, §5.3,
// §6.1): every vertex of every object moves linearly from its position at t = 0 (the scene) to
// its position at t = 1 (`positions_t1`), the topology is the same in both frames. Every
// vertex-triangle and edge-edge pair that the elementary tests (proxima/ccd/elementary.hpp) report
// as touching in [0, 1] is found, between objects and within an object (adjacent primitives
// excluded), with its time of impact.
//
// Exact with respect to the elementary tests: the result holds exactly the pairs that testing every
// primitive pair with `vertex_face` / `edge_edge` reports, with the same times of impact. The
// broad phase (boxes, one hierarchy per object, object boxes swept and pruned) only decides
// which pairs are tested; the argument that it never drops a pair the elementary test would
// report, rounding included, is at the top of engine/src/ccd/frame_ccd.cpp. The elementary tests
// are conservative (never a false negative, never a late time of impact), so the result is too.
// One exception to "exactly": a pair that the prefilter (elementary_prefilter_rejects), or with it
// on the boxes at both frames, prove never comes within min_distance + tolerance is not tested,
// so it is absent even where the elementary test, reaching its work bound, would have reported it
// `capped` (a larger bound rejects it).
// Vertices used by no triangle are not primitives and are never tested.

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "proxima/ccd/elementary.hpp"
#include "proxima/mesh/mesh.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"

namespace proxima::ccd {

// Edges of a topology: the unique (smaller vertex, larger vertex) pairs of its triangles' sides,
// sorted; the edge index is the position in this list. A side joining a vertex to itself (a
// triangle listing a vertex twice) is a point, not an edge, and is left out: whatever it could
// touch, the triangle's other sides through that vertex touch too.
std::vector<std::array<std::uint32_t, 2>> mesh_edges(const MeshTopology& topology);

// One pair of primitives that touches at some t in [0, 1].
//   vertex_face: `primitive` is a vertex of `object`, `other_primitive` a triangle of `other`
//                (between objects both directions occur, so `object` may exceed `other`);
//   edge_edge:   `primitive` and `other_primitive` are edge indices (mesh_edges) of `object` and
//                `other`, object <= other, and primitive < other_primitive when object == other.
// The elementary test saw the points in the order of elementary.hpp: for vf the vertex, then the
// triangle's corners in the topology's order; for ee the edge of `object` (smaller vertex first),
// then the edge of `other`.
struct CcdPair {
    CcdKind kind = CcdKind::vertex_face;
    std::uint32_t object = 0;
    std::uint32_t primitive = 0;
    std::uint32_t other = 0;
    std::uint32_t other_primitive = 0;
    double toi = 1.0;     // no later than the earliest contact of the pair
    bool capped = false;  // the elementary test reached its work bound (hit and toi conservative)
    // The primitives' vertex ids in their objects' own numbering, so that a caller can act on
    // them without the edge list: vf: `vertices` = {the vertex}, `other_vertices` = the triangle's
    // three corners in the topology's order; ee: each edge's two vertices, smaller first. The
    // first vertex_count(kind) / other_vertex_count(kind) entries are used, the rest are 0.
    std::array<std::uint32_t, 3> vertices{};
    std::array<std::uint32_t, 3> other_vertices{};
};

constexpr std::size_t vertex_count(CcdKind kind) {
    return kind == CcdKind::vertex_face ? 1 : 2;
}
constexpr std::size_t other_vertex_count(CcdKind kind) {
    return kind == CcdKind::vertex_face ? 3 : 2;
}

// Earliest time of impact of one object pair (object <= other; object == other for
// self-contacts): `pair` indexes CcdResult::pairs (the first of the pairs with that toi).
struct ObjectPairToi {
    std::uint32_t object = 0;
    std::uint32_t other = 0;
    double toi = 1.0;
    std::size_t pair = 0;
};

struct CcdStats {
    // Triangle pairs whose boxes are not apart (from the hierarchies; with the prefilter on, boxes
    // at both frames, otherwise swept boxes: frame_ccd.cpp), within and between objects.
    std::uint64_t candidate_pairs = 0;
    // Distinct primitive pairs (vf and ee) tested with the elementary tests after the per-primitive
    // box filter and the prefilter (elementary_prefilter_rejects); brute force would test
    // `brute_force_tests`.
    std::uint64_t elementary_tests = 0;
    // Pairs that passed the box filter but were rejected by the prefilter (not tested).
    // Not sent over the wire (proxima.proto has no field for it).
    std::uint64_t prefilter_rejects = 0;
    std::uint64_t brute_force_tests = 0;
    // Elementary tests that reached their work bound.
    std::uint64_t capped_tests = 0;
    std::uint64_t object_pairs_tested = 0;  // object pairs whose boxes are not apart
    // Boxes, hierarchies, traversals and the prefilter; then the elementary tests. The traversals
    // and the tests run in one parallel loop (each job tests the pairs it finds): its wall time is
    // split between the two in proportion to the CPU time each took.
    double broad_phase_seconds = 0.0;
    double narrow_phase_seconds = 0.0;
    double total_seconds = 0.0;
};

struct CcdRequest {
    ElementaryOptions elementary;  // min_distance >= 0, tolerance > 0
    bool between_objects = true;   // pairs of primitives of two different objects
    bool self = true;              // pairs within one object (adjacent primitives excluded)
    // Run the prefilter (elementary_prefilter_rejects) before each elementary test. It drops
    // only pairs that the elementary test would not report (or would report capped: a pair that
    // provably never comes within min_distance + tolerance); false tests every candidate, for
    // checking the filter.
    bool prefilter = true;
};

struct CcdResult {
    // Sorted by (kind: vf first, object, primitive, other, other_primitive): deterministic,
    // independent of the thread count.
    std::vector<CcdPair> pairs;
    std::vector<ObjectPairToi>
        object_pairs;                     // one per object pair with a contact, by (object, other)
    std::optional<std::size_t> earliest;  // index in pairs of the earliest toi (first on ties)
    CcdStats stats;
};

// `scene` holds the objects at t = 0; positions_t1[i] the vertices of object i at t = 1 (same count
// and order). Within an object, a vertex is not tested against the triangles it is a corner of and
// an edge is not tested against the edges it shares a vertex with; between objects every pair is.
// Errors: invalid_argument (wrong number of position sets, wrong vertex count, non-finite
// coordinate, min_distance negative or not finite, tolerance not positive, max_boxes 0), cancelled
// / deadline_exceeded from the token (checked between chunks of work; partial results discarded).
StatusOr<CcdResult> continuous_collisions(const Scene& scene,
                                          std::span<const std::vector<Vec3>> positions_t1,
                                          const CcdRequest& request = {},
                                          const CancelToken* cancel = nullptr);

}  // namespace proxima::ccd
