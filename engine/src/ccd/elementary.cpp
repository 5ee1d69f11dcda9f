// Elementary CCD tests (vertex-face, edge-edge): inclusion-based root finding over the
// (t, u, v) domain, earliest time first, with a rigorous bound on floating-point rounding.
//
// The problem. Every point moves linearly, x(t) = (1 - t) x_t0 + t x_t1, t in [0, 1].
//   vertex_face: F(t, u, v) = p(t) - a(t) - u (b(t) - a(t)) - v (c(t) - a(t)),
//                u, v >= 0, u + v <= 1   (the point of the triangle a + u (b - a) + v (c - a))
//   edge_edge:   F(t, u, v) = a0(t) + u (a1(t) - a0(t)) - b0(t) - v (b1(t) - b0(t)),
//                u, v in [0, 1]
// The primitives touch (come within distance d) at time t iff F(t, u, v) = 0 (|F| <= d) for some
// (u, v) in the domain. Each coordinate F_k is multilinear in (t, u, v) (no t^2, u^2, v^2 or u v
// term), so over a region B = [t0,t1]x[u0,u1]x[v0,v1] it lies between the minimum and maximum of
// its values at B's 8 corners.
//
// The solver. Regions wait in a queue grouped by t0: the group with the smallest t0 is served
// first, last in first out within a group (depth first among regions that start at the same
// time). A region is examined by computing F at its 8 corners; with e_k the rounding bound below,
// it is excluded when for some axis k the interval [min_k - e_k, max_k + e_k] misses [-d, d]: then
// no point of B has |F_k| <= d, exactly. A region of the vertex-face domain with u0 + v0 > 1 lies
// outside the triangle and is dropped (u0, v0 are dyadic bisection points, so the sum is exact).
// It is also excluded along a few directions: fixed ones per test (see add_direction) and the
// region normal of its own time interval (see RegionNormal).
// The region served is accepted as a contact when its time interval is at most toi_tolerance wide
// and a point of it at t1 is within the band on every axis (see "Point certificate"), or when on
// every axis [min_k, max_k] lies within [-(d + tol + e_k), d + tol + e_k] (every point of it is
// within d + tol + 2 e_k of touching on every axis) and its time interval is at most
// toi_tolerance wide (such a region that is wider is bisected in t), or when no side of it may be
// split any more (all widths at the 2^-50 floor).
// Otherwise it is bisected along the parameter most likely to let a half be excluded: for each
// axis not yet within the tolerance, the slack is how far its range reaches past the far end of
// [-d - e, d + e] (a half is excluded once a split removes more than that from one side), and
// the score of t, u or v is the largest ratio of its contribution to the axis' range (the largest
// corner difference along it) to that slack (the region normal's range counts too, see examine).
// Splitting by raw contribution instead makes degenerate queries (parallel or collinear edges, a
// triangle collapsed to a segment, where the contacts form a curve) refine the whole curve before
// time advances: tens of thousands of regions where this rule needs about a hundred. Both halves
// are examined when created; the survivors are queued (the lower one, which the queue would serve
// next, is served directly). Earliest time: the region served always has the smallest t0 of all
// queued regions, and the region holding the true earliest contact (t*, u*, v*) is never excluded,
// so when a region is accepted its t0 <= t*: reporting toi = t0 is never late. When `max_boxes`
// regions have been examined the test stops and reports a contact at the t0 of the region being
// refined (no later than any region not yet excluded), flagged `capped`. Every examined region
// costs the same bounded work (8 corners), so the work per test is bounded by max_boxes.
//
// Rounding (u = 2^-53, the unit roundoff; all t, u, v are dyadic in [0, 1] with at most 50
// fractional bits, so 1 - t is exact). Per axis k let M be the largest |coordinate| of the 8
// input points on that axis. The solver precomputes, at both frames, the three differences
//   vertex_face: g0 = p - a, gu = b - a, gv = c - a;   edge_edge: g0 = a0 - b0, gu = a0 - a1,
//   gv = b1 - b0    (so that F = g0(t) - u gu(t) - v gv(t) in both cases)
// and at a corner computes
//   g(t) = fl(fl((1 - t) G_t0) + fl(t G_t1))  for each of g0, gu, gv, then
//   F = fl(fl(g0 - fl(u gu)) - fl(v gv)).
// Error of each step against the same formula in exact arithmetic on the double inputs
// (first order in u; the O(u^2 M) terms are a few hundred u^2 M, far inside the slack below):
//   G = fl(x - y):                  |x - y| <= 2M,          error <= 2uM
//   g(t):  inputs 2uM ((1-t) + t = 1), products u(1-t)|G_t0| + u t|G_t1| <= 2uM,
//          sum u |g| <= 2uM                                   error <= 6uM,  |g| <= 2M
//   fl(u gu): 6uM + u 2M                                      error <= 8uM,  |.| <= 2M
//   h = fl(g0 - u gu): 6uM + 8uM + u 4M                       error <= 18uM, |h| <= 4M
//   F = fl(h - v gv): 18uM + 8uM + u 6M                       error <= 32uM
// (with a fused multiply-add the compiler only removes roundings, so the bound still holds).
// Input rounding: the exact inputs (e.g. rationals) differ from the doubles by at most 1 ulp
// <= 2uM each; F is a linear combination of the 8 input points with weights whose absolute values
// sum to 1 + |1 - u - v| + u + v <= 4 (vf; corners may have u + v up to 2) or
// |1 - u| + u + |1 - v| + v = 2 (ee), so this adds at most 8uM. In all
//   |computed F_k - exact F_k| <= 40 u M < e_k := 64 u M + 2^-1060 = M 2^-47 + 2^-1060,
// where the absolute term covers underflow (each operation adds at most 2^-1075 absolutely when its
// result is subnormal, inputs are within 2^-1074; a few dozen such terms stay below 2^-1068).
// Overflow is excluded by scaling: an axis with M > 2^1000 is multiplied by 2^-64 (exact except
// for values that become subnormal, whose error is covered by the absolute term) together with
// d (rounded up) and tol. The exclusion tests compare fl(max + e) < -d and fl(min - e) > d:
// rounding to nearest is monotone and -d, d are doubles, so each holds only if it holds exactly.
// tests/engine/ccd/test_ccd_elementary.cpp checks the bound against exact GMP evaluation.
//
// The inclusion test uses |F_k| <= d on each axis (a box around the sphere of radius d), so with
// d > 0 contacts up to sqrt(3) d apart may be reported: conservative, never a miss.

#include "proxima/ccd/elementary.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "cpu_features.hpp"

namespace proxima::ccd {

namespace {

constexpr double ERROR_SCALE = 0x1p-47;       // 64 u
constexpr double ERROR_ABSOLUTE = 0x1p-1060;  // underflow
constexpr double HUGE_COORDINATE = 0x1p1000;  // axes beyond this are scaled by 2^-64
constexpr double HUGE_SCALE = 0x1p-64;
constexpr double MIN_WIDTH = 0x1p-50;  // no side of a region is bisected below this width

// The solver's inner functions are forced inline so that the copy of the solver compiled for AVX2
// (solve_avx2 below) gets its own copies of them in its instruction set.
#if defined(__GNUC__) || defined(__clang__)
#define PROXIMA_CCD_INLINE inline __attribute__((always_inline))
#else
#define PROXIMA_CCD_INLINE inline
#endif

// One test, with the coordinates arranged per axis.
struct Problem {
    bool vertex_face = true;
    // g[k][q][end]: q = 0: g0, 1: gu, 2: gv; end 0: at t = 0, 1: at t = 1.
    double g[3][3][2] = {};
    double error[3] = {};    // e_k
    double reject[3] = {};   // d_k: exclusion threshold
    double accept[3] = {};   // d_k + tol_k + e_k: acceptance threshold
    double toi_width = 0.0;  // a region is accepted only once t1 - t0 <= this (toi_tolerance)
    // Direction exclusion (see "Direction exclusion" below): a region is also excluded when
    // F . w[i] lies beyond w_thr[i] (or below -w_thr[i]) at all 8 corners.
    int directions = 0;
    double w[4][3] = {};
    double w_thr[4] = {};
    // The region normal (see "Region normal" below): only when no axis is scaled (M_k <= 2^200).
    bool region_normal = false;
    double largest[3] = {};  // M_k
    bool valid = false;
};

struct Region {
    double t0, t1, u0, u1, v0, v1;
    std::uint32_t depth;
    std::uint8_t split;  // 0: t, 1: u, 2: v, 3: accepted
};

// Regions waiting to be refined, grouped by t0. The group with the smallest t0 is served first,
// last in first out within a group (depth first among regions that start at the same time).
class RegionQueue {
  public:
    bool empty() const { return m_active == 0; }

    void clear() {
        for (std::size_t i = 0; i < m_active; ++i) {
            m_groups[i].regions.clear();
        }
        m_active = 0;
    }

    void push(const Region& r) {
        // m_groups[0, m_active) are sorted by decreasing t0: the last has the smallest.
        std::size_t i = m_active;
        while (i > 0 && m_groups[i - 1].t0 < r.t0) {
            --i;
        }
        if (i > 0 && m_groups[i - 1].t0 == r.t0) {
            m_groups[i - 1].regions.push_back(r);
            return;
        }
        if (m_active == m_groups.size()) {
            m_groups.emplace_back();
        }
        // The spare (empty) group at m_active moves to position i.
        for (std::size_t j = m_active; j > i; --j) {
            std::swap(m_groups[j], m_groups[j - 1]);
        }
        m_groups[i].t0 = r.t0;
        m_groups[i].regions.push_back(r);
        ++m_active;
    }

    Region pop() {
        auto& group = m_groups[m_active - 1];
        const Region r = group.regions.back();
        group.regions.pop_back();
        if (group.regions.empty()) {
            --m_active;
        }
        return r;
    }

  private:
    struct Group {
        double t0 = 0.0;
        std::vector<Region> regions;
    };
    std::vector<Group> m_groups;
    std::size_t m_active = 0;
};

// Multiply by 2^-64 rounding up (for the distance threshold of a scaled axis).
double scale_up(double x) {
    const double s = x * HUGE_SCALE;
    return s * 0x1p64 < x ? std::nextafter(s, std::numeric_limits<double>::infinity()) : s;
}

// Direction exclusion. An accepted region holds a point with exact |F_k| <= a_k :=
// d + tol + 2^-45 M_k + 2^-1059 on every axis (see the prefilter's comment below: d + tol + 2 e_k
// at the certificate's point or the corner of a region within the band, d + 2^-45 M_k at the width
// floor), so |F . w| <= sum |w_k| a_k there. F . w is multilinear in (t, u, v) like each F_k, so
// over a region it lies between its values at the 8 corners; if those all exceed sum |w_k| a_k (or
// all lie below its negative), no region inside is ever accepted, and excluding it cannot change
// which accepted region has the smallest t0. The computed corner value fl(w_0 f_0 + w_1 f_1 + w_2
// f_2), with |w_k| <= 1, each f_k within 40 u M_k of the exact F_k and |f_k| <= 6 M_k (+ rounding),
// errs by at most sum |w_k| (40 + 19) u M_k plus a few 2^-1075 of underflow: below 2^-47 sum |w_k|
// M_k + 2^-1070. The threshold w_thr = sum |w_k| (d + tol + 2^-44 M_k) (1 + 2^-40) + 2^-1000 covers
// a_k, that error, and its own roundings (relative < 8 u). Only when no axis is scaled (M_k <=
// 2^200, so products cannot overflow) and w is finite and nonzero; w is divided by its largest
// |component| so that |w_k| <= 1. Which w is tried changes only how many regions are examined: the
// in-plane normals of the triangle's sides (vf) or of the two edges (ee) at mid-frame. (The
// normal of the triangle or the edges' common normal at mid-frame was one too, until the region
// normal, tested at each region's own time with the tighter threshold d, made it redundant: the
// solver was 4-7 % faster on the real frames' tests without it, with 0-3 % more regions.)
void add_direction(Problem& pr, const Vec3& n, const double largest[3], double d, double tol) {
    const double big = std::max({std::abs(n.x), std::abs(n.y), std::abs(n.z)});
    if (!(big > 0.0) || !std::isfinite(big)) {
        return;
    }
    const double w[3] = {n.x / big, n.y / big, n.z / big};
    double thr = 0.0;
    for (int k = 0; k < 3; ++k) {
        thr += std::abs(w[k]) * (d + tol + 0x1p-44 * largest[k]);
    }
    thr = thr * (1.0 + 0x1p-40) + 0x1p-1000;
    if (!(thr < std::numeric_limits<double>::infinity())) {
        return;
    }
    for (int k = 0; k < 3; ++k) {
        pr.w[pr.directions][k] = w[k];
    }
    pr.w_thr[pr.directions] = thr;
    ++pr.directions;
}

void add_directions(Problem& pr, const CcdPoints& points, const double largest[3], double d,
                    double tol) {
    for (int k = 0; k < 3; ++k) {
        if (!(largest[k] <= 0x1p200)) {
            return;
        }
    }
    Vec3 mid[4];
    for (std::size_t j = 0; j < 4; ++j) {
        mid[j] = points[j] + points[j + 4];  // twice the mid-frame point: only a direction
    }
    if (pr.vertex_face) {
        const Vec3 n = cross(mid[2] - mid[1], mid[3] - mid[1]);
        for (int j = 0; j < 3; ++j) {
            add_direction(pr, cross(n, mid[1 + (j + 1) % 3] - mid[1 + j]), largest, d, tol);
        }
    } else {
        const Vec3 da = mid[1] - mid[0];
        const Vec3 db = mid[3] - mid[2];
        const Vec3 n = cross(da, db);
        add_direction(pr, cross(n, da), largest, d, tol);
        add_direction(pr, cross(n, db), largest, d, tol);
    }
}

// `directions`: also the exclusion directions (ElementaryOptions::direction_exclusion).
Problem make_problem(CcdKind kind, const CcdPoints& points, double d, double tol, bool directions) {
    Problem pr;
    double largest[3] = {};  // M_k
    pr.vertex_face = kind == CcdKind::vertex_face;
    // Differences (x - y) of point indices within one frame: g0, gu, gv.
    static constexpr int VF[3][2] = {{0, 1}, {2, 1}, {3, 1}};
    static constexpr int EE[3][2] = {{0, 2}, {0, 1}, {3, 2}};
    const auto& pairs = pr.vertex_face ? VF : EE;
    for (int k = 0; k < 3; ++k) {
        double m = 0.0;
        for (const auto& p : points) {
            const double c = p[k];
            if (!std::isfinite(c)) {
                return pr;  // invalid
            }
            m = std::max(m, std::abs(c));
        }
        double scale = 1.0;
        double dk = d;
        double tk = tol;
        if (m > HUGE_COORDINATE) {
            scale = HUGE_SCALE;
            m *= HUGE_SCALE;
            dk = scale_up(d);
            tk = tol * HUGE_SCALE;
        }
        for (int q = 0; q < 3; ++q) {
            for (int end = 0; end < 2; ++end) {
                const std::size_t far = end == 0 ? 0 : 4;
                const double x = points[static_cast<std::size_t>(pairs[q][0]) + far][k];
                const double y = points[static_cast<std::size_t>(pairs[q][1]) + far][k];
                pr.g[k][q][end] = x * scale - y * scale;
            }
        }
        pr.error[k] = m * ERROR_SCALE + ERROR_ABSOLUTE;
        pr.reject[k] = dk;
        pr.accept[k] = dk + tk + pr.error[k];
        largest[k] = m;
        pr.largest[k] = m;
    }
    pr.region_normal = largest[0] <= 0x1p200 && largest[1] <= 0x1p200 && largest[2] <= 0x1p200;
    pr.valid = true;
    if (directions) {
        add_directions(pr, points, largest, d, tol);
    }
    return pr;
}

// The 8 corner values of one axis (or one direction) as four pairs: pair 2 ti + ui holds the
// corners (ti, ui, vi = 0) and (ti, ui, vi = 1). GCC's and Clang's vector extensions: on baseline
// x86-64 each operation on a pair is one SSE2 instruction, and every lane is rounded exactly as
// the scalar expression it replaces (IEEE operations on doubles, no fused multiply-add: baseline
// x86-64 has none), so the values, and the rounding bound above, are those of the scalar formulas.
using Pair = double __attribute__((vector_size(16)));
using PairBits = std::int64_t __attribute__((vector_size(16)));
struct Corners {
    Pair q[4];
    double operator[](int c) const { return q[c >> 1][c & 1]; }  // corner 4 ti + 2 ui + vi
};

PROXIMA_CCD_INLINE Pair pair_min(const Pair& a, const Pair& b) {
    return a < b ? a : b;
}
PROXIMA_CCD_INLINE Pair pair_max(const Pair& a, const Pair& b) {
    return a > b ? a : b;
}
PROXIMA_CCD_INLINE Pair pair_abs(const Pair& a) {  // as std::abs: the sign bit cleared
    constexpr std::int64_t SIGN_OFF = std::numeric_limits<std::int64_t>::max();
    const PairBits mask = {SIGN_OFF, SIGN_OFF};
    return reinterpret_cast<Pair>(reinterpret_cast<PairBits>(a) & mask);
}

PROXIMA_CCD_INLINE double lowest(const Corners& f) {
    const Pair m = pair_min(pair_min(f.q[0], f.q[1]), pair_min(f.q[2], f.q[3]));
    return std::min(m[0], m[1]);
}
PROXIMA_CCD_INLINE double highest(const Corners& f) {
    const Pair m = pair_max(pair_max(f.q[0], f.q[1]), pair_max(f.q[2], f.q[3]));
    return std::max(m[0], m[1]);
}

// g0, gu, gv of every axis at one time t: g(t) = fl(fl((1 - t) G_t0) + fl(t G_t1)). Computed once
// per split for both halves (both halves of a u or v split have their parent's times; a t split's
// share the middle).
struct AtTime {
    double g[3][3];
};
PROXIMA_CCD_INLINE void at_time(const Problem& pr, double tt, AtTime& a) {
    const double omt = 1.0 - tt;  // exact: tt is dyadic in [0, 1]
    for (int k = 0; k < 3; ++k) {
        for (int q = 0; q < 3; ++q) {
            a.g[k][q] = omt * pr.g[k][q][0] + tt * pr.g[k][q][1];
        }
    }
}

// Region normal. Fixed directions lose their grip near a contact: the primitives rotate, so F . w
// still varies with u and v unless u and v are narrowed as far as t is, and a traced cloth hit
// needed ~56 bisections (u ~2^-19, v ~2^-17, t ~2^-20) to be excluded up to its contact and
// accepted. So every region is also tested along the normal of the primitives at the middle of its
// own time interval: w = gu(tm) x gv(tm) (the triangle's normal for vf, the edges' common normal
// for ee), from the sums gu(t0) + gu(t1), gv(t0) + gv(t1) (any w is valid; this one is orthogonal
// to the directions u and v move F along at tm, so F . w barely depends on u and v across a narrow
// time interval and the region is excluded by splitting t alone). w is divided by its largest
// |component| (|w_k| <= 1). The region is excluded when F . w > thr at all 8 corners (or < -thr)
// with thr = sum |w_k| (d + 2^-44 M_k) (1 + 2^-40) + 2^-1000: the computed corner value errs by
// less than 2^-47 sum |w_k| M_k + 2^-1070 (see the fixed directions below), and |F . w| <=
// |F|_inf |w|_1 <= d |w|_1 at a point within d, so such a region holds no point within d of
// touching, and F . w is multilinear, so the corners bound it. Unlike the fixed directions it does
// not leave room for d + tol: a region whose points are all within the band but none within d is
// excluded too (a resting pair inside the band is refined towards its true contact, or found
// apart). Only when no axis is scaled (M_k <= 2^200: no product overflows) and w is finite and
// nonzero.
struct RegionNormal {
    bool valid = false;
    double w[3] = {};
    double thr = 0.0;
};
PROXIMA_CCD_INLINE void region_normal(const Problem& pr, const AtTime& at0, const AtTime& at1,
                                      RegionNormal& rn) {
    rn.valid = false;
    if (!pr.region_normal) {
        return;
    }
    double gu[3];
    double gv[3];
    for (int k = 0; k < 3; ++k) {
        gu[k] = at0.g[k][1] + at1.g[k][1];
        gv[k] = at0.g[k][2] + at1.g[k][2];
    }
    const double n[3] = {gu[1] * gv[2] - gu[2] * gv[1], gu[2] * gv[0] - gu[0] * gv[2],
                         gu[0] * gv[1] - gu[1] * gv[0]};
    const double big = std::max({std::abs(n[0]), std::abs(n[1]), std::abs(n[2])});
    if (!(big > 0.0) || !(big < std::numeric_limits<double>::infinity())) {
        return;
    }
    double thr = 0.0;
    for (int k = 0; k < 3; ++k) {
        rn.w[k] = n[k] / big;
        thr += std::abs(rn.w[k]) * (pr.reject[k] + 0x1p-44 * pr.largest[k]);
    }
    rn.thr = thr * (1.0 + 0x1p-40) + 0x1p-1000;
    rn.valid = true;
}

// F_k at the 8 corners, from g0, gu, gv at the region's two times: F = fl(fl(g0 - fl(u gu)) -
// fl(v gv)) in every lane.
PROXIMA_CCD_INLINE void corners_axis(const AtTime& at0, const AtTime& at1, int k, const double u[2],
                                     const Pair& v, Corners& fk) {
    for (int ti = 0; ti < 2; ++ti) {
        const double* g = (ti == 0 ? at0 : at1).g[k];
        const Pair gvv = {g[2], g[2]};
        for (int ui = 0; ui < 2; ++ui) {
            const double h = g[0] - u[ui] * g[1];
            const Pair hh = {h, h};
            fk.q[2 * ti + ui] = hh - v * gvv;
        }
    }
}

// F at the 8 corners of r: f[k][4 ti + 2 ui + vi].
inline void corners(const Problem& pr, const double t[2], const double u[2], const double v[2],
                    double f[3][8]) {
    const Pair vv = {v[0], v[1]};
    AtTime at0;
    AtTime at1;
    at_time(pr, t[0], at0);
    at_time(pr, t[1], at1);
    for (int k = 0; k < 3; ++k) {
        Corners fk;
        corners_axis(at0, at1, k, u, vv, fk);
        for (int c = 0; c < 8; ++c) {
            f[k][c] = fk[c];
        }
    }
}

// F . w at the 8 corners from the axes' corner values.
PROXIMA_CCD_INLINE void corners_along(const Corners f[3], const double w[3], Corners& x) {
    const Pair w0 = {w[0], w[0]};
    const Pair w1 = {w[1], w[1]};
    const Pair w2 = {w[2], w[2]};
    for (int j = 0; j < 4; ++j) {
        x.q[j] = w0 * f[0].q[j] + w1 * f[1].q[j] + w2 * f[2].q[j];
    }
}

// Split scores of one axis or direction with corner values f, range [lo, hi] and exclusion
// window [-window, window]: how many times the contribution of t, u, v to the range (the largest
// corner difference along it) exceeds the slack (how far the range reaches past the far end of the
// window, plus `pad`; a half is excluded once a split removes more than that from one side).
PROXIMA_CCD_INLINE void add_scores(const Corners& f, double lo, double hi, double window,
                                   double pad, double& dt, double& du, double& dv) {
    const double inv_slack = 1.0 / (std::min(hi + window, window - lo) + pad);
    // The largest change along t (corners c and c + 4), u (c, c + 2), v (c, c + 1).
    const Pair mt = pair_max(pair_abs(f.q[2] - f.q[0]), pair_abs(f.q[3] - f.q[1]));
    const Pair mu = pair_max(pair_abs(f.q[1] - f.q[0]), pair_abs(f.q[3] - f.q[2]));
    Pair mv = pair_abs(f.q[0] - __builtin_shufflevector(f.q[0], f.q[0], 1, 0));
    for (int j = 1; j < 4; ++j) {
        mv = pair_max(mv, pair_abs(f.q[j] - __builtin_shufflevector(f.q[j], f.q[j], 1, 0)));
    }
    dt = std::max(dt, std::max(mt[0], mt[1]) * inv_slack);
    du = std::max(du, std::max(mu[0], mu[1]) * inv_slack);
    dv = std::max(dv, mv[0] * inv_slack);  // both lanes hold the same magnitudes
}

// Examines r: false when it is excluded; otherwise sets r.split (3 when accepted).
// at0, at1: g0, gu, gv at r.t0 and r.t1 (at_time); rn: the region normal of [r.t0, r.t1].
PROXIMA_CCD_INLINE bool examine(const Problem& pr, Region& r, const AtTime& at0, const AtTime& at1,
                                const RegionNormal& rn) {
    const double u[2] = {r.u0, r.u1};
    const Pair v = {r.v0, r.v1};
    // First the exclusion test, axis by axis, computing an axis' corners only when the axes
    // before it did not exclude the region (the values are the same either way).
    Corners f[3];
    double los[3];
    double his[3];
    for (int k = 0; k < 3; ++k) {
        corners_axis(at0, at1, k, u, v, f[k]);
        const double lo = lowest(f[k]);
        const double hi = highest(f[k]);
        // Rounding is monotone and the thresholds are doubles: see the file comment.
        if (hi + pr.error[k] < -pr.reject[k] || lo - pr.error[k] > pr.reject[k]) {
            return false;
        }
        los[k] = lo;
        his[k] = hi;
    }
    // Then the direction exclusion (see add_direction): w_0 f_0 + w_1 f_1 + w_2 f_2 at each
    // corner. A region within the band on every axis never passes it, but such regions are rare:
    // no shortcut for them.
    for (int i = 0; i < pr.directions; ++i) {
        Corners x;
        corners_along(f, pr.w[i], x);
        if (lowest(x) > pr.w_thr[i] || highest(x) < -pr.w_thr[i]) {
            return false;
        }
    }
    // And the region normal (see RegionNormal).
    Corners nx{};
    double n_lo = 0.0;
    double n_hi = 0.0;
    if (rn.valid) {
        corners_along(f, rn.w, nx);
        n_lo = lowest(nx);
        n_hi = highest(nx);
        if (n_lo > rn.thr || n_hi < -rn.thr) {
            return false;
        }
    }
    bool accepted = true;
    // Split scores of the axes not yet within the tolerance, and of the region normal.
    double dt = 0.0;
    double du = 0.0;
    double dv = 0.0;
    for (int k = 0; k < 3; ++k) {
        if (his[k] <= pr.accept[k] && los[k] >= -pr.accept[k]) {
            continue;  // this axis is within the tolerance
        }
        accepted = false;
        add_scores(f[k], los[k], his[k], pr.reject[k] + pr.error[k], pr.error[k], dt, du, dv);
    }
    if (accepted) {
        // Within the tolerance on every axis: a contact once its time interval is narrow enough
        // (toi_tolerance), else split in t until it is (or it reaches the width floor), so that
        // the toi is within toi_tolerance of the earliest time the band is reached.
        r.split = r.t1 - r.t0 > pr.toi_width && r.t1 - r.t0 > MIN_WIDTH ? 0 : 3;
        return true;
    }
    if (rn.valid && std::max(n_hi, -n_lo) > 16.0 * rn.thr) {
        // Near a contact F . w changes with t and barely with u and v: its scores ask for t splits
        // where the axes' ask for u and v. Counted only where t dominates them (by 2x) and the
        // range reaches well past the threshold; otherwise (primitives moving within one plane,
        // F . w near 0 throughout) its slack is tiny and its scores would ask for splits that
        // never exclude anything: 30 pairs of rod-twist went from < 50 to thousands of regions.
        double nt = 0.0;
        double nu = 0.0;
        double nv = 0.0;
        add_scores(nx, n_lo, n_hi, rn.thr, 0x1p-1000, nt, nu, nv);
        if (nt >= 2.0 * (nu + nv)) {
            dt = std::max(dt, nt);
            du = std::max(du, nu);
            dv = std::max(dv, nv);
        }
    }
    // Bisect the parameter most likely to exclude a half (the largest score), among those still
    // wider than the floor; a region that may not be split any more is accepted.
    if (r.t1 - r.t0 <= MIN_WIDTH) {
        dt = -1.0;
    }
    if (r.u1 - r.u0 <= MIN_WIDTH) {
        du = -1.0;
    }
    if (r.v1 - r.v0 <= MIN_WIDTH) {
        dv = -1.0;
    }
    if (dt < 0.0 && du < 0.0 && dv < 0.0) {
        r.split = 3;
    } else if (dt >= du && dt >= dv) {
        r.split = 0;
    } else if (du >= dv) {
        r.split = 1;
    } else {
        r.split = 2;
    }
    return true;
}

// Point certificate. The region served has the smallest t0 of all regions not excluded, so its t0
// is never later than the earliest contact; it may be reported as soon as the primitives are
// shown to be within the band somewhere in it. When its time interval is at most toi_tolerance
// wide, the solver looks for one point (t1, u, v) of the region with computed |F_k| <= d + tol +
// e_k on every axis (exact |F_k| <= d + tol + 2 e_k): the (u, v) nearest to touching at t1 (least
// squares on g0 - u gu - v gv), clamped into the region, else the nearest point on each side of
// the region's (u, v) rectangle (and on u + v = 1 for vf). F is computed at it by the corner
// formula, whose rounding bound holds for any u, v in [0, 1] (only t needs to be dyadic, for 1 - t
// to be exact). Without it a region had to lie within the band as a whole, so u and v were
// bisected until their width times the primitives' size was below tol: ~2^-19 on cloth frames.

// u + v <= 1 exactly (u, v in [0, 1]; the rounding error of the sum by Knuth's two-sum).
PROXIMA_CCD_INLINE bool sum_at_most_one(double u, double v) {
    const double sum = u + v;
    const double vv = sum - u;
    const double err = (u - (sum - vv)) + (v - vv);
    return sum < 1.0 || (sum == 1.0 && err <= 0.0);
}

// The point (t1, u, v) moved into r (and, for vf, into the triangle); true when it is within the
// band on every axis. a: g0, gu, gv at r.t1.
PROXIMA_CCD_INLINE bool within_band_at(const Problem& pr, const AtTime& a, const Region& r,
                                       double u, double v) {
    u = std::clamp(u, r.u0, r.u1);
    v = std::clamp(v, r.v0, r.v1);
    if (!(u >= r.u0 && u <= r.u1 && v >= r.v0 && v <= r.v1)) {
        return false;  // NaN
    }
    if (pr.vertex_face && !sum_at_most_one(u, v)) {
        // r.u0 + r.v0 <= 1 (other regions are dropped); 1 - u may round up: step down.
        v = std::max(std::min(v, 1.0 - u), r.v0);
        u = std::max(std::min(u, 1.0 - v), r.u0);
        for (int step = 0; step < 4 && !sum_at_most_one(u, v); ++step) {
            if (v > r.v0) {
                v = std::max(std::nextafter(v, 0.0), r.v0);
            } else {
                u = std::max(std::nextafter(u, 0.0), r.u0);
            }
        }
        if (!sum_at_most_one(u, v)) {
            return false;
        }
    }
    for (int k = 0; k < 3; ++k) {
        const double h = a.g[k][0] - u * a.g[k][1];
        const double fk = h - v * a.g[k][2];
        if (!(std::abs(fk) <= pr.accept[k])) {
            return false;
        }
    }
    return true;
}

// The s minimizing |h - s gd| (0 when gd = 0).
PROXIMA_CCD_INLINE double line_minimum(const double h[3], const double gd[3]) {
    const double num = h[0] * gd[0] + h[1] * gd[1] + h[2] * gd[2];
    const double den = gd[0] * gd[0] + gd[1] * gd[1] + gd[2] * gd[2];
    return den > 0.0 ? num / den : 0.0;
}

PROXIMA_CCD_INLINE bool certified(const Problem& pr, const AtTime& a, const Region& r) {
    double g0[3];
    double gu[3];
    double gv[3];
    for (int k = 0; k < 3; ++k) {
        g0[k] = a.g[k][0];
        gu[k] = a.g[k][1];
        gv[k] = a.g[k][2];
    }
    const double a00 = gu[0] * gu[0] + gu[1] * gu[1] + gu[2] * gu[2];
    const double a01 = gu[0] * gv[0] + gu[1] * gv[1] + gu[2] * gv[2];
    const double a11 = gv[0] * gv[0] + gv[1] * gv[1] + gv[2] * gv[2];
    const double b0 = g0[0] * gu[0] + g0[1] * gu[1] + g0[2] * gu[2];
    const double b1 = g0[0] * gv[0] + g0[1] * gv[1] + g0[2] * gv[2];
    const double det = a00 * a11 - a01 * a01;
    if (det > 0x1p-80 * a00 * a11) {
        const double u = (b0 * a11 - b1 * a01) / det;
        const double v = (a00 * b1 - a01 * b0) / det;
        if (within_band_at(pr, a, r, u, v)) {
            return true;
        }
        if (u >= r.u0 && u <= r.u1 && v >= r.v0 && v <= r.v1 && (!pr.vertex_face || u + v <= 1.0)) {
            return false;  // the nearest point is inside r, and not within the band
        }
    }
    double h[3];
    for (const double u : {r.u0, r.u1}) {
        for (int k = 0; k < 3; ++k) {
            h[k] = g0[k] - u * gu[k];
        }
        if (within_band_at(pr, a, r, u, line_minimum(h, gv))) {
            return true;
        }
    }
    for (const double v : {r.v0, r.v1}) {
        for (int k = 0; k < 3; ++k) {
            h[k] = g0[k] - v * gv[k];
        }
        if (within_band_at(pr, a, r, line_minimum(h, gu), v)) {
            return true;
        }
    }
    if (pr.vertex_face && r.u1 + r.v1 > 1.0) {
        // u + v = 1: F = (g0 - gv) - u (gu - gv).
        double hd[3];
        for (int k = 0; k < 3; ++k) {
            h[k] = g0[k] - gv[k];
            hd[k] = gu[k] - gv[k];
        }
        const double u = line_minimum(h, hd);
        if (within_band_at(pr, a, r, u, 1.0 - u)) {
            return true;
        }
    }
    return false;
}

PROXIMA_CCD_INLINE ElementaryResult solve_body(CcdKind kind, const CcdPoints& points,
                                               const ElementaryOptions& options) {
    ElementaryResult result;
    double d = options.min_distance;
    if (std::isnan(d)) {
        result.hit = result.capped = true;
        result.toi = 0.0;
        return result;
    }
    d = std::max(d, 0.0);
    double tol = options.tolerance;
    if (!(tol > 0.0)) {
        tol = 0.0;  // NaN or <= 0: refine to the width floor
    }
    Problem pr = make_problem(kind, points, d, tol, options.direction_exclusion);
    pr.toi_width = options.toi_tolerance > 0.0 ? options.toi_tolerance : 0.0;  // NaN: the floor
    if (!pr.valid) {
        // Non-finite coordinates: nothing can be excluded.
        result.hit = result.capped = true;
        result.toi = 0.0;
        return result;
    }
    const std::uint32_t cap = options.max_boxes;
    if (cap == 0) {
        result.hit = result.capped = true;
        result.toi = 0.0;
        return result;
    }
    Region root{0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0, 0};
    result.boxes = 1;
    AtTime at_lo;
    AtTime at_mid;
    AtTime at_hi;
    at_time(pr, 0.0, at_lo);
    at_time(pr, 1.0, at_hi);
    RegionNormal normals[2];
    region_normal(pr, at_lo, at_hi, normals[0]);
    if (!examine(pr, root, at_lo, at_hi, normals[0])) {
        return result;
    }
    thread_local RegionQueue queue;
    queue.clear();
    // The lower half of a split keeps its parent's t0, the smallest of all waiting regions, and is
    // queued last: the queue would serve it next, so it is kept here instead of being pushed and
    // popped (`next`). The same regions in the same order.
    Region next = root;
    bool have_next = true;
    while (have_next || !queue.empty()) {
        const Region r = have_next ? next : queue.pop();
        have_next = false;
        if (r.split == 3) {
            result.hit = true;
            result.toi = r.t0;
            return result;
        }
        at_time(pr, r.t0, at_lo);
        at_time(pr, r.t1, at_hi);
        if (r.t1 - r.t0 <= pr.toi_width && certified(pr, at_hi, r)) {
            result.hit = true;
            result.toi = r.t0;
            return result;
        }
        Region halves[2] = {r, r};
        halves[0].depth = halves[1].depth = r.depth + 1;
        const AtTime* times[2][2] = {{&at_lo, &at_hi}, {&at_lo, &at_hi}};
        const RegionNormal* rn[2] = {&normals[0], &normals[0]};
        if (r.split == 0) {
            halves[0].t1 = halves[1].t0 = 0.5 * (r.t0 + r.t1);
            at_time(pr, halves[0].t1, at_mid);
            times[0][1] = &at_mid;
            times[1][0] = &at_mid;
            region_normal(pr, at_lo, at_mid, normals[0]);
            region_normal(pr, at_mid, at_hi, normals[1]);
            rn[1] = &normals[1];
        } else {
            region_normal(pr, at_lo, at_hi, normals[0]);
            if (r.split == 1) {
                halves[0].u1 = halves[1].u0 = 0.5 * (r.u0 + r.u1);
            } else {
                halves[0].v1 = halves[1].v0 = 0.5 * (r.v0 + r.v1);
            }
        }
        // The upper half first, so that the lower one is served first among equal t0.
        for (int i = 1; i >= 0; --i) {
            Region& h = halves[i];
            if (pr.vertex_face && h.u0 + h.v0 > 1.0) {
                continue;  // outside the triangle (exact: dyadic)
            }
            if (result.boxes >= cap) {
                // Every region not excluded has t0 >= r.t0.
                result.hit = result.capped = true;
                result.toi = r.t0;
                queue.clear();
                return result;
            }
            ++result.boxes;
            if (examine(pr, h, *times[i][0], *times[i][1], *rn[i])) {
                if (i == 0) {
                    next = h;
                    have_next = true;
                } else {
                    queue.push(h);
                }
            }
        }
    }
    queue.clear();
    return result;
}

// The solver compiled for baseline x86-64 (SSE2), and, on x86-64, a second copy compiled for AVX2,
// used when the processor has it (checked once at run time; Debian's packages are baseline, so
// the engine never requires it). The copies compute every value with the same IEEE operations in
// the same order (AVX2 only adds three-operand encodings and wider registers; fused multiply-add
// is a separate instruction set, not enabled), so they give the same answers bit for bit:
// CcdElementary.DispatchedSolverEqualsPortable checks it on random and public queries.
ElementaryResult solve_portable(CcdKind kind, const CcdPoints& points,
                                const ElementaryOptions& options) {
    return solve_body(kind, points, options);
}

#ifdef PROXIMA_X86_64_DISPATCH
__attribute__((target("avx2"))) ElementaryResult solve_avx2(CcdKind kind, const CcdPoints& points,
                                                            const ElementaryOptions& options) {
    return solve_body(kind, points, options);
}

// Read once at start-up (the prefilter runs per candidate; a call before this, from another
// file's static initializer, would take the portable copy: the same answers).
const bool HAS_AVX2 = detail::cpu_has_avx2();

ElementaryResult solve(CcdKind kind, const CcdPoints& points, const ElementaryOptions& options) {
    return HAS_AVX2 ? solve_avx2(kind, points, options) : solve_portable(kind, points, options);
}
#else
ElementaryResult solve(CcdKind kind, const CcdPoints& points, const ElementaryOptions& options) {
    return solve_portable(kind, points, options);
}
#endif

}  // namespace

const char* ccd_kind_name(CcdKind kind) {
    return kind == CcdKind::vertex_face ? "vf" : "ee";
}

ElementaryResult vertex_face(const CcdPoints& points, const ElementaryOptions& options) {
    return solve(CcdKind::vertex_face, points, options);
}

ElementaryResult edge_edge(const CcdPoints& points, const ElementaryOptions& options) {
    return solve(CcdKind::edge_edge, points, options);
}

ElementaryResult elementary(CcdKind kind, const CcdPoints& points,
                            const ElementaryOptions& options) {
    return solve(kind, points, options);
}

ElementaryResult elementary_portable(CcdKind kind, const CcdPoints& points,
                                     const ElementaryOptions& options) {
    return solve_portable(kind, points, options);
}

// The prefilter (elementary_prefilter_rejects; docs/algorithms.md, "CCD prefilter"). What it
// must respect: the solver reports an uncapped hit only when some point (t, u, v) of the domain
// has exact |F_k| <= d + tol + 2^-45 M on every axis k (M the largest |coordinate| of the 8
// points). For a region accepted by the point certificate that point is (t1, u, v), in the domain
// (u + v <= 1 checked exactly for vf); for one within the band as a whole, its corner (t0, u0, v0)
// (u0 + v0 <= 1 is checked for vf); either with computed |F_k| <= d + tol + e_k, so exact
// <= d + tol + 2 e_k = d + tol + M_k 2^-46 (+ 2^-1059, negligible under the guard M >= 2^-300).
// A region accepted at the width floor passed the exclusion test on every axis (some corner within
// d + 2 e_k exactly) while F_k = g0 - u gu - v gv varies by at most (12 + 2 + 2) M 2^-50 across
// it, so |F_k(t0, u0, v0)| <= d + M 2^-45. Each test below proves |F|_inf > d + tol + 2^-44 M
// (less its own rounding error, far below 2^-45 M) at every point of the domain, so the solver
// can only report such a pair `capped` (a larger work bound would reject it). Guards: finite
// coordinates with 2^-300 <= M <= 2^200 (no overflow in products of up to four coordinates, M^3
// normal), d not NaN, max_boxes >= 1; otherwise no decision. u = 2^-53; rounding to nearest is
// monotone and every threshold is a double, so fl(a - b) > thr holds only if a - b > thr exactly.
//
// 1. Axis filter. F_k(t, u, v) is, for fixed t, a convex combination of x_k - y_k over a vertex x
//    of the first primitive and y of the second (vf: the vertex minus each triangle corner, weights
//    1 - u - v, u, v; ee: a_i - b_j, weights products of (1 - u, u) and (1 - v, v)), and each
//    x_k(t) - y_k(t) is linear in t. If all of them exceed the threshold at t = 0 and t = 1 (or all
//    lie below its negative), so does F_k everywhere. Each computed difference is within
//    u |x - y| <= 2 u M of exact; the threshold is (d + tol + 2^-44 M)(1 + 2^-40).
// 2. Direction filter: the same with F . w for a fixed vector w (any double vector; we try the
//    normal and in-plane edge normals of the primitives at mid-frame, and for ee the two edge
//    directions), since |F|_inf >= |F . w| / |w|_1. A computed dot product of a difference with w
//    errs by at most 8 u M |w|_1 (difference error, three products, two sums); the threshold
//    (d + tol + 2^-43 M) |w|_1 (1 + 2^-40) covers it with 2^-44 M |w|_1 to spare, and its own
//    roundings (relative < 5 u) by the factor. A w with 2^-44 M |w|_1 < 2^-1000 is skipped
//    (underflowed products err absolutely, by up to 2^-1075 each).
// 3. Plane filter (Tang et al. 2010's coplanarity test made distance-aware). With n(t) the
//    normal of the triangle's plane (vf) or the common normal of the two edges' lines (ee) and
//    V(t) the signed volume
//      vf: V = (p - a) . ((b - a) x (c - a)),  n = (b - a) x (c - a)
//      ee: V = (b0 - a0) . ((a1 - a0) x (b1 - b0)),  n = (a1 - a0) x (b1 - b0)
//    F . n = V (vf) or -V (ee) at every (t, u, v), since n is orthogonal to both directions that
//    u and v move along; so |F|_inf >= |V| / |n|_1 (Hölder). X, Y, Z (the three
//    differences) are linear in t, so V(t) = X(t) . (Y(t) x Z(t)) is a cubic with Bernstein
//    coefficients b0 = T000, b1 = (T100 + T010 + T001) / 3, b2 = (T110 + T101 + T011) / 3,
//    b3 = T111, where Tijk = Xi . (Yj x Zk) (index 0: t = 0, 1: t = 1), and n(t) a quadratic with
//    Bernstein coefficients Y0 x Z0, (Y0 x Z1 + Y1 x Z0) / 2, Y1 x Z1. On [0, 1] a Bernstein
//    polynomial lies within the hull of its coefficients, so V(t) >= min b_i and |n(t)|_1 <= N,
//    the largest L1 norm of the n_i. If min b_i > D N (or max b_i < -D N) with D = d + tol +
//    2^-44 M, then |F|_inf > D everywhere (V(t) != 0, so n(t) != 0).
//    Rounding (first order): each difference errs by <= 2uM (|.| <= 2M), a cross-product
//    component by <= 32 u M^2 (|.| <= 8 M^2), a triple product Tijk by <= 370 u M^3 (|.| <=
//    48 M^3), a sum of three by <= 1350 u M^3; we subtract E = 2^-40 M^3 = 8192 u M^3 per triple
//    product. N's components err by <= 80 u M^2 and its sums by a few more: we add 2^-42 M^2 =
//    2048 u M^2. The threshold D N is a product of a few rounded terms (relative error < 10 u):
//    we multiply it by 1 + 2^-40.
namespace {

// Filter 2 for one direction w: all differences (both frames) beyond the threshold on one side.
template <int N>
PROXIMA_CCD_INLINE bool separated_along(const Vec3 (&diff)[N], const Vec3& w, double slack,
                                        double m) {
    const double norm1 = std::abs(w.x) + std::abs(w.y) + std::abs(w.z);
    if (!(0x1p-44 * m * norm1 >= 0x1p-1000)) {
        return false;  // w too short: underflowed products could err by more than the slack
    }
    const double thr = slack * norm1 * (1.0 + 0x1p-40);
    if (!(thr < std::numeric_limits<double>::infinity())) {
        return false;
    }
    const double first = dot(diff[0], w);
    if (first > thr) {
        for (int i = 1; i < N; ++i) {
            if (!(dot(diff[i], w) > thr)) {
                return false;
            }
        }
        return true;
    }
    if (first < -thr) {
        for (int i = 1; i < N; ++i) {
            if (!(dot(diff[i], w) < -thr)) {
                return false;
            }
        }
        return true;
    }
    return false;
}

// Filter 1 on axis k.
template <int N>
PROXIMA_CCD_INLINE bool separated_along_axis(const Vec3 (&diff)[N], int k, double thr) {
    const double first = diff[0][k];
    if (first > thr) {
        for (int i = 1; i < N; ++i) {
            if (!(diff[i][k] > thr)) {
                return false;
            }
        }
        return true;
    }
    if (first < -thr) {
        for (int i = 1; i < N; ++i) {
            if (!(diff[i][k] < -thr)) {
                return false;
            }
        }
        return true;
    }
    return false;
}

PROXIMA_CCD_INLINE bool prefilter_body(CcdKind kind, const CcdPoints& points,
                                       const ElementaryOptions& options) {
    double d = options.min_distance;
    if (std::isnan(d) || options.max_boxes == 0) {
        return false;  // the solver reports these unexamined
    }
    d = std::max(d, 0.0);
    const double tol = options.tolerance > 0.0 ? options.tolerance : 0.0;  // as solve()
    double m = 0.0;
    for (const auto& p : points) {
        for (int k = 0; k < 3; ++k) {
            if (!std::isfinite(p[k])) {
                return false;
            }
            m = std::max(m, std::abs(p[k]));
        }
    }
    if (!(m >= 0x1p-300 && m <= 0x1p200)) {
        return false;
    }
    // Filters 1 and 2: the three axes, then the normal and in-plane edge normals of the
    // primitives at mid-frame (any vector is valid; these are the likely separating ones).
    const double slack = d + tol + 0x1p-43 * m;  // d + tol + 2^-44 M + the dot products' error
    const double axis_thr = (d + tol + 0x1p-44 * m) * (1.0 + 0x1p-40);  // differences: 2uM
    if (kind == CcdKind::vertex_face) {
        Vec3 diff[6];
        for (int end = 0; end < 2; ++end) {
            const auto* q = points.data() + std::ptrdiff_t{4} * end;
            for (int j = 0; j < 3; ++j) {
                diff[3 * end + j] = q[0] - q[1 + j];
            }
        }
        for (int k = 0; k < 3; ++k) {
            if (separated_along_axis(diff, k, axis_thr)) {
                return true;
            }
        }
        Vec3 mid[4];
        for (int j = 0; j < 4; ++j) {
            mid[j] = points[j] + points[j + 4];  // twice the mid-frame point: only a direction
        }
        const Vec3 n = cross(mid[2] - mid[1], mid[3] - mid[1]);
        if (separated_along(diff, n, slack, m)) {
            return true;
        }
        for (int j = 0; j < 3; ++j) {
            const Vec3 w = cross(n, mid[1 + (j + 1) % 3] - mid[1 + j]);
            if (separated_along(diff, w, slack, m)) {
                return true;
            }
        }
    } else {
        Vec3 diff[8];
        for (int end = 0; end < 2; ++end) {
            const auto* q = points.data() + std::ptrdiff_t{4} * end;
            for (int i = 0; i < 2; ++i) {
                for (int j = 0; j < 2; ++j) {
                    diff[4 * end + 2 * i + j] = q[i] - q[2 + j];
                }
            }
        }
        for (int k = 0; k < 3; ++k) {
            if (separated_along_axis(diff, k, axis_thr)) {
                return true;
            }
        }
        Vec3 mid[4];
        for (int j = 0; j < 4; ++j) {
            mid[j] = points[j] + points[j + 4];
        }
        const Vec3 da = mid[1] - mid[0];
        const Vec3 db = mid[3] - mid[2];
        const Vec3 n = cross(da, db);
        if (separated_along(diff, n, slack, m) || separated_along(diff, cross(n, da), slack, m) ||
            separated_along(diff, cross(n, db), slack, m) || separated_along(diff, da, slack, m) ||
            separated_along(diff, db, slack, m)) {
            return true;
        }
    }
    // Filter 3 (plane). X, Y, Z at t = 0 (index 0) and t = 1 (index 4 in points).
    Vec3 x[2];
    Vec3 y[2];
    Vec3 z[2];
    for (int end = 0; end < 2; ++end) {
        const auto* q = points.data() + std::ptrdiff_t{4} * end;
        if (kind == CcdKind::vertex_face) {
            x[end] = q[0] - q[1];
            y[end] = q[2] - q[1];
            z[end] = q[3] - q[1];
        } else {
            x[end] = q[2] - q[0];
            y[end] = q[1] - q[0];
            z[end] = q[3] - q[2];
        }
    }
    const Vec3 c00 = cross(y[0], z[0]);
    const Vec3 c01 = cross(y[0], z[1]);
    const Vec3 c10 = cross(y[1], z[0]);
    const Vec3 c11 = cross(y[1], z[1]);
    const Vec3 mid = c01 + c10;
    auto l1 = [](const Vec3& v) { return std::abs(v.x) + std::abs(v.y) + std::abs(v.z); };
    const double n = std::max({l1(c00), l1(c11), 0.5 * l1(mid)}) + 0x1p-42 * (m * m);
    const double thr = (d + tol + 0x1p-44 * m) * n * (1.0 + 0x1p-40);
    const double thr3 = 3.0 * thr;
    const double e = 0x1p-40 * (m * m * m);
    const double e3 = 3.0 * e;
    const double b0 = dot(x[0], c00);
    const double s1 = dot(x[1], c00) + dot(x[0], c10) + dot(x[0], c01);
    const double s2 = dot(x[1], c10) + dot(x[1], c01) + dot(x[0], c11);
    const double b3 = dot(x[1], c11);
    if (b0 - e > thr && b3 - e > thr && s1 - e3 > thr3 && s2 - e3 > thr3) {
        return true;
    }
    return b0 + e < -thr && b3 + e < -thr && s1 + e3 < -thr3 && s2 + e3 < -thr3;
}

// As the solver: a copy for AVX2 where the processor has it, the same operations in the same order.
bool prefilter_portable(CcdKind kind, const CcdPoints& points, const ElementaryOptions& options) {
    return prefilter_body(kind, points, options);
}

#ifdef PROXIMA_X86_64_DISPATCH
__attribute__((target("avx2"))) bool prefilter_avx2(CcdKind kind, const CcdPoints& points,
                                                    const ElementaryOptions& options) {
    return prefilter_body(kind, points, options);
}
#endif

}  // namespace

bool elementary_prefilter_rejects(CcdKind kind, const CcdPoints& points,
                                  const ElementaryOptions& options) {
#ifdef PROXIMA_X86_64_DISPATCH
    if (HAS_AVX2) {
        return prefilter_avx2(kind, points, options);
    }
#endif
    return prefilter_portable(kind, points, options);
}

bool elementary_prefilter_rejects_portable(CcdKind kind, const CcdPoints& points,
                                           const ElementaryOptions& options) {
    return prefilter_portable(kind, points, options);
}

CcdCornerValues elementary_corner_values(CcdKind kind, const CcdPoints& points,
                                         const CcdRegion& region) {
    CcdCornerValues out;
    for (double x : region) {
        if (!(x >= 0.0 && x <= 1.0) || std::ldexp(x, 52) != std::floor(std::ldexp(x, 52))) {
            return out;
        }
    }
    for (const auto& p : points) {
        for (int k = 0; k < 3; ++k) {
            if (!std::isfinite(p[k]) || std::abs(p[k]) > HUGE_COORDINATE) {
                return out;
            }
        }
    }
    const Problem pr = make_problem(kind, points, 0.0, 0.0, false);
    const double t[2] = {region[0], region[1]};
    const double u[2] = {region[2], region[3]};
    const double v[2] = {region[4], region[5]};
    double f[3][8];
    corners(pr, t, u, v, f);
    for (int k = 0; k < 3; ++k) {
        for (int c = 0; c < 8; ++c) {
            out.values[static_cast<std::size_t>(k)][static_cast<std::size_t>(c)] = f[k][c];
        }
        out.error_bound[static_cast<std::size_t>(k)] = pr.error[k];
    }
    out.valid = true;
    return out;
}

}  // namespace proxima::ccd
