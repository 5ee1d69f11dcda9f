#pragma once
// Small value types for points, vectors and boxes, in double precision. Units are whatever the
// caller's coordinates are in (the engine never rescales). Kept free of Eigen so that every
// translation unit that touches geometry stays cheap to compile.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

namespace proxima {

struct Vec3 {
    double x = 0.0;
    double y = 0.0;
    double z = 0.0;

    constexpr double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
    constexpr double& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
    friend constexpr bool operator==(const Vec3&, const Vec3&) = default;
};

constexpr Vec3 operator+(const Vec3& a, const Vec3& b) {
    return {a.x + b.x, a.y + b.y, a.z + b.z};
}
constexpr Vec3 operator-(const Vec3& a, const Vec3& b) {
    return {a.x - b.x, a.y - b.y, a.z - b.z};
}
constexpr Vec3 operator-(const Vec3& a) {
    return {-a.x, -a.y, -a.z};
}
constexpr Vec3 operator*(double s, const Vec3& a) {
    return {s * a.x, s * a.y, s * a.z};
}
constexpr Vec3 operator*(const Vec3& a, double s) {
    return {s * a.x, s * a.y, s * a.z};
}
constexpr Vec3 operator/(const Vec3& a, double s) {
    return {a.x / s, a.y / s, a.z / s};
}
constexpr Vec3& operator+=(Vec3& a, const Vec3& b) {
    a = a + b;
    return a;
}
constexpr Vec3& operator-=(Vec3& a, const Vec3& b) {
    a = a - b;
    return a;
}

constexpr double dot(const Vec3& a, const Vec3& b) {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}
constexpr Vec3 cross(const Vec3& a, const Vec3& b) {
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
constexpr double squared_norm(const Vec3& a) {
    return dot(a, a);
}
inline double norm(const Vec3& a) {
    return std::sqrt(dot(a, a));
}
constexpr Vec3 cwise_min(const Vec3& a, const Vec3& b) {
    return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)};
}
constexpr Vec3 cwise_max(const Vec3& a, const Vec3& b) {
    return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)};
}
inline bool is_finite(const Vec3& a) {
    return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z);
}

// Axis-aligned box. An empty box has lo > hi on every axis, so that extending it by any point
// gives that point's box; distances from an empty box are +inf.
struct Aabb {
    Vec3 lo{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
            std::numeric_limits<double>::infinity()};
    Vec3 hi{-std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
            -std::numeric_limits<double>::infinity()};

    bool empty() const { return lo.x > hi.x; }
    void extend(const Vec3& p) {
        lo = cwise_min(lo, p);
        hi = cwise_max(hi, p);
    }
    void extend(const Aabb& b) {
        lo = cwise_min(lo, b.lo);
        hi = cwise_max(hi, b.hi);
    }
    Vec3 center() const { return 0.5 * (lo + hi); }
    Vec3 extent() const { return hi - lo; }
    Aabb grown(double r) const { return {lo - Vec3{r, r, r}, hi + Vec3{r, r, r}}; }
};

inline Aabb triangle_box(const Vec3& a, const Vec3& b, const Vec3& c) {
    return {cwise_min(a, cwise_min(b, c)), cwise_max(a, cwise_max(b, c))};
}

// Squared Euclidean distance between two boxes: a lower bound on the squared distance between
// anything inside them, up to rounding (callers compare it against a threshold widened by the
// rounding slack of distance/bounds.hpp).
inline double box_squared_distance(const Aabb& a, const Aabb& b) {
    double d = 0.0;
    for (int k = 0; k < 3; ++k) {
        const double gap = std::max({0.0, a.lo[k] - b.hi[k], b.lo[k] - a.hi[k]});
        d += gap * gap;
    }
    return d;
}

}  // namespace proxima
