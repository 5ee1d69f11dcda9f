// The triangle lower bounds (proxima/distance/bounds.hpp) directly: never above the computed exact
// distance they stand in for (random pairs at several scales, touching and near-touching pairs,
// slivers), tight where each is meant to be strong (parallel planes for the plane bound,
// neighbours of one flat sheet for the axis bound, neighbours across a triangle between them for
// the edge bound), zero for intersecting triangles; and the
// threshold helpers the searches compare against (the traversal's never below the exact one).

#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>

#include "proxima/distance/bounds.hpp"
#include "proxima/distance/primitives.hpp"

namespace proxima {
namespace {

double exact_distance(const Triangle& a, const Triangle& b) {
    return std::sqrt(triangle_triangle(a, b).squared_distance);
}

double slack_of(const Triangle& a, const Triangle& b) {
    Aabb box;
    for (const auto& t : {a, b}) {
        for (const auto& p : t) {
            box.extend(p);
        }
    }
    return rounding_slack(coordinate_scale(box));
}

Triangle random_triangle(std::mt19937_64& rng, const Vec3& centre, double size) {
    std::uniform_real_distribution<double> u(-size, size);
    Triangle t;
    for (auto& p : t) {
        p = centre + Vec3{u(rng), u(rng), u(rng)};
    }
    return t;
}

TEST(TriangleLowerBounds, NeverAboveTheComputedDistance) {
    std::mt19937_64 rng(20261125);
    int separated = 0;
    for (const double scale : {1e-3, 1.0, 1e3, 1e6}) {
        std::uniform_real_distribution<double> offset(-2.0 * scale, 2.0 * scale);
        for (int i = 0; i < 4000; ++i) {
            // Far from the origin too: the slack grows with the coordinates' magnitude.
            const Vec3 base{offset(rng) * 10.0, offset(rng), offset(rng)};
            const Triangle a = random_triangle(rng, base, scale);
            const Triangle b =
                random_triangle(rng, base + Vec3{offset(rng), offset(rng), offset(rng)}, scale);
            const double slack = slack_of(a, b);
            const double exact = exact_distance(a, b);
            const double plane = plane_lower_bound(a, b, slack);
            const double axis = axis_lower_bound(a, b, slack);
            const double edge = edge_lower_bound(a, b, slack);
            const double both = plane_edge_lower_bound(a, b, slack);
            ASSERT_LE(plane, exact) << "scale " << scale << " pair " << i;
            ASSERT_LE(axis, exact) << "scale " << scale << " pair " << i;
            ASSERT_LE(edge, exact) << "scale " << scale << " pair " << i;
            ASSERT_LE(both, exact) << "scale " << scale << " pair " << i;
            ASSERT_GE(plane, 0.0);
            ASSERT_GE(axis, 0.0);
            ASSERT_GE(edge, 0.0);
            ASSERT_GE(both, 0.0);
            // Without a threshold to stop at, the early-out evaluation gives the strongest of the
            // bounds it evaluates (edge, plane, both: not the axis bound).
            const double lb = std::max({plane, edge, both});
            ASSERT_EQ(lower_bound_until(a, b, slack, std::numeric_limits<double>::infinity()), lb);
            if (lb > 0.0) {
                const double below = lb * lb * (1.0 - 1e-12);
                const double reached = lower_bound_until(a, b, slack, below);
                ASSERT_GE(reached * reached, below);
                // A low threshold stops it early (after one triangle's edges, say): still a
                // bound.
                for (const double low : {below * 1e-4, below * 0.25}) {
                    const double early = lower_bound_until(a, b, slack, low);
                    ASSERT_GE(early * early, low);
                    ASSERT_LE(early, exact) << "scale " << scale << " pair " << i;
                }
                ASSERT_LE(reached, exact);
                // A positive bound proves the pair disjoint: the exact test told so gives the
                // same answer, bit for bit.
                const auto full = triangle_triangle(a, b);
                const auto told = triangle_triangle(a, b, true);
                ASSERT_EQ(full.squared_distance, told.squared_distance);
                ASSERT_EQ(full.point_a, told.point_a);
                ASSERT_EQ(full.point_b, told.point_b);
            }
            ASSERT_EQ(triangle_lower_bound(a, b, slack), std::max(plane, axis));
            separated += exact > 0.0 && triangle_lower_bound(a, b, slack) > 0.0 ? 1 : 0;
        }
    }
    // The bounds are useful, not just safe: most separated random pairs get a positive bound.
    EXPECT_GT(separated, 8000);
}

TEST(TriangleLowerBounds, NearTouchingPairsStayBelowTheComputedDistance) {
    // b is a copied at small gaps along a's normal and sideways: the bound must stay under the
    // computed distance even when it is a few ulps.
    std::mt19937_64 rng(7);
    for (int i = 0; i < 2000; ++i) {
        const Triangle a = random_triangle(rng, {100.0, -50.0, 3.0}, 1.0);
        const Vec3 c = cross(a[1] - a[0], a[2] - a[0]);
        const Vec3 n = (1.0 / norm(c)) * c;
        const double gap = std::ldexp(1.0, -(i % 50));  // 1 down to 2^-49
        Triangle b = a;
        for (auto& p : b) {
            p = p + gap * n + Vec3{1e-3 * (i % 3), 0.0, 0.0};
        }
        const double slack = slack_of(a, b);
        const double exact = exact_distance(a, b);
        ASSERT_LE(plane_lower_bound(a, b, slack), exact) << "gap " << gap;
        ASSERT_LE(axis_lower_bound(a, b, slack), exact) << "gap " << gap;
        ASSERT_LE(edge_lower_bound(a, b, slack), exact) << "gap " << gap;
        ASSERT_LE(plane_edge_lower_bound(a, b, slack), exact) << "gap " << gap;
    }
}

TEST(TriangleLowerBounds, EdgeBoundIsTightAcrossATriangleBetweenNeighbours) {
    // Two coplanar triangles of a sheet facing each other across a gap perpendicular to a's edge
    // (1,0,0)-(1,1,0): the centroid axis is oblique to the gap, the edge's in-plane normal is
    // along it, so the edge bound is the tight one. Gaps down to 2^-49 keep it below the
    // computed distance.
    const Triangle a{Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{1, 1, 0}};
    for (int k = 0; k < 50; ++k) {
        const double gap = std::ldexp(1.0, -k);  // 1 down to 2^-49
        const Triangle b{Vec3{1 + gap, 0, 0}, Vec3{2 + gap, 1, 0}, Vec3{1 + gap, 1, 0}};
        const double slack = slack_of(a, b);
        const double exact = exact_distance(a, b);
        ASSERT_DOUBLE_EQ(exact, gap);
        const double edge = edge_lower_bound(a, b, slack);
        ASSERT_LE(edge, exact) << "gap " << gap;
        if (k < 20) {
            EXPECT_NEAR(edge, gap, 1e-9) << "gap " << gap;
            EXPECT_LT(axis_lower_bound(a, b, slack), 0.9 * gap) << "gap " << gap;
        }
    }
    // Sheared and slightly out of plane copies beside that edge: no edge normal points straight
    // at b; still never above the distance.
    std::mt19937_64 rng(31);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (int i = 0; i < 2000; ++i) {
        const Vec3 shift{1.0 + 0.5 * std::abs(u(rng)), u(rng), 1e-3 * u(rng)};
        const Triangle b{a[0] + shift, a[1] + shift + Vec3{0, 0.3 * u(rng), 0}, a[2] + shift};
        const double slack = slack_of(a, b);
        ASSERT_LE(edge_lower_bound(a, b, slack), exact_distance(a, b)) << "pair " << i;
        ASSERT_LE(edge_lower_bound(b, a, slack), exact_distance(a, b)) << "pair " << i;
    }
}

TEST(TriangleLowerBounds, EdgeBoundsCoverTheirOwnRoundingWithoutSlack) {
    // The edge bound's own error term (its lever arm from the triangles' corners), alone: no
    // slack. Random oblique triangles and b on the far side of one of a's edges, in a's plane,
    // a few ulps of the triangles' size away, at several scales and distances from the origin:
    // the rounding of the in-plane projections is then as large as the gap, and the bound must
    // still stay under the computed distance (it fails with the error term left out).
    std::mt19937_64 rng(2026);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    int positive = 0;
    int both_positive = 0;
    for (const double scale : {1e-3, 1.0, 1e3}) {
        for (int i = 0; i < 20000; ++i) {
            const Vec3 base = (50.0 * scale) * Vec3{u(rng), u(rng), u(rng)};
            const Triangle a = random_triangle(rng, base, scale);
            const Vec3 e = a[1] - a[0];
            const Vec3 n = cross(e, a[2] - a[0]);
            Vec3 m = cross(e, n);  // in a's plane, normal to edge 0
            if (dot(m, a[2] - a[0]) > 0.0) {
                m = -1.0 * m;  // away from the third corner
            }
            const double len = norm(m);
            if (!(len > 0.0)) {
                continue;
            }
            m = (1.0 / len) * m;
            const double gap = scale * std::ldexp(1.0, -44 - (i % 8));  // a few ulps of the size
            const double s = 0.25 + 0.5 * std::abs(u(rng));
            const Vec3 foot = a[0] + s * e + gap * m;
            const Triangle b{foot, foot + scale * std::abs(u(rng)) * m + 0.3 * e,
                             foot + scale * std::abs(u(rng)) * m - 0.3 * e};
            const double exact = exact_distance(a, b);
            const double edge = edge_lower_bound(a, b, 0.0);
            ASSERT_LE(edge, exact) << "scale " << scale << " pair " << i;
            ASSERT_LE(lower_bound_until(a, b, 0.0, 1e-300), exact) << "scale " << scale;
            positive += edge > 0.0 ? 1 : 0;
            // The same pair lifted off a's plane by about as much: the plane and edge gaps
            // together, also without slack.
            const Vec3 up = (gap * (0.5 + std::abs(u(rng))) / norm(n)) * n;
            const Triangle lifted{b[0] + up, b[1] + up, b[2] + up};
            const double lifted_exact = exact_distance(a, lifted);
            ASSERT_LE(plane_edge_lower_bound(a, lifted, 0.0), lifted_exact)
                << "scale " << scale << " pair " << i;
            ASSERT_LE(lower_bound_until(a, lifted, 0.0, std::numeric_limits<double>::infinity()),
                      lifted_exact)
                << "scale " << scale << " pair " << i;
            both_positive += plane_edge_lower_bound(a, lifted, 0.0) > 0.0 ? 1 : 0;
        }
    }
    // Most of them are separated by more than the error term: the test reaches the bound.
    EXPECT_GT(positive, 1000);
    EXPECT_GT(both_positive, 1000);
}

TEST(TriangleLowerBounds, PlaneAndEdgeTogetherAreTightBesideAndAbove) {
    // b lies above a's plane by h and beyond a's edge (1,0,0)-(1,1,0) by g, as across a fold of
    // cloth: each gap alone bounds the distance by h or g, the two together by sqrt(h^2 + g^2),
    // which is the distance here; and lower_bound_until reaches it where the others fall short.
    const Triangle a{Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{1, 1, 0}};
    for (int k = 0; k < 40; ++k) {
        const double h = std::ldexp(0.75, -k);
        const double g = std::ldexp(1.0, -k);
        const Triangle b{Vec3{1 + g, 0, h}, Vec3{2 + g, 1, h}, Vec3{1 + g, 1, h}};
        const double slack = slack_of(a, b);
        const double exact = exact_distance(a, b);
        ASSERT_NEAR(exact, 1.25 * g, 1e-15 * g + 1e-16);
        const double both = plane_edge_lower_bound(a, b, slack);
        ASSERT_LE(both, exact) << "k " << k;
        ASSERT_LE(plane_edge_lower_bound(b, a, slack), exact) << "k " << k;
        if (k < 20) {
            EXPECT_NEAR(both, exact, 1e-9) << "k " << k;
            EXPECT_LT(std::max({plane_lower_bound(a, b, slack), edge_lower_bound(a, b, slack),
                                axis_lower_bound(a, b, slack)}),
                      0.85 * exact)
                << "k " << k;
            // A threshold above the other bounds but below the distance: reached.
            const double t = 0.95 * exact;
            const double reached = lower_bound_until(a, b, slack, t * t);
            EXPECT_GE(reached, t) << "k " << k;
            EXPECT_LE(reached, exact) << "k " << k;
        }
    }
}

TEST(TriangleLowerBounds, PlaneBoundIsTightForParallelTrianglesAbove) {
    const Triangle a{Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}};
    const Triangle b{Vec3{0.1, 0.1, 2}, Vec3{0.6, 0.1, 2}, Vec3{0.1, 0.6, 2}};
    const double slack = slack_of(a, b);
    const double exact = exact_distance(a, b);
    ASSERT_DOUBLE_EQ(exact, 2.0);
    const double plane = plane_lower_bound(a, b, slack);
    EXPECT_LE(plane, exact);
    EXPECT_NEAR(plane, 2.0, 1e-9);
}

TEST(TriangleLowerBounds, AxisBoundSeparatesNeighboursOfOneFlatSheet) {
    // Two coplanar triangles 0.25 apart along x: no supporting plane separates them, the
    // centroid axis does.
    const Triangle a{Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}};
    const Triangle b{Vec3{1.25, 0, 0}, Vec3{2.25, 0, 0}, Vec3{1.25, 1, 0}};
    const double slack = slack_of(a, b);
    const double exact = exact_distance(a, b);
    EXPECT_DOUBLE_EQ(exact, 0.25);
    EXPECT_EQ(plane_lower_bound(a, b, slack), 0.0);
    const double axis = axis_lower_bound(a, b, slack);
    EXPECT_GT(axis, 0.0);
    EXPECT_LE(axis, exact);
}

TEST(TriangleLowerBounds, IntersectingAndTouchingTrianglesGetZero) {
    const Triangle a{Vec3{0, 0, 0}, Vec3{2, 0, 0}, Vec3{0, 2, 0}};
    const Triangle crossing{Vec3{0.5, 0.5, -1}, Vec3{0.5, 0.5, 1}, Vec3{1.5, 0.2, 0}};
    const Triangle sharing_an_edge{Vec3{2, 0, 0}, Vec3{0, 2, 0}, Vec3{2, 2, 1}};
    for (const auto& b : {crossing, sharing_an_edge}) {
        const double slack = slack_of(a, b);
        EXPECT_EQ(exact_distance(a, b), 0.0);
        EXPECT_EQ(plane_lower_bound(a, b, slack), 0.0);
        EXPECT_EQ(axis_lower_bound(a, b, slack), 0.0);
        EXPECT_EQ(edge_lower_bound(a, b, slack), 0.0);
        EXPECT_EQ(lower_bound_until(a, b, slack, 1e-30), 0.0);
    }
}

TEST(TriangleLowerBounds, SliversAreNeverTrustedAboveTheDistance) {
    // Nearly collinear corners: the supporting plane's normal is noise.
    std::mt19937_64 rng(99);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (int i = 0; i < 1000; ++i) {
        const Vec3 p{u(rng), u(rng), u(rng)};
        const Vec3 d{u(rng), u(rng), u(rng)};
        const Triangle sliver{p, p + d, p + 0.5 * d + Vec3{1e-14 * u(rng), 0.0, 1e-14}};
        const Triangle other = random_triangle(rng, p + Vec3{0.0, 0.0, 0.5}, 0.4);
        const double slack = slack_of(sliver, other);
        const double exact = exact_distance(sliver, other);
        ASSERT_LE(plane_lower_bound(sliver, other, slack), exact);
        ASSERT_LE(plane_lower_bound(other, sliver, slack), exact);
        ASSERT_LE(axis_lower_bound(sliver, other, slack), exact);
        ASSERT_LE(edge_lower_bound(sliver, other, slack), exact);
        ASSERT_LE(edge_lower_bound(other, sliver, slack), exact);
    }
}

TEST(CullThresholds, WidenTheBestDistanceAndFollowALiveBound) {
    EXPECT_GT(cull_threshold_sq(4.0, 0.0), 4.0);
    EXPECT_GT(cull_threshold_sq(4.0, 1e-6), cull_threshold_sq(4.0, 0.0));
    EXPECT_EQ(cull_threshold_sq(0.0, 0.0), 0.0);
    EXPECT_GT(cull_threshold_sq(0.0, 1e-9), 0.0);

    double live = 9.0;
    CullThreshold threshold(live, 1e-9);
    EXPECT_EQ(threshold.get(), cull_threshold_sq(9.0, 1e-9));
    live = 1.0;  // the search found a closer pair
    EXPECT_EQ(threshold.get(), cull_threshold_sq(1.0, 1e-9));
}

TEST(CullThresholds, TheTraversalThresholdIsNeverBelowTheExactOne) {
    // Bounds from 0 over every magnitude a squared distance takes (with the slacks of coordinate
    // scales from 1e-6 to 1e9), and the values where the square-root term dominates: b of the
    // order of the slack's square.
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> mantissa(1.0, 2.0);
    std::uniform_int_distribution<int> exponent(-300, 300);
    std::uniform_int_distribution<int> scale_exponent(-6, 9);
    for (int k = 0; k < 200000; ++k) {
        const double slack = rounding_slack(std::ldexp(mantissa(rng), scale_exponent(rng) * 3));
        double b = std::ldexp(mantissa(rng), exponent(rng));
        if (k % 4 == 0) {
            b = slack * slack * std::ldexp(mantissa(rng), exponent(rng) % 40);
        } else if (k % 97 == 0) {
            b = 0.0;
        }
        ASSERT_GE(traversal_threshold_sq(b, slack), cull_threshold_sq(b, slack))
            << "bound " << b << " slack " << slack;
    }
    EXPECT_EQ(traversal_threshold_sq(std::numeric_limits<double>::infinity(), 1e-12),
              std::numeric_limits<double>::infinity());
    // A stopped search reads a negative bound: every box distance must then reach it.
    EXPECT_LT(traversal_threshold_sq(-1.0, 1e-6), 0.0);
    // Not much larger: a few parts per billion of the bound.
    EXPECT_LT(traversal_threshold_sq(4.0, 1e-12), 4.0 * (1.0 + 1e-8));
}

TEST(CullThresholds, SlackGrowsWithTheCoordinatesMagnitude) {
    Aabb box;
    box.extend(Vec3{-3.0, 1.0, 2.0});
    box.extend(Vec3{1.0, 5.0, -7.5});
    EXPECT_EQ(coordinate_scale(box), 7.5);
    EXPECT_EQ(rounding_slack(7.5), 1e-12 * 7.5);
    EXPECT_LT(rounding_slack(1.0), rounding_slack(1e6));
}

// edge_frames (four at a time, AVX2 where the processor has it) must give edge_frame's frames bit
// for bit, branches included: slivers (plane length 0), zero-length edges (normal and extent 0),
// a point triangle, and every lane position of each. It fails if a lane's blend, an operation's
// order or a max's NaN rule differs from edge_frame.
TEST(TriangleLowerBounds, FramesFourAtATimeAreEdgeFramesBitForBit) {
    auto bits = [](double x) { return std::bit_cast<std::uint64_t>(x); };
    auto same = [&](const EdgeFrame& a, const EdgeFrame& b) {
        bool ok = bits(a.plane.nn) == bits(b.plane.nn) &&
                  bits(a.plane.l1l2) == bits(b.plane.l1l2) && bits(a.reach) == bits(b.reach);
        for (int c = 0; c < 3; ++c) {
            ok = ok && bits(a.plane.n[c]) == bits(b.plane.n[c]) &&
                 bits(a.centroid[c]) == bits(b.centroid[c]);
        }
        for (int i = 0; i < 3; ++i) {
            ok = ok && bits(a.extent[i]) == bits(b.extent[i]);
            for (int c = 0; c < 3; ++c) {
                ok = ok && bits(a.normal[i][c]) == bits(b.normal[i][c]);
            }
        }
        return ok;
    };
    std::mt19937_64 rng(41);
    std::vector<Triangle> tris;
    for (const double scale : {1e-6, 1.0, 1e3, 1e8}) {
        const Vec3 base{0.3 * scale, -1.7 * scale, 1e4};
        for (int k = 0; k < 200; ++k) {
            tris.push_back(random_triangle(rng, base, scale));
        }
    }
    const Vec3 p{1.0, 2.0, 3.0};
    const Vec3 q{1.5, 2.0, 3.0};
    tris.push_back({p, p, p});                                         // a point
    tris.push_back({p, q, q});                                         // a zero-length edge
    tris.push_back({p, q, Vec3{2.0, 2.0, 3.0}});                       // collinear: no plane
    tris.push_back({p, q, Vec3{1.25, 2.0 + 1e-12, 3.0}});              // a sliver
    tris.push_back({p, Vec3{1.0, 2.0, 3.0 + 1e-300}, q});              // an edge below any square
    tris.push_back({Vec3{-0.0, 0.0, -0.0}, Vec3{0.0, -0.0, 0.0}, q});  // signed zeros
    int checked = 0;
    for (std::size_t start = 0; start + 4 <= tris.size(); ++start) {
        EdgeFrame got[4];
        const Triangle* const in[4] = {&tris[start], &tris[start + 1], &tris[start + 2],
                                       &tris[start + 3]};
        EdgeFrame* const out[4] = {&got[0], &got[1], &got[2], &got[3]};
        edge_frames(in, out);
        for (int l = 0; l < 4; ++l) {
            ASSERT_TRUE(same(got[l], edge_frame(tris[start + l]))) << "triangle " << start + l;
            ++checked;
        }
    }
    EXPECT_EQ(checked, 4 * static_cast<int>(tris.size() - 3));
}

// The edge gap with b's corners in vector lanes (AVX2 where the processor has it) must equal the
// scalar copy bit for bit: random pairs at four scales, pairs placed just beyond an edge so that
// corners clear it or not by a few ulps, and degenerate triangles (zero normals). Fails with a
// lane out of order, a changed comparison or a different minimum.
TEST(TriangleLowerBounds, EdgeGapInLanesIsTheScalarGapBitForBit) {
    auto bits = [](double x) { return std::bit_cast<std::uint64_t>(x); };
    std::mt19937_64 rng(4242);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    int positive = 0;
    int checked = 0;
    auto check = [&](const Triangle& a, const Triangle& b) {
        const EdgeFrame fa = edge_frame(a);
        const double got = detail::edge_side(a, fa, b);
        ASSERT_EQ(bits(got), bits(detail::edge_side_portable(a, fa, b)));
        positive += got > 0.0;
        ++checked;
    };
    for (const double scale : {1e-6, 1.0, 1e3, 1e8}) {
        const Vec3 base{0.3 * scale, -1.7 * scale, 2.5 * scale};
        for (int k = 0; k < 500; ++k) {
            const Triangle a = random_triangle(rng, base, scale);
            check(a, random_triangle(rng, base, scale));
            // b beside a's first edge, in a's plane up to a small tilt, a gap from 0 to a few ulps
            // of the scale: its corners clear the edge or not by rounding.
            const EdgeFrame fa = edge_frame(a);
            const Vec3 out = fa.normal[0];
            const double gap = unit(rng) < 0.5 ? unit(rng) * 1e-15 * scale : unit(rng) * scale;
            const Vec3 along = a[1] - a[0];
            Triangle b;
            for (int c = 0; c < 3; ++c) {
                b[c] =
                    a[0] + unit(rng) * along + (gap + fa.extent[0] + c * unit(rng) * scale) * out;
            }
            check(a, b);
            // One corner on a's edge (a's own corner): its projection equals the edge's floor
            // exactly when the extent is that corner's, so "beyond" must be strict.
            b[0] = a[1];
            check(a, b);
        }
    }
    const Vec3 p{1.0, 2.0, 3.0};
    const Vec3 q{1.5, 2.0, 3.0};
    check({p, p, p}, {q, q + Vec3{0, 1, 0}, q + Vec3{0, 0, 1}});
    check({p, q, q}, {p + Vec3{0, 2, 0}, q + Vec3{0, 3, 0}, q + Vec3{0, 2, 1}});
    check({p, q, Vec3{1.25, 2.0 + 1e-12, 3.0}}, {p + Vec3{0, 1, 0}, q + Vec3{0, 1, 0}, q});
    EXPECT_EQ(checked, 6003);
    EXPECT_GT(positive, 1000);  // the placed pairs mostly clear the edge
}

}  // namespace
}  // namespace proxima
