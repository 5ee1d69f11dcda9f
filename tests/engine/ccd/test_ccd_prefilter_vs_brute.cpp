// The CCD prefilter (elementary_prefilter_rejects: axis, direction and plane filters) against the
// exact elementary tests: whenever the prefilter rejects a query, the solver must report no hit,
// or a capped one that a much larger work bound then rejects. Random queries of every kind the
// filters decide on, concentrated where they are most likely to be wrong: gaps within a few
// rounding units of the acceptance threshold d + tol (along an axis, and along (1, 1, 1) where
// the Euclidean bounds of the plane and direction filters are tightest), motion in the triangle's
// plane, (nearly) parallel and collinear edges, contact exactly at t = 0 or t = 1, degenerate
// triangles, and coordinates from 2^-250 to 2^190 with large offsets.
// The same queries check the solver's direction exclusion (ElementaryOptions::
// direction_exclusion) against the solver without it: every answer that does not reach the work
// bound without it is identical (hit, toi bits, not capped), and never more regions are examined.

#include <gtest/gtest.h>

#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <random>

#include "proxima/ccd/elementary.hpp"
#include "support/sanitized.hpp"

namespace proxima::ccd {
namespace {

constexpr CcdKind VF = CcdKind::vertex_face;
constexpr CcdKind EE = CcdKind::edge_edge;

struct Tally {
    int queries = 0;
    int rejected = 0;
    int hits = 0;
    int capped_rejected = 0;
    std::uint64_t boxes = 0;          // with the direction exclusion
    std::uint64_t boxes_without = 0;  // without it
    int finished_with_it = 0;         // capped without it, not with it
    int compare_every = 1;            // compare with the exclusion off on every n-th query
};

// The direction exclusion only skips regions that hold no accepted region: the same answer as
// without it, in no more regions (a capped answer without it may finish with it: then it must
// equal the answer of a larger work bound, when that one finishes).
void check_direction_exclusion(CcdKind kind, const CcdPoints& pts, const ElementaryOptions& opt,
                               const ElementaryResult& r, Tally& tally, const char* what, int i) {
    if (i % tally.compare_every != 0) {
        return;
    }
    ElementaryOptions off = opt;
    off.direction_exclusion = false;
    auto r0 = elementary(kind, pts, off);
    tally.boxes += r.boxes;
    tally.boxes_without += r0.boxes;
    EXPECT_LE(r.boxes, r0.boxes) << what << " query " << i;
    if (r0.capped && !r.capped) {
        // Confirmed against a 4x larger bound for the first 20 per test (each costs up to
        // 200,000 regions; the in-plane queries have dozens).
        if (++tally.finished_with_it > 20) {
            return;
        }
        off.max_boxes = 200'000;
        r0 = elementary(kind, pts, off);
        if (r0.capped) {
            return;
        }
    }
    if (r0.capped) {
        EXPECT_TRUE(r.capped) << what << " query " << i;
        return;
    }
    const bool same = r.hit == r0.hit && !r.capped &&
                      std::bit_cast<std::uint64_t>(r.toi) == std::bit_cast<std::uint64_t>(r0.toi);
    if (!same) {
        ADD_FAILURE() << what << " query " << i << " (" << ccd_kind_name(kind)
                      << "): with the direction exclusion hit " << r.hit << " toi " << r.toi
                      << " capped " << r.capped << ", without hit " << r0.hit << " toi " << r0.toi
                      << " (d " << opt.min_distance << ", tol " << opt.tolerance << ")";
        for (const auto& p : pts) {
            std::printf("  %.17g %.17g %.17g\n", p.x, p.y, p.z);
        }
    }
}

// The direction exclusion must have something to do on these queries.
void expect_fewer_boxes(const Tally& tally, const char* what) {
    std::printf(
        "%s: %llu regions examined with the direction exclusion, %llu without; %d capped only "
        "without it\n",
        what, static_cast<unsigned long long>(tally.boxes),
        static_cast<unsigned long long>(tally.boxes_without), tally.finished_with_it);
    EXPECT_LT(tally.boxes, tally.boxes_without) << what;
}

// The property, for one query.
void check(CcdKind kind, const CcdPoints& pts, const ElementaryOptions& opt, Tally& tally,
           const char* what, int i) {
    ++tally.queries;
    const bool rejected = elementary_prefilter_rejects(kind, pts, opt);
    const auto r = elementary(kind, pts, opt);
    tally.hits += r.hit ? 1 : 0;
    check_direction_exclusion(kind, pts, opt, r, tally, what, i);
    if (!rejected) {
        return;
    }
    ++tally.rejected;
    if (r.hit && !r.capped) {
        ADD_FAILURE() << what << " query " << i << " (" << ccd_kind_name(kind)
                      << "): the prefilter rejected a hit at toi " << r.toi << " (d "
                      << opt.min_distance << ", tol " << opt.tolerance << ")";
        for (const auto& p : pts) {
            std::printf("  %.17g %.17g %.17g\n", p.x, p.y, p.z);
        }
        return;
    }
    if (r.capped) {
        ++tally.capped_rejected;
        ElementaryOptions more = opt;
        more.max_boxes = 500'000;
        const auto r2 = elementary(kind, pts, more);
        EXPECT_TRUE(!r2.hit || r2.capped) << what << " query " << i;
    }
}

// A rotation taking (0, 0, 1) to the unit vector n (Householder-style, in doubles: the rounding
// only moves the points, the tests read the points as given).
std::array<Vec3, 3> frame_for(const Vec3& n) {
    const Vec3 a = std::abs(n.x) < 0.9 ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
    Vec3 e1 = cross(a, n);
    e1 = e1 / norm(e1);
    const Vec3 e2 = cross(n, e1);
    return {e1, e2, n};
}

Vec3 in_frame(const std::array<Vec3, 3>& f, const Vec3& c, const Vec3& p) {
    return c + p.x * f[0] + p.y * f[1] + p.z * f[2];
}

class Gen {
  public:
    explicit Gen(std::uint64_t seed) : m_rng(seed) {}
    double uniform(double lo, double hi) { return std::uniform_real_distribution<>(lo, hi)(m_rng); }
    int integer(int lo, int hi) { return std::uniform_int_distribution<>(lo, hi)(m_rng); }
    Vec3 point(double r) { return {uniform(-r, r), uniform(-r, r), uniform(-r, r)}; }
    Vec3 unit() {
        for (;;) {
            const Vec3 p = point(1.0);
            const double n = norm(p);
            if (n > 0.1 && n <= 1.0) {
                return p / n;
            }
        }
    }
    ElementaryOptions options() {
        ElementaryOptions o;
        const int pick = integer(0, 3);
        o.min_distance =
            pick == 0 ? 0.0 : (pick == 1 ? 1e-3 : (pick == 2 ? uniform(0, 0.05) : 1e-9));
        o.tolerance = integer(0, 3) == 0 ? uniform(1e-8, 1e-3) : 1e-6;
        o.max_boxes = 50'000;
        return o;
    }
    std::mt19937_64& rng() { return m_rng; }

  private:
    std::mt19937_64 m_rng;
};

// Scales every coordinate by 2^e and adds an offset (both applied exactly as doubles allow).
CcdPoints rescale(const CcdPoints& pts, int e, const Vec3& offset) {
    CcdPoints out;
    for (std::size_t j = 0; j < 8; ++j) {
        out[j] = Vec3{std::ldexp(pts[j].x, e), std::ldexp(pts[j].y, e), std::ldexp(pts[j].z, e)} +
                 offset;
    }
    return out;
}

// Gap to aim for: min_distance d (where the solver's hits end) or d + tol (the filters'
// threshold), give or take a few rounding units of the largest coordinate, or plainly random.
double critical_gap(Gen& g, const ElementaryOptions& o, double scale) {
    const double base = g.integer(0, 1) == 0 ? o.min_distance + o.tolerance : o.min_distance;
    switch (g.integer(0, 4)) {
        case 0:
            return base * g.uniform(0.0, 3.0);
        case 1:
            return base + g.uniform(-8.0, 16.0) * 0x1p-46 * scale;
        case 2:
            return base * (1.0 + g.uniform(-1e-9, 1e-9));
        case 3:
            return std::nextafter(base, 2.0 * base + 1.0);
        default:
            return base * (1.0 + g.integer(0, 64) * 0x1p-50);
    }
}

TEST(CcdPrefilterVsBrute, RandomQueries) {
    Gen g(20261126);
    Tally tally;
    for (int i = 0; i < 20000; ++i) {
        CcdPoints pts;
        const double r = g.integer(0, 1) == 0 ? 1.0 : 0.05;
        for (auto& p : pts) {
            p = g.point(r);
        }
        // Small motions half of the time (resting-contact frames).
        if (g.integer(0, 1) == 0) {
            for (std::size_t j = 0; j < 4; ++j) {
                pts[j + 4] = pts[j] + g.point(0.01);
            }
        }
        check(i % 2 == 0 ? VF : EE, pts, g.options(), tally, "random", i);
    }
    std::printf("random: %d queries, %d hits, %d rejected (%d capped)\n", tally.queries, tally.hits,
                tally.rejected, tally.capped_rejected);
    EXPECT_GT(tally.rejected, 5000);
    expect_fewer_boxes(tally, "random");
}

// A vertex gliding past a triangle (or an edge past an edge) at a gap near the acceptance
// threshold, in a random orientation or with the gap along (1, 1, 1), sometimes reaching the
// gap exactly at t = 0 or t = 1.
TEST(CcdPrefilterVsBrute, GapsNearTheThreshold) {
    Gen g(4242);
    Tally tally;
    for (int i = 0; i < 40000; ++i) {
        const auto opt = g.options();
        const int orient = g.integer(0, 2);
        const Vec3 n =
            orient == 0 ? Vec3{0, 0, 1} : (orient == 1 ? Vec3{1, 1, 1} / std::sqrt(3.0) : g.unit());
        const auto f = frame_for(n);
        const Vec3 c = g.integer(0, 1) == 0 ? Vec3{} : g.point(1.0);
        // Along (1, 1, 1) a Euclidean gap of sqrt(3) g is a gap of g on every axis: the case
        // where the plane and direction filters' Euclidean bounds are tight.
        const double gap = critical_gap(g, opt, 2.0) *
                           (orient == 1 && g.integer(0, 1) == 0 ? std::sqrt(3.0) : 1.0);
        const double s = g.uniform(0.01, 1.0);  // primitive size
        const int mode = g.integer(0, 2);       // 0: gap at all t; 1: at t = 0; 2: at t = 1
        auto height = [&](int end) {
            if (mode == 0) {
                return gap;
            }
            return (mode == 1) == (end == 0) ? gap : gap + g.uniform(0.0, s);
        };
        CcdPoints pts;
        const bool vf = i % 2 == 0;
        for (int end = 0; end < 2; ++end) {
            const Vec3 shift{g.uniform(-s, s) * 0.1, g.uniform(-s, s) * 0.1, 0.0};
            const auto o = static_cast<std::size_t>(4 * end);
            if (vf) {
                // Triangle in the plane z = 0 of the frame, vertex above its interior.
                pts[o + 1] = in_frame(f, c, Vec3{0, 0, 0} + shift);
                pts[o + 2] = in_frame(f, c, Vec3{s, 0, 0} + shift);
                pts[o + 3] = in_frame(f, c, Vec3{0, s, 0} + shift);
                pts[o + 0] = in_frame(f, c, Vec3{0.3 * s, 0.3 * s, height(end)} + shift);
            } else {
                // Crossing edges, one at z = 0 and one at z = gap.
                pts[o + 0] = in_frame(f, c, Vec3{-s, 0, 0} + shift);
                pts[o + 1] = in_frame(f, c, Vec3{s, 0, 0} + shift);
                pts[o + 2] = in_frame(f, c, Vec3{0, -s, height(end)} + shift);
                pts[o + 3] = in_frame(f, c, Vec3{0, s, height(end)} + shift);
            }
        }
        check(vf ? VF : EE, pts, opt, tally, "gap", i);
    }
    std::printf("gaps near the threshold: %d queries, %d hits, %d rejected (%d capped)\n",
                tally.queries, tally.hits, tally.rejected, tally.capped_rejected);
    EXPECT_GT(tally.rejected, 1000);
    EXPECT_GT(tally.hits, 1000);
    expect_fewer_boxes(tally, "gaps");
}

// Motion in (or next to) the triangle's plane and (nearly) parallel or collinear edges: the
// configurations where the plane filter has nothing to work with and the direction filter
// separates in the plane.
TEST(CcdPrefilterVsBrute, InPlaneAndParallel) {
    Gen g(99);
    Tally tally;
    // Slow queries (parallel edges): a third is compared, a ninth under the sanitizers (whose
    // stage runs the comparison ~3x slower; the release stage keeps the third).
    tally.compare_every = test::SANITIZED ? 9 : 3;
    for (int i = 0; i < 30000; ++i) {
        const auto opt = g.options();
        const auto f = frame_for(g.integer(0, 1) == 0 ? Vec3{0, 0, 1} : g.unit());
        const Vec3 c = g.point(1.0);
        const double s = g.uniform(0.01, 1.0);
        const double gap = critical_gap(g, opt, 2.0);
        const double z = g.integer(0, 1) == 0 ? 0.0 : g.uniform(-1.0, 1.0) * opt.tolerance;
        CcdPoints pts;
        const bool vf = i % 2 == 0;
        for (int end = 0; end < 2; ++end) {
            const auto o = static_cast<std::size_t>(4 * end);
            const Vec3 shift{g.uniform(-s, s) * 0.05, 0.0, 0.0};
            if (vf) {
                // The vertex beyond the hypotenuse (x + y = s), gap away within the plane, or
                // beyond the leg y = 0.
                pts[o + 1] = in_frame(f, c, Vec3{0, 0, 0} + shift);
                pts[o + 2] = in_frame(f, c, Vec3{s, 0, 0} + shift);
                pts[o + 3] = in_frame(f, c, Vec3{0, s, 0} + shift);
                const double along = g.uniform(0.1, 0.9) * s;
                pts[o + 0] = g.integer(0, 1) == 0
                                 ? in_frame(f, c,
                                            Vec3{along + gap / std::sqrt(2.0),
                                                 s - along + gap / std::sqrt(2.0), z} +
                                                shift)
                                 : in_frame(f, c, Vec3{along, -gap, z} + shift);
            } else {
                // Parallel edges gap apart within a plane, or collinear with a gap between ends.
                if (g.integer(0, 1) == 0) {
                    pts[o + 0] = in_frame(f, c, Vec3{0, 0, 0} + shift);
                    pts[o + 1] = in_frame(f, c, Vec3{s, 0, 0} + shift);
                    pts[o + 2] = in_frame(f, c, Vec3{0.5 * s, gap, z} + shift);
                    pts[o + 3] = in_frame(
                        f, c, Vec3{1.5 * s, gap * (1.0 + g.uniform(-1e-6, 1e-6)), z} + shift);
                } else {
                    pts[o + 0] = in_frame(f, c, Vec3{0, 0, 0} + shift);
                    pts[o + 1] = in_frame(f, c, Vec3{s, 0, 0} + shift);
                    pts[o + 2] = in_frame(f, c, Vec3{s + gap, 0, z} + shift);
                    pts[o + 3] = in_frame(f, c, Vec3{2 * s + gap, 0, z} + shift);
                }
            }
        }
        check(vf ? VF : EE, pts, opt, tally, "in-plane", i);
    }
    std::printf("in-plane and parallel: %d queries, %d hits, %d rejected (%d capped)\n",
                tally.queries, tally.hits, tally.rejected, tally.capped_rejected);
    EXPECT_GT(tally.rejected, 1000);
    expect_fewer_boxes(tally, "in-plane");
}

// Degenerate primitives (a triangle collapsed to a segment or a point, an edge to a point) and
// queries rescaled by 2^-250 .. 2^190 with offsets, so that the thresholds' relative margins are
// exercised far from unit scale.
TEST(CcdPrefilterVsBrute, DegenerateAndRescaled) {
    Gen g(31337);
    Tally tally;
    for (int i = 0; i < 20000; ++i) {
        auto opt = g.options();
        CcdPoints pts;
        for (auto& p : pts) {
            p = g.point(1.0);
        }
        switch (g.integer(0, 3)) {
            case 0:  // triangle (or second edge) collapsed to a segment
                pts[3] = 0.5 * (pts[1] + pts[2]);
                pts[7] = 0.25 * pts[5] + 0.75 * pts[6];
                break;
            case 1:  // collapsed to a point
                pts[2] = pts[3] = pts[1];
                pts[6] = pts[7] = pts[5];
                break;
            case 2:  // small motion, nearly touching
                for (std::size_t j = 0; j < 4; ++j) {
                    pts[j + 4] = pts[j] + g.point(1e-3);
                }
                pts[0] = 0.3 * pts[1] + 0.3 * pts[2] + 0.4 * pts[3] + g.point(1e-5);
                pts[4] = 0.3 * pts[5] + 0.3 * pts[6] + 0.4 * pts[7] + g.point(1e-5);
                break;
            default:
                break;
        }
        const int e = g.integer(0, 2) == 0 ? 0 : g.integer(-250, 190);
        const Vec3 offset = g.integer(0, 1) == 0 ? Vec3{} : std::ldexp(1.0, e) * g.point(1e6);
        pts = rescale(pts, e, offset);
        opt.min_distance = std::ldexp(opt.min_distance, e);
        opt.tolerance = std::ldexp(opt.tolerance, e);
        check(i % 2 == 0 ? VF : EE, pts, opt, tally, "degenerate/rescaled", i);
    }
    std::printf("degenerate and rescaled: %d queries, %d hits, %d rejected (%d capped)\n",
                tally.queries, tally.hits, tally.rejected, tally.capped_rejected);
    EXPECT_GT(tally.rejected, 1000);
    expect_fewer_boxes(tally, "degenerate");
}

// No decision on input the solver reports unexamined, and none outside the guarded range.
TEST(CcdPrefilterVsBrute, NoDecisionOutsideItsGuards) {
    CcdPoints far{Vec3{0, 0, 10}, Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0},
                  Vec3{0, 0, 10}, Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}};
    EXPECT_TRUE(elementary_prefilter_rejects(VF, far));
    ElementaryOptions o;
    o.max_boxes = 0;
    EXPECT_FALSE(elementary_prefilter_rejects(VF, far, o));
    o = {};
    o.min_distance = std::nan("");
    EXPECT_FALSE(elementary_prefilter_rejects(VF, far, o));
    o = {};
    o.min_distance = 20.0;  // within reach
    EXPECT_FALSE(elementary_prefilter_rejects(VF, far, o));
    auto bad = far;
    bad[3].x = std::numeric_limits<double>::infinity();
    EXPECT_FALSE(elementary_prefilter_rejects(VF, bad));
    EXPECT_FALSE(elementary_prefilter_rejects(VF, rescale(far, 250, {})));
    EXPECT_FALSE(elementary_prefilter_rejects(VF, rescale(far, -320, {})));
    EXPECT_TRUE(elementary_prefilter_rejects(VF, rescale(far, -200, {}),
                                             {std::ldexp(0.0, 0), std::ldexp(1e-6, -200)}));
}

}  // namespace
}  // namespace proxima::ccd
