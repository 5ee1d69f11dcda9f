// Elementary CCD tests (proxima/ccd/elementary.hpp): known answers (a vertex through a triangle,
// parallel and crossing edges, contact at t = 0 and t = 1, degenerate triangles and edges, motion
// in the triangle's plane, minimum distance, the work cap, bad input), random queries built with an
// exact contact (hit, and a time of impact no later than the contact), the rounding-error bound
// against exact GMP evaluation on rational inputs, and the acceptance test: every query of the
// public CCD benchmark (PROXIMA_DATA_DIR/ccd-queries) with zero false negatives.

#include <gmp.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "proxima/ccd/elementary.hpp"
#include "proxima/distance/primitives.hpp"
#include "proxima/io/ccd_queries.hpp"

namespace proxima::ccd {
namespace {

namespace fs = std::filesystem;

constexpr CcdKind VF = CcdKind::vertex_face;
constexpr CcdKind EE = CcdKind::edge_edge;

// Static points: the same position at t = 0 and t = 1.
CcdPoints moving(const std::array<Vec3, 4>& t0, const std::array<Vec3, 4>& t1) {
    return {t0[0], t0[1], t0[2], t0[3], t1[0], t1[1], t1[2], t1[3]};
}

const std::array<Vec3, 4> TRIANGLE_Z0 = {Vec3{}, Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}};

CcdPoints vertex_and_static_triangle(const Vec3& p0, const Vec3& p1) {
    return {p0, TRIANGLE_Z0[1], TRIANGLE_Z0[2], TRIANGLE_Z0[3],
            p1, TRIANGLE_Z0[1], TRIANGLE_Z0[2], TRIANGLE_Z0[3]};
}

TEST(CcdElementary, VertexThroughTriangleAtHalf) {
    const auto pts = vertex_and_static_triangle({0.25, 0.25, 1.0}, {0.25, 0.25, -1.0});
    const auto r = vertex_face(pts);
    EXPECT_TRUE(r.hit);
    EXPECT_FALSE(r.capped);
    // Never late; within the tolerance in time (|F_z| = |1 - 2t| <= tol + 2e at t0).
    EXPECT_LE(r.toi, 0.5);
    EXPECT_GE(r.toi, 0.5 - 1e-6);
    EXPECT_EQ(elementary(VF, pts).toi, r.toi);
}

// A slow approach: the vertex sinks from 1.3e-6 above the triangle to 0.7e-6 below it,
// h(t) = 1.3e-6 - 2e-6 t: it enters the band d + tol (tol = 1e-6) at t = 0.15 and touches at
// t = 0.65. The toi may be up to toi_tolerance earlier than the band's entry, never later than the
// touch.
TEST(CcdElementary, TimeOfImpactIsWithinItsToleranceOfTheBand) {
    const auto pts = vertex_and_static_triangle({0.25, 0.25, 1.3e-6}, {0.25, 0.25, -0.7e-6});
    const auto fine = vertex_face(pts);  // toi_tolerance 1e-6
    EXPECT_TRUE(fine.hit);
    EXPECT_FALSE(fine.capped);
    EXPECT_LE(fine.toi, 0.65);
    EXPECT_GE(fine.toi, 0.15 - 1e-6);
    // The whole step allowed (the solver before toi_tolerance): the first time interval within
    // the band is reported at its start, a dyadic grid point well before the touch.
    ElementaryOptions step;
    step.toi_tolerance = 1.0;
    const auto s = vertex_face(pts, step);
    EXPECT_TRUE(s.hit);
    EXPECT_LE(s.toi, 0.5);
    // Refining time excludes the sub-intervals where the vertex is still above the triangle, so
    // the default toi is much closer to the touch (within its tolerance of the earliest region
    // the exclusion test cannot reject).
    EXPECT_GT(fine.toi, 0.6) << fine.toi;
    EXPECT_GT(fine.toi, s.toi + 0.1);
    // Zero: refined to the width floor, still never late.
    ElementaryOptions exact;
    exact.toi_tolerance = 0.0;
    const auto e = vertex_face(pts, exact);
    EXPECT_TRUE(e.hit);
    EXPECT_GE(e.toi, fine.toi);
    EXPECT_LE(e.toi, 0.65);
}

TEST(CcdElementary, VertexMissesTriangle) {
    // Through the plane outside the triangle (beyond the hypotenuse), and parallel above it.
    EXPECT_FALSE(vertex_face(vertex_and_static_triangle({0.6, 0.6, 1.0}, {0.6, 0.6, -1.0})).hit);
    EXPECT_FALSE(vertex_face(vertex_and_static_triangle({0.2, 0.2, 0.5}, {0.3, 0.2, 0.5})).hit);
    // Moving away.
    EXPECT_FALSE(vertex_face(vertex_and_static_triangle({0.2, 0.2, 0.1}, {0.2, 0.2, 2.0})).hit);
}

TEST(CcdElementary, TriangleMovesOntoVertex) {
    // The vertex is still; the triangle rises from z = -1 to z = 1 and meets it at t = 0.5.
    const Vec3 p{0.3, 0.3, 0.0};
    const auto pts = moving({p, Vec3{0, 0, -1}, Vec3{1, 0, -1}, Vec3{0, 1, -1}},
                            {p, Vec3{0, 0, 1}, Vec3{1, 0, 1}, Vec3{0, 1, 1}});
    const auto r = vertex_face(pts);
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 0.5);
    EXPECT_GE(r.toi, 0.5 - 1e-6);
}

TEST(CcdElementary, TouchingAtStartAndEnd) {
    // On the triangle at t = 0, leaving: toi 0.
    auto r = vertex_face(vertex_and_static_triangle({0.2, 0.2, 0.0}, {0.2, 0.2, 1.0}));
    EXPECT_TRUE(r.hit);
    EXPECT_EQ(r.toi, 0.0);
    // Reaching the triangle exactly at t = 1.
    r = vertex_face(vertex_and_static_triangle({0.2, 0.2, 1.0}, {0.2, 0.2, 0.0}));
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 1.0);
    EXPECT_GE(r.toi, 1.0 - 2e-6);
    // Stopping just short of it (2^-30 above) is a miss with a tolerance of 2^-40.
    ElementaryOptions tight;
    tight.tolerance = 0x1p-40;
    EXPECT_FALSE(
        vertex_face(vertex_and_static_triangle({0.2, 0.2, 1.0}, {0.2, 0.2, 0x1p-30}), tight).hit);
    // Edges crossing exactly at t = 0 and at t = 1.
    const std::array<Vec3, 4> crossing = {Vec3{-1, 0, 0}, Vec3{1, 0, 0}, Vec3{0, -1, 0},
                                          Vec3{0, 1, 0}};
    const std::array<Vec3, 4> lifted = {Vec3{-1, 0, 0}, Vec3{1, 0, 0}, Vec3{0, -1, 1},
                                        Vec3{0, 1, 1}};
    r = edge_edge(moving(crossing, lifted));
    EXPECT_TRUE(r.hit);
    EXPECT_EQ(r.toi, 0.0);
    r = edge_edge(moving(lifted, crossing));
    EXPECT_TRUE(r.hit);
    EXPECT_GE(r.toi, 1.0 - 2e-6);
}

TEST(CcdElementary, CrossingEdges) {
    // Edge b drops from z = 1 to z = -1 across edge a: contact at t = 0.5 at the midpoints.
    const auto pts = moving({Vec3{-1, 0, 0}, Vec3{1, 0, 0}, Vec3{0, -1, 1}, Vec3{0, 1, 1}},
                            {Vec3{-1, 0, 0}, Vec3{1, 0, 0}, Vec3{0, -1, -1}, Vec3{0, 1, -1}});
    const auto r = edge_edge(pts);
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 0.5);
    EXPECT_GE(r.toi, 0.5 - 1e-6);
    // The same drop beside edge a's end (x = 1.5): a miss.
    auto beside = pts;
    for (int i : {2, 3, 6, 7}) {
        beside[static_cast<std::size_t>(i)].x = 1.5;
    }
    EXPECT_FALSE(edge_edge(beside).hit);
}

TEST(CcdElementary, ParallelEdges) {
    // Parallel edges 0.5 apart, sliding along each other: never touch.
    auto pts = moving({Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{-2, 0.5, 0}, Vec3{-1, 0.5, 0}},
                      {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{2, 0.5, 0}, Vec3{3, 0.5, 0}});
    EXPECT_FALSE(edge_edge(pts).hit);
    // Parallel and closing: b moves onto a's line at t = 0.5 while overlapping it (a segment of
    // contacts, the degenerate case).
    pts = moving({Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0.5, 0.5, 0}, Vec3{1.5, 0.5, 0}},
                 {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0.5, -0.5, 0}, Vec3{1.5, -0.5, 0}});
    auto r = edge_edge(pts);
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 0.5);
    EXPECT_GE(r.toi, 0.5 - 1e-6);
    // Collinear, sliding into each other along the common line: first contact at t = 0.25.
    pts = moving({Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{2, 0, 0}, Vec3{3, 0, 0}},
                 {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{-2, 0, 0}, Vec3{-1, 0, 0}});
    r = edge_edge(pts);
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 0.25);
    EXPECT_GE(r.toi, 0.25 - 1e-6);
}

TEST(CcdElementary, DegenerateTriangleAndEdge) {
    // A triangle collapsed to the point (0.5, 0.5, 0): the vertex passes through it, or beside.
    const Vec3 c{0.5, 0.5, 0.0};
    auto pts = CcdPoints{Vec3{0.5, 0.5, 1}, c, c, c, Vec3{0.5, 0.5, -1}, c, c, c};
    auto r = vertex_face(pts);
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 0.5);
    pts[0].x = pts[4].x = 0.5 + 1e-3;
    EXPECT_FALSE(vertex_face(pts).hit);
    // A triangle collapsed to a segment from (0,0,0) to (1,0,0): crossed at x = 0.5, t = 0.5.
    pts = CcdPoints{Vec3{0.5, 0, 1},  Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0.5, 0, 0},
                    Vec3{0.5, 0, -1}, Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0.5, 0, 0}};
    r = vertex_face(pts);
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 0.5);
    EXPECT_GE(r.toi, 0.5 - 1e-6);
    // An edge collapsed to a point crossing a segment, and passing beside its end.
    pts = moving({Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0.25, 0, 1}, Vec3{0.25, 0, 1}},
                 {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0.25, 0, -1}, Vec3{0.25, 0, -1}});
    r = edge_edge(pts);
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 0.5);
    for (int i : {2, 3, 6, 7}) {
        pts[static_cast<std::size_t>(i)].x = 1.25;
    }
    EXPECT_FALSE(edge_edge(pts).hit);
    // Both edges points: they meet at t = 0.5 or miss by 1e-3.
    pts = moving({Vec3{0, 0, 0}, Vec3{0, 0, 0}, Vec3{1, 1, 1}, Vec3{1, 1, 1}},
                 {Vec3{1, 1, 1}, Vec3{1, 1, 1}, Vec3{0, 0, 0}, Vec3{0, 0, 0}});
    EXPECT_TRUE(edge_edge(pts).hit);
    pts[2].z = pts[3].z = 1.002;
    EXPECT_FALSE(edge_edge(pts).hit);
}

TEST(CcdElementary, MotionInTheTrianglePlane) {
    // Sliding in the plane z = 0 into the triangle: enters at x = 0, t = 0.5.
    auto r = vertex_face(vertex_and_static_triangle({-1, 0.25, 0}, {1, 0.25, 0}));
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 0.5);
    EXPECT_GE(r.toi, 0.5 - 1e-5);
    // Sliding in the plane beside the triangle (y = -0.1): never inside.
    EXPECT_FALSE(vertex_face(vertex_and_static_triangle({-1, -0.1, 0}, {1, -0.1, 0})).hit);
    // Coplanar edges: b sweeps in the plane z = 0 across a's end region and crosses it at t = 0.5.
    const auto pts = moving({Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0.5, 1, 0}, Vec3{0.5, 2, 0}},
                            {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0.5, -1, 0}, Vec3{0.5, 0, 0}});
    r = edge_edge(pts);
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 0.5);
    EXPECT_GE(r.toi, 0.5 - 1e-5);
}

TEST(CcdElementary, MinimumDistance) {
    // The vertex slides 0.1 above the plane, entering the triangle's column at x = 0 (t = 0.5).
    const auto pts = vertex_and_static_triangle({-1, 0.25, 0.1}, {1, 0.25, 0.1});
    ElementaryOptions o;
    EXPECT_FALSE(vertex_face(pts, o).hit);
    o.min_distance = 0.05;
    EXPECT_FALSE(vertex_face(pts, o).hit);
    o.min_distance = 0.11;
    auto r = vertex_face(pts, o);
    EXPECT_TRUE(r.hit);
    // Within 0.11 from x = -sqrt(0.11^2 - 0.1^2) (t ~ 0.477) on; never later than that.
    EXPECT_LE(r.toi, 0.5 - std::sqrt(0.11 * 0.11 - 0.01) / 2.0);
    // Edges passing 0.2 apart (b at z = 0.2 crossing over a).
    const auto ee = moving({Vec3{-1, 0, 0}, Vec3{1, 0, 0}, Vec3{-1, -1, 0.2}, Vec3{-1, 1, 0.2}},
                           {Vec3{-1, 0, 0}, Vec3{1, 0, 0}, Vec3{1, -1, 0.2}, Vec3{1, 1, 0.2}});
    o.min_distance = 0.1;
    EXPECT_FALSE(edge_edge(ee, o).hit);
    o.min_distance = 0.25;
    r = edge_edge(ee, o);
    EXPECT_TRUE(r.hit);
    EXPECT_EQ(r.toi, 0.0);  // within 0.25 from the start (b is over a's end at x = -1)
}

TEST(CcdElementary, WorkCapIsConservative) {
    const auto pts = vertex_and_static_triangle({0.25, 0.25, 1.0}, {0.25, 0.25, -1.0});
    for (std::uint32_t cap : {0u, 1u, 2u, 5u, 20u}) {
        ElementaryOptions o;
        o.max_boxes = cap;
        const auto r = vertex_face(pts, o);
        EXPECT_TRUE(r.hit) << cap;
        EXPECT_LE(r.toi, 0.5) << cap;
        EXPECT_LE(r.boxes, cap);
        if (r.capped) {
            EXPECT_EQ(r.boxes, cap);
        }
    }
    // A clear miss is excluded by the first region, cap or not.
    ElementaryOptions one;
    one.max_boxes = 1;
    const auto miss = vertex_face(vertex_and_static_triangle({5, 5, 1}, {5, 5, -1}), one);
    EXPECT_FALSE(miss.hit);
    EXPECT_EQ(miss.boxes, 1u);
}

TEST(CcdElementary, BadInputIsConservative) {
    auto pts = vertex_and_static_triangle({5, 5, 1}, {5, 5, -1});
    pts[3].y = std::numeric_limits<double>::quiet_NaN();
    auto r = vertex_face(pts);
    EXPECT_TRUE(r.hit);
    EXPECT_TRUE(r.capped);
    EXPECT_EQ(r.toi, 0.0);
    pts[3].y = std::numeric_limits<double>::infinity();
    EXPECT_TRUE(edge_edge(pts).hit);
    ElementaryOptions o;
    o.min_distance = std::numeric_limits<double>::quiet_NaN();
    EXPECT_TRUE(vertex_face(vertex_and_static_triangle({5, 5, 1}, {5, 5, -1}), o).hit);
    // Tolerance 0 or NaN: refined to the width floor, still terminates and still finds contact.
    o = {};
    o.tolerance = 0.0;
    r = vertex_face(vertex_and_static_triangle({0.25, 0.25, 1.0}, {0.25, 0.25, -1.0}), o);
    EXPECT_TRUE(r.hit);
    EXPECT_LE(r.toi, 0.5);
    o.tolerance = std::numeric_limits<double>::quiet_NaN();
    EXPECT_TRUE(
        vertex_face(vertex_and_static_triangle({0.25, 0.25, 1.0}, {0.25, 0.25, -1.0}), o).hit);
}

TEST(CcdElementary, HugeAndTinyCoordinates) {
    // Scaled by 2^1010 (beyond the overflow guard) and by 2^-1000: the same answers.
    for (double s : {0x1p1010, 0x1p-1000, 0x1p500}) {
        auto pts = vertex_and_static_triangle({0.25, 0.25, 1.0}, {0.25, 0.25, -1.0});
        for (auto& p : pts) {
            p = p * s;
        }
        ElementaryOptions o;
        o.tolerance = 1e-6 * s;
        auto r = vertex_face(pts, o);
        EXPECT_TRUE(r.hit) << s;
        EXPECT_LE(r.toi, 0.5) << s;
        EXPECT_GE(r.toi, 0.5 - 1e-5) << s;
        auto miss = vertex_and_static_triangle({0.6, 0.6, 1.0}, {0.6, 0.6, -1.0});
        for (auto& p : miss) {
            p = p * s;
        }
        EXPECT_FALSE(vertex_face(miss, o).hit) << s;
    }
}

// Random queries with an exact contact at t = 1/2: small dyadic coordinates, so every point of
// the construction is exact in double. The test must report it, no later than t = 1/2.
TEST(CcdElementary, RandomExactContactsAreFound) {
    std::mt19937_64 rng(12345);
    std::uniform_int_distribution<int> coord(-64, 64);
    std::uniform_int_distribution<int> eighths(0, 8);
    auto point = [&] { return Vec3{coord(rng) / 16.0, coord(rng) / 16.0, coord(rng) / 16.0}; };
    int vf_hits = 0;
    int ee_hits = 0;
    for (int i = 0; i < 2000; ++i) {
        // vertex-face: a triangle moving randomly; the vertex at t = 1/2 is a point of it.
        CcdPoints pts;
        for (int j = 1; j < 4; ++j) {
            pts[static_cast<std::size_t>(j)] = point();
            pts[static_cast<std::size_t>(j + 4)] = point();
        }
        int ui = eighths(rng);
        int vi = std::uniform_int_distribution<int>(0, 8 - ui)(rng);
        const double u = ui / 8.0;
        const double v = vi / 8.0;
        auto mid = [&](int j) {
            return 0.5 * (pts[static_cast<std::size_t>(j)] + pts[static_cast<std::size_t>(j + 4)]);
        };
        const Vec3 x = mid(1) + u * (mid(2) - mid(1)) + v * (mid(3) - mid(1));
        pts[0] = point();
        pts[4] = 2.0 * x - pts[0];
        auto r = vertex_face(pts);
        ASSERT_TRUE(r.hit) << "vf query " << i;
        ASSERT_LE(r.toi, 0.5) << "vf query " << i;
        vf_hits += r.hit ? 1 : 0;

        // edge-edge: edge a moving randomly; edge b's midpoint at t = 1/2 is a point of a.
        for (int j : {0, 1, 3}) {
            pts[static_cast<std::size_t>(j)] = point();
            pts[static_cast<std::size_t>(j + 4)] = point();
        }
        ui = eighths(rng);
        const Vec3 xa = mid(0) + (ui / 8.0) * (mid(1) - mid(0));
        const Vec3 b0_mid = 2.0 * xa - mid(3);  // b's midpoint (v = 1/2) is xa
        pts[2] = point();
        pts[6] = 2.0 * b0_mid - pts[2];
        r = edge_edge(pts);
        ASSERT_TRUE(r.hit) << "ee query " << i;
        ASSERT_LE(r.toi, 0.5) << "ee query " << i;
        ee_hits += r.hit ? 1 : 0;
    }
    EXPECT_EQ(vf_hits, 2000);
    EXPECT_EQ(ee_hits, 2000);
}

// Random separated queries (the two primitives' swept boxes 0.5 apart on x): never a hit.
TEST(CcdElementary, RandomSeparatedQueriesAreMisses) {
    std::mt19937_64 rng(777);
    std::uniform_real_distribution<double> c(0.0, 1.0);
    for (int i = 0; i < 2000; ++i) {
        CcdPoints pts;
        for (std::size_t j = 0; j < 8; ++j) {
            pts[j] = {c(rng), c(rng), c(rng)};
        }
        // vf: the vertex (0, 4) shifted to x in [1.5, 2.5]; ee: edge a (0, 1, 4, 5) likewise.
        auto vf = pts;
        vf[0].x += 1.5;
        vf[4].x += 1.5;
        EXPECT_FALSE(vertex_face(vf).hit) << i;
        auto ee = pts;
        for (std::size_t j : {0u, 1u, 4u, 5u}) {
            ee[j].x += 1.5;
        }
        EXPECT_FALSE(edge_edge(ee).hit) << i;
    }
}

// Every reported (uncapped) contact has a point within the band soon after its toi: the solver
// accepts a region [t0, t1] x U x V once t1 - t0 <= toi_tolerance and it finds a point of it within
// d + tol (+ rounding) on every axis, at t1 (the point certificate), or at its corner t0 (a region
// within the band as a whole), or at the width floor. Widths are powers of two, so the witness
// time is toi or toi + 2^-k with 2^-k <= toi_tolerance. Checked here independently, with the
// engine's closest-point routines (Euclidean, so within sqrt(3) (d + tol) of the max-norm band), on
// random moving primitives that touch at t = 1/2, on near misses that pass up to 20 (d + tol)
// beside the triangle's side or beyond the edge's end at t = 1/2 (through the plane or the other
// edge's line, so that only the axes can exclude them and a loose certificate would report a
// pair outside the band), and on random pairs that may or may not touch.
TEST(CcdElementary, ReportedContactsHaveAPointWithinTheBandSoonAfter) {
    std::mt19937_64 rng(4242);
    std::uniform_real_distribution<double> c(-1.0, 1.0);
    std::uniform_real_distribution<double> w(0.0, 1.0);
    auto lerp = [](const Vec3& a, const Vec3& b, double t) { return (1.0 - t) * a + t * b; };
    auto gap = [&](CcdKind kind, const CcdPoints& p, double t) {
        const Vec3 x[4] = {lerp(p[0], p[4], t), lerp(p[1], p[5], t), lerp(p[2], p[6], t),
                           lerp(p[3], p[7], t)};
        const auto cp = kind == VF ? point_triangle(x[0], x[1], x[2], x[3])
                                   : segment_segment(x[0], x[1], x[2], x[3]);
        return std::sqrt(cp.squared_distance);
    };
    int checked = 0;
    std::uint64_t boxes = 0;
    for (const double d : {0.0, 1e-3}) {
        ElementaryOptions o;
        o.min_distance = d;
        const double band = std::sqrt(3.0) * (d + o.tolerance) * (1.0 + 1e-9) + 1e-12;
        for (int i = 0; i < 1500; ++i) {
            CcdPoints pts;
            for (auto& p : pts) {
                p = {c(rng), c(rng), c(rng)};
            }
            const CcdKind kind = i % 2 == 0 ? VF : EE;
            if (i % 3 != 0) {
                // Make them touch at t = 1/2: move the first point (vf) or the first edge (ee) so
                // that a random point of the first primitive meets one of the second.
                auto mid = [&](std::size_t j) { return 0.5 * (pts[j] + pts[j + 4]); };
                double a = w(rng);
                double b = w(rng);
                if (kind == VF && a + b > 1.0) {
                    a = 1.0 - a;
                    b = 1.0 - b;
                }
                if (i % 3 == 2) {
                    // Near miss: on the triangle's side (b = 0) or at the edge's end (a = 0).
                    (kind == VF ? b : a) = 0.0;
                }
                const Vec3 target = kind == VF
                                        ? mid(1) + a * (mid(2) - mid(1)) + b * (mid(3) - mid(1))
                                        : mid(2) + b * (mid(3) - mid(2));
                const Vec3 from = kind == VF ? mid(0) : mid(0) + a * (mid(1) - mid(0));
                Vec3 shift = target - from;
                if (i % 3 == 2) {
                    // Then move it out: the vertex away from the triangle across that side, in
                    // the triangle's plane; the edge along itself, its end a0 away from the
                    // other edge (towards a1's side).
                    Vec3 out = mid(1) - mid(0);
                    if (kind == VF) {
                        const Vec3 side = mid(2) - mid(1);
                        out = cross(cross(side, mid(3) - mid(1)), side);
                        if (dot(out, mid(3) - mid(1)) > 0.0) {
                            out = -1.0 * out;
                        }
                    }
                    const double len = std::sqrt(dot(out, out));
                    if (len > 1e-3) {
                        shift = shift + (w(rng) * 20.0 * (d + o.tolerance) / len) * out;
                    }
                }
                for (std::size_t j : kind == VF ? std::vector<std::size_t>{0, 4}
                                                : std::vector<std::size_t>{0, 1, 4, 5}) {
                    pts[j] = pts[j] + shift;
                }
            }
            const auto r = elementary(kind, pts, o);
            boxes += r.boxes;
            if (!r.hit || r.capped) {
                EXPECT_TRUE(i % 3 != 1) << "a constructed contact was missed, query " << i;
                continue;
            }
            double nearest = gap(kind, pts, r.toi);
            for (int k = 20; k <= 52; ++k) {
                const double t = r.toi + std::ldexp(1.0, -k);
                if (t <= 1.0) {
                    nearest = std::min(nearest, gap(kind, pts, t));
                }
            }
            EXPECT_LE(nearest, band) << "query " << i << " d " << d << " toi " << r.toi;
            if (i % 3 == 1) {
                EXPECT_LE(r.toi, 0.5) << "query " << i;  // never later than the contact
            }
            ++checked;
        }
    }
    EXPECT_GT(checked, 1200);  // 1,000 constructed contacts, and some of the others
    // The work it took (the same on every machine): regions per query on these pairs.
    std::printf("regions per query: %.1f\n", static_cast<double>(boxes) / 3000.0);
}

// A pair that stays inside the band but never comes within d: the vertex rests 0.5e-6 above the
// triangle (tol = 1e-6). The region normal's test (threshold d, not d + tol) finds it apart; with
// d = 1e-6 it touches from the start.
TEST(CcdElementary, RestingInsideTheBandButNeverWithinDIsApart) {
    const auto pts = vertex_and_static_triangle({0.25, 0.25, 0.5e-6}, {0.3, 0.2, 0.5e-6});
    const auto r = vertex_face(pts);
    EXPECT_FALSE(r.hit);
    EXPECT_LE(r.boxes, 3u);
    ElementaryOptions o;
    o.min_distance = 1e-6;
    const auto near = vertex_face(pts, o);
    EXPECT_TRUE(near.hit);
    EXPECT_EQ(near.toi, 0.0);
}

// ---- The rounding-error bound against exact arithmetic -------------------------------------

class Q {
  public:
    Q() { mpq_init(m_q); }
    explicit Q(double d) : Q() { mpq_set_d(m_q, d); }
    ~Q() { mpq_clear(m_q); }
    Q(const Q& o) : Q() { mpq_set(m_q, o.m_q); }
    Q& operator=(const Q& o) {
        mpq_set(m_q, o.m_q);
        return *this;
    }
    friend Q operator+(const Q& a, const Q& b) {
        Q r;
        mpq_add(r.m_q, a.m_q, b.m_q);
        return r;
    }
    friend Q operator-(const Q& a, const Q& b) {
        Q r;
        mpq_sub(r.m_q, a.m_q, b.m_q);
        return r;
    }
    friend Q operator*(const Q& a, const Q& b) {
        Q r;
        mpq_mul(r.m_q, a.m_q, b.m_q);
        return r;
    }
    mpq_t& get() { return m_q; }
    const mpq_t& get() const { return m_q; }
    double to_double() const { return mpq_get_d(m_q); }

  private:
    mpq_t m_q;
};

// A random rational near `center` (within `spread`), with a large denominator, and the double it
// rounds to (mpq_get_d truncates: within 1 ulp, the bound's assumption).
struct Coordinate {
    Q exact;
    double rounded;
};

Coordinate random_rational(std::mt19937_64& rng, double center, double spread) {
    std::uniform_real_distribution<double> unit(-1.0, 1.0);
    Coordinate c;
    Q base(center + spread * unit(rng));
    // Perturb by a non-dyadic amount below 1 ulp: base + k / (3 * 7 * 2^80) * |base|.
    Q frac;
    mpq_set_si(frac.get(), static_cast<long>(rng() % 1000) - 500, 21);
    mpz_mul_2exp(mpq_denref(frac.get()), mpq_denref(frac.get()), 62);
    mpq_canonicalize(frac.get());
    Q mag(std::max(std::abs(base.to_double()), 1e-300));
    c.exact = base + frac * mag * Q(0x1p-2);
    c.rounded = c.exact.to_double();
    return c;
}

Q lerp(const Q& x0, const Q& x1, const Q& t) {
    return (Q(1.0) - t) * x0 + t * x1;
}

// Exact F_k at (t, u, v) on the exact coordinates xs[point][frame].
Q exact_f(CcdKind kind, const std::array<std::array<Q, 2>, 4>& xs, double t, double u, double v) {
    const Q qt(t), qu(u), qv(v);
    std::array<Q, 4> x;
    for (std::size_t j = 0; j < 4; ++j) {
        x[j] = lerp(xs[j][0], xs[j][1], qt);
    }
    if (kind == CcdKind::vertex_face) {
        return x[0] - x[1] - qu * (x[2] - x[1]) - qv * (x[3] - x[1]);
    }
    return x[0] + qu * (x[1] - x[0]) - x[2] - qv * (x[3] - x[2]);
}

struct Scenario {
    const char* name;
    double center;       // coordinates near this
    double spread;       // ... within this
    double motion;       // t1 positions differ from t0 by up to this
    double common_move;  // and everything translates by up to this
};

TEST(CcdElementary, RoundingErrorBoundHoldsAgainstExactArithmetic) {
    const Scenario scenarios[] = {
        {"unit box", 0.0, 1.0, 1.0, 0.0},
        {"large offset, tiny motion", 1e6, 1e-3, 1e-9, 0.0},
        {"huge offset, tiny features", 3e12, 1e-4, 1e-7, 1e-7},
        {"near-cancellation", 1.0, 1e-12, 1e-12, 0.5},
        {"mixed magnitudes", 0.0, 1e8, 1e-6, 0.0},
        {"tiny", 0.0, 1e-200, 1e-200, 0.0},
        {"large", 0.0, 1e250, 1e250, 0.0},
    };
    std::mt19937_64 rng(2024);
    std::uniform_int_distribution<int> level(0, 50);
    double worst_ratio = 0.0;
    for (const auto& sc : scenarios) {
        for (int trial = 0; trial < 300; ++trial) {
            const CcdKind kind = trial % 2 == 0 ? VF : EE;
            // Exact rational coordinates per axis, point, frame, and their doubles.
            std::array<std::array<std::array<Q, 2>, 4>, 3> exact;
            CcdPoints pts;
            std::uniform_real_distribution<double> unit(-1.0, 1.0);
            const double shift = sc.common_move * unit(rng);
            for (int k = 0; k < 3; ++k) {
                for (int j = 0; j < 4; ++j) {
                    const auto c0 = random_rational(rng, sc.center, sc.spread);
                    const auto c1 = random_rational(rng, c0.rounded + shift + sc.motion * unit(rng),
                                                    sc.motion * 1e-3);
                    exact[static_cast<std::size_t>(k)][static_cast<std::size_t>(j)] = {c0.exact,
                                                                                       c1.exact};
                    pts[static_cast<std::size_t>(j)][k] = c0.rounded;
                    pts[static_cast<std::size_t>(j + 4)][k] = c1.rounded;
                }
            }
            // A random dyadic region: bisection points at random depths.
            auto dyadic_interval = [&] {
                const int l = level(rng);
                const double w = std::ldexp(1.0, -l);
                const auto cells = static_cast<std::uint64_t>(std::ldexp(1.0, l));
                const double lo = static_cast<double>(rng() % cells) * w;
                return std::array<double, 2>{lo, lo + w};
            };
            const auto ti = dyadic_interval();
            const auto ui = dyadic_interval();
            const auto vi = dyadic_interval();
            const CcdRegion region{ti[0], ti[1], ui[0], ui[1], vi[0], vi[1]};
            const auto cv = elementary_corner_values(kind, pts, region);
            ASSERT_TRUE(cv.valid) << sc.name;
            for (int k = 0; k < 3; ++k) {
                const auto ks = static_cast<std::size_t>(k);
                for (int c = 0; c < 8; ++c) {
                    const Q fe = exact_f(kind, exact[ks], ti[c >> 2], ui[(c >> 1) & 1], vi[c & 1]);
                    const Q diff = Q(cv.values[ks][static_cast<std::size_t>(c)]) - fe;
                    const double err = std::abs(diff.to_double());
                    ASSERT_LE(err, cv.error_bound[ks])
                        << sc.name << " trial " << trial << " axis " << k << " corner " << c;
                    if (cv.error_bound[ks] > 0.0) {
                        worst_ratio = std::max(worst_ratio, err / cv.error_bound[ks]);
                    }
                }
            }
        }
    }
    std::printf("largest |computed - exact| / bound: %.3g\n", worst_ratio);
    EXPECT_LT(worst_ratio, 1.0);
}

TEST(CcdElementary, CornerValuesRejectBadRegions) {
    const auto pts = vertex_and_static_triangle({0.25, 0.25, 1.0}, {0.25, 0.25, -1.0});
    EXPECT_TRUE(elementary_corner_values(VF, pts, {0, 1, 0, 0.5, 0.25, 0.75}).valid);
    EXPECT_FALSE(elementary_corner_values(VF, pts, {0, 1.5, 0, 1, 0, 1}).valid);
    EXPECT_FALSE(elementary_corner_values(VF, pts, {0, 0.1, 0, 1, 0, 1}).valid);  // not dyadic
    auto bad = pts;
    bad[0].x = std::numeric_limits<double>::infinity();
    EXPECT_FALSE(elementary_corner_values(VF, bad, {0, 1, 0, 1, 0, 1}).valid);
}

// ---- Acceptance: the public benchmark, zero false negatives ---------------------------------

// The public benchmark's query files (PROXIMA_DATA_DIR/ccd-queries, every .csv below it), sorted.
std::vector<fs::path> public_query_files(const fs::path& root) {
    std::vector<fs::path> files;
    for (const auto& e : fs::recursive_directory_iterator(root)) {
        if (e.is_regular_file() && e.path().extension() == ".csv") {
            files.push_back(e.path());
        }
    }
    std::sort(files.begin(), files.end());
    return files;
}

// fn(file, kind, index in the file, query) for every query of `files`, in order.
template <class Fn>
void for_each_public_query(const std::vector<fs::path>& files, Fn&& fn) {
    for (const auto& file : files) {
        const auto kind = ccd_kind_from_path(file.string());
        ASSERT_TRUE(kind.has_value()) << file;
        auto read = read_ccd_queries(file.string());
        ASSERT_TRUE(read.ok()) << read.status().to_string();
        for (std::size_t i = 0; i < read->size(); ++i) {
            fn(file, *kind, i, read.value()[i]);
        }
    }
}

TEST(CcdElementary, PublicBenchmarkHasNoFalseNegatives) {
    const fs::path root = fs::path(PROXIMA_DATA_DIR) / "ccd-queries";
    if (!fs::is_directory(root)) {
        GTEST_SKIP() << "CCD benchmark data not found at " << root
                     << " (PROXIMA_DATA_DIR/ccd-queries)";
    }
    const auto files = public_query_files(root);
    ASSERT_GE(files.size(), 42u);
    std::size_t queries = 0;
    std::size_t positives = 0;
    std::size_t false_negatives = 0;
    std::size_t false_positives = 0;
    std::size_t capped = 0;
    std::size_t prefiltered = 0;
    const auto start = std::chrono::steady_clock::now();
    for_each_public_query(files, [&](const fs::path& file, CcdKind kind, std::size_t i,
                                     const auto& q) {
        ASSERT_TRUE(q.truth.has_value()) << file;
        const auto r = elementary(kind, q.points);
        if (elementary_prefilter_rejects(kind, q.points)) {
            // The plane / direction filter may only drop pairs that never touch, and never one
            // the solver reports uncapped.
            ++prefiltered;
            EXPECT_FALSE(*q.truth) << "prefilter rejected a colliding query: " << file << " " << i;
            EXPECT_TRUE(!r.hit || r.capped) << "prefilter rejected a hit: " << file << " " << i;
        }
        ++queries;
        positives += *q.truth ? 1 : 0;
        capped += r.capped ? 1 : 0;
        if (*q.truth && !r.hit) {
            ++false_negatives;
            ADD_FAILURE() << "false negative: " << file << " query " << i;
        }
        false_positives += (!*q.truth && r.hit) ? 1 : 0;
        EXPECT_GE(r.toi, 0.0);
        EXPECT_LE(r.toi, 1.0);
    });
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::printf(
        "ccd-queries: %zu queries (%zu colliding) in %zu files: %zu false negatives, %zu "
        "false positives, %zu capped, %.2f s with parsing; the prefilter rejects %zu\n",
        queries, positives, files.size(), false_negatives, false_positives, capped, seconds,
        prefiltered);
    EXPECT_EQ(queries, 7279u);
    EXPECT_EQ(positives, 435u);
    EXPECT_EQ(false_negatives, 0u);
}

// `elementary` and `elementary_prefilter_rejects` may run copies compiled for AVX2 (chosen at run
// time); they must give the portable copies' answers bit for bit: hit, toi, capped and the number
// of regions examined (so the same regions, in the same order). Random queries near contact
// (exact contacts, small gaps, motion in the plane), with the default options, a minimum distance,
// a tighter tolerance and the direction exclusion off, then every public query.
TEST(CcdElementary, DispatchedSolverEqualsPortable) {
    std::vector<ElementaryOptions> variants(4);
    variants[1].min_distance = 1e-3;
    variants[2].tolerance = 1e-9;
    variants[2].toi_tolerance = 0.0;
    variants[3].direction_exclusion = false;
    std::size_t compared = 0;
    std::size_t hits = 0;
    auto compare = [&](CcdKind kind, const CcdPoints& pts, const std::string& what) {
        for (const auto& opt : variants) {
            const auto a = elementary(kind, pts, opt);
            const auto b = elementary_portable(kind, pts, opt);
            ASSERT_EQ(a.hit, b.hit) << what;
            ASSERT_EQ(a.capped, b.capped) << what;
            ASSERT_EQ(a.boxes, b.boxes) << what;
            ASSERT_EQ(std::memcmp(&a.toi, &b.toi, sizeof a.toi), 0)
                << what << ": toi " << a.toi << " vs " << b.toi;
            ASSERT_EQ(elementary_prefilter_rejects(kind, pts, opt),
                      elementary_prefilter_rejects_portable(kind, pts, opt))
                << what;
            ++compared;
            hits += a.hit ? 1 : 0;
        }
    };
    std::mt19937_64 rng(2026);
    std::uniform_real_distribution<double> coord(-1.0, 1.0);
    std::uniform_real_distribution<double> small(-1e-3, 1e-3);
    auto point = [&] { return Vec3{coord(rng), coord(rng), coord(rng)}; };
    for (int i = 0; i < 1500; ++i) {
        CcdPoints pts;
        for (auto& p : pts) {
            p = point();
        }
        const CcdKind kind = i % 2 == 0 ? VF : EE;
        compare(kind, pts, "random " + std::to_string(i));
        // Near contact: the first point ends (or starts) near a point of the other primitive.
        const double a = std::uniform_real_distribution<double>(0.0, 0.5)(rng);
        const double b = std::uniform_real_distribution<double>(0.0, 0.5)(rng);
        const std::size_t end = i % 3 == 0 ? 0 : 4;
        const Vec3 target = kind == VF ? pts[1 + end] + a * (pts[2 + end] - pts[1 + end]) +
                                             b * (pts[3 + end] - pts[1 + end])
                                       : pts[2 + end] + b * (pts[3 + end] - pts[2 + end]) -
                                             a * (pts[1 + end] - pts[end]);
        pts[end] = target + Vec3{small(rng), small(rng), small(rng)} * (i % 5 == 0 ? 0.0 : 1.0);
        compare(kind, pts, "near " + std::to_string(i));
        // Resting: the same positions at both ends, slightly perturbed.
        for (std::size_t j = 0; j < 4; ++j) {
            pts[j + 4] = pts[j] + Vec3{small(rng), small(rng), small(rng)} * 1e-3;
        }
        compare(kind, pts, "resting " + std::to_string(i));
    }
    EXPECT_EQ(compared, 1500u * 3u * variants.size());
    EXPECT_GT(hits, 1000u);  // the comparison covers contacts, not only misses
    const fs::path root = fs::path(PROXIMA_DATA_DIR) / "ccd-queries";
    if (!fs::is_directory(root)) {
        GTEST_SKIP() << "CCD benchmark data not found at " << root;
    }
    variants.resize(1);  // the public queries at the defaults (the others: cost)
    for_each_public_query(public_query_files(root),
                          [&](const fs::path& file, CcdKind kind, std::size_t i, const auto& q) {
                              compare(kind, q.points, file.string() + " " + std::to_string(i));
                          });
}

}  // namespace
}  // namespace proxima::ccd
