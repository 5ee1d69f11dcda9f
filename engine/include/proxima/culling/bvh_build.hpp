#pragma once
// The split rule that both AABB hierarchies share (culling/bvh.hpp: Bvh, built eagerly and
// refitted; massive/lazy_bvh.hpp: LazyBvh, children built on first visit): the axis along which
// the triangle centres of a node spread most, and the median partition of the node's slot range
// along it. What differs stays with each tree: the centre of a triangle (box centre vs vertex
// mean), how ties are ordered, how the partition reads the centres, the node layout and when
// nodes are built.

#include <algorithm>
#include <cstdint>
#include <vector>

#include "proxima/geometry/vec3.hpp"

namespace proxima::bvh_build {

// The axis (0, 1 or 2) along which the box of the centres is longest; x, then y, on ties.
inline int longest_axis(const Aabb& centres) {
    const Vec3 e = centres.extent();
    return (e.x >= e.y && e.x >= e.z) ? 0 : (e.y >= e.z ? 1 : 2);
}

// Partitions the slots [begin, end) of `order` (triangle indices) at their median centre along
// the longest axis of `centres` (the box of their centres, centre_of(t) giving a triangle's):
// slots before the returned middle slot begin + (end - begin) / 2 hold centres <= those after,
// equal coordinates ordered by triangle index (LazyBvh: the same tree whichever thread expands
// a node). Bvh partitions its own contiguous (centre, index) items instead (culling/bvh.cpp).
template <class CentreOf>
std::uint32_t split_at_median(std::vector<std::uint32_t>& order, std::uint32_t begin,
                              std::uint32_t end, const Aabb& centres, const CentreOf& centre_of) {
    const int axis = longest_axis(centres);
    const std::uint32_t mid = begin + (end - begin) / 2;
    std::nth_element(order.begin() + begin, order.begin() + mid, order.begin() + end,
                     [&](std::uint32_t a, std::uint32_t b) {
                         const double ca = centre_of(a)[axis];
                         const double cb = centre_of(b)[axis];
                         return ca < cb || (ca == cb && a < b);
                     });
    return mid;
}

}  // namespace proxima::bvh_build
