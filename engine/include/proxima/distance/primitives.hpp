#pragma once
// Closest points and distances between points, segments and triangles, and the exact
// triangle-triangle intersection test. All in double precision; all robust on degenerate input
// (zero-area triangles, zero-length segments, parallel and collinear edges, coincident vertices):
// they never return NaN for finite input and never divide by zero.
//
// Conventions: `squared_distance` is |point_a - point_b|^2 as computed from the returned points'
// construction (it is the value every comparison in the engine uses, so brute force and culled
// queries agree bit for bit). `point_a` lies on the first primitive, `point_b` on the second.

#include <array>

#include "proxima/geometry/vec3.hpp"

namespace proxima {

using Triangle = std::array<Vec3, 3>;

struct ClosestPoints {
    double squared_distance = std::numeric_limits<double>::infinity();
    Vec3 point_a;
    Vec3 point_b;
};

// Closest point of triangle (a, b, c) to p. point_a = p, point_b on the triangle.
ClosestPoints point_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c);

// Closest points of segments [p0, p1] and [q0, q1]. Parallel, collinear and zero-length segments
// are handled (any closest pair is returned when it is not unique).
ClosestPoints segment_segment(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1);

// Exact test: do the closed segment [p, q] and the closed triangle (a, b, c) share a point?
// Degenerate triangles are treated as the union of their edges, zero-length segments as points.
bool segment_triangle_intersect(const Vec3& p, const Vec3& q, const Vec3& a, const Vec3& b,
                                const Vec3& c);

// Exact test: do the closed triangles share a point? Touching (a shared vertex, an edge lying on
// the other triangle, coplanar overlap) counts as intersecting. If `witness` is given and the
// triangles intersect, it receives a point of (or within rounding of) the intersection.
bool triangles_intersect(const Triangle& ta, const Triangle& tb, Vec3* witness = nullptr);

// Distance between two closed triangles with the closest points. Exactly 0 (with both points at a
// witness of the intersection) when `triangles_intersect` says they share a point; otherwise the
// minimum over the 6 vertex-triangle and 9 edge-edge closest pairs (an edge pair certified closest
// is returned before the vertex-triangle pairs are computed: docs/algorithms.md, Stage III).
// `apart`: the caller has proved the triangles disjoint (a positive conservative lower bound,
// proxima/distance/bounds.hpp), so the intersection test is skipped; the result is bit-identical,
// since nothing after that test depends on it.
ClosestPoints triangle_triangle(const Triangle& ta, const Triangle& tb, bool apart = false);

namespace detail {
// Segments with sin^2(angle) below this are "nearly parallel": Ericson's parameters are then
// poorly conditioned, so the endpoint candidates are considered as well.
inline constexpr double NEARLY_PARALLEL = 1e-10;

// triangle_triangle's edge pairs (engine/src/distance/edge_pairs.cpp). Pair k = 3 i + j is ta's
// edge i (corner i to corner i + 1) against tb's edge j, with candidate closest points
// p = ta[i] + s (ta[i + 1] - ta[i]) and q = tb[j] + t (tb[j + 1] - tb[j]): Ericson's 5.1.9
// branch-free (the clamped line-line s, the best t for it, then the best s for that t; a
// zero-length edge has parameter 0). Certified: not nearly parallel, and Larsen's test holds
// (both triangles on the far sides of the planes through p and q normal to q - p).
// The pairs are taken in a fixed order that depends on the corners only: first the four pairs of
// edges meeting at the closest pair of corners (the first closest in row order), then the others
// in row order. The choice is the first certified pair in that order; where none is, the first
// of the pairs with the smallest |q - p|^2 (pair -1 when none is finite), and `nearly_parallel`
// says whether any of the nine is.
struct EdgePairChoice {
    int pair = -1;
    double s = 0.0;
    double t = 0.0;
    bool certified = false;
    bool nearly_parallel = false;  // only where !certified
};
// With AVX2 where the processor has it (the four pairs at the closest corners first, the other
// five only when none of those is certified); closest_edge_pair_portable is the scalar copy, the
// same choice and parameters bit for bit (exposed for the tests).
EdgePairChoice closest_edge_pair(const Triangle& ta, const Triangle& tb);
EdgePairChoice closest_edge_pair_portable(const Triangle& ta, const Triangle& tb);
}  // namespace detail

}  // namespace proxima
