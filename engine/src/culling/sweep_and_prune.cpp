#include "proxima/culling/sweep_and_prune.hpp"

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "proxima/distance/bounds.hpp"

namespace proxima {

double box_max_distance(const Aabb& a, const Aabb& b) {
    double s = 0.0;
    for (int k = 0; k < 3; ++k) {
        const double d = std::max(std::abs(a.hi[k] - b.lo[k]), std::abs(b.hi[k] - a.lo[k]));
        s += d * d;
    }
    // Round up: this bound seeds a strict "<" search, so it must not fall below the true value.
    return std::sqrt(s) * (1.0 + 1e-12);
}

void SweepAndPrune::update(const Scene& scene) {
    const std::size_t n = scene.size();
    std::unordered_map<ObjectId, std::size_t> index;
    index.reserve(n);
    m_box_lo.resize(n);
    m_box_hi.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
        index.emplace(scene[i].id, i);
        m_box_lo[i] = scene[i].box.lo.x;
        m_box_hi[i] = scene[i].box.hi.x;
    }
    // Previous order of surviving objects, then new objects at the end.
    std::vector<std::uint32_t> order;
    order.reserve(n);
    std::vector<char> placed(n, 0);
    for (auto id : m_ids) {
        if (auto it = index.find(id); it != index.end()) {
            order.push_back(static_cast<std::uint32_t>(it->second));
            placed[it->second] = 1;
        }
    }
    for (std::size_t i = 0; i < n; ++i) {
        if (placed[i] == 0) {
            order.push_back(static_cast<std::uint32_t>(i));
        }
    }
    // Insertion sort: linear when the order is nearly right, which it is between frames.
    m_swaps = m_intervals.resort(m_box_lo, m_box_hi, std::move(order));
    m_ids.resize(n);
    m_rank.assign(n, 0);
    m_scale = 0.0;
    const auto& sorted = m_intervals.order();
    for (std::size_t k = 0; k < n; ++k) {
        const auto& obj = scene[sorted[k]];
        m_ids[k] = obj.id;
        m_rank[sorted[k]] = k;
        m_scale = std::max(m_scale, coordinate_scale(obj.box));
    }
}

void SweepAndPrune::within(const Scene& scene, std::size_t i, double radius,
                           std::vector<std::size_t>& out) const {
    const double r = SortedIntervals::widened(radius, rounding_slack(m_scale));
    std::vector<std::pair<double, std::size_t>> found;
    m_intervals.within(
        scene[i].box, r, 0.0, [&](std::uint32_t j) -> const Aabb& { return scene[j].box; },
        [&](std::uint32_t j, double d) {
            if (j != i) {
                found.emplace_back(d, j);
            }
        });
    std::sort(found.begin(), found.end());
    for (const auto& f : found) {
        out.push_back(f.second);
    }
}

double SweepAndPrune::separation_upper_bound(const Scene& scene, std::size_t i) const {
    const std::size_t n = m_intervals.size();
    if (n < 2) {
        return std::numeric_limits<double>::infinity();
    }
    // Neighbours in the sorted order are the likely closest boxes; any other box gives a valid
    // (if looser) bound, so looking at a few on each side is enough.
    constexpr std::size_t REACH = 4;
    const std::size_t k = m_rank[i];
    double best = std::numeric_limits<double>::infinity();
    const std::size_t lo = k >= REACH ? k - REACH : 0;
    const std::size_t hi = std::min(n - 1, k + REACH);
    for (std::size_t p = lo; p <= hi; ++p) {
        if (p != k) {
            best =
                std::min(best, box_max_distance(scene[i].box, scene[m_intervals.order()[p]].box));
        }
    }
    return best;
}

}  // namespace proxima
