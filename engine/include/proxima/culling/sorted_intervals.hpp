#pragma once
// Boxes sorted by lo.x with the largest x extent: the sorted intervals that answer "which boxes
// may lie within r of this box" with one binary search and a box test per candidate. Used by
// Stage I (SweepAndPrune: re-sorted across frames from the previous order) and by the massive
// model's static piece index (massive::PieceIndex: built once).

#include <algorithm>
#include <cstdint>
#include <span>
#include <vector>

#include "proxima/geometry/vec3.hpp"

namespace proxima {

class SortedIntervals {
  public:
    // Sorts boxes 0..n by (lo.x, index); lo and hi are the boxes' x bounds by index.
    void build(std::span<const double> lo, std::span<const double> hi);

    // Re-sorts `order` (a permutation of 0..n, e.g. the previous order of surviving boxes, then
    // new ones) by lo.x with insertion sort: linear when the order is nearly right, and boxes
    // with equal lo.x keep their given order. Returns the number of element moves.
    std::uint64_t resort(std::span<const double> lo, std::span<const double> hi,
                         std::vector<std::uint32_t> order);

    // The query radius: `radius` widened relatively and by the rounding slack of the coordinates.
    static double widened(double radius, double slack) { return radius * (1.0 + 1e-9) + slack; }

    // Calls visit(index, squared box distance), in sorted order, for every box whose lo.x lies in
    // [box.lo.x - r - max extent * (1 + extent_margin), box.hi.x + r] and whose box (box_of(index))
    // is within r of `box` (squared distance <= r * r); r is already widened.
    template <class BoxOf, class Visit>
    void within(const Aabb& box, double r, double extent_margin, const BoxOf& box_of,
                const Visit& visit) const {
        const double from = box.lo.x - r - m_max_extent * (1.0 + extent_margin);
        const double to = box.hi.x + r;
        const double r_sq = r * r;
        const auto first = std::lower_bound(m_lo.begin(), m_lo.end(), from);
        for (auto k = static_cast<std::size_t>(first - m_lo.begin());
             k < m_lo.size() && m_lo[k] <= to; ++k) {
            const std::uint32_t i = m_order[k];
            const double d = box_squared_distance(box, box_of(i));
            if (d <= r_sq) {
                visit(i, d);
            }
        }
    }

    std::size_t size() const { return m_order.size(); }
    // Box indices in sorted order.
    const std::vector<std::uint32_t>& order() const { return m_order; }
    // lo.x in sorted order.
    const std::vector<double>& lo() const { return m_lo; }
    double max_extent() const { return m_max_extent; }

  private:
    // Fills m_lo and m_max_extent from m_order.
    void index(std::span<const double> lo, std::span<const double> hi);

    std::vector<std::uint32_t> m_order;
    std::vector<double> m_lo;
    double m_max_extent = 0.0;
};

}  // namespace proxima
