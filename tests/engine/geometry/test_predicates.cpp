// Exactness of orient2d / orient3d. References are independent of GMP and of long double: either
// the sign is known analytically, or the inputs are integers small enough for an exact __int128
// evaluation. Several tests also check that plain double evaluation gets some of these signs wrong,
// so that they would catch a predicate that silently dropped its exact stage.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <random>

#include "proxima/geometry/predicates.hpp"

namespace proxima {
namespace {

// __extension__: __int128 is a GCC/Clang extension, and the build uses -Wpedantic.
__extension__ typedef __int128 I128;

int sign_of(I128 v) {
    return v > 0 ? 1 : (v < 0 ? -1 : 0);
}
int sign_of(double v) {
    return v > 0.0 ? 1 : (v < 0.0 ? -1 : 0);
}

// Integer-valued doubles below 2^62 convert exactly.
I128 to_i128(double v) {
    return static_cast<I128>(static_cast<long long>(v));
}

// Exact reference for integer-valued coordinates with |differences| < 2^61.
int orient2d_int(double ax, double ay, double bx, double by, double cx, double cy) {
    const I128 acx = to_i128(ax) - to_i128(cx);
    const I128 acy = to_i128(ay) - to_i128(cy);
    const I128 bcx = to_i128(bx) - to_i128(cx);
    const I128 bcy = to_i128(by) - to_i128(cy);
    return sign_of(acx * bcy - acy * bcx);
}

// Exact reference for integer-valued coordinates with |differences| < 2^41 (terms < 2^123).
int orient3d_int(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
    I128 m[3][3];
    const Vec3* rows[3] = {&a, &b, &c};
    for (int i = 0; i < 3; ++i) {
        for (int k = 0; k < 3; ++k) {
            m[i][k] = to_i128((*rows[i])[k]) - to_i128(d[k]);
        }
    }
    const I128 det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
                     m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                     m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    return sign_of(det);
}

double naive_orient2d(double ax, double ay, double bx, double by, double cx, double cy) {
    return (ax - cx) * (by - cy) - (ay - cy) * (bx - cx);
}

double naive_orient3d(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
    const Vec3 ad = a - d;
    const Vec3 bd = b - d;
    const Vec3 cd = c - d;
    return ad.x * (bd.y * cd.z - bd.z * cd.y) - ad.y * (bd.x * cd.z - bd.z * cd.x) +
           ad.z * (bd.x * cd.y - bd.y * cd.x);
}

double random_int(std::mt19937_64& rng, long long lo, long long hi) {
    return static_cast<double>(std::uniform_int_distribution<long long>(lo, hi)(rng));
}

Vec3 random_int_vec(std::mt19937_64& rng, long long lo, long long hi) {
    return {random_int(rng, lo, hi), random_int(rng, lo, hi), random_int(rng, lo, hi)};
}

TEST(Predicates, KnownSigns) {
    EXPECT_EQ(orient2d(0, 0, 1, 0, 0, 1), 1);   // counter-clockwise
    EXPECT_EQ(orient2d(0, 0, 0, 1, 1, 0), -1);  // clockwise
    EXPECT_EQ(orient2d(0, 0, 1, 1, 2, 2), 0);
    EXPECT_EQ(orient2d(1, 1, 1, 1, 1, 1), 0);

    const Vec3 a{0, 0, 0};
    const Vec3 b{1, 0, 0};
    const Vec3 c{0, 1, 0};
    // Shewchuk's convention: positive when d is below the plane of counter-clockwise a, b, c.
    EXPECT_EQ(orient3d(a, b, c, Vec3{0, 0, -1}), 1);
    EXPECT_EQ(orient3d(a, b, c, Vec3{0.3, 0.3, 1}), -1);
    EXPECT_EQ(orient3d(a, b, c, Vec3{5, -7, 0}), 0);
    EXPECT_EQ(orient3d(a, a, c, Vec3{5, -7, 3}), 0);
}

TEST(Predicates, KnownSignsOfNonDyadicCollinearPoints) {
    // The doubles nearest 0.1, 0.2 and 0.3 are not equally spaced (0.1 + 0.2 != 0.3), and the
    // products in the naive formula round; but points (v, v) lie exactly on the line y = x.
    EXPECT_EQ(orient2d(0.1, 0.1, 0.2, 0.2, 0.3, 0.3), 0);
    // Shifting b's y by one ulp: the value is (ax - cx) * (by - bx) with ax < cx, so raising b
    // above the line makes it negative.
    EXPECT_EQ(orient2d(0.1, 0.1, 0.2, std::nextafter(0.2, 1.0), 0.3, 0.3), -1);
    EXPECT_EQ(orient2d(0.1, 0.1, 0.2, std::nextafter(0.2, 0.0), 0.3, 0.3), 1);
}

// Shewchuk's classic example: points within a few ulps of (0.5, 0.5) against the line through
// (12, 12) and (24, 24). The exact value is 12 * (py - px), so the sign is sign(j - i).
TEST(Predicates, ShewchukOrient2dGrid) {
    const double u = 0x1p-53;
    int naive_wrong = 0;
    for (int i = 0; i < 256; ++i) {
        for (int j = 0; j < 256; ++j) {
            const double px = 0.5 + i * u;
            const double py = 0.5 + j * u;
            const int expected = (j > i) - (j < i);
            ASSERT_EQ(orient2d(px, py, 12, 12, 24, 24), expected) << i << " " << j;
            ASSERT_EQ(orient2d(12, 12, 24, 24, px, py), expected) << i << " " << j;
            naive_wrong += sign_of(naive_orient2d(px, py, 12, 12, 24, 24)) != expected;
        }
    }
    // The grid is only a meaningful test if naive evaluation fails on it.
    EXPECT_GT(naive_wrong, 1000);
}

// The same construction in 3D: a, b, c span the plane z = x; d is a few ulps from (0.5, 0.5, 0.5).
// The determinant is affine in d and vanishes on the plane, so it equals K * (dz - dx) with K its
// value at d = (0, 0, 1) (a small-integer determinant that double evaluates exactly).
TEST(Predicates, ShewchukStyleOrient3dGrid) {
    const Vec3 a{12, 0, 12};
    const Vec3 b{24, 5, 24};
    const Vec3 c{18, 17, 18};
    const int k_sign = sign_of(naive_orient3d(a, b, c, Vec3{0, 0, 1}));
    ASSERT_NE(k_sign, 0);
    ASSERT_EQ(k_sign, orient3d_int(a, b, c, Vec3{0, 0, 1}));
    const double u = 0x1p-53;
    int naive_wrong = 0;
    for (int i = 0; i < 64; ++i) {
        for (int k = 0; k < 64; ++k) {
            for (int j : {0, 7, 40}) {
                const Vec3 d{0.5 + i * u, 0.5 + j * u, 0.5 + k * u};
                const int expected = k_sign * ((k > i) - (k < i));
                ASSERT_EQ(orient3d(a, b, c, d), expected) << i << " " << j << " " << k;
                ASSERT_EQ(orient3d(d, a, b, c), -expected) << i << " " << j << " " << k;
                naive_wrong += sign_of(naive_orient3d(a, b, c, d)) != expected;
            }
        }
    }
    EXPECT_GT(naive_wrong, 1000);
}

// Nearly collinear integer points with 52-bit coordinates: products need ~106 bits, so double
// evaluation errs; __int128 is exact.
TEST(Predicates, NearlyCollinearAgainstInt128) {
    std::mt19937_64 rng(12345);
    const long long big = 1LL << 50;
    int naive_wrong = 0;
    int zeros = 0;
    for (int n = 0; n < 20000; ++n) {
        const double ax = random_int(rng, -big, big);
        const double ay = random_int(rng, -big, big);
        const double bx = random_int(rng, -big, big);
        const double by = random_int(rng, -big, big);
        // Every fourth case is exactly on the line (an integer parameter); the others are on it
        // up to rounding to integers, then nudged by at most 2.
        const bool exact = n % 4 == 0;
        const double t =
            exact ? random_int(rng, -1, 2) : std::uniform_real_distribution<double>(-1.0, 2.0)(rng);
        const double cx = std::round(ax + t * (bx - ax)) + (exact ? 0.0 : random_int(rng, -2, 2));
        const double cy = std::round(ay + t * (by - ay)) + (exact ? 0.0 : random_int(rng, -2, 2));
        const int expected = orient2d_int(ax, ay, bx, by, cx, cy);
        ASSERT_EQ(orient2d(ax, ay, bx, by, cx, cy), expected) << n;
        naive_wrong += sign_of(naive_orient2d(ax, ay, bx, by, cx, cy)) != expected;
        zeros += expected == 0;
    }
    EXPECT_GT(naive_wrong, 100);
    EXPECT_GT(zeros, 0);
}

// Nearly coplanar integer points: b - a = v (large), c - a = v + w (w small), d on the plane up
// to a small integer offset. The determinant is then tiny compared with its terms.
TEST(Predicates, NearlyCoplanarAgainstInt128) {
    std::mt19937_64 rng(777);
    const long long big = 1LL << 38;
    int naive_wrong = 0;
    int zeros = 0;
    for (int n = 0; n < 20000; ++n) {
        const Vec3 a = random_int_vec(rng, -big, big);
        const Vec3 v = random_int_vec(rng, -big, big);
        const Vec3 w = random_int_vec(rng, -8, 8);
        const Vec3 b = a + v;
        const Vec3 c = a + v + w;
        // Every fourth case is exactly coplanar (integer combination, no nudge).
        const bool exact = n % 4 == 0;
        const double alpha =
            exact ? random_int(rng, -1, 1) : std::uniform_real_distribution<double>(-0.9, 0.9)(rng);
        const double beta = exact ? random_int(rng, -50, 50)
                                  : std::uniform_real_distribution<double>(-50.0, 50.0)(rng);
        const Vec3 e = exact ? Vec3{} : random_int_vec(rng, -1, 1);
        const Vec3 on_plane = a + alpha * v + beta * w;
        const Vec3 d{std::round(on_plane.x) + e.x, std::round(on_plane.y) + e.y,
                     std::round(on_plane.z) + e.z};
        const int expected = orient3d_int(a, b, c, d);
        ASSERT_EQ(orient3d(a, b, c, d), expected) << n;
        naive_wrong += sign_of(naive_orient3d(a, b, c, d)) != expected;
        zeros += expected == 0;
    }
    EXPECT_GT(naive_wrong, 100);
    EXPECT_GT(zeros, 0);
}

int permutation_parity(const std::array<int, 4>& p) {
    int inversions = 0;
    for (int i = 0; i < 4; ++i) {
        for (int j = i + 1; j < 4; ++j) {
            inversions += p[i] > p[j];
        }
    }
    return inversions % 2 == 0 ? 1 : -1;
}

// Swapping two points negates both determinants (orient3d is the 4x4 determinant of the
// homogeneous points; orient2d the 3x3 one). Inputs are random, nearly degenerate doubles with
// arbitrary bits, so the exact stage is exercised too.
TEST(Predicates, PermutationAntisymmetry) {
    std::mt19937_64 rng(4242);
    std::uniform_real_distribution<double> coord(-10.0, 10.0);
    std::uniform_real_distribution<double> param(-1.0, 2.0);
    int nonzero = 0;
    for (int n = 0; n < 3000; ++n) {
        std::array<Vec3, 4> pts;
        pts[0] = {coord(rng), coord(rng), coord(rng)};
        pts[1] = {coord(rng), coord(rng), coord(rng)};
        pts[2] = {coord(rng), coord(rng), coord(rng)};
        // Nearly coplanar (n % 3 == 0), nearly collinear in xy (n % 3 == 1), or generic.
        const double s = param(rng);
        const double t = param(rng);
        pts[3] = pts[0] + s * (pts[1] - pts[0]) + t * (pts[2] - pts[0]);
        if (n % 3 == 1) {
            pts[2] = pts[0] + s * (pts[1] - pts[0]);
        } else if (n % 3 == 2) {
            pts[3] = {coord(rng), coord(rng), coord(rng)};
        }
        const int base = orient3d(pts[0], pts[1], pts[2], pts[3]);
        nonzero += base != 0;
        std::array<int, 4> perm{0, 1, 2, 3};
        do {
            const int s3 = orient3d(pts[perm[0]], pts[perm[1]], pts[perm[2]], pts[perm[3]]);
            ASSERT_EQ(s3, permutation_parity(perm) * base) << n;
        } while (std::next_permutation(perm.begin(), perm.end()));

        const Vec3& p = pts[0];
        const Vec3& q = pts[1];
        const Vec3& r = pts[2];
        const int o = orient2d(p.x, p.y, q.x, q.y, r.x, r.y);
        ASSERT_EQ(orient2d(q.x, q.y, r.x, r.y, p.x, p.y), o);
        ASSERT_EQ(orient2d(r.x, r.y, p.x, p.y, q.x, q.y), o);
        ASSERT_EQ(orient2d(q.x, q.y, p.x, p.y, r.x, r.y), -o);
        ASSERT_EQ(orient2d(p.x, p.y, r.x, r.y, q.x, q.y), -o);
        ASSERT_EQ(orient2d(r.x, r.y, q.x, q.y, p.x, p.y), -o);
    }
    EXPECT_GT(nonzero, 1000);
}

// Exactly coplanar integer points stay exactly coplanar under scaling by a power of two, including
// scales where double products underflow (2^-1000) or overflow (2^900); off-plane points keep the
// sign of the unscaled integer determinant.
TEST(Predicates, ExactZeroUnderPowerOfTwoScaling) {
    std::mt19937_64 rng(99);
    const int exponents[] = {-1000, -600, -300, 0, 300, 600, 900};
    for (int n = 0; n < 300; ++n) {
        const Vec3 o = random_int_vec(rng, -(1 << 20), 1 << 20);
        const Vec3 u = random_int_vec(rng, -(1 << 8), 1 << 8);
        const Vec3 v = random_int_vec(rng, -(1 << 8), 1 << 8);
        std::array<Vec3, 4> pts;
        for (auto& p : pts) {
            p = o + random_int(rng, -64, 64) * u + random_int(rng, -64, 64) * v;
        }
        Vec3 off = pts[3] + random_int_vec(rng, -1, 1);
        const int off_sign = orient3d_int(pts[0], pts[1], pts[2], off);
        const int off_sign_2d = orient2d_int(pts[0].x, pts[0].y, pts[1].x, pts[1].y, off.x, off.y);
        // Collinear in 2D: the xy projections of o, o + k u, o + m u.
        const double k = random_int(rng, -64, 64);
        const double m = random_int(rng, -64, 64);
        for (int e : exponents) {
            const double s = std::ldexp(1.0, e);
            const Vec3 a = s * pts[0];
            const Vec3 b = s * pts[1];
            const Vec3 c = s * pts[2];
            ASSERT_EQ(orient3d(a, b, c, s * pts[3]), 0) << n << " 2^" << e;
            ASSERT_EQ(orient3d(a, b, c, s * off), off_sign) << n << " 2^" << e;
            const Vec3 p0 = s * o;
            const Vec3 p1 = s * (o + k * u);
            const Vec3 p2 = s * (o + m * u);
            ASSERT_EQ(orient2d(p0.x, p0.y, p1.x, p1.y, p2.x, p2.y), 0) << n << " 2^" << e;
            ASSERT_EQ(orient2d(a.x, a.y, b.x, b.y, s * off.x, s * off.y), off_sign_2d)
                << n << " 2^" << e;
        }
    }
}

TEST(Predicates, TinyAndSubnormalCoordinates) {
    // A triangle of size 2^-1070 (subnormal coordinates): every product underflows to zero.
    const double t = 0x1p-1070;
    EXPECT_EQ(orient2d(0, 0, t, 0, 0, t), 1);
    EXPECT_EQ(orient2d(0, 0, 0, t, t, 0), -1);
    EXPECT_EQ(orient3d(Vec3{0, 0, 0}, Vec3{t, 0, 0}, Vec3{0, t, 0}, Vec3{0, 0, -t}), 1);
    EXPECT_EQ(orient3d(Vec3{0, 0, 0}, Vec3{t, 0, 0}, Vec3{0, t, 0}, Vec3{0, 0, t}), -1);
    // A point 1e-300 above a unit triangle.
    EXPECT_EQ(orient3d(Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0.25, 0.25, 1e-300}), -1);
    EXPECT_EQ(orient3d(Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0.25, 0.25, -1e-300}), 1);
    // Huge coordinates whose products overflow.
    const double h = 0x1p1000;
    EXPECT_EQ(orient2d(0, 0, h, 0, 0, h), 1);
    EXPECT_EQ(orient3d(Vec3{0, 0, 0}, Vec3{h, 0, 0}, Vec3{0, h, 0}, Vec3{h, h, 0}), 0);
    EXPECT_EQ(orient3d(Vec3{0, 0, 0}, Vec3{h, 0, 0}, Vec3{0, h, 0}, Vec3{h, h, -1.0}), 1);
}

// The batched plane filter must agree with orient3d everywhere, including where its own filter
// is undecided or out of range.
TEST(Predicates, PlaneSideMatchesOrient3d) {
    std::mt19937_64 rng(5150);
    std::uniform_real_distribution<double> coord(-10.0, 10.0);
    std::uniform_real_distribution<double> param(-1.0, 2.0);
    int zeros = 0;
    for (int n = 0; n < 2000; ++n) {
        const double scale = std::ldexp(1.0, std::array<int, 4>{0, -1000, 900, -40}[n % 4]);
        Vec3 a{coord(rng), coord(rng), coord(rng)};
        Vec3 b{coord(rng), coord(rng), coord(rng)};
        Vec3 c{coord(rng), coord(rng), coord(rng)};
        if (n % 5 == 0) {
            c = a + param(rng) * (b - a);  // nearly or exactly degenerate plane
        }
        a = scale * a;
        b = scale * b;
        c = scale * c;
        const detail::PlaneSide side(a, b, c);
        std::array<Vec3, 4> xs;
        for (int k = 0; k < 4; ++k) {
            Vec3 x = a + param(rng) * (b - a) + param(rng) * (c - a);  // nearly coplanar
            if (k == 0) {
                x = b;  // coplanar
            } else if (k == 3) {
                x = scale * Vec3{coord(rng), coord(rng), coord(rng)};
            }
            xs[k] = x;
            const int expected = orient3d(a, b, c, x);
            double height = 0.0;
            ASSERT_EQ(side(x), expected) << n << " " << k;
            ASSERT_EQ(side(x, height), expected) << n << " " << k;
            if (k == 3 && n % 5 != 0 && (n % 4 == 0 || n % 4 == 3)) {
                // A generic point against a generic plane, at a scale where the products neither
                // underflow nor overflow: the height is far from rounding level.
                EXPECT_EQ(sign_of(height), -expected) << n;
            }
            zeros += expected == 0;
        }
        // Three corners at once (AVX2 where the processor has it): the same signs and the same
        // heights, bit for bit, each corner in each lane.
        for (const std::array<Vec3, 3>& t :
             {std::array<Vec3, 3>{xs[0], xs[1], xs[2]}, std::array<Vec3, 3>{xs[3], xs[0], xs[1]},
              std::array<Vec3, 3>{xs[2], xs[3], xs[0]}}) {
            int sign[3];
            double height[3];
            side.corners(t, sign, height);
            for (int i = 0; i < 3; ++i) {
                double h = 0.0;
                ASSERT_EQ(sign[i], side(t[i], h)) << n << " " << i;
                ASSERT_EQ(std::bit_cast<std::uint64_t>(height[i]), std::bit_cast<std::uint64_t>(h))
                    << n << " " << i;
            }
        }
    }
    EXPECT_GE(zeros, 2000);
}

TEST(Predicates, ExactFallbackOnlyWhenNeeded) {
    const unsigned long long before = detail::exact_fallback_count();
    for (int i = 0; i < 100; ++i) {
        (void)orient2d(0, 0, 1, 0, 0.3, 1 + i);
        (void)orient3d(Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0.2, 0.1, 1.0 + i});
        // Exactly degenerate but decided by the filter: all products are exactly zero.
        (void)orient3d(Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0.2, 0.1, 0});
    }
    EXPECT_EQ(detail::exact_fallback_count(), before);
    EXPECT_EQ(orient2d(0.5 + 0x1p-53, 0.5, 12, 12, 24, 24), -1);
    EXPECT_GT(detail::exact_fallback_count(), before);
}

}  // namespace
}  // namespace proxima
