#pragma once
// Elementary continuous collision tests (seed 000 §3.2, §5.3): a vertex against a triangle and an
// edge against an edge, every vertex moving linearly from its position at t = 0 to its position at
// t = 1. The tests are conservative: they never miss a contact, and a reported time of impact is
// never later than the true earliest one (the argument is in docs/algorithms.md).

#include <array>
#include <cstdint>
#include <optional>
#include <string_view>

#include "proxima/geometry/vec3.hpp"

namespace proxima::ccd {

enum class CcdKind { vertex_face, edge_edge };

// "vf" or "ee".
const char* ccd_kind_name(CcdKind kind);

struct ElementaryOptions {
    // Report contact when the primitives come within this distance (>= 0); 0 is touching.
    double min_distance = 0.0;
    // Precision of the time of impact, and the size below which a region of (t, u, v) that still
    // may hold a root is reported as contact rather than refined further.
    double tolerance = 1e-6;
    // Work bound: at most this many regions are examined per test. When it is reached the test
    // reports contact at the earliest time it could not exclude (conservative, flagged `capped`).
    std::uint32_t max_boxes = 200'000;
};

struct ElementaryResult {
    bool hit = false;     // the primitives may touch in [0, 1]; never false when they do
    double toi = 1.0;     // when hit: a time in [0, 1] no later than the earliest contact
    bool capped = false;  // the work bound was reached (hit is then true)
    std::uint32_t boxes = 0;  // regions examined
};

// The eight points in the order of the public CCD benchmark (Wang et al. 2021):
//   vertex_face: v_t0, f0_t0, f1_t0, f2_t0, v_t1, f0_t1, f1_t1, f2_t1
//   edge_edge:   ea0_t0, ea1_t0, eb0_t0, eb1_t0, ea0_t1, ea1_t1, eb0_t1, eb1_t1
using CcdPoints = std::array<Vec3, 8>;

ElementaryResult vertex_face(const CcdPoints& points, const ElementaryOptions& options = {});
ElementaryResult edge_edge(const CcdPoints& points, const ElementaryOptions& options = {});
ElementaryResult elementary(CcdKind kind, const CcdPoints& points,
                            const ElementaryOptions& options = {});

}  // namespace proxima::ccd
