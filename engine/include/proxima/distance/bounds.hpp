#pragma once
// Cheap, conservative lower bounds on the distance between two triangles, used to skip exact
// tests that cannot beat the current best. "Conservative" includes rounding: each bound has the
// floating-point error of its own evaluation, and the error of the exact test it stands in for,
// subtracted, so a skipped pair can never be one whose *computed* distance is the answer.

#include "proxima/distance/primitives.hpp"

namespace proxima {

// Slack, in scene units, for comparisons between a bound and computed distances of primitives
// whose coordinates are at most `scale` in magnitude: covers the absolute rounding error of both.
inline double rounding_slack(double scale) {
    return 1e-12 * scale;
}

// The effective squared bound a lower bound must reach before a pair may be skipped: the current
// best distance widened by a relative factor and the absolute slack.
inline double cull_threshold_sq(double best_sq, double slack) {
    const double b = std::sqrt(best_sq) * (1.0 + 1e-9) + slack;
    return b * b;
}

// A threshold at least cull_threshold_sq(best_sq, slack) for every best_sq >= 0 (and below 0
// for a negative one), without its square root: 2 sqrt(b) s <= 1e-9 b + 1e9 s^2 (AM-GM), so the
// exact threshold is at most b (1 + 3e-9) + (1e9 + 3) s^2, well inside the margins here for the
// rounding of both. For a traversal that reads thresholds far more often than bounds change: it
// may propose a few more pairs than cull_threshold_sq would, never fewer.
inline double traversal_threshold_sq(double best_sq, double slack) {
    return best_sq * (1.0 + 4e-9) + 2e9 * slack * slack;
}

// The cull threshold of a bound that a search may lower as it goes (a reference to the live
// bound), recomputed only when the bound changed: a square root per improvement, not per test.
class CullThreshold {
  public:
    CullThreshold(const double& bound_sq, double slack) : m_bound_sq(bound_sq), m_slack(slack) {}
    double get() {
        if (m_bound_sq != m_seen) {
            m_seen = m_bound_sq;
            m_value = cull_threshold_sq(m_bound_sq, m_slack);
        }
        return m_value;
    }

  private:
    const double& m_bound_sq;
    double m_slack;
    double m_seen = -1.0;
    double m_value = 0.0;
};

// Largest coordinate magnitude of a box (for rounding_slack).
inline double coordinate_scale(const Aabb& box) {
    double s = 0.0;
    for (int k = 0; k < 3; ++k) {
        s = std::max({s, std::abs(box.lo[k]), std::abs(box.hi[k])});
    }
    return s;
}

// Separating-plane bound: the distance from one triangle's supporting plane to the other triangle
// when the other lies strictly on one side, the larger of the two; 0 when neither plane separates
// (or a triangle is too thin for its plane to be trusted). Never above the true distance by more
// than the rounding slack it accounts for.
double plane_lower_bound(const Triangle& a, const Triangle& b, double slack);

// Separating-axis bound along the line through the two centroids: the gap between the triangles'
// projections on it. Strong where the plane bound is useless: neighbouring triangles of one flat
// sheet (the usual intra-object case).
double axis_lower_bound(const Triangle& a, const Triangle& b, double slack);

// In-plane edge bound: for each edge of either triangle, the gap along the direction in that
// triangle's plane perpendicular to the edge, away from the triangle. Strong where the centroid
// axis is oblique to the gap: 2-ring neighbours of a sheet, which face each other across an edge
// of a triangle between them. Never above the computed distance by more than its rounding slack.
double edge_lower_bound(const Triangle& a, const Triangle& b, double slack);

// A triangle's plane as the plane bound uses it: the unnormalised normal n, |n| (0 where the plane
// is not trusted: a sliver) and the product of the lengths of the edges from the first corner
// (for the error term).
struct PlaneFrame {
    Vec3 n;
    double nn;
    double l1l2;
};

// What the edge, plane and axis bounds need of one triangle alone, so that a search can compute it
// once per triangle rather than once per pair: each edge's unit in-plane normal (away from the
// third corner) and the triangle's extent beyond the edge along it (0 up to rounding); its plane;
// its centroid (the axis bound's, (a + b + c) / 3).
struct EdgeFrame {
    Vec3 normal[3];
    double extent[3];
    PlaneFrame plane;
    Vec3 centroid;
    double reach;  // the largest L1 distance from the first corner to the others
};
EdgeFrame edge_frame(const Triangle& a);
namespace detail {
// The edge bound's one-sided gap: how far all of b lies beyond the outside of one of a's edges,
// along that edge's in-plane normal (fa = edge_frame(a)), before rounding allowances; 0 when b
// clears none. Runs b's three corners at once with AVX2 where the processor has it;
// edge_side_portable is the scalar copy, the same value bit for bit (exposed for the tests).
double edge_side(const Triangle& a, const EdgeFrame& fa, const Triangle& b);
double edge_side_portable(const Triangle& a, const EdgeFrame& fa, const Triangle& b);
}  // namespace detail

// *out[l] = edge_frame(*in[l]) for four triangles, the same frames bit for bit (at once with AVX2
// where the processor has it: a frame's square roots and divisions dominate its cost).
void edge_frames(const Triangle* const in[4], EdgeFrame* const out[4]);
// The same bound from frames made by edge_frame(a) and edge_frame(b).
double edge_lower_bound(const Triangle& a, const EdgeFrame& fa, const Triangle& b,
                        const EdgeFrame& fb, double slack);
// plane_lower_bound from the frames: the same value, bit for bit.
double plane_lower_bound(const Triangle& a, const EdgeFrame& fa, const Triangle& b,
                         const EdgeFrame& fb, double slack);

// The plane and edge gaps of one triangle's frame together: b above a's plane by h and beyond one
// of a's edges by g is at least sqrt(h^2 + g^2) from a (either way round, the larger). 0 unless
// some triangle has both gaps positive.
double plane_edge_lower_bound(const Triangle& a, const Triangle& b, double slack);

// The edge, plane and plane-and-edge bounds in turn, stopping at the first whose square
// reaches `threshold_sq`: the largest bound evaluated (no axis bound). The caller may skip the pair
// when its square reaches the threshold; a positive value also proves the triangles disjoint.
double lower_bound_until(const Triangle& a, const Triangle& b, double slack, double threshold_sq);
double lower_bound_until(const Triangle& a, const EdgeFrame& fa, const Triangle& b,
                         const EdgeFrame& fb, double slack, double threshold_sq);

// The larger of the plane and axis bounds.
inline double triangle_lower_bound(const Triangle& a, const Triangle& b, double slack) {
    return std::max(plane_lower_bound(a, b, slack), axis_lower_bound(a, b, slack));
}

}  // namespace proxima
