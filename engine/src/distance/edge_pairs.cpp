// triangle_triangle's edge pairs: see detail::closest_edge_pair in
// proxima/distance/primitives.hpp.
//
// On the self query's candidates nearly every exact test ends at an edge pair that Larsen's test
// certifies (counted with temporary counters on the pairs a lower bound proved apart: 96 % of
// rod-twist's, 88 % of cloth-ball's; for 90 % of rod-twist's one of the four pairs at the closest
// corners). With the pairs tried one after another with an early exit, after the plane signs,
// the exact test was 30 % of rod-twist's self query's instructions (22 % without the plane
// signs). The AVX2 copy computes the corners' distances in three vectors, the four pairs at the
// closest corners in one, and the other five (two more vectors) only when none of those four is
// certified, with the same IEEE operations in the same order as the scalar copy (this file is
// compiled with -ffp-contract=off): every value is the same bit for bit, so the choice does not
// depend on the processor.
#include <algorithm>
#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "cpu_features.hpp"
#include "proxima/distance/primitives.hpp"

#ifdef PROXIMA_X86_64_DISPATCH
#include <immintrin.h>
#endif

namespace proxima::detail {

namespace {

// Argument order matters: std::max(0.0, NaN) is 0.0, so a NaN quotient (0 / 0) maps to 0.
inline double clamp01(double t) {
    return std::min(1.0, std::max(0.0, t));
}

// ta's corner off edge i (edge i runs from corner i to corner i + 1).
constexpr int off_edge(int i) {
    return i == 0 ? 2 : i - 1;
}

// All nine pairs (lanes 9-11 are scratch for the vector copy), and each pair of corners' squared
// distance |ta[i] - tb[j]|^2 at the same index k = 3 i + j.
struct NinePairs {
    double s[12];
    double t[12];
    double squared_distance[12];
    double corner_sq[12];
    unsigned certified;
    unsigned nearly_parallel;
};

// The first closest pair of corners in row order, as k = 3 i + j (0 when none is finite).
int closest_corners(const double corner_sq[]) {
    int best = 0;
    double nearest = std::numeric_limits<double>::infinity();
    for (int k = 0; k < 9; ++k) {
        if (corner_sq[k] < nearest) {
            nearest = corner_sq[k];
            best = k;
        }
    }
    return best;
}

// The first set bit of `mask` in the pairs' order (see EdgePairChoice).
int first_in_order(const double corner_sq[], unsigned mask) {
    if ((mask & (mask - 1)) == 0) {
        return std::countr_zero(mask);
    }
    const int corners = closest_corners(corner_sq);
    const int ka = corners / 3;
    const int kb = corners % 3;
    for (const int x : {ka, off_edge(ka)}) {
        for (const int y : {kb, off_edge(kb)}) {
            if ((mask & (1U << (3 * x + y))) != 0) {
                return 3 * x + y;
            }
        }
    }
    return std::countr_zero(mask);
}

EdgePairChoice choose(const NinePairs& n) {
    EdgePairChoice c;
    if (n.certified != 0) {
        c.pair = first_in_order(n.corner_sq, n.certified);
        c.certified = true;
    } else {
        // std::min(best, NaN) is best: a NaN never wins, as in a scan with "<".
        double best = std::numeric_limits<double>::infinity();
        for (int k = 0; k < 9; ++k) {
            best = std::min(best, n.squared_distance[k]);
        }
        unsigned closest = 0;
        for (int k = 0; k < 9; ++k) {
            closest |= n.squared_distance[k] == best ? 1U << k : 0U;
        }
        if (closest != 0 && best < std::numeric_limits<double>::infinity()) {
            c.pair = first_in_order(n.corner_sq, closest);
        }
        c.nearly_parallel = n.nearly_parallel != 0;
    }
    if (c.pair >= 0) {
        c.s = n.s[c.pair];
        c.t = n.t[c.pair];
    }
    return c;
}

void nine_pairs_portable(const Triangle& ta, const Triangle& tb, NinePairs& out) {
    const Vec3 da[3] = {ta[1] - ta[0], ta[2] - ta[1], ta[0] - ta[2]};
    const Vec3 db[3] = {tb[1] - tb[0], tb[2] - tb[1], tb[0] - tb[2]};
    double len_a[3];
    double len_b[3];
    double inv_a[3];
    double inv_b[3];
    for (int i = 0; i < 3; ++i) {
        len_a[i] = dot(da[i], da[i]);
        len_b[i] = dot(db[i], db[i]);
        inv_a[i] = len_a[i] > 0.0 ? 1.0 / len_a[i] : 0.0;
        inv_b[i] = len_b[i] > 0.0 ? 1.0 / len_b[i] : 0.0;
    }
    out.certified = 0;
    out.nearly_parallel = 0;
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            const int k = 3 * i + j;
            const double a = len_a[i];
            const double e = len_b[j];
            const Vec3 r = ta[i] - tb[j];
            const double b = dot(da[i], db[j]);
            const double c = dot(da[i], r);
            const double f = dot(db[j], r);
            const double denom = a * e - b * b;
            const bool nearly_parallel = !(denom > NEARLY_PARALLEL * a * e);
            const double s0 = clamp01((b * f - c * e) / denom);
            const double t = clamp01((b * s0 + f) * inv_b[j]);
            const double s = clamp01((b * t - c) * inv_a[i]);
            const Vec3 p = ta[i] + s * da[i];
            const Vec3 q = tb[j] + t * db[j];
            const Vec3 v = q - p;
            // Larsen's test (PQP's TriDist): p and q are mutually closest on their edges, so each
            // edge lies in a half-space bounded by the plane through p (resp. q) normal to v. If
            // the third corners lie there too, the planes separate the triangles by |v| and this
            // pair is closest. Not trusted for nearly parallel edges (poorly conditioned).
            const bool certified = !nearly_parallel && dot(ta[off_edge(i)] - p, v) <= 0.0 &&
                                   dot(tb[off_edge(j)] - q, v) >= 0.0;
            out.s[k] = s;
            out.t[k] = t;
            out.squared_distance[k] = dot(v, v);
            out.corner_sq[k] = dot(r, r);
            out.certified |= certified ? 1U << k : 0U;
            out.nearly_parallel |= nearly_parallel ? 1U << k : 0U;
        }
    }
}

}  // namespace

EdgePairChoice closest_edge_pair_portable(const Triangle& ta, const Triangle& tb) {
    NinePairs n;
    nine_pairs_portable(ta, tb, n);
    return choose(n);
}

#ifdef PROXIMA_X86_64_DISPATCH
namespace {

// Which pair each lane of a vector computes: ta's edge a[l] against tb's edge b[l], as 32-bit
// permutation indices into a vector whose lanes 0-2 hold corners or edges 0-2 (each double is two
// 32-bit halves), for the edges' first corners, their directions and lengths, and for the
// corners off them.
struct Lanes {
    alignas(32) std::int32_t a[8];
    alignas(32) std::int32_t b[8];
    alignas(32) std::int32_t off_a[8];
    alignas(32) std::int32_t off_b[8];
    int pair[4];
};

constexpr Lanes lanes(std::array<int, 4> ea, std::array<int, 4> eb) {
    Lanes l{};
    for (std::size_t i = 0; i < 4; ++i) {
        const std::size_t lo = 2 * i;
        const std::size_t hi = 2 * i + 1;
        l.a[lo] = 2 * ea[i];
        l.a[hi] = 2 * ea[i] + 1;
        l.b[lo] = 2 * eb[i];
        l.b[hi] = 2 * eb[i] + 1;
        l.off_a[lo] = 2 * off_edge(ea[i]);
        l.off_a[hi] = 2 * off_edge(ea[i]) + 1;
        l.off_b[lo] = 2 * off_edge(eb[i]);
        l.off_b[hi] = 2 * off_edge(eb[i]) + 1;
        l.pair[i] = 3 * ea[i] + eb[i];
    }
    return l;
}

// The nine pairs in row order: 0-3, 4-7, and 8 (its vector's other lanes repeat it).
constexpr std::array<Lanes, 3> ROWS = {lanes({0, 0, 0, 1}, {0, 1, 2, 0}),
                                       lanes({1, 1, 2, 2}, {1, 2, 0, 1}),
                                       lanes({2, 2, 2, 2}, {2, 2, 2, 2})};

// The four pairs of edges meeting at corners (ka, kb), in order, for each k = 3 ka + kb.
constexpr std::array<Lanes, 9> AT_CORNERS = [] {
    std::array<Lanes, 9> t{};
    for (int ka = 0; ka < 3; ++ka) {
        for (int kb = 0; kb < 3; ++kb) {
            t[3 * ka + kb] =
                lanes({ka, ka, off_edge(ka), off_edge(ka)}, {kb, off_edge(kb), kb, off_edge(kb)});
        }
    }
    return t;
}();

struct V3 {
    __m256d x, y, z;
};

__attribute__((target("avx2"))) inline __m256d permute(__m256d v, __m256i index) {
    return _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(v), index));
}

__attribute__((target("avx2"))) inline V3 permute(const V3& v, __m256i index) {
    return {permute(v.x, index), permute(v.y, index), permute(v.z, index)};
}

__attribute__((target("avx2"))) inline __m256i load(const std::int32_t* index) {
    return _mm256_load_si256(reinterpret_cast<const __m256i*>(index));
}

__attribute__((target("avx2"))) inline V3 sub(const V3& a, const V3& b) {
    return {_mm256_sub_pd(a.x, b.x), _mm256_sub_pd(a.y, b.y), _mm256_sub_pd(a.z, b.z)};
}

// a + s * d, as Vec3's operators compute it.
__attribute__((target("avx2"))) inline V3 along(const V3& a, __m256d s, const V3& d) {
    return {_mm256_add_pd(a.x, _mm256_mul_pd(s, d.x)), _mm256_add_pd(a.y, _mm256_mul_pd(s, d.y)),
            _mm256_add_pd(a.z, _mm256_mul_pd(s, d.z))};
}

// a.x * b.x + a.y * b.y + a.z * b.z, left to right (dot in vec3.hpp).
__attribute__((target("avx2"))) inline __m256d dot4(const V3& a, const V3& b) {
    return _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(a.x, b.x), _mm256_mul_pd(a.y, b.y)),
                         _mm256_mul_pd(a.z, b.z));
}

// clamp01: maxpd(x, 0) is 0 for a NaN x and for either zero (std::max(0.0, x) = 0 < x ? x : 0),
// then minpd(y, 1) = y < 1 ? y : 1 (std::min(1.0, y)).
__attribute__((target("avx2"))) inline __m256d clamp4(__m256d x) {
    return _mm256_min_pd(_mm256_max_pd(x, _mm256_setzero_pd()), _mm256_set1_pd(1.0));
}

// A triangle's corners in lanes 0-2 (lane 3 repeats corner 0), its edge directions (edge l from
// corner l to corner l + 1), their squared lengths and 1 / length^2 (0 for a zero-length edge).
struct Corners {
    V3 p;
    V3 d;
    __m256d len;
    __m256d inv;
};

__attribute__((target("avx2"))) inline Corners corners(const Triangle& t) {
    Corners c;
    c.p = {_mm256_set_pd(t[0].x, t[2].x, t[1].x, t[0].x),
           _mm256_set_pd(t[0].y, t[2].y, t[1].y, t[0].y),
           _mm256_set_pd(t[0].z, t[2].z, t[1].z, t[0].z)};
    c.d = sub(V3{_mm256_permute4x64_pd(c.p.x, 0x49), _mm256_permute4x64_pd(c.p.y, 0x49),
                 _mm256_permute4x64_pd(c.p.z, 0x49)},  // lanes 1, 2, 0, 1
              c.p);
    c.len = dot4(c.d, c.d);
    const __m256d positive = _mm256_cmp_pd(c.len, _mm256_setzero_pd(), _CMP_GT_OQ);
    c.inv = _mm256_and_pd(positive, _mm256_div_pd(_mm256_set1_pd(1.0), c.len));
    return c;
}

// The four pairs of `lanes`: stores s, t and |q - p|^2 at s[0..3], t[0..3], sq[0..3] and returns
// the lanes' certified bits (0-3) and nearly parallel bits (4-7). nine_pairs_portable's
// operations, lane by lane.
__attribute__((target("avx2"))) inline unsigned four_pairs(const Corners& A, const Corners& B,
                                                           const Lanes& lanes, double* s_out,
                                                           double* t_out, double* sq_out) {
    const __m256i ia = load(lanes.a);
    const __m256i ib = load(lanes.b);
    const V3 pa = permute(A.p, ia);
    const V3 da = permute(A.d, ia);
    const __m256d a = permute(A.len, ia);
    const __m256d inv_a = permute(A.inv, ia);
    const V3 pb = permute(B.p, ib);
    const V3 db = permute(B.d, ib);
    const __m256d e = permute(B.len, ib);
    const __m256d inv_e = permute(B.inv, ib);
    const V3 r = sub(pa, pb);
    const __m256d b = dot4(da, db);
    const __m256d c = dot4(da, r);
    const __m256d f = dot4(db, r);
    const __m256d denom = _mm256_sub_pd(_mm256_mul_pd(a, e), _mm256_mul_pd(b, b));
    // NEARLY_PARALLEL * a * e evaluates (NEARLY_PARALLEL * a) * e.
    const __m256d limit = _mm256_mul_pd(_mm256_mul_pd(_mm256_set1_pd(NEARLY_PARALLEL), a), e);
    const __m256d nearly_parallel = _mm256_cmp_pd(denom, limit, _CMP_NGT_UQ);  // !(denom > limit)
    const __m256d s0 =
        clamp4(_mm256_div_pd(_mm256_sub_pd(_mm256_mul_pd(b, f), _mm256_mul_pd(c, e)), denom));
    const __m256d t = clamp4(_mm256_mul_pd(_mm256_add_pd(_mm256_mul_pd(b, s0), f), inv_e));
    const __m256d s = clamp4(_mm256_mul_pd(_mm256_sub_pd(_mm256_mul_pd(b, t), c), inv_a));
    const V3 p = along(pa, s, da);
    const V3 q = along(pb, t, db);
    const V3 v = sub(q, p);
    const V3 oa = permute(A.p, load(lanes.off_a));
    const V3 ob = permute(B.p, load(lanes.off_b));
    const __m256d side_a = _mm256_cmp_pd(dot4(sub(oa, p), v), _mm256_setzero_pd(), _CMP_LE_OQ);
    const __m256d side_b = _mm256_cmp_pd(dot4(sub(ob, q), v), _mm256_setzero_pd(), _CMP_GE_OQ);
    const __m256d certified = _mm256_andnot_pd(nearly_parallel, _mm256_and_pd(side_a, side_b));
    _mm256_storeu_pd(s_out, s);
    _mm256_storeu_pd(t_out, t);
    _mm256_storeu_pd(sq_out, dot4(v, v));
    return static_cast<unsigned>(_mm256_movemask_pd(certified)) |
           (static_cast<unsigned>(_mm256_movemask_pd(nearly_parallel)) << 4);
}

// closest_corners of the nine squared distances in lanes 0-2 of sq[0..2], without its branches
// (which the processor mispredicts: which corners are closest is close to a coin toss): NaN lanes
// and lane 3 count as infinite, the smallest value's first lane in row order wins, and 0 when
// none is finite.
__attribute__((target("avx2"))) inline int closest_corners_avx2(const __m256d sq[3]) {
    const __m256d inf = _mm256_set1_pd(std::numeric_limits<double>::infinity());
    __m256d v[3];
    for (std::size_t i = 0; i < 3; ++i) {
        // NaN to infinity (a NaN never wins a "<" scan), lane 3 too.
        v[i] = _mm256_blend_pd(
            _mm256_blendv_pd(sq[i], inf, _mm256_cmp_pd(sq[i], sq[i], _CMP_UNORD_Q)), inf, 0x8);
    }
    __m256d m = _mm256_min_pd(_mm256_min_pd(v[0], v[1]), v[2]);
    m = _mm256_min_pd(m, _mm256_permute4x64_pd(m, 0x4E));  // lanes 2, 3, 0, 1
    m = _mm256_min_pd(m, _mm256_permute4x64_pd(m, 0xB1));  // lanes 1, 0, 3, 2
    if (!(_mm256_cvtsd_f64(m) < std::numeric_limits<double>::infinity())) {
        return 0;
    }
    unsigned at_min = 0;
    for (std::size_t i = 0; i < 3; ++i) {
        at_min |=
            (static_cast<unsigned>(_mm256_movemask_pd(_mm256_cmp_pd(v[i], m, _CMP_EQ_OQ))) & 7U)
            << (3 * i);
    }
    return std::countr_zero(at_min);
}

__attribute__((target("avx2"))) EdgePairChoice closest_edge_pair_avx2(const Triangle& ta,
                                                                      const Triangle& tb) {
    const Corners A = corners(ta);
    const Corners B = corners(tb);
    NinePairs n;
    // |ta[i] - tb[j]|^2 for j = 0-2 in lanes 0-2, at k = 3 i + j (lane 3 is overwritten or
    // scratch).
    const V3 ai[3] = {{_mm256_permute4x64_pd(A.p.x, 0x00), _mm256_permute4x64_pd(A.p.y, 0x00),
                       _mm256_permute4x64_pd(A.p.z, 0x00)},
                      {_mm256_permute4x64_pd(A.p.x, 0x55), _mm256_permute4x64_pd(A.p.y, 0x55),
                       _mm256_permute4x64_pd(A.p.z, 0x55)},
                      {_mm256_permute4x64_pd(A.p.x, 0xAA), _mm256_permute4x64_pd(A.p.y, 0xAA),
                       _mm256_permute4x64_pd(A.p.z, 0xAA)}};
    __m256d sq[3];
    for (std::size_t i = 0; i < 3; ++i) {
        const V3 r = sub(ai[i], B.p);
        sq[i] = dot4(r, r);
        _mm256_storeu_pd(n.corner_sq + 3 * i, sq[i]);
    }
    // The four pairs at the closest corners: the first certified one in their order is the
    // choice (they come first in the order).
    const Lanes& at = AT_CORNERS[static_cast<std::size_t>(closest_corners_avx2(sq))];
    double s4[4];
    double t4[4];
    double sq4[4];
    const unsigned first = four_pairs(A, B, at, s4, t4, sq4) & 0xFU;
    if (first != 0) {
        const int l = std::countr_zero(first);
        EdgePairChoice c;
        c.pair = at.pair[l];
        c.s = s4[l];
        c.t = t4[l];
        c.certified = true;
        return c;
    }
    // None of them is: all nine (those four again, the same values), chosen as the scalar copy
    // chooses.
    unsigned bits[3];
    for (std::size_t g = 0; g < 3; ++g) {
        bits[g] = four_pairs(A, B, ROWS[g], n.s + 4 * g, n.t + 4 * g, n.squared_distance + 4 * g);
    }
    n.certified = (bits[0] & 0xFU) | ((bits[1] & 0xFU) << 4) | ((bits[2] & 1U) << 8);
    n.nearly_parallel = (bits[0] >> 4) | ((bits[1] >> 4) << 4) | (((bits[2] >> 4) & 1U) << 8);
    return choose(n);
}

// Read once at start-up (a call before this, from another file's static initializer, takes the
// portable copy: the same choice).
const bool HAS_AVX2 = cpu_has_avx2();

}  // namespace
#endif

EdgePairChoice closest_edge_pair(const Triangle& ta, const Triangle& tb) {
#ifdef PROXIMA_X86_64_DISPATCH
    if (HAS_AVX2) {
        return closest_edge_pair_avx2(ta, tb);
    }
#endif
    return closest_edge_pair_portable(ta, tb);
}

}  // namespace proxima::detail
