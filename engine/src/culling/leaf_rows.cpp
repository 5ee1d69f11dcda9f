// The self traversal's leaf rows: see proxima/culling/leaf_rows.hpp.
#include "proxima/culling/leaf_rows.hpp"

#include <algorithm>
#include <limits>

#include "cpu_features.hpp"

#ifdef PROXIMA_X86_64_DISPATCH
#include <immintrin.h>
#endif

namespace proxima::detail {

namespace {
template <class T>
void allocate(std::unique_ptr<T[]>& a, std::size_t n) {
    a = std::make_unique_for_overwrite<T[]>(n + LeafSlots::PAD);
    std::fill(a.get() + n, a.get() + n + LeafSlots::PAD, T{});
}
}  // namespace

void LeafSlots::resize(std::size_t n) {
    for (auto* a : {&lox, &loy, &loz, &hix, &hiy, &hiz}) {
        allocate(*a, n);
    }
    for (auto* a : {&v0, &v1, &v2}) {
        allocate(*a, n);
    }
    for (int i = 0; i < DiagonalExtents::N; ++i) {
        allocate(dlo[i], n);
        allocate(dhi[i], n);
    }
    for (auto* a : {&flox, &floy, &floz, &fhix, &fhiy, &fhiz}) {
        allocate(*a, n);
    }
    for (int i = 0; i < DiagonalExtents::N; ++i) {
        allocate(fdlo[i], n);
        allocate(fdhi[i], n);
    }
}

namespace {
// box_squared_distance(box, slot k's box), the same operations in the same order.
double slot_box_distance(const LeafSlots& slots, std::uint32_t k, const Aabb& box) {
    const double gx = std::max(std::max(0.0, box.lo.x - slots.hix[k]), slots.lox[k] - box.hi.x);
    const double gy = std::max(std::max(0.0, box.lo.y - slots.hiy[k]), slots.loy[k] - box.hi.y);
    const double gz = std::max(std::max(0.0, box.lo.z - slots.hiz[k]), slots.loz[k] - box.hi.z);
    double d = 0.0;
    d += gx * gx;
    d += gy * gy;
    d += gz * gz;
    return d;
}

}  // namespace

unsigned leaf_rows_near_portable(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                                 const Aabb& box, const DiagonalExtents& diagonals,
                                 const double* threshold_sq, double other_sq, double dop_error) {
    unsigned near = 0;
    for (std::uint32_t p = 0; p < n; ++p) {
        const double th = std::max(threshold_sq[p], other_sq);
        if (slot_box_distance(slots, first + p, box) < th &&
            !diagonals_far(diagonals, slots.diagonals(first + p), dop_error, th)) {
            near |= 1U << p;
        }
    }
    return near;
}

namespace {
// x > y ? x : y, as _mm256_max_ps (no NaN reaches it).
inline float larger(float x, float y) {
    return x > y ? x : y;
}
// The margins of leaf_row's single-precision tests (see leaf_rows.hpp).
constexpr float ROW_MARGIN = 1.0F - 0x1p-18F;
constexpr float ROW_FLOAT_MAX = std::numeric_limits<float>::max();
}  // namespace

unsigned leaf_row_portable(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                           std::uint32_t row, float row_threshold_sq, const float* threshold_sq,
                           float dop_error) {
    const TriangleIndices v{slots.v0[row], slots.v1[row], slots.v2[row]};
    unsigned pass = 0;
    for (std::uint32_t q = 0; q < n; ++q) {
        const std::uint32_t k = first + q;
        if (v[0] == slots.v0[k] || v[0] == slots.v1[k] || v[0] == slots.v2[k] ||
            v[1] == slots.v0[k] || v[1] == slots.v1[k] || v[1] == slots.v2[k] ||
            v[2] == slots.v0[k] || v[2] == slots.v1[k] || v[2] == slots.v2[k]) {
            continue;
        }
        const float th = larger(row_threshold_sq, threshold_sq[q]);
        // The box distance, as box_squared_distance, capped below overflow.
        const float gx =
            larger(larger(0.0F, slots.flox[row] - slots.fhix[k]), slots.flox[k] - slots.fhix[row]);
        const float gy =
            larger(larger(0.0F, slots.floy[row] - slots.fhiy[k]), slots.floy[k] - slots.fhiy[row]);
        const float gz =
            larger(larger(0.0F, slots.floz[row] - slots.fhiz[k]), slots.floz[k] - slots.fhiz[row]);
        float d = 0.0F;
        d += gx * gx;
        d += gy * gy;
        d += gz * gz;
        d = d < ROW_FLOAT_MAX ? d : ROW_FLOAT_MAX;
        if (!(d * ROW_MARGIN < th)) {
            continue;
        }
        // diagonals_far with the margin.
        float g[DiagonalExtents::N];
        for (int i = 0; i < DiagonalExtents::N; ++i) {
            g[i] = larger(slots.fdlo[i][k] - slots.fdhi[i][row],
                          slots.fdlo[i][row] - slots.fdhi[i][k]);
        }
        const float h = larger(larger(g[0], g[1]), larger(g[2], g[3])) - dop_error;
        if (h > 0.0F && (h * h) * ROW_MARGIN > 3.0F * th) {
            continue;
        }
        pass |= 1U << q;
    }
    return pass;
}

double leaf_thresholds_portable(const std::atomic<double>* bounds, const std::uint32_t* idx,
                                std::uint32_t n, double slack, double* out, float* out_f) {
    double largest = 0.0;
    for (std::uint32_t q = 0; q < n; ++q) {
        out[q] = traversal_threshold_sq(bounds[idx[q]].load(std::memory_order_relaxed), slack);
        out_f[q] = float_threshold(out[q]);
        largest = std::max(largest, out[q]);
    }
    return largest;
}

#ifdef PROXIMA_X86_64_DISPATCH
namespace {

// Four slots' box distances to `box` (slots k..k+3), as slot_box_distance.
__attribute__((target("avx2"))) __m256d box_distances_avx2(const LeafSlots& slots, std::uint32_t k,
                                                           const Aabb& box) {
    const __m256d zero = _mm256_setzero_pd();
    // max(max(0, box.lo - hi), lo - box.hi) per axis, then ((0 + gx²) + gy²) + gz²: as the
    // portable copy.
    const __m256d gx = _mm256_max_pd(
        _mm256_max_pd(zero,
                      _mm256_sub_pd(_mm256_set1_pd(box.lo.x), _mm256_loadu_pd(&slots.hix[k]))),
        _mm256_sub_pd(_mm256_loadu_pd(&slots.lox[k]), _mm256_set1_pd(box.hi.x)));
    const __m256d gy = _mm256_max_pd(
        _mm256_max_pd(zero,
                      _mm256_sub_pd(_mm256_set1_pd(box.lo.y), _mm256_loadu_pd(&slots.hiy[k]))),
        _mm256_sub_pd(_mm256_loadu_pd(&slots.loy[k]), _mm256_set1_pd(box.hi.y)));
    const __m256d gz = _mm256_max_pd(
        _mm256_max_pd(zero,
                      _mm256_sub_pd(_mm256_set1_pd(box.lo.z), _mm256_loadu_pd(&slots.hiz[k]))),
        _mm256_sub_pd(_mm256_loadu_pd(&slots.loz[k]), _mm256_set1_pd(box.hi.z)));
    __m256d d = _mm256_add_pd(zero, _mm256_mul_pd(gx, gx));
    d = _mm256_add_pd(d, _mm256_mul_pd(gy, gy));
    return _mm256_add_pd(d, _mm256_mul_pd(gz, gz));
}

// Diagonal i's gap between a and slots k..k+3, and the lanes of those slots that
// diagonals_far(a, slot, dop_error, th) keeps apart (a bit per lane): the same operations in the
// same order.
__attribute__((target("avx2"))) __m256d diagonal_gap_avx2(const LeafSlots& slots, std::uint32_t k,
                                                          const DiagonalExtents& a, int i) {
    return _mm256_max_pd(_mm256_sub_pd(_mm256_loadu_pd(&slots.dlo[i][k]), _mm256_set1_pd(a.hi[i])),
                         _mm256_sub_pd(_mm256_set1_pd(a.lo[i]), _mm256_loadu_pd(&slots.dhi[i][k])));
}

__attribute__((target("avx2"))) unsigned diagonals_far_avx2(const LeafSlots& slots, std::uint32_t k,
                                                            const DiagonalExtents& a,
                                                            double dop_error, __m256d th) {
    const __m256d gap = _mm256_max_pd(
        _mm256_max_pd(diagonal_gap_avx2(slots, k, a, 0), diagonal_gap_avx2(slots, k, a, 1)),
        _mm256_max_pd(diagonal_gap_avx2(slots, k, a, 2), diagonal_gap_avx2(slots, k, a, 3)));
    const __m256d h = _mm256_sub_pd(gap, _mm256_set1_pd(dop_error));
    const __m256d far = _mm256_and_pd(
        _mm256_cmp_pd(h, _mm256_setzero_pd(), _CMP_GT_OQ),
        _mm256_cmp_pd(_mm256_mul_pd(h, h), _mm256_mul_pd(_mm256_set1_pd(3.0), th), _CMP_GE_OQ));
    return static_cast<unsigned>(_mm256_movemask_pd(far));
}

__attribute__((target("avx2"))) unsigned leaf_rows_near_avx2(const LeafSlots& slots,
                                                             std::uint32_t first, std::uint32_t n,
                                                             const Aabb& box,
                                                             const DiagonalExtents& diagonals,
                                                             const double* threshold_sq,
                                                             double other_sq, double dop_error) {
    unsigned near = 0;
    const __m256d other = _mm256_set1_pd(other_sq);
    for (std::uint32_t p = 0; p < n; p += 4) {
        const __m256d d = box_distances_avx2(slots, first + p, box);
        const __m256d th = _mm256_max_pd(_mm256_loadu_pd(threshold_sq + p), other);
        auto close = static_cast<unsigned>(_mm256_movemask_pd(_mm256_cmp_pd(d, th, _CMP_LT_OQ)));
        if (close != 0) {
            close &= ~diagonals_far_avx2(slots, first + p, diagonals, dop_error, th);
        }
        near |= close << p;
    }
    return near & static_cast<unsigned>((std::uint64_t{1} << n) - 1U);
}

// Eight slots' (k..k+7) single-precision box distances to slot `row`'s box (leaf_row_portable's
// operations), and the lanes whose diagonal gaps keep them apart.
// max(max(0, lo[row] - hi[k..k+7]), lo[k..k+7] - hi[row]): one axis of the box gaps.
__attribute__((target("avx2"))) inline __m256 row_gap(const float* lo, const float* hi,
                                                      std::uint32_t k, std::uint32_t row) {
    return _mm256_max_ps(_mm256_max_ps(_mm256_setzero_ps(), _mm256_sub_ps(_mm256_set1_ps(lo[row]),
                                                                          _mm256_loadu_ps(hi + k))),
                         _mm256_sub_ps(_mm256_loadu_ps(lo + k), _mm256_set1_ps(hi[row])));
}

__attribute__((target("avx2"))) __m256 row_box_distances(const LeafSlots& slots, std::uint32_t k,
                                                         std::uint32_t row) {
    const __m256 zero = _mm256_setzero_ps();
    const __m256 gx = row_gap(slots.flox.get(), slots.fhix.get(), k, row);
    const __m256 gy = row_gap(slots.floy.get(), slots.fhiy.get(), k, row);
    const __m256 gz = row_gap(slots.floz.get(), slots.fhiz.get(), k, row);
    __m256 d = _mm256_add_ps(zero, _mm256_mul_ps(gx, gx));
    d = _mm256_add_ps(d, _mm256_mul_ps(gy, gy));
    d = _mm256_add_ps(d, _mm256_mul_ps(gz, gz));
    return _mm256_min_ps(d, _mm256_set1_ps(ROW_FLOAT_MAX));
}

__attribute__((target("avx2"))) unsigned row_diagonals_far(const LeafSlots& slots, std::uint32_t k,
                                                           std::uint32_t row, float dop_error,
                                                           __m256 th) {
    __m256 g[DiagonalExtents::N];
    for (int i = 0; i < DiagonalExtents::N; ++i) {
        g[i] = _mm256_max_ps(
            _mm256_sub_ps(_mm256_loadu_ps(&slots.fdlo[i][k]), _mm256_set1_ps(slots.fdhi[i][row])),
            _mm256_sub_ps(_mm256_set1_ps(slots.fdlo[i][row]), _mm256_loadu_ps(&slots.fdhi[i][k])));
    }
    const __m256 h =
        _mm256_sub_ps(_mm256_max_ps(_mm256_max_ps(g[0], g[1]), _mm256_max_ps(g[2], g[3])),
                      _mm256_set1_ps(dop_error));
    const __m256 far =
        _mm256_and_ps(_mm256_cmp_ps(h, _mm256_setzero_ps(), _CMP_GT_OQ),
                      _mm256_cmp_ps(_mm256_mul_ps(_mm256_mul_ps(h, h), _mm256_set1_ps(ROW_MARGIN)),
                                    _mm256_mul_ps(_mm256_set1_ps(3.0F), th), _CMP_GT_OQ));
    return static_cast<unsigned>(_mm256_movemask_ps(far));
}

__attribute__((target("avx2"))) unsigned leaf_row_avx2(const LeafSlots& slots, std::uint32_t first,
                                                       std::uint32_t n, std::uint32_t row,
                                                       float row_threshold_sq,
                                                       const float* threshold_sq, float dop_error) {
    unsigned pass = 0;
    const __m256 row_th = _mm256_set1_ps(row_threshold_sq);
    const __m256i a0 = _mm256_set1_epi32(static_cast<int>(slots.v0[row]));
    const __m256i a1 = _mm256_set1_epi32(static_cast<int>(slots.v1[row]));
    const __m256i a2 = _mm256_set1_epi32(static_cast<int>(slots.v2[row]));
    for (std::uint32_t q = 0; q < n; q += 8) {
        const std::uint32_t k = first + q;
        const __m256 d = row_box_distances(slots, k, row);
        const __m256 th = _mm256_max_ps(row_th, _mm256_loadu_ps(threshold_sq + q));
        auto close = static_cast<unsigned>(_mm256_movemask_ps(
            _mm256_cmp_ps(_mm256_mul_ps(d, _mm256_set1_ps(ROW_MARGIN)), th, _CMP_LT_OQ)));
        const __m256i b0 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(&slots.v0[k]));
        const __m256i b1 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(&slots.v1[k]));
        const __m256i b2 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(&slots.v2[k]));
        __m256i shared = _mm256_or_si256(_mm256_cmpeq_epi32(a0, b0), _mm256_cmpeq_epi32(a0, b1));
        shared = _mm256_or_si256(shared, _mm256_cmpeq_epi32(a0, b2));
        shared = _mm256_or_si256(shared, _mm256_cmpeq_epi32(a1, b0));
        shared = _mm256_or_si256(shared, _mm256_cmpeq_epi32(a1, b1));
        shared = _mm256_or_si256(shared, _mm256_cmpeq_epi32(a1, b2));
        shared = _mm256_or_si256(shared, _mm256_cmpeq_epi32(a2, b0));
        shared = _mm256_or_si256(shared, _mm256_cmpeq_epi32(a2, b1));
        shared = _mm256_or_si256(shared, _mm256_cmpeq_epi32(a2, b2));
        const auto adjacent =
            static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(shared)));
        close &= ~adjacent & 0xFFU;
        // The diagonal gaps only where a box passed.
        if (close != 0) {
            close &= ~row_diagonals_far(slots, k, row, dop_error, th);
        }
        pass |= close << q;
    }
    return pass & static_cast<unsigned>((std::uint64_t{1} << n) - 1U);
}

// leaf_thresholds_portable four at a time: the bounds loaded one by one (relaxed loads), then
// b * (1 + 4e-9) + 2e9 * slack * slack and float_threshold's y = th + (|th| 2^-22 + 1e-36),
// infinite above 1e30 (cvtpd2ps rounds to nearest as the conversion does), in the same order.
__attribute__((target("avx2"))) double leaf_thresholds_avx2(const std::atomic<double>* bounds,
                                                            const std::uint32_t* idx,
                                                            std::uint32_t n, double slack,
                                                            double* out, float* out_f) {
    const __m256d scale = _mm256_set1_pd(1.0 + 4e-9);
    const __m256d absolute = _mm256_set1_pd(2e9 * slack * slack);
    const __m256d sign = _mm256_set1_pd(-0.0);
    const __m256d rel = _mm256_set1_pd(0x1p-22);
    const __m256d tiny = _mm256_set1_pd(1e-36);
    const __m256d huge = _mm256_set1_pd(1e30);
    const __m256d inf = _mm256_set1_pd(std::numeric_limits<double>::infinity());
    __m256d largest = _mm256_setzero_pd();
    std::uint32_t q = 0;
    for (; q + 4 <= n; q += 4) {
        const __m256d b = _mm256_set_pd(bounds[idx[q + 3]].load(std::memory_order_relaxed),
                                        bounds[idx[q + 2]].load(std::memory_order_relaxed),
                                        bounds[idx[q + 1]].load(std::memory_order_relaxed),
                                        bounds[idx[q]].load(std::memory_order_relaxed));
        const __m256d th = _mm256_add_pd(_mm256_mul_pd(b, scale), absolute);
        _mm256_storeu_pd(out + q, th);
        const __m256d y =
            _mm256_add_pd(th, _mm256_add_pd(_mm256_mul_pd(_mm256_andnot_pd(sign, th), rel), tiny));
        const __m256d capped = _mm256_blendv_pd(y, inf, _mm256_cmp_pd(y, huge, _CMP_GT_OQ));
        _mm_storeu_ps(out_f + q, _mm256_cvtpd_ps(capped));
        // std::max(largest, th) = largest < th ? th : largest: maxpd(th, largest).
        largest = _mm256_max_pd(th, largest);
    }
    alignas(32) double lanes[4];
    _mm256_store_pd(lanes, largest);
    // The last n mod 4 by the portable copy (its largest is 0 when there are none).
    return std::max(std::max(std::max(lanes[0], lanes[1]), std::max(lanes[2], lanes[3])),
                    leaf_thresholds_portable(bounds, idx + q, n - q, slack, out + q, out_f + q));
}

// float_below / float_above of in[begin..end) into out, four at a time (the same operations:
// cvtpd2ps rounds to nearest as the conversion does; minpd(x, m) = x < m ? x : m is std::min(x, m)
// for no NaN, maxpd likewise).
template <bool Above>
__attribute__((target("avx2"))) void to_float_avx2(const double* in, float* out, std::size_t begin,
                                                   std::size_t end) {
    const __m256d sign = _mm256_set1_pd(-0.0);
    const __m256d rel = _mm256_set1_pd(0x1p-22);
    const __m256d abs_margin = _mm256_set1_pd(1e-44);
    const __m256d limit =
        _mm256_set1_pd(Above ? -static_cast<double>(std::numeric_limits<float>::max())
                             : static_cast<double>(std::numeric_limits<float>::max()));
    std::size_t k = begin;
    for (; k + 4 <= end; k += 4) {
        const __m256d x = _mm256_loadu_pd(in + k);
        const __m256d margin =
            _mm256_add_pd(_mm256_mul_pd(_mm256_andnot_pd(sign, x), rel), abs_margin);
        const __m256d y = Above ? _mm256_max_pd(_mm256_add_pd(x, margin), limit)
                                : _mm256_min_pd(_mm256_sub_pd(x, margin), limit);
        _mm_storeu_ps(out + k, _mm256_cvtpd_ps(y));
    }
    for (; k < end; ++k) {
        out[k] = Above ? float_above(in[k]) : float_below(in[k]);
    }
}

// Read once at start-up (leaf_row runs about a million times a query; a call before this, from
// another file's static initializer, would take the portable copy: the same result).
const bool HAS_AVX2 = cpu_has_avx2();

}  // namespace

unsigned leaf_row(const LeafSlots& slots, std::uint32_t first, std::uint32_t n, std::uint32_t row,
                  float row_threshold_sq, const float* threshold_sq, float dop_error) {
    return HAS_AVX2
               ? leaf_row_avx2(slots, first, n, row, row_threshold_sq, threshold_sq, dop_error)
               : leaf_row_portable(slots, first, n, row, row_threshold_sq, threshold_sq, dop_error);
}

double leaf_thresholds(const std::atomic<double>* bounds, const std::uint32_t* idx, std::uint32_t n,
                       double slack, double* out, float* out_f) {
    return HAS_AVX2 ? leaf_thresholds_avx2(bounds, idx, n, slack, out, out_f)
                    : leaf_thresholds_portable(bounds, idx, n, slack, out, out_f);
}

unsigned leaf_rows_near(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                        const Aabb& box, const DiagonalExtents& diagonals,
                        const double* threshold_sq, double other_sq, double dop_error) {
    return HAS_AVX2 ? leaf_rows_near_avx2(slots, first, n, box, diagonals, threshold_sq, other_sq,
                                          dop_error)
                    : leaf_rows_near_portable(slots, first, n, box, diagonals, threshold_sq,
                                              other_sq, dop_error);
}
#else
unsigned leaf_row(const LeafSlots& slots, std::uint32_t first, std::uint32_t n, std::uint32_t row,
                  float row_threshold_sq, const float* threshold_sq, float dop_error) {
    return leaf_row_portable(slots, first, n, row, row_threshold_sq, threshold_sq, dop_error);
}

double leaf_thresholds(const std::atomic<double>* bounds, const std::uint32_t* idx, std::uint32_t n,
                       double slack, double* out, float* out_f) {
    return leaf_thresholds_portable(bounds, idx, n, slack, out, out_f);
}

unsigned leaf_rows_near(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                        const Aabb& box, const DiagonalExtents& diagonals,
                        const double* threshold_sq, double other_sq, double dop_error) {
    return leaf_rows_near_portable(slots, first, n, box, diagonals, threshold_sq, other_sq,
                                   dop_error);
}
#endif

namespace {
// float_below (Above false) or float_above of in[begin..end) into out.
template <bool Above>
void to_float(const double* in, float* out, std::size_t begin, std::size_t end) {
#ifdef PROXIMA_X86_64_DISPATCH
    if (HAS_AVX2) {
        to_float_avx2<Above>(in, out, begin, end);
        return;
    }
#endif
    for (std::size_t k = begin; k < end; ++k) {
        out[k] = Above ? float_above(in[k]) : float_below(in[k]);
    }
}
}  // namespace

void LeafSlots::round_to_float(std::size_t begin, std::size_t end) {
    to_float<false>(lox.get(), flox.get(), begin, end);
    to_float<false>(loy.get(), floy.get(), begin, end);
    to_float<false>(loz.get(), floz.get(), begin, end);
    to_float<true>(hix.get(), fhix.get(), begin, end);
    to_float<true>(hiy.get(), fhiy.get(), begin, end);
    to_float<true>(hiz.get(), fhiz.get(), begin, end);
    for (int i = 0; i < DiagonalExtents::N; ++i) {
        to_float<false>(dlo[i].get(), fdlo[i].get(), begin, end);
        to_float<true>(dhi[i].get(), fdhi[i].get(), begin, end);
    }
}

}  // namespace proxima::detail
