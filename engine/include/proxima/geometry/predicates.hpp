#pragma once
// Exact orientation predicates on double-precision input. The sign is always the sign of the
// exact real determinant of the given doubles: a floating-point evaluation with a static error
// bound decides almost every call; the rare undecided ones are re-evaluated in exact rational
// arithmetic (GMP). Everything that decides *whether* primitives touch goes through these.

#include "proxima/geometry/vec3.hpp"

namespace proxima {

// Sign (+1, 0, -1) of | ax-cx  ay-cy ; bx-cx  by-cy |: +1 when a, b, c turn counter-clockwise.
int orient2d(double ax, double ay, double bx, double by, double cx, double cy);

// Sign (+1, 0, -1) of the determinant | a-d ; b-d ; c-d |: +1 when d lies below the plane through
// a, b, c oriented counter-clockwise seen from above (Shewchuk's convention), 0 when coplanar.
int orient3d(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d);

namespace detail {
// Counters of how often the exact fallback ran; for tests and statistics only.
unsigned long long exact_fallback_count();
}  // namespace detail

}  // namespace proxima
