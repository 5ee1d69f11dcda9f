#pragma once
// Stage I of seed 000 (§5.1): object boxes kept sorted along x across frames. Objects move
// little between frames, so re-sorting the previous order with insertion sort costs O(n + swaps)
// (temporal coherence). Range queries over the sorted intervals give the objects whose boxes come
// within a radius of an object's box.

#include <cstdint>
#include <vector>

#include "proxima/culling/sorted_intervals.hpp"
#include "proxima/scene.hpp"

namespace proxima {

class SweepAndPrune {
  public:
    // Re-sorts after the scene changed. Keeps the previous order for surviving objects.
    void update(const Scene& scene);

    // Scene indices j != i whose box may lie within `radius` of object i's box (the radius widened
    // by the rounding slack of the scene's coordinates), appended in increasing box distance.
    void within(const Scene& scene, std::size_t i, double radius,
                std::vector<std::size_t>& out) const;

    // A conservative upper bound on the distance from object i to its closest other object, from
    // the boxes alone (seed §5.1: the farthest corners of the box of a nearby object along the
    // sorted axis); +inf when i is the only object.
    double separation_upper_bound(const Scene& scene, std::size_t i) const;

    // Number of element moves the last update's insertion sort made (coherence statistic).
    std::uint64_t last_swaps() const { return m_swaps; }

  private:
    std::vector<ObjectId> m_ids;      // sorted order of the previous frame, by id
    SortedIntervals m_intervals;      // scene indices sorted by box.lo.x
    std::vector<std::size_t> m_rank;  // scene index -> position in the sorted order
    double m_scale = 0.0;             // largest coordinate magnitude (for rounding slack)
    std::vector<double> m_box_lo;     // update's scratch: box.lo.x by scene index
    std::vector<double> m_box_hi;     // update's scratch: box.hi.x by scene index
    std::uint64_t m_swaps = 0;
};

// Largest distance between a point of box a and a point of box b: an upper bound on the distance
// between anything inside a and anything inside b.
double box_max_distance(const Aabb& a, const Aabb& b);

}  // namespace proxima
