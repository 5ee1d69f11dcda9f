// The overlap graph's edges (seed 001 §4.1) and the schedule's binary form. The partition into
// localized subgraphs (plan_schedule) is in partition.cpp.

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
            const auto s = static_cast<std::size_t>(
                std::clamp(count, 1.0, std::min(4096.0, static_cast<double>(n / 16 + 1))));
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
        width *= static_cast<double>(strips) / static_cast<double>(strips / 2);
        strips /= 2;
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

// -------------------------------------------------------------------------------------------------
// Binary form. Little-endian throughout:
//   "PXSCHED\0" (8 bytes), u32 version (1),
//   f64 tolerance, u64 cache_bytes, u64 node_count, u64 edge_count,
//   u64 components, u64 high_valence_nodes, u64 metis_calls, u32 levels,
//   u64 subgraph count, then per subgraph:
//     u8 kind, u32 level, u64 weight, u32 node count, u32 edge count,
//     node count x u32 node, edge count x (u32 a, u32 b).

namespace {

constexpr std::array<char, 8> MAGIC = {'P', 'X', 'S', 'C', 'H', 'E', 'D', '\0'};
constexpr std::uint32_t VERSION = 1;
constexpr std::size_t SUBGRAPH_HEADER = 1 + 4 + 8 + 4 + 4;

class Writer {
  public:
    explicit Writer(std::string& out) : m_out(out) {}
    void u8(std::uint8_t v) { m_out.push_back(static_cast<char>(v)); }
    void u32(std::uint32_t v) {
        for (int k = 0; k < 4; ++k) {
            m_out.push_back(static_cast<char>((v >> (8 * k)) & 0xff));
        }
    }
    void u64(std::uint64_t v) {
        for (int k = 0; k < 8; ++k) {
            m_out.push_back(static_cast<char>((v >> (8 * k)) & 0xff));
        }
    }
    void f64(double v) { u64(std::bit_cast<std::uint64_t>(v)); }

  private:
    std::string& m_out;
};

class Reader {
  public:
    explicit Reader(std::string_view in) : m_in(in) {}
    std::size_t left() const { return m_in.size() - m_pos; }
    bool u8(std::uint8_t& v) {
        if (left() < 1) {
            return false;
        }
        v = static_cast<std::uint8_t>(m_in[m_pos++]);
        return true;
    }
    bool u32(std::uint32_t& v) {
        std::uint64_t w = 0;
        if (!bytes(4, w)) {
            return false;
        }
        v = static_cast<std::uint32_t>(w);
        return true;
    }
    bool u64(std::uint64_t& v) { return bytes(8, v); }
    bool f64(double& v) {
        std::uint64_t w = 0;
        if (!bytes(8, w)) {
            return false;
        }
        v = std::bit_cast<double>(w);
        return true;
    }

  private:
    bool bytes(std::size_t count, std::uint64_t& v) {
        if (left() < count) {
            return false;
        }
        v = 0;
        for (std::size_t k = 0; k < count; ++k) {
            v |= static_cast<std::uint64_t>(static_cast<unsigned char>(m_in[m_pos + k])) << (8 * k);
        }
        m_pos += count;
        return true;
    }
    std::string_view m_in;
    std::size_t m_pos = 0;
};

Status malformed(const std::string& what) {
    return invalid_argument("schedule: malformed bytes: " + what);
}

}  // namespace

std::string serialize_schedule(const Schedule& schedule) {
    std::size_t size = MAGIC.size() + 4 + 8 * 8 + 4;
    for (const auto& s : schedule.subgraphs) {
        size += SUBGRAPH_HEADER + 4 * s.nodes.size() + 8 * s.edges.size();
    }
    std::string out;
    out.reserve(size);
    out.append(MAGIC.data(), MAGIC.size());
    Writer w(out);
    w.u32(VERSION);
    w.f64(schedule.tolerance);
    w.u64(schedule.cache_bytes);
    w.u64(schedule.node_count);
    w.u64(schedule.edge_count);
    w.u64(schedule.components);
    w.u64(schedule.high_valence_nodes);
    w.u64(schedule.metis_calls);
    w.u32(schedule.levels);
    w.u64(schedule.subgraphs.size());
    for (const auto& s : schedule.subgraphs) {
        w.u8(static_cast<std::uint8_t>(s.kind));
        w.u32(s.level);
        w.u64(s.weight);
        w.u32(static_cast<std::uint32_t>(s.nodes.size()));
        w.u32(static_cast<std::uint32_t>(s.edges.size()));
        for (auto v : s.nodes) {
            w.u32(v);
        }
        for (const auto& [a, b] : s.edges) {
            w.u32(a);
            w.u32(b);
        }
    }
    return out;
}

StatusOr<Schedule> deserialize_schedule(std::string_view bytes) {
    if (bytes.size() < MAGIC.size() || std::memcmp(bytes.data(), MAGIC.data(), MAGIC.size()) != 0) {
        return malformed("not a schedule (bad magic)");
    }
    Reader r(bytes.substr(MAGIC.size()));
    std::uint32_t version = 0;
    if (!r.u32(version)) {
        return malformed("truncated header");
    }
    if (version != VERSION) {
        return invalid_argument("schedule: unsupported version " + std::to_string(version) +
                                " (this build reads version " + std::to_string(VERSION) + ")");
    }
    Schedule s;
    std::uint64_t count = 0;
    if (!r.f64(s.tolerance) || !r.u64(s.cache_bytes) || !r.u64(s.node_count) ||
        !r.u64(s.edge_count) || !r.u64(s.components) || !r.u64(s.high_valence_nodes) ||
        !r.u64(s.metis_calls) || !r.u32(s.levels) || !r.u64(count)) {
        return malformed("truncated header");
    }
    if (!std::isfinite(s.tolerance) || s.tolerance < 0.0) {
        return malformed("tolerance is negative or not finite");
    }
    if (s.node_count > (1ull << 32)) {
        return malformed("node count " + std::to_string(s.node_count) + " exceeds 2^32");
    }
    // Every count is checked against the bytes left before anything is allocated.
    if (count > r.left() / SUBGRAPH_HEADER) {
        return malformed(std::to_string(count) + " subgraphs cannot fit in " +
                         std::to_string(r.left()) + " bytes");
    }
    if (s.edge_count > r.left() / 8) {
        return malformed(std::to_string(s.edge_count) + " edges cannot fit in " +
                         std::to_string(r.left()) + " bytes");
    }
    s.subgraphs.resize(count);
    std::vector<Edge> all;
    all.reserve(s.edge_count);
    std::vector<std::uint32_t> sorted;
    std::vector<char> touched;
    for (std::uint64_t i = 0; i < count; ++i) {
        auto& g = s.subgraphs[i];
        const std::string where = "subgraph " + std::to_string(i) + ": ";
        std::uint8_t kind = 0;
        std::uint32_t nn = 0;
        std::uint32_t ne = 0;
        if (!r.u8(kind) || !r.u32(g.level) || !r.u64(g.weight) || !r.u32(nn) || !r.u32(ne)) {
            return malformed(where + "truncated");
        }
        if (kind > static_cast<std::uint8_t>(LocalizedSubgraph::Kind::partition)) {
            return malformed(where + "unknown kind " + std::to_string(kind));
        }
        g.kind = static_cast<LocalizedSubgraph::Kind>(kind);
        if (g.level > s.levels) {
            return malformed(where + "level " + std::to_string(g.level) + " above the plan's " +
                             std::to_string(s.levels));
        }
        if (nn > r.left() / 4 || ne > (r.left() - 4ull * nn) / 8) {
            return malformed(where + "counts exceed the bytes left");
        }
        if (ne == 0 || nn < 2) {
            return malformed(where + "no edge");
        }
        if (all.size() + ne > s.edge_count) {
            return malformed(where + "more edges than the plan's " + std::to_string(s.edge_count));
        }
        g.nodes.resize(nn);
        for (auto& v : g.nodes) {
            if (!r.u32(v)) {
                return malformed(where + "truncated");
            }
            if (v >= s.node_count) {
                return malformed(where + "node " + std::to_string(v) + " out of range (" +
                                 std::to_string(s.node_count) + " nodes)");
            }
        }
        g.edges.resize(ne);
        for (auto& [a, b] : g.edges) {
            if (!r.u32(a) || !r.u32(b)) {
                return malformed(where + "truncated");
            }
            if (a >= b || b >= s.node_count) {
                return malformed(where + "edge (" + std::to_string(a) + ", " + std::to_string(b) +
                                 ") is not a < b < " + std::to_string(s.node_count));
            }
            all.emplace_back(a, b);
        }
        // `nodes` must be exactly the endpoints of the edges, each once.
        sorted = g.nodes;
        std::sort(sorted.begin(), sorted.end());
        if (std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end()) {
            return malformed(where + "a node is listed twice");
        }
        touched.assign(nn, 0);
        for (const auto& [a, b] : g.edges) {
            for (auto v : {a, b}) {
                auto it = std::lower_bound(sorted.begin(), sorted.end(), v);
                if (it == sorted.end() || *it != v) {
                    return malformed(where + "edge endpoint " + std::to_string(v) +
                                     " is not in the node list");
                }
                touched[static_cast<std::size_t>(it - sorted.begin())] = 1;
            }
        }
        if (std::find(touched.begin(), touched.end(), 0) != touched.end()) {
            return malformed(where + "a listed node has no edge");
        }
    }
    if (r.left() != 0) {
        return malformed(std::to_string(r.left()) + " trailing bytes");
    }
    if (all.size() != s.edge_count) {
        return malformed("the subgraphs hold " + std::to_string(all.size()) +
                         " edges, the plan has " + std::to_string(s.edge_count));
    }
    std::sort(all.begin(), all.end());
    if (auto it = std::adjacent_find(all.begin(), all.end()); it != all.end()) {
        return malformed("edge (" + std::to_string(it->first) + ", " + std::to_string(it->second) +
                         ") is in two subgraphs");
    }
    return s;
}

}  // namespace proxima::massive
