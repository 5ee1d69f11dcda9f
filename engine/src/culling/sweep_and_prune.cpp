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
    for (std::size_t i = 0; i < n; ++i) {
        index.emplace(scene[i].id, i);
    }
    // Previous order of surviving objects, then new objects at the end.
    std::vector<std::size_t> order;
    order.reserve(n);
    std::vector<char> placed(n, 0);
    for (auto id : m_ids) {
        if (auto it = index.find(id); it != index.end()) {
            order.push_back(it->second);
            placed[it->second] = 1;
        }
    }
    for (std::size_t i = 0; i < n; ++i) {
        if (placed[i] == 0) {
            order.push_back(i);
        }
    }
    // Insertion sort: linear when the order is nearly right, which it is between frames.
    m_swaps = 0;
    for (std::size_t k = 1; k < order.size(); ++k) {
        const auto v = order[k];
        const double key = scene[v].box.lo.x;
        std::size_t j = k;
        while (j > 0 && scene[order[j - 1]].box.lo.x > key) {
            order[j] = order[j - 1];
            --j;
            ++m_swaps;
        }
        order[j] = v;
    }
    m_order = std::move(order);
    m_ids.resize(n);
    m_lo.resize(n);
    m_rank.assign(n, 0);
    m_max_extent = 0.0;
    m_scale = 0.0;
    for (std::size_t k = 0; k < n; ++k) {
        const auto& obj = scene[m_order[k]];
        m_ids[k] = obj.id;
        m_lo[k] = obj.box.lo.x;
        m_rank[m_order[k]] = k;
        m_max_extent = std::max(m_max_extent, obj.box.hi.x - obj.box.lo.x);
        m_scale = std::max(m_scale, coordinate_scale(obj.box));
    }
}

void SweepAndPrune::within(const Scene& scene, std::size_t i, double radius,
                           std::vector<std::size_t>& out) const {
    const Aabb& box = scene[i].box;
    const double r = radius * (1.0 + 1e-9) + rounding_slack(m_scale);
    // Every j with box.lo.x - r - extent(j) <= lo_j <= box.hi.x + r may come within r along x.
    const double from = box.lo.x - r - m_max_extent;
    const double to = box.hi.x + r;
    auto first = std::lower_bound(m_lo.begin(), m_lo.end(), from);
    auto last = std::upper_bound(m_lo.begin(), m_lo.end(), to);
    const double r_sq = r * r;
    std::vector<std::pair<double, std::size_t>> found;
    for (auto it = first; it != last; ++it) {
        const auto j = m_order[static_cast<std::size_t>(it - m_lo.begin())];
        if (j == i) {
            continue;
        }
        const double d = box_squared_distance(box, scene[j].box);
        if (d <= r_sq) {
            found.emplace_back(d, j);
        }
    }
    std::sort(found.begin(), found.end());
    for (const auto& f : found) {
        out.push_back(f.second);
    }
}

double SweepAndPrune::separation_upper_bound(const Scene& scene, std::size_t i) const {
    const std::size_t n = m_order.size();
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
            best = std::min(best, box_max_distance(scene[i].box, scene[m_order[p]].box));
        }
    }
    return best;
}

}  // namespace proxima
