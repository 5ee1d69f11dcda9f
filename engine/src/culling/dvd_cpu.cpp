// The CPU backend of the discrete-Voronoi kernel (proxima/culling/dvd.hpp), and the kernel's
// single-precision point-triangle distance, which the GLSL kernel mirrors operation for operation.
// This file is compiled with -ffp-contract=off (engine/CMakeLists.txt): no fused multiply-add, so
// every product and sum below is rounded on its own, as in GLSL with `precise`.
//
// ---------------------------------------------------------------------------------------------
// THE OPERATION SEQUENCE (mirror it exactly; every line is one IEEE single-precision operation
// or a comparison; parentheses are the evaluation order; no fma, no min()/max()/clamp()/dot()
// library calls, only the final sqrt):
//
//   segment(p, v0, v1) -> (ss, ee, ww):          // squared distance from p to segment [v0, v1]
//       wx = px - v0x;  wy = py - v0y;  wz = pz - v0z
//       ex = v1x - v0x; ey = v1y - v0y; ez = v1z - v0z
//       ee = ((ex * ex) + (ey * ey)) + (ez * ez)
//       ww = ((wx * wx) + (wy * wy)) + (wz * wz)
//       we = ((wx * ex) + (wy * ey)) + (wz * ez)
//       t = 0
//       if (ee > 0) { t = we / ee; if (t < 0) t = 0; if (t > 1) t = 1; }
//       dx = wx - (t * ex); dy = wy - (t * ey); dz = wz - (t * ez)
//       ss = ((dx * dx) + (dy * dy)) + (dz * dz)
//
//   point_triangle_distance_squared(p, a, b, c):
//       (s0, e0, w0) = segment(p, a, b)        // edge ab, w = p - a
//       (s1, e1, w1) = segment(p, b, c)        // edge bc, w = p - b
//       (s2, e2, w2) = segment(p, c, a)        // edge ca, w = p - c
//       best = s0; if (s1 < best) best = s1; if (s2 < best) best = s2
//       abx = bx - ax; aby = by - ay; abz = bz - az
//       acx = cx - ax; acy = cy - ay; acz = cz - az
//       apx = px - ax; apy = py - ay; apz = pz - az
//       nx = (aby * acz) - (abz * acy)
//       ny = (abz * acx) - (abx * acz)
//       nz = (abx * acy) - (aby * acx)
//       nn = ((nx * nx) + (ny * ny)) + (nz * nz)
//       if (nn > 0) {
//           side(p, v0, v1, n):                // ((v1 - v0) x (p - v0)) . n
//               ex = v1x - v0x; ey = v1y - v0y; ez = v1z - v0z
//               wx = px - v0x;  wy = py - v0y;  wz = pz - v0z
//               cx = (ey * wz) - (ez * wy)
//               cy = (ez * wx) - (ex * wz)
//               cz = (ex * wy) - (ey * wx)
//               return ((cx * nx) + (cy * ny)) + (cz * nz)
//           q0 = side(p, a, b, n); q1 = side(p, b, c, n); q2 = side(p, c, a, n)
//           g = e0 + e2                        // |ab|^2 + |ac|^2 (fl(c - a) = -fl(a - c))
//           tol0 = TOL * ((e0 + w0) * g); tol1 = TOL * ((e1 + w1) * g); tol2 = TOL * ((e2 + w2) *
//           g) if (q0 >= -tol0 && q1 >= -tol1 && q2 >= -tol2) {
//               h = ((nx * apx) + (ny * apy)) + (nz * apz)
//               f = (h * h) / nn
//               if (f < best) best = f
//           }
//       }
//       return best
//   with TOL = 2^-20 (exactly 9.5367431640625e-07).
//
//   kernel loop per sample i (p = sample point, o = its owner):
//       r2 = radius * radius; best = +inf; nearest = NO_TRIANGLE
//       for k in bucket_offsets[b] .. bucket_offsets[b + 1] - 1 (ascending triangle indices):
//           t = bucket_triangles[k]
//           inter mode: skip when triangle_object[t] == triangle_object[o]
//           intra mode: skip when t == o or t shares a vertex id with o
//           d2 = point_triangle_distance_squared(p, corner 0, corner 1, corner 2 of t)
//           if (d2 <= r2 && d2 < best) { best = d2; nearest = t; }
//       distance[i] = nearest == NO_TRIANGLE ? +inf : sqrt(best)
// ---------------------------------------------------------------------------------------------
//
// Why this shape (docs/algorithms.md, "Discrete-Voronoi culling", has the full error argument):
// the culler needs the computed distance never to exceed the true one by more than
// kernel_error_bound (+ triangle_error_term), because a too-large value would make its lower bound
// wrong. The three edge candidates are each a distance to a subset of the triangle, computed with
// an error of a few units in the last place of the coordinates; the face candidate (distance to
// the supporting plane, a lower bound of the distance to the triangle) is taken whenever the
// projection of p may lie inside the triangle: the inside test accepts everything within `TOL`
// times a magnitude that exceeds the test's own rounding error, so a projection truly inside is
// never rejected; a projection wrongly accepted gives a smaller value (still safe for a lower
// bound). Only the plane distance of a badly shaped triangle (ill-conditioned normal) can be off
// by more; then the edge candidates are within the inradius, hence triangle_error_term.

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "proxima/culling/dvd.hpp"

namespace proxima::dvd {

namespace {

constexpr float TOL = 9.5367431640625e-07f;  // 2^-20
static_assert(TOL == 1.0f / 1048576.0f);

struct Segment {
    float ss;  // squared distance
    float ee;  // squared length of the edge
    float ww;  // squared distance from p to the first end
};

Segment segment(const float p[3], const float v0[3], const float v1[3]) {
    const float wx = p[0] - v0[0];
    const float wy = p[1] - v0[1];
    const float wz = p[2] - v0[2];
    const float ex = v1[0] - v0[0];
    const float ey = v1[1] - v0[1];
    const float ez = v1[2] - v0[2];
    const float ee = ((ex * ex) + (ey * ey)) + (ez * ez);
    const float ww = ((wx * wx) + (wy * wy)) + (wz * wz);
    const float we = ((wx * ex) + (wy * ey)) + (wz * ez);
    float t = 0.0f;
    if (ee > 0.0f) {
        t = we / ee;
        if (t < 0.0f) {
            t = 0.0f;
        }
        if (t > 1.0f) {
            t = 1.0f;
        }
    }
    const float dx = wx - (t * ex);
    const float dy = wy - (t * ey);
    const float dz = wz - (t * ez);
    return {((dx * dx) + (dy * dy)) + (dz * dz), ee, ww};
}

// ((e x w) . n) with e = v1 - v0, w = p - v0.
float side(const float p[3], const float v0[3], const float v1[3], float nx, float ny, float nz) {
    const float ex = v1[0] - v0[0];
    const float ey = v1[1] - v0[1];
    const float ez = v1[2] - v0[2];
    const float wx = p[0] - v0[0];
    const float wy = p[1] - v0[1];
    const float wz = p[2] - v0[2];
    const float cx = (ey * wz) - (ez * wy);
    const float cy = (ez * wx) - (ex * wz);
    const float cz = (ex * wy) - (ey * wx);
    return ((cx * nx) + (cy * ny)) + (cz * nz);
}

bool finite_all(const std::vector<float>& v) {
    return std::all_of(v.begin(), v.end(), [](float x) { return std::isfinite(x); });
}

class CpuBackend final : public Backend {
  public:
    std::string name() const override { return "cpu"; }
    bool is_gpu() const override { return false; }
    Status run(const KernelInput& in, KernelOutput& out) override {
        if (Status s = validate(in); !s.ok()) {
            return s;
        }
        const std::size_t n = in.sample_owner.size();
        out.distance.assign(n, std::numeric_limits<float>::infinity());
        out.nearest.assign(n, NO_TRIANGLE);
        const float r2 = in.radius * in.radius;
        const bool intra = in.mode == Mode::intra_object;
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 256), [&](const auto& range) {
            for (std::size_t i = range.begin(); i != range.end(); ++i) {
                const float* p = &in.sample_points[3 * i];
                const std::uint32_t owner = in.sample_owner[i];
                const std::uint32_t* ov = &in.triangle_indices[3 * std::size_t{owner}];
                const std::uint32_t bucket = in.sample_bucket[i];
                float best = std::numeric_limits<float>::infinity();
                std::uint32_t nearest = NO_TRIANGLE;
                for (std::uint32_t k = in.bucket_offsets[bucket]; k < in.bucket_offsets[bucket + 1];
                     ++k) {
                    const std::uint32_t t = in.bucket_triangles[k];
                    if (!intra) {
                        if (in.triangle_object[t] == in.triangle_object[owner]) {
                            continue;
                        }
                    } else {
                        if (t == owner) {
                            continue;
                        }
                        const std::uint32_t* tv = &in.triangle_indices[3 * std::size_t{t}];
                        bool adjacent = false;
                        for (int x = 0; x < 3; ++x) {
                            for (int y = 0; y < 3; ++y) {
                                adjacent = adjacent || tv[x] == ov[y];
                            }
                        }
                        if (adjacent) {
                            continue;
                        }
                    }
                    const float* v = &in.triangle_vertices[9 * std::size_t{t}];
                    const float d2 = point_triangle_distance_squared(p, v, v + 3, v + 6);
                    if (d2 <= r2 && d2 < best) {
                        best = d2;
                        nearest = t;
                    }
                }
                out.distance[i] = nearest == NO_TRIANGLE ? best : std::sqrt(best);
                out.nearest[i] = nearest;
            }
        });
        return {};
    }
};

}  // namespace

float point_triangle_distance_squared(const float p[3], const float a[3], const float b[3],
                                      const float c[3]) {
    const Segment s0 = segment(p, a, b);
    const Segment s1 = segment(p, b, c);
    const Segment s2 = segment(p, c, a);
    float best = s0.ss;
    if (s1.ss < best) {
        best = s1.ss;
    }
    if (s2.ss < best) {
        best = s2.ss;
    }
    const float abx = b[0] - a[0];
    const float aby = b[1] - a[1];
    const float abz = b[2] - a[2];
    const float acx = c[0] - a[0];
    const float acy = c[1] - a[1];
    const float acz = c[2] - a[2];
    const float apx = p[0] - a[0];
    const float apy = p[1] - a[1];
    const float apz = p[2] - a[2];
    const float nx = (aby * acz) - (abz * acy);
    const float ny = (abz * acx) - (abx * acz);
    const float nz = (abx * acy) - (aby * acx);
    const float nn = ((nx * nx) + (ny * ny)) + (nz * nz);
    if (nn > 0.0f) {
        const float q0 = side(p, a, b, nx, ny, nz);
        const float q1 = side(p, b, c, nx, ny, nz);
        const float q2 = side(p, c, a, nx, ny, nz);
        const float g = s0.ee + s2.ee;
        const float tol0 = TOL * ((s0.ee + s0.ww) * g);
        const float tol1 = TOL * ((s1.ee + s1.ww) * g);
        const float tol2 = TOL * ((s2.ee + s2.ww) * g);
        if (q0 >= -tol0 && q1 >= -tol1 && q2 >= -tol2) {
            const float h = ((nx * apx) + (ny * apy)) + (nz * apz);
            const float f = (h * h) / nn;
            if (f < best) {
                best = f;
            }
        }
    }
    return best;
}

// Derivation (u = 2^-24; GLSL rounds +, -, * correctly and allows up to 2.5 ulp for / and about
// 3 ulp for sqrt, so every division and square root below is charged 4u). M bounds the magnitude
// of every float coordinate relative to the origin; all difference vectors are then at most
// 2*sqrt(3)*M long.
//  1. Rounding the double inputs to float moves the sample and every vertex by at most
//     sqrt(3)*u*M: the distance changes by at most 2*sqrt(3)*u*M (~3.5uM).
//  2. Each difference vector (w = p - v0, e = v1 - v0, ...) is rounded once (relative u per
//     component): equivalent to moving p and the triangle by at most 2*sqrt(3)*u*M each
//     (~7uM for the distance).
//  3. An edge candidate with exact inputs w, e: the clamped parameter t is within
//     (2*gamma3 + 4u)|w|/|e| of the exact one (the dot products err by gamma3*|w||e|, and
//     |t*||e| <= |w|), which moves the point on the edge by at most 10.1u|w|; forming
//     d = w - t e errs by u(|e| + |d|); the final sum of squares and sqrt by 6u relative.
//     Total <= 12u|w| + 3u|e| + 6u*dist <= 73uM.
//  4. When the closest point is interior: the inside test's rounding error is at most
//     14.3u|e||w||ab||ac| <= 3.6u (|e|^2+|w|^2)(|ab|^2+|ac|^2) < TOL * (...) computed, so the
//     face candidate is taken; its value errs by at most (14.4*kappa + 10)u|ap| where
//     kappa = |ab||ac| / |ab x ac| (the normal's conditioning): <= (50 kappa + 35)uM. For a
//     badly shaped triangle the edges are within the inradius r: excess <= r + 73uM.
//  The sum of the shape-independent terms is below 120uM: kernel_error_bound returns twice that
//  (256uM = 2^-16 M), and triangle_error_term twice min(r, 50 kappa u M) (128 kappa u M), both
//  rounded up. A triangle with no face candidate (nn == 0) is degenerate in float: its points lie
//  within its (float) inradius, ~0, of its edges; the double triangle's inradius differs from the
//  float one's by O(uM), inside the headroom between 120uM and 256uM.
double kernel_error_bound(double max_abs_coordinate) {
    const double m = std::abs(max_abs_coordinate);
    // 2^-16 * M, plus an absolute term for underflow of products of tiny coordinates.
    return std::ldexp(m, -16) + 1e-30;
}

double triangle_error_term(const double a[3], const double b[3], const double c[3],
                           double max_abs_coordinate) {
    double ab[3], ac[3], bc[3];
    for (int k = 0; k < 3; ++k) {
        ab[k] = b[k] - a[k];
        ac[k] = c[k] - a[k];
        bc[k] = c[k] - b[k];
    }
    const double n[3] = {ab[1] * ac[2] - ab[2] * ac[1], ab[2] * ac[0] - ab[0] * ac[2],
                         ab[0] * ac[1] - ab[1] * ac[0]};
    auto norm = [](const double v[3]) {
        return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    };
    const double area2 = norm(n);
    if (!(area2 > 0.0)) {
        return 0.0;
    }
    const double perimeter = norm(ab) + norm(ac) + norm(bc);
    const double inradius = area2 / perimeter;
    const double kappa = norm(ab) * norm(ac) / area2;
    // 1% up for the rounding of this double evaluation.
    return 1.01 *
           std::min(2.0 * inradius, 128.0 * kappa * std::ldexp(std::abs(max_abs_coordinate), -24));
}

Status validate(const KernelInput& in) {
    if (!(in.radius > 0.0f) || !std::isfinite(in.radius)) {
        return invalid_argument("dvd kernel: radius must be finite and > 0, got " +
                                std::to_string(in.radius));
    }
    if (in.mode != Mode::inter_object && in.mode != Mode::intra_object) {
        return invalid_argument("dvd kernel: unknown mode " +
                                std::to_string(static_cast<std::uint32_t>(in.mode)));
    }
    if (in.triangle_vertices.size() % 9 != 0) {
        return invalid_argument("dvd kernel: triangle_vertices size " +
                                std::to_string(in.triangle_vertices.size()) +
                                " is not a multiple of 9");
    }
    const std::size_t nt = in.triangle_vertices.size() / 9;
    if (nt >= NO_TRIANGLE) {
        return invalid_argument("dvd kernel: too many triangles");
    }
    if (in.triangle_indices.size() != 3 * nt) {
        return invalid_argument("dvd kernel: triangle_indices has " +
                                std::to_string(in.triangle_indices.size()) + " entries, expected " +
                                std::to_string(3 * nt));
    }
    if (in.triangle_object.size() != nt) {
        return invalid_argument("dvd kernel: triangle_object has " +
                                std::to_string(in.triangle_object.size()) + " entries, expected " +
                                std::to_string(nt));
    }
    if (!finite_all(in.triangle_vertices)) {
        return invalid_argument("dvd kernel: a triangle coordinate is not finite");
    }
    if (!(in.bucket_size > 0.0f) || !std::isfinite(in.bucket_size) ||
        !std::isfinite(in.bucket_origin[0]) || !std::isfinite(in.bucket_origin[1]) ||
        !std::isfinite(in.bucket_origin[2])) {
        return invalid_argument("dvd kernel: bucket grid origin and size must be finite, size > 0");
    }
    std::uint64_t buckets = 1;
    for (auto d : in.bucket_dims) {
        buckets *= d;
        if (buckets >= NO_TRIANGLE) {
            return invalid_argument("dvd kernel: bucket grid too large");
        }
    }
    if (in.bucket_offsets.size() != buckets + 1) {
        return invalid_argument("dvd kernel: bucket_offsets has " +
                                std::to_string(in.bucket_offsets.size()) + " entries, expected " +
                                std::to_string(buckets + 1));
    }
    if (in.bucket_offsets.front() != 0 || in.bucket_offsets.back() != in.bucket_triangles.size()) {
        return invalid_argument(
            "dvd kernel: bucket_offsets must start at 0 and end at bucket_triangles' size");
    }
    for (std::size_t b = 0; b < buckets; ++b) {
        const auto lo = in.bucket_offsets[b];
        const auto hi = in.bucket_offsets[b + 1];
        if (hi < lo) {
            return invalid_argument("dvd kernel: bucket_offsets decrease at bucket " +
                                    std::to_string(b));
        }
        for (auto k = lo; k < hi; ++k) {
            if (in.bucket_triangles[k] >= nt) {
                return invalid_argument(
                    "dvd kernel: bucket " + std::to_string(b) + " lists triangle " +
                    std::to_string(in.bucket_triangles[k]) + " of " + std::to_string(nt));
            }
            if (k > lo && in.bucket_triangles[k] <= in.bucket_triangles[k - 1]) {
                return invalid_argument("dvd kernel: bucket " + std::to_string(b) +
                                        " list is not strictly ascending");
            }
        }
    }
    if (in.sample_points.size() % 3 != 0) {
        return invalid_argument("dvd kernel: sample_points size is not a multiple of 3");
    }
    const std::size_t ns = in.sample_points.size() / 3;
    if (in.sample_owner.size() != ns || in.sample_bucket.size() != ns) {
        return invalid_argument("dvd kernel: " + std::to_string(ns) + " samples but " +
                                std::to_string(in.sample_owner.size()) + " owners and " +
                                std::to_string(in.sample_bucket.size()) + " buckets");
    }
    if (!finite_all(in.sample_points)) {
        return invalid_argument("dvd kernel: a sample coordinate is not finite");
    }
    for (std::size_t i = 0; i < ns; ++i) {
        if (in.sample_owner[i] >= nt) {
            return invalid_argument("dvd kernel: sample " + std::to_string(i) + " owner " +
                                    std::to_string(in.sample_owner[i]) + " out of range (" +
                                    std::to_string(nt) + " triangles)");
        }
        if (in.sample_bucket[i] >= buckets) {
            return invalid_argument("dvd kernel: sample " + std::to_string(i) + " bucket " +
                                    std::to_string(in.sample_bucket[i]) + " out of range (" +
                                    std::to_string(buckets) + " buckets)");
        }
    }
    return {};
}

std::shared_ptr<Backend> make_cpu_backend() {
    return std::make_shared<CpuBackend>();
}

}  // namespace proxima::dvd
