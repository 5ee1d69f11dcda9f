// The overlap graph's edges (seed 001 §4.1). The partition into localized subgraphs
// (plan_schedule) is in partition.cpp, the schedule's binary form in schedule_format.cpp.

#include "proxima/massive/overlap_graph.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>

#include <tbb/parallel_for.h>

#include "proxima/distance/bounds.hpp"

namespace proxima::massive {

namespace {

using Edge = std::pair<std::uint32_t, std::uint32_t>;

bool usable(const Aabb& box) {
    return !box.empty() && is_finite(box.lo) && is_finite(box.hi) && box.lo.y <= box.hi.y &&
           box.lo.z <= box.hi.z;
}

}  // namespace

std::vector<Edge> overlap_edges(const std::vector<GraphNode>& nodes, double tolerance) {
    // Boxes that are empty or not finite cannot be compared: such a node gets no edge (the store
    // never produces one; plan_schedule's callers validate boxes on import).
    std::vector<std::uint32_t> ids;
    ids.reserve(nodes.size());
    double scale = 0.0;
    for (std::size_t i = 0; i < nodes.size(); ++i) {
        if (usable(nodes[i].box)) {
            ids.push_back(static_cast<std::uint32_t>(i));
            scale = std::max(scale, coordinate_scale(nodes[i].box));
        }
    }
    const double tol = (std::isfinite(tolerance) && tolerance > 0.0) ? tolerance : 0.0;
    // The decisive test is box_squared_distance <= r^2, with r widened like every other culling
    // threshold of the engine (relative factor plus the rounding slack of the coordinates).
    const double r = tol * (1.0 + 1e-9) + rounding_slack(scale);
    const double r_sq = r * r;
    // The sweep's interval test is only a filter, so it is widened again: its own rounding (a
    // few ulps of the largest coordinate) can never drop a pair the decisive test would keep.
    const double r_sweep = r * (1.0 + 1e-6) + 1e-14 * scale;

    // Sweep along the axis with the fewest interval overlaps (§4.1 sorts along one axis; picking
    // the most selective one keeps long pipes along x from costing O(n^2) tests). The count of
    // candidate pairs per axis is exact and costs one sort and n binary searches.
    const std::size_t n = ids.size();
    int axis = 0;
    std::vector<std::uint32_t> order(ids);
    std::vector<double> lo(n);
    {
        std::uint64_t best = ~0ull;
        std::vector<std::uint32_t> trial(ids);
        std::vector<double> keys(n);
        for (int k = 0; k < 3; ++k) {
            std::sort(trial.begin(), trial.end(), [&](std::uint32_t a, std::uint32_t b) {
                const double la = nodes[a].box.lo[k];
                const double lb = nodes[b].box.lo[k];
                return la < lb || (la == lb && a < b);
            });
            for (std::size_t p = 0; p < n; ++p) {
                keys[p] = nodes[trial[p]].box.lo[k];
            }
            std::uint64_t candidates = 0;
            for (std::size_t p = 0; p < n && candidates < best; ++p) {
                const double to = nodes[trial[p]].box.hi[k] + r_sweep;
                const auto first = keys.begin() + static_cast<std::ptrdiff_t>(p);
                candidates +=
                    static_cast<std::uint64_t>(std::upper_bound(first, keys.end(), to) - first);
            }
            if (candidates < best) {
                best = candidates;
                axis = k;
                order = trial;
                lo = keys;
            }
        }
    }

    // A single sorted list still pairs every two boxes that overlap along the sweep axis, which
    // in a 3-D layout is far more than those that overlap: the sweep runs in strips along a
    // second axis (each box in every strip its interval, grown by r, meets), and a pair is
    // reported only by the strip holding the larger of its two lower bounds on that axis (a
    // point of both intervals, so exactly one strip reports it).
    const int a1 = (axis + 1) % 3;
    const int a2 = (axis + 2) % 3;
    int strip_axis = a1;
    std::size_t strips = 1;
    double origin = 0.0;
    double width = 1.0;
    {
        std::vector<double> extent(n);
        for (int k : {a1, a2}) {
            if (n == 0) {
                break;
            }
            double low = std::numeric_limits<double>::infinity();
            double high = -low;
            for (std::size_t p = 0; p < n; ++p) {
                const Aabb& b = nodes[order[p]].box;
                extent[p] = b.hi[k] - b.lo[k];
                low = std::min(low, b.lo[k]);
                high = std::max(high, b.hi[k]);
            }
            auto mid = extent.begin() + static_cast<std::ptrdiff_t>(n / 2);
            std::nth_element(extent.begin(), mid, extent.end());
            // Strips about twice a typical box wide: most boxes lie in one or two of them.
            const double w = 2.0 * (*mid + r_sweep);
            const double count = w > 0.0 ? std::floor((high - low) / w) : 1.0;
            const std::size_t most = n / 16 + 1;
            const auto s = static_cast<std::size_t>(
                std::clamp(count, 1.0, std::min(4096.0, static_cast<double>(most))));
            if (s > strips) {
                strips = s;
                strip_axis = k;
                origin = low;
                width = (high - low) / static_cast<double>(s);
            }
        }
    }
    auto strip_of = [&](double x) {
        const double f = std::floor((x - origin) / width);
        return static_cast<std::size_t>(std::clamp(f, 0.0, static_cast<double>(strips - 1)));
    };
    // Boxes spanning many strips (a few long beams among small parts) are listed in each: fewer,
    // wider strips when that would list more than 8 boxes per box on average.
    while (strips > 1) {
        std::uint64_t listed = 0;
        for (std::size_t p = 0; p < n; ++p) {
            const Aabb& b = nodes[order[p]].box;
            listed += strip_of(b.hi[strip_axis] + r_sweep) - strip_of(b.lo[strip_axis]) + 1;
        }
        if (listed <= 8 * static_cast<std::uint64_t>(n)) {
            break;
        }
        const std::size_t half = strips / 2;
        width *= static_cast<double>(strips) / static_cast<double>(half);
        strips = half;
    }

    // Boxes in sweep order, one array per coordinate (upper bounds grown by r_sweep, the very
    // values strip membership uses), so the inner loop streams through memory and rejects most
    // candidates on the other two axes with a few loads.
    std::vector<double> hi(n), lo1(n), hi1(n), lo2(n), hi2(n), key(n);
    std::vector<std::uint32_t> object(n);
    std::vector<std::size_t> first_strip(n), last_strip(n);
    std::vector<std::size_t> start_of(strips + 1, 0);
    for (std::size_t p = 0; p < n; ++p) {
        const Aabb& b = nodes[order[p]].box;
        hi[p] = b.hi[axis] + r_sweep;
        lo1[p] = b.lo[a1];
        hi1[p] = b.hi[a1] + r_sweep;
        lo2[p] = b.lo[a2];
        hi2[p] = b.hi[a2] + r_sweep;
        key[p] = b.lo[strip_axis];
        object[p] = nodes[order[p]].object;
        first_strip[p] = strip_of(b.lo[strip_axis]);
        last_strip[p] = strip_of(strip_axis == a1 ? hi1[p] : hi2[p]);
        for (std::size_t s = first_strip[p]; s <= last_strip[p]; ++s) {
            ++start_of[s + 1];
        }
    }
    std::partial_sum(start_of.begin(), start_of.end(), start_of.begin());
    std::vector<std::uint32_t> members(start_of.back());
    {
        std::vector<std::size_t> fill(start_of.begin(), start_of.end() - 1);
        for (std::size_t p = 0; p < n; ++p) {
            for (std::size_t s = first_strip[p]; s <= last_strip[p]; ++s) {
                members[fill[s]++] = static_cast<std::uint32_t>(p);
            }
        }
    }

    // In each strip, each box against the boxes that start after it and no farther than r along
    // the sweep axis (a pair within r is found from whichever of the two starts first). Strips
    // run in parallel; the result is sorted afterwards, so it does not depend on the scheduling.
    std::vector<std::vector<Edge>> found(strips);
    tbb::parallel_for(std::size_t{0}, strips, [&](std::size_t s) {
        auto& out = found[s];
        const std::uint32_t* list = members.data() + start_of[s];
        const std::size_t count = start_of[s + 1] - start_of[s];
        for (std::size_t i = 0; i < count; ++i) {
            const std::uint32_t p = list[i];
            for (std::size_t j = i + 1; j < count && lo[list[j]] <= hi[p]; ++j) {
                const std::uint32_t q = list[j];
                if (lo1[q] > hi1[p] || lo1[p] > hi1[q] || lo2[q] > hi2[p] || lo2[p] > hi2[q] ||
                    object[q] == object[p] || strip_of(std::max(key[p], key[q])) != s) {
                    continue;
                }
                const std::uint32_t a = order[p];
                const std::uint32_t b = order[q];
                if (box_squared_distance(nodes[a].box, nodes[b].box) <= r_sq) {
                    out.emplace_back(std::min(a, b), std::max(a, b));
                }
            }
        }
    });

    // Counting sort by first endpoint, then each bucket by the second: O(n + k) plus small sorts.
    std::vector<std::uint32_t> start(nodes.size() + 1, 0);
    std::size_t total = 0;
    for (const auto& f : found) {
        total += f.size();
        for (const auto& e : f) {
            ++start[e.first + 1];
        }
    }
    std::partial_sum(start.begin(), start.end(), start.begin());
    std::vector<Edge> edges(total);
    {
        std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
        for (auto& f : found) {
            for (const auto& e : f) {
                edges[fill[e.first]++] = e;
            }
            std::vector<Edge>().swap(f);
        }
    }
    tbb::parallel_for(std::size_t{0}, nodes.size(), [&](std::size_t i) {
        std::sort(edges.begin() + start[i], edges.begin() + start[i + 1]);
    });
    return edges;
}

}  // namespace proxima::massive
