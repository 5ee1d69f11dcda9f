// Closest points (point-triangle, segment-segment, triangle-triangle) against dense sampling and
// independent references, and the exact intersection tests against an exact rational LP
// reference on small-integer inputs (where touching and degenerate configurations are common and
// exactly representable).

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

#include "proxima/distance/primitives.hpp"
#include "proxima/geometry/predicates.hpp"

namespace proxima {
namespace {

// ---- Independent references -----------------------------------------------------------------

Vec3 ref_closest_on_segment(const Vec3& p, const Vec3& a, const Vec3& b) {
    const Vec3 d = b - a;
    const double len2 = dot(d, d);
    if (len2 == 0.0) {
        return a;
    }
    const double t = std::clamp(dot(p - a, d) / len2, 0.0, 1.0);
    return a + t * d;
}

double ref_point_segment(const Vec3& p, const Vec3& a, const Vec3& b) {
    return norm(p - ref_closest_on_segment(p, a, b));
}

// Projection via the normal equations when it falls inside, else the nearest edge.
double ref_point_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
    const double edges = std::min(
        {ref_point_segment(p, a, b), ref_point_segment(p, b, c), ref_point_segment(p, c, a)});
    const Vec3 u = b - a;
    const Vec3 v = c - a;
    const Vec3 w = p - a;
    const double uu = dot(u, u);
    const double uv = dot(u, v);
    const double vv = dot(v, v);
    const double det = uu * vv - uv * uv;
    if (!(det > 1e-20 * uu * vv)) {
        return edges;
    }
    const double s = (vv * dot(w, u) - uv * dot(w, v)) / det;
    const double t = (uu * dot(w, v) - uv * dot(w, u)) / det;
    if (s >= 0.0 && t >= 0.0 && s + t <= 1.0) {
        return std::min(edges, norm(p - (a + s * u + t * v)));
    }
    return edges;
}

double ref_point_triangle(const Vec3& p, const Triangle& t) {
    return ref_point_triangle(p, t[0], t[1], t[2]);
}

// f(s) = distance from p0 + s (p1 - p0) to segment [q0, q1] is convex in s, so golden-section
// search converges to the true minimum.
double ref_segment_segment(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1) {
    auto f = [&](double s) { return ref_point_segment(p0 + s * (p1 - p0), q0, q1); };
    const double g = (std::sqrt(5.0) - 1.0) / 2.0;
    double lo = 0.0;
    double hi = 1.0;
    double x1 = hi - g * (hi - lo);
    double x2 = lo + g * (hi - lo);
    double f1 = f(x1);
    double f2 = f(x2);
    for (int i = 0; i < 120; ++i) {
        if (f1 <= f2) {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - g * (hi - lo);
            f1 = f(x1);
        } else {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + g * (hi - lo);
            f2 = f(x2);
        }
    }
    return std::min({f1, f2, f(0.0), f(1.0)});
}

// Distance between non-intersecting triangles from the independent references above.
double ref_triangle_triangle(const Triangle& a, const Triangle& b) {
    double best = std::numeric_limits<double>::infinity();
    for (int i = 0; i < 3; ++i) {
        best = std::min(best, ref_point_triangle(a[i], b));
        best = std::min(best, ref_point_triangle(b[i], a));
        for (int j = 0; j < 3; ++j) {
            best = std::min(best, ref_segment_segment(a[i], a[(i + 1) % 3], b[j], b[(j + 1) % 3]));
        }
    }
    return best;
}

// Points a + (i/n)(b - a) + (j/n)(c - a), i + j <= n: every point of the triangle is within
// (longest edge)/n of one of them.
std::vector<Vec3> triangle_samples(const Vec3& a, const Vec3& b, const Vec3& c, int n) {
    std::vector<Vec3> out;
    out.reserve(static_cast<size_t>((n + 1) * (n + 2) / 2));
    for (int i = 0; i <= n; ++i) {
        for (int j = 0; i + j <= n; ++j) {
            out.push_back(a + (double(i) / n) * (b - a) + (double(j) / n) * (c - a));
        }
    }
    return out;
}

double longest_edge(const Vec3& a, const Vec3& b, const Vec3& c) {
    return std::max({norm(b - a), norm(c - b), norm(a - c)});
}

// Barycentric coordinates of x's projection onto the plane of (a, b, c), and the residual.
struct Barycentric {
    double v;
    double w;
    double residual;
};

Barycentric barycentric(const Vec3& x, const Vec3& a, const Vec3& b, const Vec3& c) {
    const Vec3 u = b - a;
    const Vec3 v = c - a;
    const Vec3 w = x - a;
    const double uu = dot(u, u);
    const double uv = dot(u, v);
    const double vv = dot(v, v);
    const double det = uu * vv - uv * uv;
    const double s = (vv * dot(w, u) - uv * dot(w, v)) / det;
    const double t = (uu * dot(w, v) - uv * dot(w, u)) / det;
    return {s, t, norm(x - (a + s * u + t * v))};
}

// x lies on the closed triangle: barycentric check for well-shaped triangles, distance check for
// all of them.
void expect_on_triangle(const Vec3& x, const Vec3& a, const Vec3& b, const Vec3& c,
                        double tol = 1e-9) {
    ASSERT_TRUE(is_finite(x));
    EXPECT_LE(ref_point_triangle(x, a, b, c), tol);
    const double area2 = norm(cross(b - a, c - a));
    const double l = longest_edge(a, b, c);
    if (area2 > 1e-3 * l * l) {
        const Barycentric bc = barycentric(x, a, b, c);
        EXPECT_GE(bc.v, -tol);
        EXPECT_GE(bc.w, -tol);
        EXPECT_LE(bc.v + bc.w, 1.0 + tol);
        EXPECT_LE(bc.residual, tol);
    }
}

void expect_on_triangle(const Vec3& x, const Triangle& t, double tol = 1e-9) {
    expect_on_triangle(x, t[0], t[1], t[2], tol);
}

void expect_consistent(const ClosestPoints& r) {
    ASSERT_TRUE(std::isfinite(r.squared_distance));
    ASSERT_TRUE(is_finite(r.point_a));
    ASSERT_TRUE(is_finite(r.point_b));
    EXPECT_EQ(r.squared_distance, squared_norm(r.point_a - r.point_b));
}

Vec3 random_vec(std::mt19937_64& rng, double lo, double hi) {
    std::uniform_real_distribution<double> d(lo, hi);
    return {d(rng), d(rng), d(rng)};
}

Triangle random_triangle(std::mt19937_64& rng, double lo, double hi) {
    return {random_vec(rng, lo, hi), random_vec(rng, lo, hi), random_vec(rng, lo, hi)};
}

Triangle translated(const Triangle& t, const Vec3& d) {
    return {t[0] + d, t[1] + d, t[2] + d};
}

// ---- Exact rational LP reference for intersections of convex hulls ---------------------------

// Fractions of 64-bit integers with 128-bit intermediates; inputs are small integers, so every
// value is a ratio of small minors. Overflow would throw rather than give a wrong reference.
__extension__ typedef __int128 I128;

struct Q {
    std::int64_t n = 0;
    std::int64_t d = 1;
};

Q make_q(I128 n, I128 d) {
    if (d < 0) {
        n = -n;
        d = -d;
    }
    I128 a = n < 0 ? -n : n;
    I128 b = d;
    while (b != 0) {
        const I128 r = a % b;
        a = b;
        b = r;
    }
    if (a > 1) {
        n /= a;
        d /= a;
    }
    const I128 lim = INT64_MAX;
    if (n > lim || n < -lim || d > lim) {
        throw std::overflow_error("rational reference overflow");
    }
    return {static_cast<std::int64_t>(n), static_cast<std::int64_t>(d)};
}
Q operator-(Q a, Q b) {
    return make_q(I128(a.n) * b.d - I128(b.n) * a.d, I128(a.d) * b.d);
}
Q operator*(Q a, Q b) {
    return make_q(I128(a.n) * b.n, I128(a.d) * b.d);
}
Q operator/(Q a, Q b) {
    return make_q(I128(a.n) * b.d, I128(a.d) * b.n);
}

std::int64_t to_int(double v) {
    if (v != std::round(v) || std::fabs(v) > 1e6) {
        throw std::invalid_argument("LP reference needs small integer coordinates");
    }
    return static_cast<std::int64_t>(v);
}

// conv(P) and conv(Q) intersect iff  sum_i x_i P_i - sum_j y_j Q_j = 0, sum x = 1, sum y = 1,
// x, y >= 0  is feasible; a feasible LP has a basic feasible solution, i.e. one supported on
// linearly independent columns, so it suffices to solve every such subsystem exactly.
bool hulls_intersect(const std::vector<Vec3>& p, const std::vector<Vec3>& q) {
    const int np = static_cast<int>(p.size());
    const int cols = np + static_cast<int>(q.size());
    std::vector<std::array<Q, 5>> column(static_cast<size_t>(cols));
    for (int c = 0; c < cols; ++c) {
        const bool from_p = c < np;
        const Vec3& v = from_p ? p[static_cast<size_t>(c)] : q[static_cast<size_t>(c - np)];
        const std::int64_t sgn = from_p ? 1 : -1;
        column[static_cast<size_t>(c)] = {Q{sgn * to_int(v.x), 1}, Q{sgn * to_int(v.y), 1},
                                          Q{sgn * to_int(v.z), 1}, Q{from_p ? 1 : 0, 1},
                                          Q{from_p ? 0 : 1, 1}};
    }
    for (int mask = 1; mask < (1 << cols); ++mask) {
        std::vector<int> sel;
        for (int c = 0; c < cols; ++c) {
            if ((mask >> c) & 1) {
                sel.push_back(c);
            }
        }
        const int k = static_cast<int>(sel.size());
        if (k > 5) {
            continue;
        }
        // Augmented 5 x (k + 1) system, Gauss-Jordan.
        std::array<std::array<Q, 6>, 5> m{};
        for (int r = 0; r < 5; ++r) {
            for (int j = 0; j < k; ++j) {
                m[r][j] = column[static_cast<size_t>(sel[j])][r];
            }
            m[r][k] = Q{r >= 3 ? 1 : 0, 1};
        }
        bool independent = true;
        for (int j = 0; j < k && independent; ++j) {
            int piv = -1;
            for (int r = j; r < 5; ++r) {
                if (m[r][j].n != 0) {
                    piv = r;
                    break;
                }
            }
            if (piv < 0) {
                independent = false;
                break;
            }
            std::swap(m[j], m[piv]);
            const Q pv = m[j][j];
            for (int c = j; c <= k; ++c) {
                m[j][c] = m[j][c] / pv;
            }
            for (int r = 0; r < 5; ++r) {
                if (r != j && m[r][j].n != 0) {
                    const Q f = m[r][j];
                    for (int c = j; c <= k; ++c) {
                        m[r][c] = m[r][c] - f * m[j][c];
                    }
                }
            }
        }
        if (!independent) {
            continue;
        }
        bool consistent = true;
        for (int r = k; r < 5; ++r) {
            consistent = consistent && m[r][k].n == 0;
        }
        bool nonnegative = true;
        for (int j = 0; j < k; ++j) {
            nonnegative = nonnegative && m[j][k].n >= 0;
        }
        if (consistent && nonnegative) {
            return true;
        }
    }
    return false;
}

bool ref_triangles_intersect(const Triangle& a, const Triangle& b) {
    return hulls_intersect({a[0], a[1], a[2]}, {b[0], b[1], b[2]});
}

const std::array<std::array<int, 3>, 6> PERMUTATIONS = {
    {{0, 1, 2}, {1, 2, 0}, {2, 0, 1}, {0, 2, 1}, {2, 1, 0}, {1, 0, 2}}};

Triangle permuted(const Triangle& t, const std::array<int, 3>& p) {
    return {t[static_cast<size_t>(p[0])], t[static_cast<size_t>(p[1])],
            t[static_cast<size_t>(p[2])]};
}

// triangles_intersect must not depend on vertex order or argument order.
void expect_order_invariant(const Triangle& a, const Triangle& b, bool expected) {
    for (const auto& pa : PERMUTATIONS) {
        for (const auto& pb : PERMUTATIONS) {
            const Triangle ta = permuted(a, pa);
            const Triangle tb = permuted(b, pb);
            ASSERT_EQ(triangles_intersect(ta, tb), expected);
            ASSERT_EQ(triangles_intersect(tb, ta), expected);
        }
    }
}

// ---- point_triangle -----------------------------------------------------------------------

TEST(PrimitivesPointTriangle, RandomAgainstDenseSampling) {
    std::mt19937_64 rng(2024);
    const int n = 60;
    for (int it = 0; it < 400; ++it) {
        const Triangle t = random_triangle(rng, -1.0, 1.0);
        // Points near the plane, far away, and in between.
        const double spread = it % 3 == 0 ? 0.2 : (it % 3 == 1 ? 2.0 : 10.0);
        const Vec3 p = random_vec(rng, -spread, spread);
        const ClosestPoints r = point_triangle(p, t[0], t[1], t[2]);
        expect_consistent(r);
        EXPECT_EQ(r.point_a, p);
        expect_on_triangle(r.point_b, t);

        double sampled = std::numeric_limits<double>::infinity();
        for (const Vec3& s : triangle_samples(t[0], t[1], t[2], n)) {
            sampled = std::min(sampled, norm(p - s));
        }
        const double d = std::sqrt(r.squared_distance);
        const double h = longest_edge(t[0], t[1], t[2]) / n;
        EXPECT_LE(d, sampled + 1e-12) << it;
        EXPECT_GE(d, sampled - h - 1e-12) << it;
        EXPECT_NEAR(d, ref_point_triangle(p, t), 1e-12) << it;
    }
}

TEST(PrimitivesPointTriangle, EveryVoronoiRegion) {
    const Vec3 a{0, 0, 0};
    const Vec3 b{2, 0, 0};
    const Vec3 c{0, 2, 0};
    struct Case {
        Vec3 p;
        Vec3 closest;
    };
    const Case cases[] = {
        {{-1, -1, 1}, a},
        {{3, -1, -1}, b},
        {{-1, 3, 2}, c},
        {{1, -1, 1}, {1, 0, 0}},
        {{-1, 1, 1}, {0, 1, 0}},
        {{2, 2, 1}, {1, 1, 0}},
        {{0.5, 0.5, 3}, {0.5, 0.5, 0}},
        {{0.5, 0.5, -3}, {0.5, 0.5, 0}},
        {{0.5, 0.5, 0}, {0.5, 0.5, 0}},
    };
    for (const Case& cs : cases) {
        const ClosestPoints r = point_triangle(cs.p, a, b, c);
        expect_consistent(r);
        EXPECT_NEAR(r.point_b.x, cs.closest.x, 1e-15);
        EXPECT_NEAR(r.point_b.y, cs.closest.y, 1e-15);
        EXPECT_NEAR(r.point_b.z, cs.closest.z, 1e-15);
    }
}

TEST(PrimitivesPointTriangle, DegenerateTriangles) {
    std::mt19937_64 rng(5);
    for (int it = 0; it < 300; ++it) {
        const Vec3 a = random_vec(rng, -1, 1);
        const Vec3 b = random_vec(rng, -1, 1);
        const double t = std::uniform_real_distribution<double>(-1.0, 2.0)(rng);
        const Triangle cases[] = {
            {a, b, a + t * (b - a)},  // collinear up to rounding
            {a, b, 0.5 * (a + b)},    // collinear (midpoint)
            {a, a, b},                // coincident vertices
            {a, b, b},
            {a, a, a},  // a point
            {a, b, a + 2.0 * (b - a)},
        };
        const Vec3 p = random_vec(rng, -2, 2);
        for (const Triangle& tri : cases) {
            const ClosestPoints r = point_triangle(p, tri[0], tri[1], tri[2]);
            expect_consistent(r);
            EXPECT_EQ(r.point_a, p);
            const double edges = std::min({ref_point_segment(p, tri[0], tri[1]),
                                           ref_point_segment(p, tri[1], tri[2]),
                                           ref_point_segment(p, tri[2], tri[0])});
            EXPECT_NEAR(std::sqrt(r.squared_distance), edges, 1e-12) << it;
            EXPECT_LE(std::min({ref_point_segment(r.point_b, tri[0], tri[1]),
                                ref_point_segment(r.point_b, tri[1], tri[2]),
                                ref_point_segment(r.point_b, tri[2], tri[0])}),
                      1e-12);
        }
    }
}

TEST(PrimitivesPointTriangle, SliversAreAccurateAboveTheirInterior) {
    // A needle and a flat cap, with points just above their interior: taking the nearest edge
    // would be off by the triangles' width (~1e-7), far more than the tolerance.
    for (double width : {1e-4, 1e-7, 1e-9}) {
        const Vec3 a{0, 0, 0};
        const Vec3 b{1, 0, 0};
        for (const Vec3& c : {Vec3{0.5, width, 0}, Vec3{0.0, width, 0}}) {
            const Vec3 inside = (a + b + c) / 3.0;
            for (double h : {1e-12, 1e-9, 0.3}) {
                const Vec3 p = inside + Vec3{0, 0, h};
                const ClosestPoints r = point_triangle(p, a, b, c);
                expect_consistent(r);
                EXPECT_NEAR(std::sqrt(r.squared_distance), h, 1e-15 + 1e-9 * h)
                    << width << " " << h;
                // The projection itself (the reference's own barycentric solve is too
                // ill-conditioned for these slivers). An in-plane offset e changes the distance
                // by only e^2 / 2h, so for large h rounding cannot tell nearby points apart.
                EXPECT_LE(norm(r.point_b - inside), 1e-15 + 1e-8 * h) << width << " " << h;
            }
        }
    }
}

TEST(PrimitivesPointTriangle, NeverNanForExtremeScales) {
    for (double s : {1e-150, 1e-30, 1.0, 1e30, 1e150}) {
        const Vec3 a{0, 0, 0};
        const Vec3 b{s, 0, 0};
        const Vec3 c{0, s, 0};
        for (const Vec3& p : {Vec3{0.25 * s, 0.25 * s, s}, Vec3{2 * s, 2 * s, 0}, Vec3{-s, 0, 0}}) {
            const ClosestPoints r = point_triangle(p, a, b, c);
            expect_consistent(r);
        }
    }
}

// ---- segment_segment -----------------------------------------------------------------------

TEST(PrimitivesSegmentSegment, RandomAgainstDenseSamplingAndReference) {
    std::mt19937_64 rng(31337);
    const int n = 200;
    for (int it = 0; it < 300; ++it) {
        const Vec3 p0 = random_vec(rng, -1, 1);
        const Vec3 p1 = random_vec(rng, -1, 1);
        const Vec3 q0 = random_vec(rng, -1, 1);
        Vec3 q1 = random_vec(rng, -1, 1);
        if (it % 4 == 0) {
            // Nearly parallel: q's direction is p's plus a small perturbation.
            q1 = q0 + (p1 - p0) * 0.7 + random_vec(rng, -1e-6, 1e-6);
        }
        const ClosestPoints r = segment_segment(p0, p1, q0, q1);
        expect_consistent(r);
        EXPECT_LE(ref_point_segment(r.point_a, p0, p1), 1e-14);
        EXPECT_LE(ref_point_segment(r.point_b, q0, q1), 1e-14);

        double sampled = std::numeric_limits<double>::infinity();
        for (int i = 0; i <= n; ++i) {
            const Vec3 x = p0 + (double(i) / n) * (p1 - p0);
            for (int j = 0; j <= n; ++j) {
                sampled = std::min(sampled, norm(x - (q0 + (double(j) / n) * (q1 - q0))));
            }
        }
        const double d = std::sqrt(r.squared_distance);
        const double h = (norm(p1 - p0) + norm(q1 - q0)) / (2.0 * n);
        EXPECT_LE(d, sampled + 1e-12) << it;
        EXPECT_GE(d, sampled - h - 1e-12) << it;
        EXPECT_NEAR(d, ref_segment_segment(p0, p1, q0, q1), 1e-9) << it;
    }
}

TEST(PrimitivesSegmentSegment, DegenerateAndParallelCases) {
    const Vec3 o{0, 0, 0};
    const Vec3 x{1, 0, 0};
    struct Case {
        Vec3 p0, p1, q0, q1;
        double distance;
    };
    const Case cases[] = {
        {o, o, o, o, 0.0},                                    // two equal points
        {o, o, {0, 3, 4}, {0, 3, 4}, 5.0},                    // two points
        {{0.5, 2, 0}, {0.5, 2, 0}, o, x, 2.0},                // point vs segment
        {o, x, {2, 0, 1}, {2, 0, 1}, std::sqrt(2.0)},         // segment vs point
        {o, x, {2, 1, 0}, {3, 1, 0}, std::sqrt(2.0)},         // parallel, apart
        {o, x, {0.5, 1, 0}, {3, 1, 0}, 1.0},                  // parallel, overlapping
        {o, x, {3, 1, 0}, {0.5, 1, 0}, 1.0},                  // antiparallel, overlapping
        {o, x, {0.5, 0, 0}, {2, 0, 0}, 0.0},                  // collinear, overlapping
        {o, x, {0.25, 0, 0}, {0.75, 0, 0}, 0.0},              // collinear, contained
        {o, x, {2, 0, 0}, {3, 0, 0}, 1.0},                    // collinear, apart
        {o, x, {-2, 0, 0}, {-1, 0, 0}, 1.0},                  // collinear, apart (before)
        {o, x, {0.5, -1, 0}, {0.5, 1, 0}, 0.0},               // crossing
        {o, x, {0.5, -1, 1}, {0.5, 1, 1}, 1.0},               // skew
        {o, x, {0.5, 0, 1e-300}, {0.5, 0, 1e-300}, 1e-300},   // tiny offset
        {o, {1e-300, 0, 0}, {0, 1, 0}, {1e-300, 1, 0}, 1.0},  // tiny parallel segments
        {o, x, {0, 1, 0}, {1, 1 + 1e-17, 0}, 1.0},            // parallel after rounding
    };
    for (const Case& cs : cases) {
        for (int swap = 0; swap < 2; ++swap) {
            const ClosestPoints r = swap == 0 ? segment_segment(cs.p0, cs.p1, cs.q0, cs.q1)
                                              : segment_segment(cs.q0, cs.q1, cs.p1, cs.p0);
            expect_consistent(r);
            EXPECT_NEAR(std::sqrt(r.squared_distance), cs.distance, 1e-15 * (1 + cs.distance));
            if (cs.distance > 1e-150) {
                EXPECT_NEAR(std::sqrt(r.squared_distance) / cs.distance, 1.0, 1e-15);
            }
        }
    }
}

TEST(PrimitivesSegmentSegment, NearlyParallelLongSegments) {
    // Nearly parallel skew segments whose closest pair is interior to both: neither the
    // denominator of the general formula nor the endpoint candidates alone are reliable.
    std::mt19937_64 rng(8);
    for (int it = 0; it < 200; ++it) {
        const Vec3 dir = random_vec(rng, -1, 1);
        const Vec3 off = random_vec(rng, -1e-3, 1e-3);
        const double angle = std::pow(10.0, -std::uniform_real_distribution<double>(3, 12)(rng));
        const Vec3 bend = angle * random_vec(rng, -1, 1);
        const Vec3 p0 = -1.0 * dir;
        const Vec3 p1 = dir;
        const Vec3 q0 = off - 1.3 * (dir + bend);
        const Vec3 q1 = off + 0.9 * (dir - bend);
        const ClosestPoints r = segment_segment(p0, p1, q0, q1);
        expect_consistent(r);
        EXPECT_NEAR(std::sqrt(r.squared_distance), ref_segment_segment(p0, p1, q0, q1), 1e-9);
        EXPECT_LE(ref_point_segment(r.point_a, p0, p1), 1e-14);
        EXPECT_LE(ref_point_segment(r.point_b, q0, q1), 1e-14);
    }
}

// ---- segment_triangle_intersect --------------------------------------------------------------

TEST(SegmentTriangleIntersect, KnownCases) {
    const Vec3 a{0, 0, 0};
    const Vec3 b{4, 0, 0};
    const Vec3 c{0, 4, 0};
    struct Case {
        Vec3 p, q;
        bool expected;
    };
    const Case cases[] = {
        {{1, 1, -1}, {1, 1, 1}, true},    // crossing the interior
        {{1, 1, 1}, {1, 1, -1}, true},    // reversed
        {{5, 5, -1}, {5, 5, 1}, false},   // crossing the plane outside
        {{1, 1, 1}, {1, 1, 2}, false},    // above
        {{1, 1, 0}, {1, 1, 2}, true},     // endpoint on the interior
        {{0, 0, 0}, {1, 1, 2}, true},     // endpoint on a vertex
        {{2, 0, -1}, {2, 0, 1}, true},    // through an edge
        {{2, 2, -1}, {2, 2, 1}, true},    // through the hypotenuse
        {{-1, -1, -1}, {1, 1, 1}, true},  // through a vertex (0, 0, 0)
        {{2.1, 2, -1}, {2.1, 2, 1}, false}, {{1, 1, 0}, {2, 1, 0}, true},  // coplanar, inside
        {{-1, 1, 0}, {5, 1, 0}, true},    // coplanar, crossing two edges
        {{-1, 5, 0}, {5, -1, 0}, true},   // coplanar, crossing the hypotenuse's line inside
        {{-1, 6, 0}, {6, -1, 0}, false},  // coplanar, parallel to the hypotenuse, outside
        {{-2, 0, 0}, {-1, 0, 0}, false},  // coplanar, collinear with an edge, apart
        {{-2, 0, 0}, {0, 0, 0}, true},    // collinear, touching at a vertex
        {{1, 0, 0}, {2, 0, 0}, true},     // collinear, on an edge
        {{1, 1, 0}, {1, 1, 0}, true},     // point inside
        {{4, 4, 0}, {4, 4, 0}, false},    // point outside, coplanar
        {{1, 1, 1}, {1, 1, 1}, false},    // point above
        {{2, 2, 0}, {2, 2, 0}, true},     // point on an edge
    };
    for (const Case& cs : cases) {
        EXPECT_EQ(segment_triangle_intersect(cs.p, cs.q, a, b, c), cs.expected)
            << cs.p.x << "," << cs.p.y << "," << cs.p.z << " -> " << cs.q.x << "," << cs.q.y << ","
            << cs.q.z;
        EXPECT_EQ(segment_triangle_intersect(cs.q, cs.p, c, b, a), cs.expected);
        EXPECT_EQ(segment_triangle_intersect(cs.p, cs.q, b, c, a), cs.expected);
    }
}

TEST(SegmentTriangleIntersect, DegenerateTriangles) {
    const Vec3 a{0, 0, 0};
    const Vec3 b{4, 0, 0};
    // Segment-like triangle along the x axis, with the middle vertex in each position.
    for (const Triangle& t :
         {Triangle{a, b, Vec3{2, 0, 0}}, Triangle{a, Vec3{2, 0, 0}, b}, Triangle{b, a, b}}) {
        EXPECT_TRUE(segment_triangle_intersect({1, -1, 0}, {1, 1, 0}, t[0], t[1], t[2]));
        EXPECT_TRUE(segment_triangle_intersect({3, -1, -1}, {3, 1, 1}, t[0], t[1], t[2]));
        EXPECT_FALSE(segment_triangle_intersect({1, -1, 1}, {1, 1, 1}, t[0], t[1], t[2]));
        EXPECT_FALSE(segment_triangle_intersect({5, -1, 0}, {5, 1, 0}, t[0], t[1], t[2]));
        EXPECT_TRUE(segment_triangle_intersect({3, 0, 0}, {7, 0, 0}, t[0], t[1], t[2]));
        EXPECT_FALSE(segment_triangle_intersect({5, 0, 0}, {7, 0, 0}, t[0], t[1], t[2]));
        EXPECT_TRUE(segment_triangle_intersect({4, 0, 0}, {7, 0, 0}, t[0], t[1], t[2]));
        EXPECT_TRUE(segment_triangle_intersect({2, 0, 0}, {2, 0, 0}, t[0], t[1], t[2]));
        EXPECT_FALSE(segment_triangle_intersect({2, 0, 1e-300}, {2, 0, 1e-300}, t[0], t[1], t[2]));
    }
    // Point-like triangle.
    const Vec3 p{1, 2, 3};
    EXPECT_TRUE(segment_triangle_intersect({0, 0, 0}, {2, 4, 6}, p, p, p));
    EXPECT_FALSE(segment_triangle_intersect({0, 0, 0}, {2, 4, 6.000000001}, p, p, p));
    EXPECT_TRUE(segment_triangle_intersect(p, p, p, p, p));
    const Vec3 o{0, 0, 0};
    const Vec3 tiny{0, 0, 1e-300};
    EXPECT_FALSE(segment_triangle_intersect(o, o, tiny, tiny, tiny));
    EXPECT_TRUE(segment_triangle_intersect(o, 2.0 * tiny, tiny, tiny, tiny));
}

TEST(SegmentTriangleIntersect, SmallIntegersAgainstExactLp) {
    std::mt19937_64 rng(17);
    int hits = 0;
    for (int it = 0; it < 4000; ++it) {
        const int range = it % 2 == 0 ? 2 : 5;
        std::uniform_int_distribution<int> d(-range, range);
        auto v = [&] { return Vec3{double(d(rng)), double(d(rng)), double(d(rng))}; };
        const Vec3 p = v();
        const Vec3 q = it % 7 == 0 ? p : v();
        const Triangle t{v(), v(), v()};
        const bool expected = hulls_intersect({p, q}, {t[0], t[1], t[2]});
        hits += expected;
        for (const auto& perm : PERMUTATIONS) {
            const Triangle tp = permuted(t, perm);
            ASSERT_EQ(segment_triangle_intersect(p, q, tp[0], tp[1], tp[2]), expected) << it;
            ASSERT_EQ(segment_triangle_intersect(q, p, tp[0], tp[1], tp[2]), expected) << it;
        }
    }
    EXPECT_GT(hits, 300);
    EXPECT_LT(hits, 3500);
}

// ---- triangles_intersect -----------------------------------------------------------------

TEST(TrianglesIntersect, ExplicitConfigurations) {
    const Triangle base{Vec3{-1, -1, 0}, Vec3{3, -1, 0}, Vec3{-1, 3, 0}};
    struct Case {
        const char* name;
        Triangle other;
        bool expected;
    };
    const Case cases[] = {
        {"crossing", {Vec3{0, 0, -1}, Vec3{1, 0, 1}, Vec3{0, 1, 1}}, true},
        {"above", {Vec3{0, 0, 1}, Vec3{1, 0, 1}, Vec3{0, 1, 2}}, false},
        {"vertex touches interior", {Vec3{0, 0, 0}, Vec3{1, 0, 1}, Vec3{0, 1, 1}}, true},
        {"vertex touches vertex", {Vec3{-1, -1, 0}, Vec3{-2, -2, 1}, Vec3{-3, -1, 1}}, true},
        {"vertex touches edge", {Vec3{1, -1, 0}, Vec3{1, -2, 1}, Vec3{2, -2, 1}}, true},
        {"edge lies on interior", {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 0, 1}}, true},
        {"edge along edge", {Vec3{0, -1, 0}, Vec3{1, -1, 0}, Vec3{0, -1, 1}}, true},
        {"edge crosses edge", {Vec3{1, -2, 0}, Vec3{1, 0, 0}, Vec3{1, -1, 2}}, true},
        {"edges skew", {Vec3{1, -2, 0.5}, Vec3{1, 0, -0.5}, Vec3{5, 5, 5}}, true},
        {"coplanar overlap", {Vec3{0, 0, 0}, Vec3{5, 0, 0}, Vec3{0, 5, 0}}, true},
        {"coplanar contained", {Vec3{0, 0, 0}, Vec3{0.5, 0, 0}, Vec3{0, 0.5, 0}}, true},
        {"coplanar contains", {Vec3{-5, -5, 0}, Vec3{10, -5, 0}, Vec3{-5, 10, 0}}, true},
        {"coplanar disjoint", {Vec3{3, 3, 0}, Vec3{4, 3, 0}, Vec3{3, 4, 0}}, false},
        {"coplanar shared edge", {Vec3{3, -1, 0}, Vec3{-1, 3, 0}, Vec3{3, 3, 0}}, true},
        {"coplanar star of David", {Vec3{1, 3.5, 0}, Vec3{-2, -0.5, 0}, Vec3{3.5, -0.5, 0}}, true},
        {"segment-like crossing", {Vec3{0, 0, -1}, Vec3{0, 0, 1}, Vec3{0, 0, 0.5}}, true},
        {"segment-like above", {Vec3{0, 0, 1}, Vec3{0, 0, 2}, Vec3{0, 0, 1.5}}, false},
        {"segment-like coplanar inside", {Vec3{0, 0, 0}, Vec3{1, 1, 0}, Vec3{0.5, 0.5, 0}}, true},
        {"segment-like coplanar outside", {Vec3{5, 5, 0}, Vec3{6, 6, 0}, Vec3{5, 5, 0}}, false},
        {"segment-like coplanar crossing", {Vec3{-5, 0, 0}, Vec3{5, 0, 0}, Vec3{0, 0, 0}}, true},
        {"point-like inside", {Vec3{0, 0, 0}, Vec3{0, 0, 0}, Vec3{0, 0, 0}}, true},
        {"point-like on vertex", {Vec3{3, -1, 0}, Vec3{3, -1, 0}, Vec3{3, -1, 0}}, true},
        {"point-like above", {Vec3{0, 0, 1}, Vec3{0, 0, 1}, Vec3{0, 0, 1}}, false},
        {"point-like coplanar outside", {Vec3{5, 5, 0}, Vec3{5, 5, 0}, Vec3{5, 5, 0}}, false},
    };
    for (const Case& cs : cases) {
        SCOPED_TRACE(cs.name);
        expect_order_invariant(base, cs.other, cs.expected);
        Vec3 w{std::nan(""), 0, 0};
        EXPECT_EQ(triangles_intersect(base, cs.other, &w), cs.expected);
        if (cs.expected) {
            expect_on_triangle(w, base, 1e-12);
            expect_on_triangle(w, cs.other, 1e-12);
        }
    }
}

TEST(TrianglesIntersect, DegenerateAgainstDegenerate) {
    const Vec3 o{0, 0, 0};
    const Triangle seg_x{Vec3{-1, 0, 0}, Vec3{1, 0, 0}, o};
    EXPECT_TRUE(triangles_intersect(seg_x, Triangle{Vec3{0, -1, 0}, Vec3{0, 1, 0}, Vec3{0, 1, 0}}));
    EXPECT_FALSE(
        triangles_intersect(seg_x, Triangle{Vec3{0, -1, 1}, Vec3{0, 1, 1}, Vec3{0, 1, 1}}));
    EXPECT_TRUE(triangles_intersect(seg_x, Triangle{Vec3{1, 0, 0}, Vec3{2, 0, 0}, Vec3{3, 0, 0}}));
    EXPECT_FALSE(
        triangles_intersect(seg_x, Triangle{Vec3{1.5, 0, 0}, Vec3{2, 0, 0}, Vec3{3, 0, 0}}));
    EXPECT_TRUE(
        triangles_intersect(seg_x, Triangle{Vec3{0.5, 0, 0}, Vec3{0.5, 0, 0}, Vec3{0.5, 0, 0}}));
    EXPECT_FALSE(triangles_intersect(
        seg_x, Triangle{Vec3{0.5, 1e-300, 0}, Vec3{0.5, 1e-300, 0}, Vec3{0.5, 1e-300, 0}}));
    const Triangle pt{o, o, o};
    EXPECT_TRUE(triangles_intersect(pt, pt));
    EXPECT_FALSE(triangles_intersect(
        pt, Triangle{Vec3{0, 0, 1e-300}, Vec3{0, 0, 1e-300}, Vec3{0, 0, 1e-300}}));
}

TEST(TrianglesIntersect, SharedVertexAndEdgePairs) {
    // Adjacent mesh faces, folded at various angles, always touch.
    std::mt19937_64 rng(3);
    for (int it = 0; it < 300; ++it) {
        const Vec3 a = random_vec(rng, -1, 1);
        const Vec3 b = random_vec(rng, -1, 1);
        const Vec3 c = random_vec(rng, -1, 1);
        const Vec3 d = random_vec(rng, -1, 1);
        const Vec3 e = random_vec(rng, -1, 1);
        expect_order_invariant({a, b, c}, {b, a, d}, true);  // shared edge
        expect_order_invariant({a, b, c}, {c, d, e}, true);  // shared vertex
        const ClosestPoints r = triangle_triangle({a, b, c}, {c, d, e});
        EXPECT_EQ(r.squared_distance, 0.0);
    }
}

TEST(TrianglesIntersect, TinyOffsetsJustApart) {
    // Configurations that touch at a feature through the origin or on a coordinate plane, then
    // pushed apart (or into each other) by tiny distances. Only coordinates that are 0 get the
    // offset, so 1e-300 is representable where it matters.
    const Triangle floor{Vec3{-1, -1, 0}, Vec3{2, -1, 0}, Vec3{-1, 2, 0}};
    const Triangle up{Vec3{0, 0, 0}, Vec3{1, 0, 1}, Vec3{0, 1, 1}};  // vertex on floor's interior
    const Triangle floor_edge{Vec3{-1, 0, 0}, Vec3{2, 0, 0}, Vec3{-1, 3, 0}};
    const Triangle wall{Vec3{-1, 0, 0}, Vec3{2, 0, 0}, Vec3{0, 0, 1}};  // shares that edge
    const Triangle floor_corner{Vec3{0, 0, 0}, Vec3{2, 0, 0}, Vec3{0, 2, 0}};
    const Triangle mirrored{Vec3{0, 0, 0}, Vec3{-2, 0, 0}, Vec3{0, -2, 0}};  // coplanar, vertex
    for (double delta : {1e-12, 1e-300}) {
        SCOPED_TRACE(delta);
        expect_order_invariant(floor, up, true);
        expect_order_invariant(floor, translated(up, {0, 0, delta}), false);
        expect_order_invariant(floor, translated(up, {0, 0, -delta}), true);
        expect_order_invariant(floor_edge, wall, true);
        expect_order_invariant(floor_edge, translated(wall, {0, -delta, 0}), false);
        expect_order_invariant(floor_edge, translated(wall, {0, delta, 0}), true);
        expect_order_invariant(floor_edge, translated(wall, {0, 0, delta}), false);
        expect_order_invariant(floor_corner, mirrored, true);
        expect_order_invariant(floor_corner, translated(mirrored, {-delta, 0, 0}), false);
        expect_order_invariant(floor_corner, translated(mirrored, {0, 0, delta}), false);
        expect_order_invariant(floor_corner, translated(mirrored, {delta, 0, 0}), true);
    }
    // At 1e-12 the separation is also visible in the distance (1e-300 squared underflows).
    const ClosestPoints r = triangle_triangle(floor, translated(up, {0, 0, 1e-12}));
    EXPECT_NEAR(r.squared_distance, 1e-24, 1e-30);
    const ClosestPoints r2 = triangle_triangle(floor_corner, translated(mirrored, {-1e-12, 0, 0}));
    EXPECT_NEAR(r2.squared_distance, 1e-24, 1e-30);
}

// Pairs that cross each other's planes with no vertex on the other's plane: the case that the
// two-predicate test (Guigue and Devillers) decides. Coordinates in -3..3 make the two segments on
// the planes' line meet end to end often (a predicate exactly 0); -30..30 makes that rare. The
// reference is the exact LP (small integers only).
TEST(TrianglesIntersect, CrossingPairsAgainstExactLp) {
    std::mt19937_64 rng(29);
    int crossing = 0;
    int hits = 0;
    int touching = 0;
    for (int it = 0; it < 40000 && crossing < 4000; ++it) {
        const int range = it % 2 == 0 ? 3 : 30;
        std::uniform_int_distribution<int> d(-range, range);
        auto v = [&] { return Vec3{double(d(rng)), double(d(rng)), double(d(rng))}; };
        const Triangle a{v(), v(), v()};
        const Triangle b{v(), v(), v()};
        int sa[3];
        int sb[3];
        for (int i = 0; i < 3; ++i) {
            sa[i] = orient3d(b[0], b[1], b[2], a[i]);
            sb[i] = orient3d(a[0], a[1], a[2], b[i]);
        }
        auto crosses = [](const int s[3]) {
            return s[0] != 0 && s[1] != 0 && s[2] != 0 && !(s[0] == s[1] && s[1] == s[2]);
        };
        if (!crosses(sa) || !crosses(sb)) {
            continue;
        }
        ++crossing;
        const bool expected = ref_triangles_intersect(a, b);
        hits += expected;
        // Touching only: a shift by one unit along some axis, one way or the other, separates
        // them (some of these meet in a single point of the planes' line).
        if (expected && range == 3) {
            for (const Vec3& shift : {Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0, 0, 1}}) {
                if (!ref_triangles_intersect(a, translated(b, shift)) ||
                    !ref_triangles_intersect(a, translated(b, -1.0 * shift))) {
                    ++touching;
                    break;
                }
            }
        }
        if (crossing <= 300) {
            expect_order_invariant(a, b, expected);
        } else {
            ASSERT_EQ(triangles_intersect(a, b), expected) << it;
            ASSERT_EQ(triangles_intersect(b, a), expected) << it;
        }
        ASSERT_EQ(triangle_triangle(a, b).squared_distance == 0.0, expected) << it;
    }
    EXPECT_EQ(crossing, 4000);
    EXPECT_GT(hits, 800);
    EXPECT_LT(hits, 3200);
    EXPECT_GT(touching, 0);
}

TEST(TrianglesIntersect, SmallIntegersAgainstExactLp) {
    std::mt19937_64 rng(11);
    int hits = 0;
    for (int it = 0; it < 3000; ++it) {
        const int range = it % 3 == 0 ? 1 : (it % 3 == 1 ? 2 : 6);
        std::uniform_int_distribution<int> d(-range, range);
        auto v = [&] { return Vec3{double(d(rng)), double(d(rng)), double(d(rng))}; };
        Triangle a{v(), v(), v()};
        Triangle b{v(), v(), v()};
        if (it % 5 == 0) {
            b[0] = a[0];  // shared vertex
        } else if (it % 5 == 1) {
            for (auto* t : {&a, &b}) {  // both in the plane z = 0
                for (auto& p : *t) {
                    p.z = 0;
                }
            }
        }
        const bool expected = ref_triangles_intersect(a, b);
        hits += expected;
        if (it < 600) {
            expect_order_invariant(a, b, expected);
        } else {
            ASSERT_EQ(triangles_intersect(a, b), expected) << it;
            ASSERT_EQ(triangles_intersect(b, a), expected) << it;
        }
        Vec3 w;
        if (triangles_intersect(a, b, &w)) {
            // The tolerance covers the rounding of the test's own barycentric solve.
            expect_on_triangle(w, a, 1e-10);
            expect_on_triangle(w, b, 1e-10);
        }
        // Power-of-two scalings keep the configuration exactly, across under- and overflow.
        if (it % 10 == 0) {
            for (int e : {-1000, 900}) {
                const double s = std::ldexp(1.0, e);
                const Triangle sa{s * a[0], s * a[1], s * a[2]};
                const Triangle sb{s * b[0], s * b[1], s * b[2]};
                ASSERT_EQ(triangles_intersect(sa, sb), expected) << it << " 2^" << e;
            }
        }
        // The distance agrees: zero exactly for intersecting pairs, positive otherwise.
        const ClosestPoints r = triangle_triangle(a, b);
        ASSERT_EQ(r.squared_distance == 0.0, expected) << it;
    }
    EXPECT_GT(hits, 600);
    EXPECT_LT(hits, 2400);
}

TEST(TrianglesIntersect, RandomOrderInvariance) {
    std::mt19937_64 rng(6);
    int hits = 0;
    for (int it = 0; it < 400; ++it) {
        const Triangle a = random_triangle(rng, -1, 1);
        const Triangle b = translated(random_triangle(rng, -1, 1), random_vec(rng, -1, 1));
        const bool base = triangles_intersect(a, b);
        hits += base;
        expect_order_invariant(a, b, base);
    }
    EXPECT_GT(hits, 40);
    EXPECT_LT(hits, 360);
}

// ---- triangle_triangle ---------------------------------------------------------------------

TEST(TriangleTriangle, RandomAgainstSamplingAndReference) {
    std::mt19937_64 rng(0xC0FFEE);
    const int n = 30;
    int hits = 0;
    int misses = 0;
    for (int it = 0; it < 2500; ++it) {
        const Triangle a = random_triangle(rng, -1, 1);
        const double spread = it % 2 == 0 ? 0.3 : 3.0;
        const Triangle b =
            translated(random_triangle(rng, -1, 1), random_vec(rng, -spread, spread));
        const ClosestPoints r = triangle_triangle(a, b);
        expect_consistent(r);
        expect_on_triangle(r.point_a, a);
        expect_on_triangle(r.point_b, b);

        const bool hit = triangles_intersect(a, b);
        ASSERT_EQ(r.squared_distance == 0.0, hit) << it;
        const ClosestPoints swapped = triangle_triangle(b, a);
        EXPECT_NEAR(swapped.squared_distance, r.squared_distance, 1e-12 * (1 + r.squared_distance));

        // Sample one triangle and measure to the other with the independent reference; the
        // result is an upper bound within h of the true distance.
        double sampled = std::numeric_limits<double>::infinity();
        for (const Vec3& s : triangle_samples(a[0], a[1], a[2], n)) {
            sampled = std::min(sampled, ref_point_triangle(s, b));
        }
        for (const Vec3& s : triangle_samples(b[0], b[1], b[2], n)) {
            sampled = std::min(sampled, ref_point_triangle(s, a));
        }
        const double h =
            std::min(longest_edge(a[0], a[1], a[2]), longest_edge(b[0], b[1], b[2])) / n;
        const double d = std::sqrt(r.squared_distance);
        EXPECT_LE(d, sampled + 1e-12) << it;
        EXPECT_GE(d, sampled - h - 1e-12) << it;
        if (hit) {
            ++hits;
        } else {
            ++misses;
            EXPECT_NEAR(d, ref_triangle_triangle(a, b), 1e-9) << it;
        }
    }
    EXPECT_GT(hits, 300);
    EXPECT_GT(misses, 300);
}

TEST(TriangleTriangle, DegenerateTrianglesGiveFiniteDistances) {
    std::mt19937_64 rng(21);
    for (int it = 0; it < 300; ++it) {
        const Vec3 p = random_vec(rng, -1, 1);
        const Vec3 q = random_vec(rng, -1, 1);
        const Triangle degenerate[] = {{p, q, 0.5 * (p + q)}, {p, p, q}, {p, p, p}};
        const Triangle other = translated(random_triangle(rng, -1, 1), random_vec(rng, -2, 2));
        for (const Triangle& t : degenerate) {
            const ClosestPoints r = triangle_triangle(t, other);
            expect_consistent(r);
            EXPECT_LE(ref_point_triangle(r.point_a, t), 1e-12);
            expect_on_triangle(r.point_b, other);
            EXPECT_EQ(r.squared_distance == 0.0, triangles_intersect(t, other));
            if (r.squared_distance > 0.0) {
                EXPECT_NEAR(std::sqrt(r.squared_distance), ref_triangle_triangle(t, other), 1e-9);
            }
        }
    }
}

TEST(TriangleTriangle, KnownDistances) {
    const Triangle a{Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}};
    // Parallel planes, overlapping in projection: the distance is the plane gap.
    const ClosestPoints r1 = triangle_triangle(a, translated(a, {0.2, 0.2, 2}));
    EXPECT_DOUBLE_EQ(r1.squared_distance, 4.0);
    // Vertex above the interior.
    const ClosestPoints r2 =
        triangle_triangle(a, {Vec3{0.25, 0.25, 0.5}, Vec3{0.25, 0.25, 3}, Vec3{1, 1, 3}});
    EXPECT_DOUBLE_EQ(r2.squared_distance, 0.25);
    EXPECT_NEAR(r2.point_a.x, 0.25, 1e-15);
    EXPECT_NEAR(r2.point_a.y, 0.25, 1e-15);
    EXPECT_EQ(r2.point_a.z, 0.0);
    // b's nearest vertex (0.5, -1, 1) against a's edge y = z = 0.
    const ClosestPoints r3 =
        triangle_triangle(a, {Vec3{0.5, -1, 1}, Vec3{0.5, -2, 1}, Vec3{0.5, -1, 3}});
    EXPECT_NEAR(r3.squared_distance, 2.0, 1e-15);  // closest pair (0.5, 0, 0) - (0.5, -1, 1)
    // Vertex (0, 0, 1) of a gently tilted triangle above b's interior, while b's own vertex
    // nearest to the tilted plane projects outside it.
    const Triangle flat{Vec3{-1, -1, 0}, Vec3{1, -1, 0}, Vec3{0, 1, 0}};
    const Triangle tilted{Vec3{0, 0, 1}, Vec3{3, 0, 1.5}, Vec3{0, 3, 1.5}};
    for (const auto& [x, y] : {std::pair{tilted, flat}, std::pair{flat, tilted}}) {
        const ClosestPoints r4 = triangle_triangle(x, y);
        EXPECT_DOUBLE_EQ(r4.squared_distance, 1.0);
        expect_on_triangle(r4.point_a, x);
        expect_on_triangle(r4.point_b, y);
    }
}

TEST(TriangleTriangle, NearlyParallelEdges) {
    // One edge of b runs nearly parallel to an edge of a, a small distance away, and b's third
    // vertex points away from a: the closest pair involves those two edges.
    std::mt19937_64 rng(404);
    for (int it = 0; it < 300; ++it) {
        const Triangle a = random_triangle(rng, -1, 1);
        const Vec3 normal = cross(a[1] - a[0], a[2] - a[0]);
        const Vec3 away = (1.0 / norm(normal)) * normal;
        const double angle = std::pow(10.0, -std::uniform_real_distribution<double>(2, 12)(rng));
        const Vec3 gap = std::uniform_real_distribution<double>(1e-6, 0.1)(rng) * away;
        const Vec3 slide = std::uniform_real_distribution<double>(-0.5, 0.5)(rng) * (a[1] - a[0]);
        const Triangle b{a[0] + gap + slide, a[1] + gap + slide + angle * random_vec(rng, -1, 1),
                         a[0] + gap + random_vec(rng, -1, 1) + 2.0 * away};
        const ClosestPoints r = triangle_triangle(a, b);
        expect_consistent(r);
        expect_on_triangle(r.point_a, a);
        expect_on_triangle(r.point_b, b);
        if (!triangles_intersect(a, b)) {
            EXPECT_NEAR(std::sqrt(r.squared_distance), ref_triangle_triangle(a, b), 1e-9) << it;
        }
    }
}

// The edge pairs with AVX2 (where the processor has it: the four pairs at the closest corners
// first, the other five only when none of those is certified) must choose exactly what the scalar
// copy chooses, with the same parameters bit for bit: random pairs at four scales, and ties that
// make the order decide (closest points at a shared corner position, which several pairs certify;
// translated copies, whose parallel edges tie; zero-length edges and point triangles). Fails with
// a lane out of order, a wrong corner table entry, a changed comparison or a different tie rule.
TEST(TriangleTriangle, EdgePairChoiceInLanesIsTheScalarChoiceBitForBit) {
    auto bits = [](double x) { return std::bit_cast<std::uint64_t>(x); };
    std::mt19937_64 rng(1414);
    int certified = 0;
    int uncertified = 0;
    int after_first_four = 0;
    auto check = [&](const Triangle& a, const Triangle& b) {
        const detail::EdgePairChoice got = detail::closest_edge_pair(a, b);
        const detail::EdgePairChoice want = detail::closest_edge_pair_portable(a, b);
        ASSERT_EQ(got.pair, want.pair);
        ASSERT_EQ(got.certified, want.certified);
        ASSERT_EQ(bits(got.s), bits(want.s));
        ASSERT_EQ(bits(got.t), bits(want.t));
        if (!want.certified) {
            ASSERT_EQ(got.nearly_parallel, want.nearly_parallel);
        }
        certified += want.certified ? 1 : 0;
        uncertified += want.certified ? 0 : 1;
        // A certified pair off the closest corners' four: the vector copy's second stage.
        if (want.certified) {
            double nearest = std::numeric_limits<double>::infinity();
            int ka = 0;
            int kb = 0;
            for (int i = 0; i < 3; ++i) {
                for (int j = 0; j < 3; ++j) {
                    const double d = squared_norm(a[i] - b[j]);
                    if (d < nearest) {
                        nearest = d;
                        ka = i;
                        kb = j;
                    }
                }
            }
            const int i = want.pair / 3;
            const int j = want.pair % 3;
            const bool at_a = i == ka || i == (ka + 2) % 3;
            const bool at_b = j == kb || j == (kb + 2) % 3;
            after_first_four += at_a && at_b ? 0 : 1;
        }
    };
    for (const double scale : {1e-6, 1.0, 1e3, 1e8}) {
        for (int it = 0; it < 2000; ++it) {
            const Triangle a = random_triangle(rng, -scale, scale);
            Triangle b = random_triangle(rng, -scale, scale);
            check(a, b);
            // b moved off a by a random vector: mostly disjoint pairs, as the self query's.
            const Vec3 shift = random_vec(rng, -2.0 * scale, 2.0 * scale);
            check(a, translated(b, shift));
            // A translated copy: parallel edges, equally close pairs.
            check(a, translated(a, shift));
            // b's corner l placed on a's corner: pairs meeting there all reach 0.
            const int l = it % 3;
            b[static_cast<std::size_t>(l)] = a[static_cast<std::size_t>(it / 3 % 3)];
            check(a, b);
            check(b, a);
        }
    }
    const Vec3 p{1.0, 2.0, 3.0};
    const Vec3 q{1.5, 2.0, 3.0};
    const Triangle others[] = {{p, p, p},
                               {p, q, q},
                               {p, q, Vec3{2.0, 2.0, 3.0}},
                               {Vec3{-0.0, 0.0, -0.0}, Vec3{0.0, -0.0, 0.0}, q}};
    for (const Triangle& x : others) {
        for (const Triangle& y : others) {
            check(x, y);
            check(x, translated(y, Vec3{0.0, 0.0, 1.0}));
        }
    }
    // Both stages and both outcomes occur.
    EXPECT_GT(certified, 10000);
    EXPECT_GT(uncertified, 100);
    EXPECT_GT(after_first_four, 100);
}

// A caller that proved two triangles disjoint skips the intersection test: the answer must be the
// same bit for bit (the self query passes `apart` for pairs a lower bound separated, brute force
// never does). Fails if anything after that test depends on it having run.
TEST(TriangleTriangle, ApartGivesTheSameAnswerBitForBit) {
    auto bits = [](double x) { return std::bit_cast<std::uint64_t>(x); };
    std::mt19937_64 rng(1515);
    int disjoint = 0;
    for (int it = 0; it < 20000; ++it) {
        const Triangle a = random_triangle(rng, -1, 1);
        const Triangle b = translated(random_triangle(rng, -1, 1), random_vec(rng, -2, 2));
        if (triangles_intersect(a, b)) {
            continue;
        }
        ++disjoint;
        const ClosestPoints x = triangle_triangle(a, b);
        const ClosestPoints y = triangle_triangle(a, b, true);
        ASSERT_EQ(bits(x.squared_distance), bits(y.squared_distance)) << it;
        for (int c = 0; c < 3; ++c) {
            ASSERT_EQ(bits(x.point_a[c]), bits(y.point_a[c])) << it;
            ASSERT_EQ(bits(x.point_b[c]), bits(y.point_b[c])) << it;
        }
    }
    EXPECT_GT(disjoint, 10000);
}

}  // namespace
}  // namespace proxima
