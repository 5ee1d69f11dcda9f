// edge_frame of four triangles at once: see edge_frames in proxima/distance/bounds.hpp.
//
// A frame costs six square roots and three divisions, one dependent on the next; one per triangle
// per self query, they took a tenth of n-body's self query. The AVX2 copy computes four triangles'
// frames at once with the same IEEE operations in the same order as edge_frame (this file is
// compiled with -ffp-contract=off), so the frames are the same bit for bit: a lane that takes one
// of edge_frame's branches (a sliver's plane, a zero-length edge normal) gets its value by a blend.
#include "proxima/distance/bounds.hpp"

#include "cpu_features.hpp"

#ifdef PROXIMA_X86_64_DISPATCH
#include <immintrin.h>
#endif

namespace proxima {

namespace {

void edge_frames_portable(const Triangle* const in[4], EdgeFrame* const out[4]) {
    for (int l = 0; l < 4; ++l) {
        *out[l] = edge_frame(*in[l]);
    }
}

#ifdef PROXIMA_X86_64_DISPATCH

struct V3 {
    __m256d x, y, z;
};

__attribute__((target("avx2"))) inline V3 sub(const V3& a, const V3& b) {
    return {_mm256_sub_pd(a.x, b.x), _mm256_sub_pd(a.y, b.y), _mm256_sub_pd(a.z, b.z)};
}

// a.x * b.x + a.y * b.y + a.z * b.z, left to right (dot in vec3.hpp).
__attribute__((target("avx2"))) inline __m256d dot4(const V3& a, const V3& b) {
    return _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(a.x, b.x), _mm256_mul_pd(a.y, b.y)),
                         _mm256_mul_pd(a.z, b.z));
}

// cross in vec3.hpp.
__attribute__((target("avx2"))) inline V3 cross4(const V3& a, const V3& b) {
    return {_mm256_sub_pd(_mm256_mul_pd(a.y, b.z), _mm256_mul_pd(a.z, b.y)),
            _mm256_sub_pd(_mm256_mul_pd(a.z, b.x), _mm256_mul_pd(a.x, b.z)),
            _mm256_sub_pd(_mm256_mul_pd(a.x, b.y), _mm256_mul_pd(a.y, b.x))};
}

// std::max(a, b) = a < b ? b : a, NaN included: maxpd(x, y) = x > y ? x : y.
__attribute__((target("avx2"))) inline __m256d max2(__m256d a, __m256d b) {
    return _mm256_max_pd(b, a);
}

// |x| + |y| + |z|, left to right (l1_norm in bounds.cpp).
__attribute__((target("avx2"))) inline __m256d l1(const V3& a) {
    const __m256d sign = _mm256_set1_pd(-0.0);
    return _mm256_add_pd(_mm256_add_pd(_mm256_andnot_pd(sign, a.x), _mm256_andnot_pd(sign, a.y)),
                         _mm256_andnot_pd(sign, a.z));
}

__attribute__((target("avx2"))) inline V3 corner(const Triangle* const t[4], int c) {
    return {_mm256_set_pd((*t[3])[c].x, (*t[2])[c].x, (*t[1])[c].x, (*t[0])[c].x),
            _mm256_set_pd((*t[3])[c].y, (*t[2])[c].y, (*t[1])[c].y, (*t[0])[c].y),
            _mm256_set_pd((*t[3])[c].z, (*t[2])[c].z, (*t[1])[c].z, (*t[0])[c].z)};
}

__attribute__((target("avx2"))) void edge_frames_avx2(const Triangle* const in[4],
                                                      EdgeFrame* const out[4]) {
    const __m256d zero = _mm256_setzero_pd();
    const V3 a[3] = {corner(in, 0), corner(in, 1), corner(in, 2)};
    // plane_frame: the normal, its length (0 for a sliver) and |e1| |e2|.
    const V3 e1 = sub(a[1], a[0]);
    const V3 e2 = sub(a[2], a[0]);
    const V3 nrm = cross4(e1, e2);
    const __m256d nn = _mm256_sqrt_pd(dot4(nrm, nrm));
    const __m256d l1l2 = _mm256_mul_pd(_mm256_sqrt_pd(dot4(e1, e1)), _mm256_sqrt_pd(dot4(e2, e2)));
    const __m256d sliver = _mm256_cmp_pd(nn, _mm256_mul_pd(_mm256_set1_pd(1e-6), l1l2),
                                         _CMP_NGT_UQ);  // !(nn > 1e-6 * l1l2)
    const __m256d plane_nn = _mm256_blendv_pd(nn, zero, sliver);
    // (a0 + a1 + a2) / 3 and the larger L1 distance from the first corner.
    const __m256d three = _mm256_set1_pd(3.0);
    const V3 centroid = {
        _mm256_div_pd(_mm256_add_pd(_mm256_add_pd(a[0].x, a[1].x), a[2].x), three),
        _mm256_div_pd(_mm256_add_pd(_mm256_add_pd(a[0].y, a[1].y), a[2].y), three),
        _mm256_div_pd(_mm256_add_pd(_mm256_add_pd(a[0].z, a[1].z), a[2].z), three)};
    const __m256d reach = max2(l1(e1), l1(e2));
    // Each edge's unit in-plane normal and the triangle's extent beyond it; both 0 where the
    // normal has no length.
    V3 normal[3];
    __m256d extent[3];
    for (int i = 0; i < 3; ++i) {
        const V3& p = a[i];
        const V3& q = a[i == 2 ? 0 : i + 1];
        const V3& r = a[i == 0 ? 2 : i - 1];
        const V3 qp = sub(q, p);
        const V3 m = cross4(qp, nrm);
        const __m256d len = _mm256_sqrt_pd(dot4(m, m));
        const __m256d none = _mm256_cmp_pd(len, zero, _CMP_NGT_UQ);  // !(len > 0)
        const __m256d inv = _mm256_div_pd(_mm256_set1_pd(1.0), len);
        const V3 u = {_mm256_mul_pd(inv, m.x), _mm256_mul_pd(inv, m.y), _mm256_mul_pd(inv, m.z)};
        const __m256d ext = max2(max2(zero, dot4(u, qp)), dot4(u, sub(r, p)));
        normal[i] = {_mm256_blendv_pd(u.x, zero, none), _mm256_blendv_pd(u.y, zero, none),
                     _mm256_blendv_pd(u.z, zero, none)};
        extent[i] = _mm256_blendv_pd(ext, zero, none);
    }
    // Back to one EdgeFrame per triangle.
    alignas(32) double v[21][4];
    int f = 0;
    for (int i = 0; i < 3; ++i) {
        _mm256_store_pd(v[f++], normal[i].x);
        _mm256_store_pd(v[f++], normal[i].y);
        _mm256_store_pd(v[f++], normal[i].z);
        _mm256_store_pd(v[f++], extent[i]);
    }
    for (const __m256d w :
         {nrm.x, nrm.y, nrm.z, plane_nn, l1l2, centroid.x, centroid.y, centroid.z, reach}) {
        _mm256_store_pd(v[f++], w);
    }
    for (int l = 0; l < 4; ++l) {
        EdgeFrame& e = *out[l];
        f = 0;
        for (int i = 0; i < 3; ++i) {
            e.normal[i] = {v[f][l], v[f + 1][l], v[f + 2][l]};
            e.extent[i] = v[f + 3][l];
            f += 4;
        }
        e.plane.n = {v[12][l], v[13][l], v[14][l]};
        e.plane.nn = v[15][l];
        e.plane.l1l2 = v[16][l];
        e.centroid = {v[17][l], v[18][l], v[19][l]};
        e.reach = v[20][l];
    }
}

// Read once at start-up (a call before this, from another file's static initializer, would take
// the portable copy: the same frames).
const bool HAS_AVX2 = detail::cpu_has_avx2();

#endif

}  // namespace

void edge_frames(const Triangle* const in[4], EdgeFrame* const out[4]) {
#ifdef PROXIMA_X86_64_DISPATCH
    if (HAS_AVX2) {
        edge_frames_avx2(in, out);
        return;
    }
#endif
    edge_frames_portable(in, out);
}

}  // namespace proxima
