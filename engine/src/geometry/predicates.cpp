// Exact orientation predicates: Shewchuk's stage-A floating-point filter, then an exact GMP
// evaluation for the inputs the filter cannot decide.
//
// Shewchuk's error bounds assume that no product underflows or overflows. Rather than widening
// the bound, the filter is only trusted when every coordinate difference is either exactly zero or
// within [2^-RANGE, 2^RANGE]: then every nonzero product lies far inside the normal range, zero
// products are exactly zero, and the classic analysis (including "det == 0 with a zero bound is an
// exact zero") holds verbatim. Inputs outside that range (tiny offsets, huge coordinates) and
// non-finite values go to the exact path.

#include "proxima/geometry/predicates.hpp"

#include <gmp.h>

#include <algorithm>
#include <atomic>
#include <climits>
#include <cmath>

#include "cpu_features.hpp"

#ifdef PROXIMA_X86_64_DISPATCH
#include <immintrin.h>
#endif

namespace proxima {

namespace {

// Half an ulp of 1.0: Shewchuk's `epsilon` for IEEE double with round-to-nearest.
constexpr double EPSILON = 0x1p-53;
constexpr double CCW_ERRBOUND_A = (3.0 + 16.0 * EPSILON) * EPSILON;
constexpr double O3D_ERRBOUND_A = (7.0 + 56.0 * EPSILON) * EPSILON;

// Differences of magnitude in [2^-330, 2^330]: 3-products stay in [2^-990, 2^990], sums of six of
// them cannot overflow and no intermediate is subnormal. orient2d shares the range (2-products in
// [2^-660, 2^660]).
constexpr double SAFE_LO = 0x1p-330;
constexpr double SAFE_HI = 0x1p+330;

std::atomic<unsigned long long> g_exact_fallbacks{0};

inline bool in_filter_range(double d) {
    const double m = std::fabs(d);
    // A NaN fails both comparisons and the equality, so it is routed to the exact path.
    return (m >= SAFE_LO && m <= SAFE_HI) || m == 0.0;
}

// GMP integers reused across calls on one thread, so that the fallback does not allocate in the
// steady state.
struct ExactWorkspace {
    static constexpr int VALUES = 12;
    mpz_t v[VALUES];
    mpz_t d[9];
    mpz_t t0, t1, t2, acc;

    ExactWorkspace() {
        for (auto& x : v) {
            mpz_init(x);
        }
        for (auto& x : d) {
            mpz_init(x);
        }
        mpz_init(t0);
        mpz_init(t1);
        mpz_init(t2);
        mpz_init(acc);
    }
    ~ExactWorkspace() {
        for (auto& x : v) {
            mpz_clear(x);
        }
        for (auto& x : d) {
            mpz_clear(x);
        }
        mpz_clear(t0);
        mpz_clear(t1);
        mpz_clear(t2);
        mpz_clear(acc);
    }
    ExactWorkspace(const ExactWorkspace&) = delete;
    ExactWorkspace& operator=(const ExactWorkspace&) = delete;
};

ExactWorkspace& workspace() {
    thread_local ExactWorkspace ws;
    return ws;
}

// Loads finite doubles as integers sharing one power-of-two scale: out[i] = x[i] * 2^-e_min, where
// 2^e_min is the smallest ulp among the inputs. The scale is positive and common to all values, so
// the sign of any homogeneous polynomial in coordinate differences (every determinant here) is
// unchanged. Each double is m * 2^(e-53) with |m| < 2^53 an integer, so the load is exact.
void load_scaled(const double* x, int n, mpz_t* out) {
    int e_min = INT_MAX;
    for (int i = 0; i < n; ++i) {
        if (x[i] != 0.0) {
            int e = 0;
            (void)std::frexp(x[i], &e);
            e_min = std::min(e_min, e - 53);
        }
    }
    for (int i = 0; i < n; ++i) {
        if (x[i] == 0.0) {
            mpz_set_ui(out[i], 0);
            continue;
        }
        int e = 0;
        const double m = std::frexp(x[i], &e);
        mpz_set_d(out[i], std::ldexp(m, 53));
        mpz_mul_2exp(out[i], out[i], static_cast<mp_bitcnt_t>(e - 53 - e_min));
    }
}

int orient2d_exact(double ax, double ay, double bx, double by, double cx, double cy) {
    g_exact_fallbacks.fetch_add(1, std::memory_order_relaxed);
    const double in[6] = {ax, ay, bx, by, cx, cy};
    for (double x : in) {
        if (!std::isfinite(x)) {
            return 0;  // Outside the contract; never hand inf or NaN to GMP.
        }
    }
    ExactWorkspace& ws = workspace();
    load_scaled(in, 6, ws.v);
    mpz_sub(ws.d[0], ws.v[0], ws.v[4]);  // ax - cx
    mpz_sub(ws.d[1], ws.v[1], ws.v[5]);  // ay - cy
    mpz_sub(ws.d[2], ws.v[2], ws.v[4]);  // bx - cx
    mpz_sub(ws.d[3], ws.v[3], ws.v[5]);  // by - cy
    mpz_mul(ws.t0, ws.d[0], ws.d[3]);
    mpz_mul(ws.t1, ws.d[1], ws.d[2]);
    return mpz_cmp(ws.t0, ws.t1) > 0 ? 1 : (mpz_cmp(ws.t0, ws.t1) < 0 ? -1 : 0);
}

int orient3d_exact(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
    g_exact_fallbacks.fetch_add(1, std::memory_order_relaxed);
    const double in[12] = {a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z, d.x, d.y, d.z};
    for (double x : in) {
        if (!std::isfinite(x)) {
            return 0;
        }
    }
    ExactWorkspace& ws = workspace();
    load_scaled(in, 12, ws.v);
    // d[3*i + k] = (point i) - d along axis k, for i in {a, b, c}.
    for (int i = 0; i < 3; ++i) {
        for (int k = 0; k < 3; ++k) {
            mpz_sub(ws.d[3 * i + k], ws.v[3 * i + k], ws.v[9 + k]);
        }
    }
    mpz_t* m = ws.d;
    // adz * (bdx*cdy - cdx*bdy)
    mpz_mul(ws.t0, m[3], m[7]);
    mpz_submul(ws.t0, m[6], m[4]);
    mpz_mul(ws.acc, m[2], ws.t0);
    // bdz * (cdx*ady - adx*cdy)
    mpz_mul(ws.t1, m[6], m[1]);
    mpz_submul(ws.t1, m[0], m[7]);
    mpz_addmul(ws.acc, m[5], ws.t1);
    // cdz * (adx*bdy - bdx*ady)
    mpz_mul(ws.t2, m[0], m[4]);
    mpz_submul(ws.t2, m[3], m[1]);
    mpz_addmul(ws.acc, m[8], ws.t2);
    return mpz_sgn(ws.acc);
}

}  // namespace

int orient2d(double ax, double ay, double bx, double by, double cx, double cy) {
    const double acx = ax - cx;
    const double bcx = bx - cx;
    const double acy = ay - cy;
    const double bcy = by - cy;
    const bool in_range =
        in_filter_range(acx) & in_filter_range(bcx) & in_filter_range(acy) & in_filter_range(bcy);
    if (in_range) {
        const double detleft = acx * bcy;
        const double detright = acy * bcx;
        const double det = detleft - detright;
        const double errbound = CCW_ERRBOUND_A * (std::fabs(detleft) + std::fabs(detright));
        // ">=" as in Shewchuk: with no underflow a zero bound means both products are exactly 0.
        if (det >= errbound || -det >= errbound) {
            return det > 0.0 ? 1 : (det < 0.0 ? -1 : 0);
        }
    }
    return orient2d_exact(ax, ay, bx, by, cx, cy);
}

int orient3d(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
    const double adx = a.x - d.x;
    const double bdx = b.x - d.x;
    const double cdx = c.x - d.x;
    const double ady = a.y - d.y;
    const double bdy = b.y - d.y;
    const double cdy = c.y - d.y;
    const double adz = a.z - d.z;
    const double bdz = b.z - d.z;
    const double cdz = c.z - d.z;
    const bool in_range = in_filter_range(adx) & in_filter_range(bdx) & in_filter_range(cdx) &
                          in_filter_range(ady) & in_filter_range(bdy) & in_filter_range(cdy) &
                          in_filter_range(adz) & in_filter_range(bdz) & in_filter_range(cdz);
    if (in_range) {
        const double bdxcdy = bdx * cdy;
        const double cdxbdy = cdx * bdy;
        const double cdxady = cdx * ady;
        const double adxcdy = adx * cdy;
        const double adxbdy = adx * bdy;
        const double bdxady = bdx * ady;
        const double det =
            adz * (bdxcdy - cdxbdy) + bdz * (cdxady - adxcdy) + cdz * (adxbdy - bdxady);
        const double permanent = (std::fabs(bdxcdy) + std::fabs(cdxbdy)) * std::fabs(adz) +
                                 (std::fabs(cdxady) + std::fabs(adxcdy)) * std::fabs(bdz) +
                                 (std::fabs(adxbdy) + std::fabs(bdxady)) * std::fabs(cdz);
        const double errbound = O3D_ERRBOUND_A * permanent;
        if (det >= errbound || -det >= errbound) {
            return det > 0.0 ? 1 : (det < 0.0 ? -1 : 0);
        }
    }
    return orient3d_exact(a, b, c, d);
}

namespace detail {
unsigned long long exact_fallback_count() {
    return g_exact_fallbacks.load(std::memory_order_relaxed);
}

// The filter evaluates w . (u x v) with u = b - a, v = c - a, w = x - a, summed over axes in order.
// That expression has exactly the rounding structure of Shewchuk's orient3d stage A (each leaf a
// rounded difference of inputs, 2x2 minors, one product per axis, a left-to-right sum of three),
// so the same bound O3D_ERRBOUND_A * permanent holds, under the same range conditions. And
// orient3d(a, b, c, x) = det[a - x; u; v] = -w . (u x v).
PlaneSide::PlaneSide(const Vec3& a, const Vec3& b, const Vec3& c) : m_a(a), m_b(b), m_c(c) {
    const Vec3 u = b - a;
    const Vec3 v = c - a;
    m_in_range = in_filter_range(u.x) & in_filter_range(u.y) & in_filter_range(u.z) &
                 in_filter_range(v.x) & in_filter_range(v.y) & in_filter_range(v.z);
    const double uyvz = u.y * v.z;
    const double uzvy = u.z * v.y;
    const double uzvx = u.z * v.x;
    const double uxvz = u.x * v.z;
    const double uxvy = u.x * v.y;
    const double uyvx = u.y * v.x;
    m_normal = {uyvz - uzvy, uzvx - uxvz, uxvy - uyvx};
    m_minors = {std::fabs(uyvz) + std::fabs(uzvy), std::fabs(uzvx) + std::fabs(uxvz),
                std::fabs(uxvy) + std::fabs(uyvx)};
}

int PlaneSide::operator()(const Vec3& x, double& height) const {
    const Vec3 w = x - m_a;
    const double det = w.x * m_normal.x + w.y * m_normal.y + w.z * m_normal.z;
    height = det;
    if (m_in_range & in_filter_range(w.x) & in_filter_range(w.y) & in_filter_range(w.z)) {
        const double permanent =
            std::fabs(w.x) * m_minors.x + std::fabs(w.y) * m_minors.y + std::fabs(w.z) * m_minors.z;
        const double errbound = O3D_ERRBOUND_A * permanent;
        if (det >= errbound || -det >= errbound) {
            return det > 0.0 ? -1 : (det < 0.0 ? 1 : 0);
        }
    }
    return orient3d(m_a, m_b, m_c, x);
}

#ifdef PROXIMA_X86_64_DISPATCH
namespace {

// in_filter_range on four magnitudes: (m >= SAFE_LO && m <= SAFE_HI) || m == 0, NaN failing all.
__attribute__((target("avx2"))) inline __m256d in_filter_range4(__m256d m) {
    return _mm256_or_pd(_mm256_and_pd(_mm256_cmp_pd(m, _mm256_set1_pd(SAFE_LO), _CMP_GE_OQ),
                                      _mm256_cmp_pd(m, _mm256_set1_pd(SAFE_HI), _CMP_LE_OQ)),
                        _mm256_cmp_pd(m, _mm256_setzero_pd(), _CMP_EQ_OQ));
}

// PlaneSide's filter on three points in lanes 0-2 (lane 3 repeats point 0): the same operations in
// the same order as operator() (this file is compiled with -ffp-contract=off). Returns the lanes
// the filter decided (bit i) and leaves each lane's det in `det`.
__attribute__((target("avx2"))) unsigned plane_filter_avx2(const Vec3& a, const Vec3& normal,
                                                           const Vec3& minors, bool in_range,
                                                           const std::array<Vec3, 3>& t,
                                                           double det_out[4]) {
    const __m256d wx =
        _mm256_sub_pd(_mm256_set_pd(t[0].x, t[2].x, t[1].x, t[0].x), _mm256_set1_pd(a.x));
    const __m256d wy =
        _mm256_sub_pd(_mm256_set_pd(t[0].y, t[2].y, t[1].y, t[0].y), _mm256_set1_pd(a.y));
    const __m256d wz =
        _mm256_sub_pd(_mm256_set_pd(t[0].z, t[2].z, t[1].z, t[0].z), _mm256_set1_pd(a.z));
    const __m256d det = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(wx, _mm256_set1_pd(normal.x)),
                                                    _mm256_mul_pd(wy, _mm256_set1_pd(normal.y))),
                                      _mm256_mul_pd(wz, _mm256_set1_pd(normal.z)));
    _mm256_storeu_pd(det_out, det);
    if (!in_range) {
        return 0;
    }
    const __m256d sign = _mm256_set1_pd(-0.0);
    const __m256d ax = _mm256_andnot_pd(sign, wx);
    const __m256d ay = _mm256_andnot_pd(sign, wy);
    const __m256d az = _mm256_andnot_pd(sign, wz);
    const __m256d ok = _mm256_and_pd(_mm256_and_pd(in_filter_range4(ax), in_filter_range4(ay)),
                                     in_filter_range4(az));
    const __m256d permanent =
        _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(ax, _mm256_set1_pd(minors.x)),
                                    _mm256_mul_pd(ay, _mm256_set1_pd(minors.y))),
                      _mm256_mul_pd(az, _mm256_set1_pd(minors.z)));
    const __m256d errbound = _mm256_mul_pd(_mm256_set1_pd(O3D_ERRBOUND_A), permanent);
    const __m256d decided =
        _mm256_or_pd(_mm256_cmp_pd(det, errbound, _CMP_GE_OQ),
                     _mm256_cmp_pd(_mm256_xor_pd(det, sign), errbound, _CMP_GE_OQ));
    return static_cast<unsigned>(_mm256_movemask_pd(_mm256_and_pd(ok, decided))) & 7U;
}

// Read once at start-up (a call before this, from another file's static initializer, takes the
// portable path: the same signs).
const bool HAS_AVX2 = cpu_has_avx2();

}  // namespace
#endif

void PlaneSide::corners(const std::array<Vec3, 3>& t, int sign[3], double height[3]) const {
#ifdef PROXIMA_X86_64_DISPATCH
    if (HAS_AVX2) {
        double det[4];
        const unsigned decided = plane_filter_avx2(m_a, m_normal, m_minors, m_in_range, t, det);
        for (int i = 0; i < 3; ++i) {
            height[i] = det[i];
            sign[i] = (decided & (1U << i)) != 0 ? (det[i] > 0.0 ? -1 : (det[i] < 0.0 ? 1 : 0))
                                                 : orient3d(m_a, m_b, m_c, t[i]);
        }
        return;
    }
#endif
    for (int i = 0; i < 3; ++i) {
        sign[i] = (*this)(t[i], height[i]);
    }
}

int PlaneSide::operator()(const Vec3& x) const {
    double height = 0.0;
    return (*this)(x, height);
}
}  // namespace detail

}  // namespace proxima
