#include "proxima/culling/sorted_intervals.hpp"

#include <algorithm>
#include <numeric>
#include <tuple>

namespace proxima {

void SortedIntervals::build(std::span<const double> lo, std::span<const double> hi) {
    m_order.resize(lo.size());
    std::iota(m_order.begin(), m_order.end(), 0u);
    std::sort(m_order.begin(), m_order.end(), [&](std::uint32_t a, std::uint32_t b) {
        return std::tie(lo[a], a) < std::tie(lo[b], b);
    });
    index(lo, hi);
}

std::uint64_t SortedIntervals::resort(std::span<const double> lo, std::span<const double> hi,
                                      std::vector<std::uint32_t> order) {
    std::uint64_t moves = 0;
    for (std::size_t k = 1; k < order.size(); ++k) {
        const auto v = order[k];
        const double key = lo[v];
        std::size_t j = k;
        while (j > 0 && lo[order[j - 1]] > key) {
            order[j] = order[j - 1];
            --j;
            ++moves;
        }
        order[j] = v;
    }
    m_order = std::move(order);
    index(lo, hi);
    return moves;
}

void SortedIntervals::index(std::span<const double> lo, std::span<const double> hi) {
    m_lo.resize(m_order.size());
    m_max_extent = 0.0;
    for (std::size_t k = 0; k < m_order.size(); ++k) {
        const auto i = m_order[k];
        m_lo[k] = lo[i];
        m_max_extent = std::max(m_max_extent, hi[i] - lo[i]);
    }
}

}  // namespace proxima
