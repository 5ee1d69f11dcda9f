// The schedule's versioned binary form (partition.hpp: serialize_schedule, deserialize_schedule),
// persisted with the store.
#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <limits>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "proxima/massive/partition.hpp"

namespace proxima::massive {

// Binary form. Little-endian throughout:
//   "PXSCHED\0" (8 bytes), u32 version (1),
//   f64 tolerance, u64 cache_bytes, u64 node_count, u64 edge_count,
//   u64 components, u64 high_valence_nodes, u64 metis_calls, u32 levels,
//   u64 subgraph count, then per subgraph:
//     u8 kind, u32 level, u64 weight, u32 node count, u32 edge count,
//     node count x u32 node, edge count x (u32 a, u32 b).

namespace {

using Edge = std::pair<std::uint32_t, std::uint32_t>;

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
    std::size_t size = MAGIC.size() + std::size_t{4 + 8 * 8 + 4};
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
