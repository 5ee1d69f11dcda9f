#pragma once
// One row of the self traversal's leaf pairs (engine/src/culling/bvh_culler.cpp): one triangle
// against up to 8 triangles of a leaf, each kept when its box comes closer than its threshold and
// it shares no vertex with the triangle. On x86-64 a copy compiled for AVX2 (four triangles at a
// time) runs where the processor has it, checked once at run time; it computes every box distance
// with the same IEEE operations in the same order as the portable copy (no fused multiply-add),
// so both keep the same triangles (tests/engine/culling/test_leaf_rows.cpp).

#include <cstddef>
#include <cstdint>
#include <vector>

#include "proxima/geometry/vec3.hpp"
#include "proxima/mesh/mesh.hpp"

namespace proxima::detail {

// Triangles' boxes and vertex ids as structure of arrays, in the order the caller chooses (the
// traversal's slot order), with PAD readable entries past the last.
struct LeafSlots {
    static constexpr std::size_t PAD = 8;
    std::vector<double> lox, loy, loz, hix, hiy, hiz;
    std::vector<std::uint32_t> v0, v1, v2;

    void resize(std::size_t n);
    void set(std::size_t k, const Aabb& box, const TriangleIndices& v) {
        lox[k] = box.lo.x;
        loy[k] = box.lo.y;
        loz[k] = box.lo.z;
        hix[k] = box.hi.x;
        hiy[k] = box.hi.y;
        hiz[k] = box.hi.z;
        v0[k] = v[0];
        v1[k] = v[1];
        v2[k] = v[2];
    }
};

// Bit q (q < n <= 8) is set when slot first + q shares no vertex with `v` and
// box_squared_distance(box, its box) < max(row_threshold_sq, threshold_sq[q]). threshold_sq must
// have 8 readable entries (those from n on are ignored).
unsigned leaf_row(const LeafSlots& slots, std::uint32_t first, std::uint32_t n, const Aabb& box,
                  const TriangleIndices& v, double row_threshold_sq, const double* threshold_sq);
// The baseline x86-64 copy, whatever the processor (tests compare the two).
unsigned leaf_row_portable(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                           const Aabb& box, const TriangleIndices& v, double row_threshold_sq,
                           const double* threshold_sq);

// The rows of a leaf that can keep anything against another leaf of box `box`: bit p (p < n <= 8)
// is set when box_squared_distance(slot first + p's box, box) < max(threshold_sq[p], other_sq).
// threshold_sq must have 8 readable entries. A row left out would keep nothing: `box` holds each
// of the other leaf's boxes, whose box distances are at least this one (the same IEEE operations
// on larger or equal gaps).
unsigned leaf_rows_near(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                        const Aabb& box, const double* threshold_sq, double other_sq);
unsigned leaf_rows_near_portable(const LeafSlots& slots, std::uint32_t first, std::uint32_t n,
                                 const Aabb& box, const double* threshold_sq, double other_sq);

}  // namespace proxima::detail
