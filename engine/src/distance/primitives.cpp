// Closest points between points, segments and triangles (Ericson, Real-Time Collision Detection,
// 5.1.5 and 5.1.9, hardened for degenerate input) and the exact triangle-triangle intersection
// test built on orient2d / orient3d.
//
// Invariants kept by every routine here:
// - every quotient either has a denominator checked to be > 0 or is clamped to its parameter
//   range, where a NaN (0 / 0) or inf quotient maps into [0, 1]; so finite input never yields NaN
//   and returned points lie on their primitives up to the rounding of `a + t * (b - a)`;
// - `squared_distance` is always squared_norm(point_a - point_b) of the returned points;
// - intersection *decisions* use only the exact predicates; floating point is used only to place
//   witness points.

#include "proxima/distance/primitives.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

#include "proxima/geometry/predicates.hpp"

namespace proxima {

namespace {

// A triangle whose squared doubled area is below THIN * (longest edge)^4 has barycentric
// coordinates that Ericson's dot-product formulas cannot resolve (their error grows like
// eps / THIN); such slivers take the slower sliver path.
constexpr double THIN = 1e-6;
// Below this the plane normal's direction is itself unreliable (error ~ eps / sqrt(ratio)), so the
// triangle is treated as the union of its edges, whose distance is then off by at most the
// triangle's width (<= 1e-10 of its size).
constexpr double DEGENERATE = 1e-20;
using detail::NEARLY_PARALLEL;

inline ClosestPoints make_result(const Vec3& pa, const Vec3& pb) {
    return {squared_norm(pa - pb), pa, pb};
}

inline double clamp01(double t) {
    // Argument order matters: std::max(0.0, NaN) is 0.0, so a NaN quotient (0 / 0) maps to 0
    // instead of propagating. Compiles to maxsd / minsd, no branches.
    return std::min(1.0, std::max(0.0, t));
}

inline Vec3 closest_on_segment(const Vec3& p, const Vec3& a, const Vec3& b) {
    const Vec3 ab = b - a;
    const double len2 = dot(ab, ab);
    const double t = len2 > 0.0 ? clamp01(dot(p - a, ab) / len2) : 0.0;
    return a + t * ab;
}

inline void keep_closer(ClosestPoints& best, const ClosestPoints& candidate) {
    if (candidate.squared_distance < best.squared_distance) {
        best = candidate;
    }
}

ClosestPoints point_triangle_edges(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
    ClosestPoints best = make_result(p, closest_on_segment(p, a, b));
    keep_closer(best, make_result(p, closest_on_segment(p, b, c)));
    keep_closer(best, make_result(p, closest_on_segment(p, c, a)));
    return best;
}

// Slivers: the closest point is either the projection of p (when it falls inside) or on an edge.
// The normal is taken at the vertex opposite the longest edge, i.e. from the two shortest edges,
// which keeps its direction accurate for needles; the inside test uses the same normal.
Vec3 closest_on_sliver(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c, double ratio) {
    ClosestPoints best = point_triangle_edges(p, a, b, c);
    if (!(ratio > DEGENERATE)) {
        return best.point_b;
    }
    const double ab2 = squared_norm(b - a);
    const double bc2 = squared_norm(c - b);
    const double ca2 = squared_norm(a - c);
    Vec3 n;
    if (bc2 >= ab2 && bc2 >= ca2) {
        n = cross(b - a, c - a);
    } else if (ca2 >= ab2) {
        n = cross(c - b, a - b);
    } else {
        n = cross(a - c, b - c);
    }
    const double n2 = dot(n, n);
    if (!(n2 > 0.0)) {
        return best.point_b;
    }
    const bool inside = dot(cross(b - a, p - a), n) >= 0.0 && dot(cross(c - b, p - b), n) >= 0.0 &&
                        dot(cross(a - c, p - c), n) >= 0.0;
    if (inside) {
        const Vec3 q = p - (dot(n, p - a) / n2) * n;
        // Ties go to the projection: when p projects inside it is the exact answer, and an edge
        // point can tie only through rounding.
        if (is_finite(q) && squared_norm(p - q) <= best.squared_distance) {
            return q;
        }
    }
    return best.point_b;
}

// What Ericson's closest-point routine needs about a triangle, computed once per triangle so that
// the three vertex queries of triangle_triangle share it.
struct TriangleFrame {
    Vec3 a, b, c;
    Vec3 ab, ac, bc;
    Vec3 normal;  // ab x ac
    double abab, abac, acac;
    double ratio;  // for slivers: squared doubled area over (longest edge)^4; 0 or NaN if unusable
    bool sliver;
};

inline TriangleFrame make_frame(const Vec3& a, const Vec3& b, const Vec3& c) {
    TriangleFrame f;
    f.a = a;
    f.b = b;
    f.c = c;
    f.ab = b - a;
    f.ac = c - a;
    f.bc = c - b;
    f.normal = cross(f.ab, f.ac);
    f.abab = dot(f.ab, f.ab);
    f.abac = dot(f.ab, f.ac);
    f.acac = dot(f.ac, f.ac);
    const double longest = std::max({f.abab, f.acac, dot(f.bc, f.bc)});
    const double scale = longest * longest;
    const double n2 = squared_norm(f.normal);
    // Also catches scale == 0 (a point-like triangle) and overflow (inf or NaN).
    f.sliver = !(n2 > THIN * scale);
    f.ratio = f.sliver && scale > 0.0 ? n2 / scale : 0.0;
    return f;
}

// Ericson 5.1.5, with d3..d6 derived from d1, d2 and the frame's edge products (bp = ap - ab,
// cp = ap - ac). Regions are tested in his order; for a non-sliver triangle every denominator is
// positive, and each is checked anyway.
inline Vec3 closest_on_triangle(const TriangleFrame& f, const Vec3& p) {
    if (f.sliver) {
        return closest_on_sliver(p, f.a, f.b, f.c, f.ratio);
    }
    const Vec3 ap = p - f.a;
    const double d1 = dot(f.ab, ap);
    const double d2 = dot(f.ac, ap);
    if (d1 <= 0.0 && d2 <= 0.0) {
        return f.a;
    }
    const double d3 = d1 - f.abab;  // ab . bp
    const double d4 = d2 - f.abac;  // ac . bp
    if (d3 >= 0.0 && d4 <= d3) {
        return f.b;
    }
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
        const double v = f.abab > 0.0 ? clamp01(d1 / f.abab) : 0.0;
        return f.a + v * f.ab;
    }
    const double d5 = d1 - f.abac;  // ab . cp
    const double d6 = d2 - f.acac;  // ac . cp
    if (d6 >= 0.0 && d5 <= d6) {
        return f.c;
    }
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
        const double w = f.acac > 0.0 ? clamp01(d2 / f.acac) : 0.0;
        return f.a + w * f.ac;
    }
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
        const double num = d4 - d3;
        const double den = num + (d5 - d6);
        const double w = den > 0.0 ? clamp01(num / den) : 0.0;
        return f.b + w * f.bc;
    }
    const double sum = va + vb + vc;
    if (!(sum > 0.0)) {
        return point_triangle_edges(p, f.a, f.b, f.c).point_b;
    }
    // Rounding can leave vb or vc slightly negative; clamping keeps the point on the triangle.
    double v = std::max(0.0, vb / sum);
    double w = std::max(0.0, vc / sum);
    if (v + w > 1.0) {
        const double s = v + w;
        v /= s;
        w /= s;
    }
    return f.a + v * f.ab + w * f.ac;
}

struct Segment {
    Vec3 p;
    Vec3 d;       // end - p
    double len2;  // d . d
};

inline Segment make_segment(const Vec3& p0, const Vec3& p1) {
    const Vec3 d = p1 - p0;
    return {p0, d, dot(d, d)};
}

// Ericson 5.1.9: parameters s on P and t on Q of a closest pair. Exact zero tests rather than
// epsilons: any positive length is a valid divisor, and a quotient that overflows to inf is
// clamped like any other. For parallel segments (denom == 0) s starts at 0 and is recomputed
// after t is clamped, as in the book. Sets `nearly_parallel` when s is poorly conditioned.
inline void closest_parameters(const Segment& sp, const Segment& sq, double& s, double& t,
                               bool& nearly_parallel) {
    const Vec3 r = sp.p - sq.p;
    const double a = sp.len2;
    const double e = sq.len2;
    const double f = dot(sq.d, r);
    s = 0.0;
    t = 0.0;
    nearly_parallel = false;
    if (!(a > 0.0)) {
        if (e > 0.0) {
            t = clamp01(f / e);
        }
        return;
    }
    const double c = dot(sp.d, r);
    if (!(e > 0.0)) {
        s = clamp01(-c / a);
        return;
    }
    const double b = dot(sp.d, sq.d);
    const double denom = a * e - b * b;
    nearly_parallel = !(denom > NEARLY_PARALLEL * a * e);
    s = denom > 0.0 ? clamp01((b * f - c * e) / denom) : 0.0;
    const double tnom = b * s + f;
    if (tnom < 0.0) {
        t = 0.0;
        s = clamp01(-c / a);
    } else if (tnom > e) {
        t = 1.0;
        s = clamp01((b - c) / a);
    } else {
        t = clamp01(tnom / e);
    }
}

}  // namespace

ClosestPoints point_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
    return make_result(p, closest_on_triangle(make_frame(a, b, c), p));
}

ClosestPoints segment_segment(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1) {
    const Segment sp = make_segment(p0, p1);
    const Segment sq = make_segment(q0, q1);
    double s = 0.0;
    double t = 0.0;
    bool nearly_parallel = false;
    closest_parameters(sp, sq, s, t, nearly_parallel);
    ClosestPoints best = make_result(p0 + s * sp.d, q0 + t * sq.d);
    if (nearly_parallel) {
        // For (nearly) parallel segments a closest pair always exists with an endpoint of one of
        // them, and these candidates are well conditioned where s above is not.
        keep_closer(best, make_result(p0, closest_on_segment(p0, q0, q1)));
        keep_closer(best, make_result(p1, closest_on_segment(p1, q0, q1)));
        keep_closer(best, make_result(closest_on_segment(q0, p0, p1), q0));
        keep_closer(best, make_result(closest_on_segment(q1, p0, p1), q1));
    }
    return best;
}

namespace {

// ---- Exact intersection helpers -----------------------------------------------------------------

struct Point2 {
    double u;
    double v;
};

inline Point2 project(const Vec3& p, int drop) {
    switch (drop) {
        case 0:
            return {p.y, p.z};
        case 1:
            return {p.z, p.x};
        default:
            return {p.x, p.y};
    }
}

inline int orient(const Point2& a, const Point2& b, const Point2& c) {
    return orient2d(a.u, a.v, b.u, b.v, c.u, c.v);
}

// Closed 2D segments [p, q] and [r, s], either possibly a single point.
bool segments_intersect_2d(const Point2& p, const Point2& q, const Point2& r, const Point2& s) {
    const int o1 = orient(p, q, r);
    const int o2 = orient(p, q, s);
    const int o3 = orient(r, s, p);
    const int o4 = orient(r, s, q);
    if (o1 == 0 && o2 == 0 && o3 == 0 && o4 == 0) {
        // All four points on one line (or the segments are points): on a line, the closed
        // segments overlap iff their coordinate ranges overlap on both axes (one axis is injective
        // on the line; the other is then implied, or constant).
        return std::max(p.u, q.u) >= std::min(r.u, s.u) &&
               std::max(r.u, s.u) >= std::min(p.u, q.u) &&
               std::max(p.v, q.v) >= std::min(r.v, s.v) && std::max(r.v, s.v) >= std::min(p.v, q.v);
    }
    // Not all collinear. If o1 == o2 == 0 here, then p == q off the line rs (o3 == o4 != 0), and
    // symmetrically; the products reject those. Otherwise this is the usual straddle test.
    return o1 * o2 <= 0 && o3 * o4 <= 0;
}

// Closed 3D segments, exactly: coplanar (orient3d == 0) and intersecting in all three axis
// projections. Necessity is clear; sufficiency because some axis projection is injective on the
// affine hull of the four points (a plane, a line or a point), and an injective affine map
// preserves whether two sets meet.
bool segments_intersect_3d(const Vec3& p, const Vec3& q, const Vec3& r, const Vec3& s) {
    if (orient3d(p, q, r, s) != 0) {
        return false;
    }
    for (int drop = 0; drop < 3; ++drop) {
        if (!segments_intersect_2d(project(p, drop), project(q, drop), project(r, drop),
                                   project(s, drop))) {
            return false;
        }
    }
    return true;
}

// Per-triangle facts needed only in coplanar or degenerate situations; computed lazily.
struct TriangleShape {
    bool known = false;
    bool degenerate = false;  // all three vertices collinear (or coincident)
    int drop = 2;             // axis whose projection keeps the triangle non-degenerate
};

void classify(const Vec3& a, const Vec3& b, const Vec3& c, TriangleShape& shape) {
    if (shape.known) {
        return;
    }
    shape.known = true;
    // The three projections all vanish iff the normal (the cross product) is exactly zero.
    for (int drop = 2; drop >= 0; --drop) {
        if (orient(project(a, drop), project(b, drop), project(c, drop)) != 0) {
            shape.drop = drop;
            shape.degenerate = false;
            return;
        }
    }
    shape.degenerate = true;
}

inline Vec3 midpoint_of_closest(const Vec3& p, const Vec3& q, const Vec3& r, const Vec3& s) {
    const ClosestPoints cp = segment_segment(p, q, r, s);
    return 0.5 * (cp.point_a + cp.point_b);
}

// Closed 2D triangle (non-degenerate) contains x: no two of the edge orientations strictly differ.
inline bool inside_triangle_2d(const Point2& a, const Point2& b, const Point2& c, const Point2& x) {
    const int o1 = orient(a, b, x);
    const int o2 = orient(b, c, x);
    const int o3 = orient(c, a, x);
    const bool has_pos = o1 > 0 || o2 > 0 || o3 > 0;
    const bool has_neg = o1 < 0 || o2 < 0 || o3 < 0;
    return !(has_pos && has_neg);
}

// Floating-point value of the orient3d determinant; used only to place witness points.
inline double orient3d_value(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
    return dot(a - d, cross(b - d, c - d));
}

// Segment [p, q] against triangle (a, b, c), given sp = orient3d(a, b, c, p) and
// sq = orient3d(a, b, c, q).
bool segment_meets_triangle(const Vec3& p, const Vec3& q, int sp, int sq, const Vec3& a,
                            const Vec3& b, const Vec3& c, TriangleShape& shape, Vec3* witness) {
    if (sp * sq > 0) {
        return false;
    }
    if (sp != 0 || sq != 0) {
        // The segment's line pierces the (necessarily non-degenerate) triangle's plane at one
        // point, which lies on the closed segment. The line meets the closed triangle iff its
        // orientations against the three directed edges do not strictly disagree.
        const int e0 = orient3d(p, q, a, b);
        const int e1 = orient3d(p, q, b, c);
        const int e2 = orient3d(p, q, c, a);
        const bool has_pos = e0 > 0 || e1 > 0 || e2 > 0;
        const bool has_neg = e0 < 0 || e1 < 0 || e2 < 0;
        if (has_pos && has_neg) {
            return false;
        }
        if (witness != nullptr) {
            if (sp == 0) {
                *witness = p;
            } else if (sq == 0) {
                *witness = q;
            } else {
                const double vp = orient3d_value(a, b, c, p);
                const double vq = orient3d_value(a, b, c, q);
                const double den = vp - vq;
                const double t = den != 0.0 ? clamp01(vp / den) : 0.5;
                *witness = p + t * (q - p);
            }
        }
        return true;
    }

    classify(a, b, c, shape);
    if (shape.degenerate) {
        // The closed hull of collinear points is the union of the three edges.
        const Vec3* edges[3][2] = {{&a, &b}, {&b, &c}, {&c, &a}};
        for (const auto& edge : edges) {
            if (segments_intersect_3d(p, q, *edge[0], *edge[1])) {
                if (witness != nullptr) {
                    *witness = midpoint_of_closest(p, q, *edge[0], *edge[1]);
                }
                return true;
            }
        }
        return false;
    }

    // Coplanar with a non-degenerate triangle: decide in a projection that is injective on the
    // plane (its projected triangle has nonzero area, exactly).
    const Point2 a2 = project(a, shape.drop);
    const Point2 b2 = project(b, shape.drop);
    const Point2 c2 = project(c, shape.drop);
    const Point2 p2 = project(p, shape.drop);
    const Point2 q2 = project(q, shape.drop);
    if (inside_triangle_2d(a2, b2, c2, p2)) {
        if (witness != nullptr) {
            *witness = p;
        }
        return true;
    }
    // p outside: the segment meets the triangle iff it meets its boundary.
    const Point2 e2[3][2] = {{a2, b2}, {b2, c2}, {c2, a2}};
    const Vec3* e3[3][2] = {{&a, &b}, {&b, &c}, {&c, &a}};
    for (int i = 0; i < 3; ++i) {
        if (segments_intersect_2d(p2, q2, e2[i][0], e2[i][1])) {
            if (witness != nullptr) {
                *witness = midpoint_of_closest(p, q, *e3[i][0], *e3[i][1]);
            }
            return true;
        }
    }
    return false;
}

inline bool strictly_one_side(const int s[3]) {
    return (s[0] > 0 && s[1] > 0 && s[2] > 0) || (s[0] < 0 && s[1] < 0 && s[2] < 0);
}

}  // namespace

bool segment_triangle_intersect(const Vec3& p, const Vec3& q, const Vec3& a, const Vec3& b,
                                const Vec3& c) {
    TriangleShape shape;
    const int sp = orient3d(a, b, c, p);
    const int sq = orient3d(a, b, c, q);
    return segment_meets_triangle(p, q, sp, sq, a, b, c, shape, nullptr);
}

namespace {

// Guigue and Devillers' test (2003) for the common case of intersect_after_planes: each triangle
// crosses the other's plane with no vertex on it (every sign nonzero), so one vertex of each is
// alone on its side. Each triangle then meets the other's plane in a segment on the line where
// the planes meet, and the closed triangles share a point iff the two segments overlap on it.
// With each triangle rotated so that its lone vertex comes first (a0, b0) and the other one's
// last two corners swapped, if needed, so that each lone vertex lies on the positive side of the
// other's plane, the segments overlap iff orient3d(a0, a1, b0, b1) <= 0 and
// orient3d(a0, a2, b2, b0) <= 0: two exact predicates instead of up to twelve. A rotation keeps a
// plane's orientation and a swap reverses it, so no plane sign is evaluated again.
bool crossing_segments_overlap(const Triangle& ta, const Triangle& tb, const int sa[3],
                               const int sb[3]) {
    auto lone = [](const int s[3]) { return s[0] == s[1] ? 2 : (s[0] == s[2] ? 1 : 0); };
    const int ia = lone(sa);
    const int ib = lone(sb);
    const Vec3& a0 = ta[ia];
    const Vec3* a1 = &ta[(ia + 1) % 3];
    const Vec3* a2 = &ta[(ia + 2) % 3];
    const Vec3& b0 = tb[ib];
    const Vec3* b1 = &tb[(ib + 1) % 3];
    const Vec3* b2 = &tb[(ib + 2) % 3];
    if (sa[ia] < 0) {
        std::swap(b1, b2);
    }
    if (sb[ib] < 0) {
        std::swap(a1, a2);
    }
    return orient3d(a0, *a1, b0, *b1) <= 0 && orient3d(a0, *a2, *b2, b0) <= 0;
}

// triangles_intersect after its plane early-outs: sa[i] = orient3d(tb, ta[i]), sb[i] likewise.
bool intersect_after_planes(const Triangle& ta, const Triangle& tb, const int sa[3],
                            const int sb[3], Vec3* witness) {
    // Where every sign is nonzero, the two-predicate test decides; when it finds a shared point
    // the search below runs too, for its witness (the same point as without the test).
    if (sa[0] != 0 && sa[1] != 0 && sa[2] != 0 && sb[0] != 0 && sb[1] != 0 && sb[2] != 0) {
        if (!crossing_segments_overlap(ta, tb, sa, sb)) {
            return false;
        }
        if (witness == nullptr) {
            return true;
        }
    }
    // Complete for closed convex sets: a nonempty intersection of two triangles (a segment, a
    // point, or a convex polygon when coplanar) has its extreme points on edges of one of them.
    TriangleShape shape_a;
    TriangleShape shape_b;
    for (int i = 0; i < 3; ++i) {
        const int j = i == 2 ? 0 : i + 1;
        if (segment_meets_triangle(ta[i], ta[j], sa[i], sa[j], tb[0], tb[1], tb[2], shape_b,
                                   witness)) {
            return true;
        }
    }
    for (int i = 0; i < 3; ++i) {
        const int j = i == 2 ? 0 : i + 1;
        if (segment_meets_triangle(tb[i], tb[j], sb[i], sb[j], ta[0], ta[1], ta[2], shape_a,
                                   witness)) {
            return true;
        }
    }
    return false;
}

}  // namespace

bool triangles_intersect(const Triangle& ta, const Triangle& tb, Vec3* witness) {
    // Signs of each triangle's vertices against the other's plane. They are all zero against a
    // degenerate triangle, so the early-outs below never fire for one.
    double height[3];
    const detail::PlaneSide side_a(ta[0], ta[1], ta[2]);
    int sb[3];
    side_a.corners(tb, sb, height);
    if (strictly_one_side(sb)) {
        return false;
    }
    const detail::PlaneSide side_b(tb[0], tb[1], tb[2]);
    int sa[3];
    side_b.corners(ta, sa, height);
    if (strictly_one_side(sa)) {
        return false;
    }
    return intersect_after_planes(ta, tb, sa, sb, witness);
}

namespace {

// Per-triangle data for the vertex-against-triangle candidates of triangle_triangle.
struct FaceFrame {
    TriangleFrame f;
    double inv_det;  // 1 / |ab x ac|^2 (Lagrange form); meaningful only when !f.sliver
};

inline FaceFrame make_face_frame(const Vec3& a, const Vec3& b, const Vec3& c) {
    FaceFrame ff{make_frame(a, b, c), 0.0};
    if (!ff.f.sliver) {
        // Not a sliver, so the determinant is well above its rounding error and positive.
        ff.inv_det = 1.0 / (ff.f.abab * ff.f.acac - ff.f.abac * ff.f.abac);
    }
    return ff;
}

// Projection q of p onto a non-sliver face; true when it falls inside the closed triangle.
inline bool project_inside(const FaceFrame& ff, const Vec3& p, Vec3& q) {
    const TriangleFrame& f = ff.f;
    const Vec3 ap = p - f.a;
    const double d1 = dot(f.ab, ap);
    const double d2 = dot(f.ac, ap);
    const double v = (f.acac * d1 - f.abac * d2) * ff.inv_det;
    const double w = (f.abab * d2 - f.abac * d1) * ff.inv_det;
    q = f.a + v * f.ab + w * f.ac;
    return v >= 0.0 && w >= 0.0 && v + w <= 1.0;
}

}  // namespace

ClosestPoints triangle_triangle(const Triangle& ta, const Triangle& tb, bool apart) {
    // Intersecting triangles answer 0 at a witness. A caller that proved them disjoint skips the
    // exact test (and its plane signs): everything below is a function of the corners alone, so
    // the result is bit-identical either way.
    if (!apart) {
        Vec3 witness;
        if (triangles_intersect(ta, tb, &witness)) {
            return {0.0, witness, witness};
        }
    }

    // Disjoint: the minimum over all candidates, unless an edge pair is certified closest first.
    // They are compared by squared distance; the winner's points are kept, and make_result
    // recomputes the same value from them.
    double best = std::numeric_limits<double>::infinity();
    Vec3 best_a;
    Vec3 best_b;
    auto consider = [&](const Vec3& pa, const Vec3& pb) {
        const double d = squared_norm(pa - pb);
        if (d < best) {
            best = d;
            best_a = pa;
            best_b = pb;
        }
    };

    // The edge pairs (detail::closest_edge_pair): the first one Larsen's test certifies in a
    // fixed order is the answer; where none is, the first of the closest is the best so far.
    const detail::EdgePairChoice edge = detail::closest_edge_pair(ta, tb);
    if (edge.pair >= 0) {
        const int i = edge.pair / 3;
        const int j = edge.pair % 3;
        const Vec3 p = ta[i] + edge.s * (ta[i == 2 ? 0 : i + 1] - ta[i]);
        const Vec3 q = tb[j] + edge.t * (tb[j == 2 ? 0 : j + 1] - tb[j]);
        if (edge.certified) {
            return make_result(p, q);
        }
        consider(p, q);
    }
    const bool any_nearly_parallel = edge.nearly_parallel;
    if (any_nearly_parallel) {
        // Well-conditioned endpoint candidates where the parameters above are not (see
        // segment_segment); rare, so simply all vertex-edge pairs.
        for (int i = 0; i < 3; ++i) {
            const Vec3& a0 = ta[i];
            const Vec3& a1 = ta[i == 2 ? 0 : i + 1];
            for (int j = 0; j < 3; ++j) {
                const Vec3& b0 = tb[j];
                const Vec3& b1 = tb[j == 2 ? 0 : j + 1];
                consider(a0, closest_on_segment(a0, b0, b1));
                consider(closest_on_segment(b0, a0, a1), b0);
            }
        }
    }

    // Vertex against triangle. When the vertex projects outside the triangle, its closest point
    // is on an edge and the pair is dominated by an edge pair above; so only the interior
    // projection is needed, except on slivers, which take the full robust routine.
    const FaceFrame fa = make_face_frame(ta[0], ta[1], ta[2]);
    const FaceFrame fb = make_face_frame(tb[0], tb[1], tb[2]);
    for (int i = 0; i < 3; ++i) {
        Vec3 q;
        if (fb.f.sliver) {
            consider(ta[i], closest_on_triangle(fb.f, ta[i]));
        } else if (project_inside(fb, ta[i], q)) {
            consider(ta[i], q);
        }
        if (fa.f.sliver) {
            consider(closest_on_triangle(fa.f, tb[i]), tb[i]);
        } else if (project_inside(fa, tb[i], q)) {
            consider(q, tb[i]);
        }
    }
    return make_result(best_a, best_b);
}

}  // namespace proxima
