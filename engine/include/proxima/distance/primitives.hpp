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
// minimum over the 6 vertex-triangle and 9 edge-edge closest pairs (a pair certified closest may
// be returned before the others are computed: docs/algorithms.md, Stage III).
// `apart`: the caller has proved the triangles disjoint (a positive conservative lower bound,
// proxima/distance/bounds.hpp), so the intersection search after the plane signs is skipped; the
// result is bit-identical, since that search finds nothing for disjoint triangles.
ClosestPoints triangle_triangle(const Triangle& ta, const Triangle& tb, bool apart = false);

}  // namespace proxima
