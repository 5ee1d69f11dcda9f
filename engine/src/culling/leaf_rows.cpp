// The self traversal's leaf rows: see proxima/culling/leaf_rows.hpp.
#include "proxima/culling/leaf_rows.hpp"

#include <algorithm>

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

Aabb slot_box(const LeafSlots& slots, std::uint32_t k) {
    return {{slots.lox[k], slots.loy[k], slots.loz[k]}, {slots.hix[k], slots.hiy[k], slots.hiz[k]}};
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

unsigned leaf_row_portable(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                           std::uint32_t row, double row_threshold_sq, const double* threshold_sq,
                           double dop_error) {
    const Aabb box = slot_box(slots, row);
    const DiagonalExtents diagonals = slots.diagonals(row);
    const TriangleIndices v{slots.v0[row], slots.v1[row], slots.v2[row]};
    unsigned pass = 0;
    for (std::uint32_t q = 0; q < n; ++q) {
        const std::uint32_t k = first + q;
        if (v[0] == slots.v0[k] || v[0] == slots.v1[k] || v[0] == slots.v2[k] ||
            v[1] == slots.v0[k] || v[1] == slots.v1[k] || v[1] == slots.v2[k] ||
            v[2] == slots.v0[k] || v[2] == slots.v1[k] || v[2] == slots.v2[k]) {
            continue;
        }
        const double th = std::max(row_threshold_sq, threshold_sq[q]);
        if (slot_box_distance(slots, k, box) < th &&
            !diagonals_far(diagonals, slots.diagonals(k), dop_error, th)) {
            pass |= 1U << q;
        }
    }
    return pass;
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

__attribute__((target("avx2"))) unsigned leaf_row_avx2(const LeafSlots& slots, std::uint32_t first,
                                                       std::uint32_t n, std::uint32_t row,
                                                       double row_threshold_sq,
                                                       const double* threshold_sq,
                                                       double dop_error) {
    const Aabb box = slot_box(slots, row);
    const DiagonalExtents diagonals = slots.diagonals(row);
    unsigned pass = 0;
    const __m256d row_th = _mm256_set1_pd(row_threshold_sq);
    const __m128i a0 = _mm_set1_epi32(static_cast<int>(slots.v0[row]));
    const __m128i a1 = _mm_set1_epi32(static_cast<int>(slots.v1[row]));
    const __m128i a2 = _mm_set1_epi32(static_cast<int>(slots.v2[row]));
    for (std::uint32_t q = 0; q < n; q += 4) {
        const std::uint32_t k = first + q;
        const __m256d d = box_distances_avx2(slots, k, box);
        const __m256d th = _mm256_max_pd(row_th, _mm256_loadu_pd(threshold_sq + q));
        auto close = static_cast<unsigned>(_mm256_movemask_pd(_mm256_cmp_pd(d, th, _CMP_LT_OQ)));
        const __m128i b0 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(&slots.v0[k]));
        const __m128i b1 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(&slots.v1[k]));
        const __m128i b2 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(&slots.v2[k]));
        __m128i shared = _mm_or_si128(_mm_cmpeq_epi32(a0, b0), _mm_cmpeq_epi32(a0, b1));
        shared = _mm_or_si128(shared, _mm_cmpeq_epi32(a0, b2));
        shared = _mm_or_si128(shared, _mm_cmpeq_epi32(a1, b0));
        shared = _mm_or_si128(shared, _mm_cmpeq_epi32(a1, b1));
        shared = _mm_or_si128(shared, _mm_cmpeq_epi32(a1, b2));
        shared = _mm_or_si128(shared, _mm_cmpeq_epi32(a2, b0));
        shared = _mm_or_si128(shared, _mm_cmpeq_epi32(a2, b1));
        shared = _mm_or_si128(shared, _mm_cmpeq_epi32(a2, b2));
        const auto adjacent = static_cast<unsigned>(_mm_movemask_ps(_mm_castsi128_ps(shared)));
        close &= ~adjacent & 0xFU;
        // The diagonal gaps only where a box passed.
        if (close != 0) {
            close &= ~diagonals_far_avx2(slots, k, diagonals, dop_error, th);
        }
        pass |= close << q;
    }
    return pass & static_cast<unsigned>((std::uint64_t{1} << n) - 1U);
}

// Read once at start-up (leaf_row runs about a million times a query; a call before this, from
// another file's static initializer, would take the portable copy: the same result).
const bool HAS_AVX2 = cpu_has_avx2();

}  // namespace

unsigned leaf_row(const LeafSlots& slots, std::uint32_t first, std::uint32_t n, std::uint32_t row,
                  double row_threshold_sq, const double* threshold_sq, double dop_error) {
    return HAS_AVX2
               ? leaf_row_avx2(slots, first, n, row, row_threshold_sq, threshold_sq, dop_error)
               : leaf_row_portable(slots, first, n, row, row_threshold_sq, threshold_sq, dop_error);
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
                  double row_threshold_sq, const double* threshold_sq, double dop_error) {
    return leaf_row_portable(slots, first, n, row, row_threshold_sq, threshold_sq, dop_error);
}

unsigned leaf_rows_near(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                        const Aabb& box, const DiagonalExtents& diagonals,
                        const double* threshold_sq, double other_sq, double dop_error) {
    return leaf_rows_near_portable(slots, first, n, box, diagonals, threshold_sq, other_sq,
                                   dop_error);
}
#endif

}  // namespace proxima::detail
