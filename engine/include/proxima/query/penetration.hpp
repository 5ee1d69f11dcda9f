#pragma once
// Local penetration depth between intersecting objects and within self-intersecting objects
// (seed 000 §3.3). Input: the exact intersecting triangle pairs of a collisions query. For each
// intersecting object pair (and each self-intersecting object) the overlapping features are the
// intersecting triangles plus a walk over connectivity into the part of each surface that lies
// inside the other one (an exact winding-number test decides "inside"); the direction comes from
// the overlapping vertex (of either side, inside the other) whose closest overlapping feature of
// the other side is farthest; the depth is the width, along that direction, of the overlap
// region's vertices (the overlapping features clipped to the other object's interior). See
// docs/algorithms.md, "Penetration depth".
//
// This is the seed's *local* penetration depth: a good estimate when the overlap is one connected,
// roughly convex region of small width; `isolated` says when it is not (several separate contact
// regions share one answer: the seed's stated limitation).

#include <cstdint>
#include <vector>

#include "proxima/query/query.hpp"

namespace proxima {

struct Penetration {
    std::uint32_t object = 0;  // scene index
    std::uint32_t other = 0;   // scene index; == object for a self-penetration
    // Unit vector: moving `object` (for a self-penetration: its `triangles` side) by
    // direction * depth separates the overlapping features locally. Zero when no estimate could be
    // made (see `sides_split`).
    Vec3 direction;
    double depth = 0.0;
    Vec3 vector;  // direction * depth
    // Overlapping features, ascending: triangles of `object` (intersecting `other`, or inside it)
    // and of `other`. For a self-penetration: the two sides the intersection splits the object
    // into, both indexing the same object.
    std::vector<std::uint32_t> triangles;
    std::vector<std::uint32_t> other_triangles;
    // The pair that gave `direction`: a triangle incident to the farthest deep vertex and the
    // other side's triangle closest to it (side `triangles` first); the first intersecting pair
    // when the normal fallback ran.
    std::uint32_t triangle = 0;
    std::uint32_t other_triangle = 0;
    // False when the overlapping features of either side form more than one connected component:
    // several separate contact regions, for which one local translation is only a rough answer.
    bool isolated = true;
    // False when a surface involved is not closed and consistently oriented (directed edges do not
    // cancel): "inside" is then undefined, no walk is done, and the overlapping features are the
    // intersecting triangles only.
    bool closed = true;
    // True when no vertex of either side lies strictly inside the other one off its features (all
    // closest-feature distances are 0, or no inside is defined) and the direction came from the
    // area-weighted normals of the overlapping features.
    bool normal_fallback = false;
    // Self-penetration only: false when the overlapping features could not be split into two sides
    // (an intersecting pair inside one connected piece of overlapping features); then direction,
    // depth and vector are zero and both feature lists hold all overlapping features.
    bool sides_split = true;
};

// One entry per intersecting object pair (object < other) and per self-intersecting object
// (object == other), in ascending (object, other) order, from `collisions`: the sorted FeaturePair
// list of a collisions query on this same scene (pairs naming objects or triangles that do not
// exist give invalid_argument). Stops with cancelled / deadline_exceeded when the token says so.
StatusOr<std::vector<Penetration>> penetration_depths(const Scene& scene,
                                                      const std::vector<FeaturePair>& collisions,
                                                      const CancelToken* cancel = nullptr);

namespace detail {
// Winding number of the triangles of `object` (all but `exclude`, when it names one) around p:
// the signed number of crossings of a ray from p along +axis (axis 0, 1, 2), each counted +1 where
// the triangle's normal (b - a) x (c - a) points along the ray. Exact: the ray is perturbed
// symbolically (Simulation of Simplicity) so that it meets no edge, and every decision is an exact
// orient2d / orient3d. For a closed, consistently oriented surface and p off it, this is the
// winding number (1 inside an outward-oriented closed surface, 0 outside).
int winding_number(const SceneObject& object, const Vec3& p, int axis = 0,
                   std::int64_t exclude = -1);
// Whether the directed edges of the topology cancel (every edge u->v has as many v->u): closed and
// consistently oriented, the surfaces on which "inside" is defined.
bool closed_oriented(const MeshTopology& topology);
}  // namespace detail

}  // namespace proxima
