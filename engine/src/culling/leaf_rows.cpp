// The self traversal's leaf rows: see proxima/culling/leaf_rows.hpp.
#include "proxima/culling/leaf_rows.hpp"

#include <algorithm>

#include "cpu_features.hpp"

#ifdef PROXIMA_X86_64_DISPATCH
#include <immintrin.h>
#endif

namespace proxima::detail {

void LeafSlots::resize(std::size_t n) {
    for (auto* a : {&lox, &loy, &loz, &hix, &hiy, &hiz}) {
        a->assign(n + PAD, 0.0);
    }
    for (auto* a : {&v0, &v1, &v2}) {
        a->assign(n + PAD, 0U);
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
                                 const Aabb& box, const double* threshold_sq, double other_sq) {
    unsigned near = 0;
    for (std::uint32_t p = 0; p < n; ++p) {
        if (slot_box_distance(slots, first + p, box) < std::max(threshold_sq[p], other_sq)) {
            near |= 1U << p;
        }
    }
    return near;
}

unsigned leaf_row_portable(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                           const Aabb& box, const TriangleIndices& v, double row_threshold_sq,
                           const double* threshold_sq) {
    unsigned pass = 0;
    for (std::uint32_t q = 0; q < n; ++q) {
        const std::uint32_t k = first + q;
        if (v[0] == slots.v0[k] || v[0] == slots.v1[k] || v[0] == slots.v2[k] ||
            v[1] == slots.v0[k] || v[1] == slots.v1[k] || v[1] == slots.v2[k] ||
            v[2] == slots.v0[k] || v[2] == slots.v1[k] || v[2] == slots.v2[k]) {
            continue;
        }
        if (slot_box_distance(slots, k, box) < std::max(row_threshold_sq, threshold_sq[q])) {
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

__attribute__((target("avx2"))) unsigned leaf_rows_near_avx2(const LeafSlots& slots,
                                                             std::uint32_t first, std::uint32_t n,
                                                             const Aabb& box,
                                                             const double* threshold_sq,
                                                             double other_sq) {
    unsigned near = 0;
    const __m256d other = _mm256_set1_pd(other_sq);
    for (std::uint32_t p = 0; p < n; p += 4) {
        const __m256d d = box_distances_avx2(slots, first + p, box);
        const __m256d th = _mm256_max_pd(_mm256_loadu_pd(threshold_sq + p), other);
        near |= static_cast<unsigned>(_mm256_movemask_pd(_mm256_cmp_pd(d, th, _CMP_LT_OQ))) << p;
    }
    return near & ((1U << n) - 1U);
}

__attribute__((target("avx2"))) unsigned leaf_row_avx2(const LeafSlots& slots, std::uint32_t first,
                                                       std::uint32_t n, const Aabb& box,
                                                       const TriangleIndices& v,
                                                       double row_threshold_sq,
                                                       const double* threshold_sq) {
    unsigned pass = 0;
    const __m256d row = _mm256_set1_pd(row_threshold_sq);
    const __m128i a0 = _mm_set1_epi32(static_cast<int>(v[0]));
    const __m128i a1 = _mm_set1_epi32(static_cast<int>(v[1]));
    const __m128i a2 = _mm_set1_epi32(static_cast<int>(v[2]));
    for (std::uint32_t q = 0; q < n; q += 4) {
        const std::uint32_t k = first + q;
        const __m256d d = box_distances_avx2(slots, k, box);
        const __m256d th = _mm256_max_pd(row, _mm256_loadu_pd(threshold_sq + q));
        const auto close =
            static_cast<unsigned>(_mm256_movemask_pd(_mm256_cmp_pd(d, th, _CMP_LT_OQ)));
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
        pass |= (close & ~adjacent & 0xFU) << q;
    }
    return pass & ((1U << n) - 1U);
}

// Read once at start-up (leaf_row runs about a million times a query; a call before this, from
// another file's static initializer, would take the portable copy: the same result).
const bool HAS_AVX2 = cpu_has_avx2();

}  // namespace

unsigned leaf_row(const LeafSlots& slots, std::uint32_t first, std::uint32_t n, const Aabb& box,
                  const TriangleIndices& v, double row_threshold_sq, const double* threshold_sq) {
    return HAS_AVX2 ? leaf_row_avx2(slots, first, n, box, v, row_threshold_sq, threshold_sq)
                    : leaf_row_portable(slots, first, n, box, v, row_threshold_sq, threshold_sq);
}

unsigned leaf_rows_near(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                        const Aabb& box, const double* threshold_sq, double other_sq) {
    return HAS_AVX2 ? leaf_rows_near_avx2(slots, first, n, box, threshold_sq, other_sq)
                    : leaf_rows_near_portable(slots, first, n, box, threshold_sq, other_sq);
}
#else
unsigned leaf_row(const LeafSlots& slots, std::uint32_t first, std::uint32_t n, const Aabb& box,
                  const TriangleIndices& v, double row_threshold_sq, const double* threshold_sq) {
    return leaf_row_portable(slots, first, n, box, v, row_threshold_sq, threshold_sq);
}

unsigned leaf_rows_near(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                        const Aabb& box, const double* threshold_sq, double other_sq) {
    return leaf_rows_near_portable(slots, first, n, box, threshold_sq, other_sq);
}
#endif

}  // namespace proxima::detail
