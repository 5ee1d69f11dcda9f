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

// The usable nodes' indices and the largest coordinate scale among them. Boxes that are empty
// or not finite cannot be compared: such a node gets no edge (the store never produces one;
// plan_schedule's callers validate boxes on import).
std::vector<std::uint32_t> usable_ids(const std::vector<GraphNode>& nodes, double& scale) {
    std::vector<std::uint32_t> ids;
    ids.reserve(nodes.size());
    scale = 0.0;
    for (std::size_t i = 0; i < nodes.size(); ++i) {
        if (usable(nodes[i].box)) {
            ids.push_back(static_cast<std::uint32_t>(i));
            scale = std::max(scale, coordinate_scale(nodes[i].box));
        }
    }
    return ids;
}

// The sweep axis, the usable nodes sorted along it and their lower bounds in that order.
struct Sweep {
    int axis = 0;
    std::vector<std::uint32_t> order;
    std::vector<double> lo;
};

// Sweep along the axis with the fewest interval overlaps (§4.1 sorts along one axis; picking
// the most selective one keeps long pipes along x from costing O(n^2) tests). The count of
// candidate pairs per axis is exact and costs one sort and n binary searches.
Sweep choose_sweep(const std::vector<GraphNode>& nodes, const std::vector<std::uint32_t>& ids,
                   double r_sweep) {
    const std::size_t n = ids.size();
    Sweep sweep{0, ids, std::vector<double>(n)};
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
            sweep.axis = k;
            sweep.order = trial;
            sweep.lo = keys;
        }
    }
    return sweep;
}

// Strips of equal width along a second axis.
struct Strips {
    int axis = 0;
    std::size_t count = 1;
    double origin = 0.0;
    double width = 1.0;

    std::size_t of(double x) const {
        const double f = std::floor((x - origin) / width);
        return static_cast<std::size_t>(std::clamp(f, 0.0, static_cast<double>(count - 1)));
    }
};

// A single sorted list still pairs every two boxes that overlap along the sweep axis, which in a
// 3-D layout is far more than those that overlap: the sweep runs in strips along a second axis
// (each box in every strip its interval, grown by r, meets), and a pair is reported only by the
// strip holding the larger of its two lower bounds on that axis (a point of both intervals, so
// exactly one strip reports it).
Strips choose_strips(const std::vector<GraphNode>& nodes, const Sweep& sweep, double r_sweep) {
    const std::size_t n = sweep.order.size();
    const int a1 = (sweep.axis + 1) % 3;
    const int a2 = (sweep.axis + 2) % 3;
    Strips strips;
    strips.axis = a1;
    std::vector<double> extent(n);
    for (int k : {a1, a2}) {
        if (n == 0) {
            break;
        }
        double low = std::numeric_limits<double>::infinity();
        double high = -low;
        for (std::size_t p = 0; p < n; ++p) {
            const Aabb& b = nodes[sweep.order[p]].box;
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
        if (s > strips.count) {
            strips.count = s;
            strips.axis = k;
            strips.origin = low;
            strips.width = (high - low) / static_cast<double>(s);
        }
    }
    // Boxes spanning many strips (a few long beams among small parts) are listed in each: fewer,
    // wider strips when that would list more than 8 boxes per box on average.
    while (strips.count > 1) {
        std::uint64_t listed = 0;
        for (std::size_t p = 0; p < n; ++p) {
            const Aabb& b = nodes[sweep.order[p]].box;
            listed += strips.of(b.hi[strips.axis] + r_sweep) - strips.of(b.lo[strips.axis]) + 1;
        }
        if (listed <= 8 * static_cast<std::uint64_t>(n)) {
            break;
        }
        const std::size_t half = strips.count / 2;
        strips.width *= static_cast<double>(strips.count) / static_cast<double>(half);
        strips.count = half;
    }
    return strips;
}

// Boxes in sweep order, one array per coordinate (upper bounds grown by r_sweep, the very values
// strip membership uses), so the inner loop streams through memory and rejects most candidates
// on the other two axes with a few loads; and each strip's members, in sweep order.
struct SweepArrays {
    std::vector<double> hi, lo1, hi1, lo2, hi2, key;
    std::vector<std::uint32_t> object;
    std::vector<std::size_t> start_of;  // strip s lists members[start_of[s], start_of[s + 1])
    std::vector<std::uint32_t> members;
};

SweepArrays sweep_arrays(const std::vector<GraphNode>& nodes, const Sweep& sweep,
                         const Strips& strips, double r_sweep) {
    const std::size_t n = sweep.order.size();
    const int axis = sweep.axis;
    const int a1 = (axis + 1) % 3;
    const int a2 = (axis + 2) % 3;
    SweepArrays s;
    s.hi.resize(n);
    s.lo1.resize(n);
    s.hi1.resize(n);
    s.lo2.resize(n);
    s.hi2.resize(n);
    s.key.resize(n);
    s.object.resize(n);
    std::vector<std::size_t> first_strip(n), last_strip(n);
    s.start_of.assign(strips.count + 1, 0);
    for (std::size_t p = 0; p < n; ++p) {
        const Aabb& b = nodes[sweep.order[p]].box;
        s.hi[p] = b.hi[axis] + r_sweep;
        s.lo1[p] = b.lo[a1];
        s.hi1[p] = b.hi[a1] + r_sweep;
        s.lo2[p] = b.lo[a2];
        s.hi2[p] = b.hi[a2] + r_sweep;
        s.key[p] = b.lo[strips.axis];
        s.object[p] = nodes[sweep.order[p]].object;
        first_strip[p] = strips.of(b.lo[strips.axis]);
        last_strip[p] = strips.of(strips.axis == a1 ? s.hi1[p] : s.hi2[p]);
        for (std::size_t k = first_strip[p]; k <= last_strip[p]; ++k) {
            ++s.start_of[k + 1];
        }
    }
    std::partial_sum(s.start_of.begin(), s.start_of.end(), s.start_of.begin());
    s.members.resize(s.start_of.back());
    std::vector<std::size_t> fill(s.start_of.begin(), s.start_of.end() - 1);
    for (std::size_t p = 0; p < n; ++p) {
        for (std::size_t k = first_strip[p]; k <= last_strip[p]; ++k) {
            s.members[fill[k]++] = static_cast<std::uint32_t>(p);
        }
    }
    return s;
}

// In each strip, each box against the boxes that start after it and no farther than r along the
// sweep axis (a pair within r is found from whichever of the two starts first). Strips run in
// parallel; the result is sorted afterwards, so it does not depend on the scheduling.
std::vector<std::vector<Edge>> sweep_strips(const std::vector<GraphNode>& nodes, const Sweep& sweep,
                                            const Strips& strips, const SweepArrays& arrays,
                                            double r_sq) {
    const auto& order = sweep.order;
    const auto& lo = sweep.lo;
    const auto& hi = arrays.hi;
    const auto& lo1 = arrays.lo1;
    const auto& hi1 = arrays.hi1;
    const auto& lo2 = arrays.lo2;
    const auto& hi2 = arrays.hi2;
    const auto& key = arrays.key;
    const auto& object = arrays.object;
    const auto& start_of = arrays.start_of;
    const auto& members = arrays.members;
    std::vector<std::vector<Edge>> found(strips.count);
    tbb::parallel_for(std::size_t{0}, strips.count, [&](std::size_t s) {
        auto& out = found[s];
        const std::uint32_t* list = members.data() + start_of[s];
        const std::size_t count = start_of[s + 1] - start_of[s];
        for (std::size_t i = 0; i < count; ++i) {
            const std::uint32_t p = list[i];
            for (std::size_t j = i + 1; j < count && lo[list[j]] <= hi[p]; ++j) {
                const std::uint32_t q = list[j];
                if (lo1[q] > hi1[p] || lo1[p] > hi1[q] || lo2[q] > hi2[p] || lo2[p] > hi2[q] ||
                    object[q] == object[p] || strips.of(std::max(key[p], key[q])) != s) {
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
    return found;
}

// Counting sort by first endpoint, then each bucket by the second: O(n + k) plus small sorts.
std::vector<Edge> sorted_edges(std::vector<std::vector<Edge>>& found, std::size_t node_count) {
    std::vector<std::uint32_t> start(node_count + 1, 0);
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
    tbb::parallel_for(std::size_t{0}, node_count, [&](std::size_t i) {
        std::sort(edges.begin() + start[i], edges.begin() + start[i + 1]);
    });
    return edges;
}

}  // namespace

std::vector<Edge> overlap_edges(const std::vector<GraphNode>& nodes, double tolerance) {
    double scale = 0.0;
    const std::vector<std::uint32_t> ids = usable_ids(nodes, scale);
    const double tol = (std::isfinite(tolerance) && tolerance > 0.0) ? tolerance : 0.0;
    // The decisive test is box_squared_distance <= r^2, with r widened like every other culling
    // threshold of the engine (relative factor plus the rounding slack of the coordinates).
    const double r = tol * (1.0 + 1e-9) + rounding_slack(scale);
    const double r_sq = r * r;
    // The sweep's interval test is only a filter, so it is widened again: its own rounding (a
    // few ulps of the largest coordinate) can never drop a pair the decisive test would keep.
    const double r_sweep = r * (1.0 + 1e-6) + 1e-14 * scale;

    const Sweep sweep = choose_sweep(nodes, ids, r_sweep);
    const Strips strips = choose_strips(nodes, sweep, r_sweep);
    const SweepArrays arrays = sweep_arrays(nodes, sweep, strips, r_sweep);
    std::vector<std::vector<Edge>> found = sweep_strips(nodes, sweep, strips, arrays, r_sq);
    return sorted_edges(found, nodes.size());
}

}  // namespace proxima::massive
