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

// orient3d(a, b, c, x) for many x against one plane, with the per-plane part of the floating-point
// filter (the normal and its error-bound minors) computed once. Always returns exactly
// orient3d(a, b, c, x); undecided queries go through orient3d itself.
class PlaneSide {
  public:
    PlaneSide(const Vec3& a, const Vec3& b, const Vec3& c);
    int operator()(const Vec3& x) const;
    // Also stores the floating-point value of ((b - a) x (c - a)) . (x - a), a height above the
    // plane scaled by the normal's length (its sign is -orient3d up to rounding).
    int operator()(const Vec3& x, double& height) const;
    // The same for a triangle's three corners at once: sign[i] = (*this)(t[i], height[i]), the
    // same signs and heights (the filter runs on the three together with AVX2 where the processor
    // has it; undecided corners go through orient3d as above).
    void corners(const std::array<Vec3, 3>& t, int sign[3], double height[3]) const;

  private:
    Vec3 m_a, m_b, m_c;
    Vec3 m_normal;  // (b - a) x (c - a) in floating point
    Vec3 m_minors;  // per axis, |u_j v_k| + |u_k v_j|: the permanent's factors
    bool m_in_range;
};
}  // namespace detail

}  // namespace proxima
