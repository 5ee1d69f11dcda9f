// plan_schedule: the partition of the overlap graph into localized subgraphs (seed 001 §4.2.1,
// §4.3, §6.3). Outline:
//   process(edges, level): connected components; a component of weight <= M is one subgraph, a
//     larger one is decomposed by one sub-algorithm, and whatever that leaves too large by the
//     other one (the seed's alternation, §6.3);
//   high_valence: nodes of highest valence whose total weight plus the heaviest other node of the
//     component fits M; their edges form one subgraph (the neighbours stream through the cache
//     while the picked nodes stay resident); the remaining edges go back to process(), and its
//     large components to METIS;
//   partition: METIS k-way parts of weight <= M; the edges inside a part form its subgraph, the
//     edges between parts form the cut graph, which goes back to process() at level + 1, and its
//     large components to high_valence.
// A greedy fallback (edges in traversal order, packed while their nodes fit M) guarantees progress
// where METIS cannot (it fails, or cuts every edge) and bounds the recursion depth.
//
// Guarantees: every edge in exactly one subgraph; `nodes` lists exactly the endpoints of its edges
// (isolated nodes are in no subgraph); weight <= M for component and partition subgraphs. A
// high_valence subgraph's weight may exceed M: its resident nodes come first in `nodes`, and their
// weight plus that of any one other node of the subgraph is <= M.
//
// Subgraph order (what an LRU cache of M gains from): depth first, so a component's subgraphs are
// contiguous; METIS parts in an order where each has many cut edges to the ones before it, each
// followed at once by its slice of the cut graph (see partition()); sibling components most
// recently used first. Edge order inside a subgraph: breadth-first from the node of most edges,
// neighbours in descending valence (ties: smaller index), a node's remaining edges emitted together
// when it is dequeued (§4.3); a disconnected subgraph restarts from the unvisited node of highest
// valence.

#include <metis.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numeric>
#include <queue>

#include "proxima/massive/partition.hpp"

namespace proxima::massive {

namespace {

using Edge = std::pair<std::uint32_t, std::uint32_t>;
using Kind = LocalizedSubgraph::Kind;

// Cut graphs deeper than this are packed greedily (never reached on real models: each level
// keeps only the edges METIS cut).
constexpr std::uint32_t MAX_LEVEL = 32;
// METIS aims at parts of this share of M, so that its imbalance tolerance stays below M.
constexpr double METIS_FILL = 0.8;
constexpr int METIS_TRIES = 6;
// METIS sums vertex weights (and sizes times neighbouring parts) in idx_t, 32 or 64 bits: the
// weights given to it are scaled so that these sums stay below these.
constexpr std::uint64_t METIS_WEIGHT_LIMIT = 1ull << 26;
constexpr std::uint64_t METIS_VOLUME_LIMIT = 1ull << 29;
// A node is taken out as high-valence only when its valence is at least this many times the
// component's mean valence (and at least HV_MIN_VALENCE): taking out ordinary nodes only costs
// loads (their neighbours stream once more) without making the rest easier to partition.
constexpr double HV_FACTOR = 4.0;
constexpr std::uint32_t HV_MIN_VALENCE = 8;
// ... and only when at least this share of its neighbours' weight has no other edge left: each
// neighbour that keeps edges streams through the cache now and is loaded again later (in the LRU
// simulation of the tests, removing dense-region nodes costs up to 0.5 loads per node byte).
constexpr double HV_FREED_SHARE = 0.5;

std::uint64_t sat_add(std::uint64_t a, std::uint64_t b) {
    return a > std::numeric_limits<std::uint64_t>::max() - b
               ? std::numeric_limits<std::uint64_t>::max()
               : a + b;
}

// The subgraph spanned by a set of edges, renumbered: local nodes in ascending global order, so
// every tie broken by the local index is broken by the global one.
struct LocalGraph {
    std::vector<std::uint32_t> node;      // local -> global node
    std::vector<std::uint32_t> edge;      // local -> global edge id
    std::vector<Edge> ends;               // local edge -> local endpoints
    std::vector<std::uint32_t> offset;    // CSR over local nodes
    std::vector<std::uint32_t> adj;       // neighbour (local)
    std::vector<std::uint32_t> adj_edge;  // the local edge to it
    std::vector<std::uint64_t> weight;    // local node weight
    std::uint64_t total = 0;

    std::uint32_t size() const { return static_cast<std::uint32_t>(node.size()); }
    std::uint32_t degree(std::uint32_t u) const { return offset[u + 1] - offset[u]; }
};

enum class Method { high_valence, metis };

class Planner {
  public:
    Planner(const std::vector<GraphNode>& nodes, const std::vector<Edge>& edges,
            std::uint64_t cache_bytes, Schedule& out, const ProgressFn& progress)
        : m_nodes(nodes),
          m_edges(edges),
          m_budget(cache_bytes),
          m_out(out),
          m_progress(progress),
          m_stamp(nodes.size(), 0),
          m_map(nodes.size(), 0),
          m_last_use(nodes.size(), 0) {
        m_report_step = std::max<std::uint64_t>(1, edges.size() / 200);
    }

    void report(bool force) {
        if (m_progress && (force || m_assigned >= m_next_report)) {
            m_progress({"partitioning", m_assigned, m_edges.size(), "edges"});
            m_next_report = m_assigned + m_report_step;
        }
    }

    // Connected components of `ids`; each one fitting M is a subgraph, the others are decomposed.
    void process(const std::vector<std::uint32_t>& ids, std::uint32_t level, Method method) {
        if (ids.empty()) {
            return;
        }
        std::vector<std::vector<std::uint32_t>> parts;
        std::vector<std::uint64_t> weights;
        std::vector<std::uint64_t> recent;
        {
            const LocalGraph g = build(ids);
            std::vector<std::uint32_t> label(g.size(), UINT32_MAX);
            std::vector<std::uint32_t> queue;
            for (std::uint32_t root = 0; root < g.size(); ++root) {
                if (label[root] != UINT32_MAX) {
                    continue;
                }
                const auto c = static_cast<std::uint32_t>(weights.size());
                weights.push_back(0);
                label[root] = c;
                queue.assign(1, root);
                for (std::size_t h = 0; h < queue.size(); ++h) {
                    const std::uint32_t u = queue[h];
                    weights[c] = sat_add(weights[c], g.weight[u]);
                    for (auto k = g.offset[u]; k < g.offset[u + 1]; ++k) {
                        if (label[g.adj[k]] == UINT32_MAX) {
                            label[g.adj[k]] = c;
                            queue.push_back(g.adj[k]);
                        }
                    }
                }
            }
            parts.resize(weights.size());
            recent.assign(weights.size(), 0);
            for (std::uint32_t e = 0; e < g.edge.size(); ++e) {
                parts[label[g.ends[e].first]].push_back(g.edge[e]);
            }
            for (std::uint32_t u = 0; u < g.size(); ++u) {
                recent[label[u]] = std::max(recent[label[u]], m_last_use[g.node[u]]);
            }
        }
        std::vector<std::size_t> by_recency(parts.size());
        std::iota(by_recency.begin(), by_recency.end(), std::size_t{0});
        // Most recently used first: their nodes may still be in the cache.
        std::stable_sort(by_recency.begin(), by_recency.end(),
                         [&](std::size_t x, std::size_t y) { return recent[x] > recent[y]; });
        for (std::size_t c : by_recency) {
            if (weights[c] <= m_budget) {
                emit(Kind::component, level, build(parts[c]));
            } else {
                decompose(parts[c], level, method);
            }
            std::vector<std::uint32_t>().swap(parts[c]);
        }
    }

  private:
    void decompose(const std::vector<std::uint32_t>& ids, std::uint32_t level, Method method) {
        if (level >= MAX_LEVEL) {
            greedy(build(ids), level);
            return;
        }
        if (method == Method::high_valence && high_valence(ids, level)) {
            return;
        }
        partition(ids, level);
    }

    LocalGraph build(const std::vector<std::uint32_t>& ids) {
        if (++m_generation == 0) {
            std::fill(m_stamp.begin(), m_stamp.end(), 0);
            m_generation = 1;
        }
        LocalGraph g;
        for (auto e : ids) {
            for (auto v : {m_edges[e].first, m_edges[e].second}) {
                if (m_stamp[v] != m_generation) {
                    m_stamp[v] = m_generation;
                    g.node.push_back(v);
                }
            }
        }
        std::sort(g.node.begin(), g.node.end());
        const std::uint32_t n = g.size();
        g.weight.resize(n);
        for (std::uint32_t u = 0; u < n; ++u) {
            m_map[g.node[u]] = u;
            g.weight[u] = m_nodes[g.node[u]].weight;
            g.total = sat_add(g.total, g.weight[u]);
        }
        g.edge = ids;
        g.ends.resize(ids.size());
        g.offset.assign(n + 1, 0);
        for (std::size_t e = 0; e < ids.size(); ++e) {
            const auto a = m_map[m_edges[ids[e]].first];
            const auto b = m_map[m_edges[ids[e]].second];
            g.ends[e] = {a, b};
            ++g.offset[a + 1];
            ++g.offset[b + 1];
        }
        std::partial_sum(g.offset.begin(), g.offset.end(), g.offset.begin());
        g.adj.resize(g.offset.back());
        g.adj_edge.resize(g.offset.back());
        std::vector<std::uint32_t> fill(g.offset.begin(), g.offset.end() - 1);
        for (std::uint32_t e = 0; e < g.ends.size(); ++e) {
            const auto [a, b] = g.ends[e];
            g.adj[fill[a]] = b;
            g.adj_edge[fill[a]++] = e;
            g.adj[fill[b]] = a;
            g.adj_edge[fill[b]++] = e;
        }
        return g;
    }

    // Each adjacency list in the traversal order: descending valence, ties by smaller index.
    static void sort_adjacency(LocalGraph& g) {
        std::vector<std::pair<std::uint32_t, std::uint32_t>> tmp;
        for (std::uint32_t u = 0; u < g.size(); ++u) {
            tmp.clear();
            for (auto k = g.offset[u]; k < g.offset[u + 1]; ++k) {
                tmp.emplace_back(g.adj[k], g.adj_edge[k]);
            }
            std::sort(tmp.begin(), tmp.end(), [&](const auto& x, const auto& y) {
                const auto dx = g.degree(x.first);
                const auto dy = g.degree(y.first);
                return dx > dy || (dx == dy && x.first < y.first);
            });
            for (std::size_t i = 0; i < tmp.size(); ++i) {
                g.adj[g.offset[u] + i] = tmp[i].first;
                g.adj_edge[g.offset[u] + i] = tmp[i].second;
            }
        }
    }

    static std::vector<std::uint32_t> by_valence(const LocalGraph& g) {
        std::vector<std::uint32_t> order(g.size());
        std::iota(order.begin(), order.end(), 0u);
        std::sort(order.begin(), order.end(), [&](std::uint32_t x, std::uint32_t y) {
            const auto dx = g.degree(x);
            const auto dy = g.degree(y);
            return dx > dy || (dx == dy && x < y);
        });
        return order;
    }

    // §4.3: breadth-first from the node of most edges, neighbours in descending valence; a node's
    // remaining edges are emitted together when it is dequeued, so each node's tests cluster.
    static std::vector<std::uint32_t> traversal(LocalGraph& g) {
        sort_adjacency(g);
        std::vector<std::uint32_t> order;
        order.reserve(g.edge.size());
        std::vector<char> visited(g.size(), 0);
        std::vector<char> done(g.edge.size(), 0);
        std::vector<std::uint32_t> queue;
        for (auto root : by_valence(g)) {
            if (visited[root] != 0) {
                continue;
            }
            visited[root] = 1;
            queue.assign(1, root);
            for (std::size_t h = 0; h < queue.size(); ++h) {
                const std::uint32_t u = queue[h];
                for (auto k = g.offset[u]; k < g.offset[u + 1]; ++k) {
                    if (done[g.adj_edge[k]] == 0) {
                        done[g.adj_edge[k]] = 1;
                        order.push_back(g.adj_edge[k]);
                    }
                    if (visited[g.adj[k]] == 0) {
                        visited[g.adj[k]] = 1;
                        queue.push_back(g.adj[k]);
                    }
                }
            }
        }
        return order;
    }

    // Appends a subgraph whose edges (local) are given in processing order; `nodes` lists the
    // nodes in the order the edges first touch them, after `first` (the resident set, if any).
    void push(Kind kind, std::uint32_t level, const LocalGraph& g,
              const std::vector<std::uint32_t>& order, const std::vector<std::uint32_t>& first) {
        LocalizedSubgraph s;
        s.kind = kind;
        s.level = level;
        s.edges.reserve(order.size());
        std::vector<char> seen(g.size(), 0);
        auto touch = [&](std::uint32_t u) {
            if (seen[u] == 0) {
                seen[u] = 1;
                s.nodes.push_back(g.node[u]);
                s.weight = sat_add(s.weight, g.weight[u]);
            }
        };
        for (auto u : first) {
            touch(u);
        }
        for (auto e : order) {
            s.edges.push_back(m_edges[g.edge[e]]);
            touch(g.ends[e].first);
            touch(g.ends[e].second);
        }
        m_out.levels = std::max(m_out.levels, level);
        m_assigned += s.edges.size();
        ++m_clock;
        for (auto v : s.nodes) {
            m_last_use[v] = m_clock;
        }
        m_out.subgraphs.push_back(std::move(s));
        report(false);
    }

    void emit(Kind kind, std::uint32_t level, LocalGraph g) {
        const auto order = traversal(g);
        push(kind, level, g, order, {});
    }

    // §4.2.1 item 2. Returns false (nothing emitted) when no node qualifies.
    bool high_valence(const std::vector<std::uint32_t>& ids, std::uint32_t level) {
        LocalGraph g = build(ids);
        const std::uint32_t n = g.size();
        const double mean = 2.0 * static_cast<double>(ids.size()) / n;
        const double threshold = std::max<double>(HV_MIN_VALENCE, HV_FACTOR * mean);
        std::vector<std::uint32_t> heavy(n);
        std::iota(heavy.begin(), heavy.end(), 0u);
        std::sort(heavy.begin(), heavy.end(), [&](std::uint32_t x, std::uint32_t y) {
            return g.weight[x] > g.weight[y] || (g.weight[x] == g.weight[y] && x < y);
        });
        std::vector<char> picked(n, 0);
        std::vector<std::uint32_t> chosen;
        std::uint64_t sum = 0;
        std::size_t h = 0;
        // to_picked[v]: edges from v to picked nodes; v is done with once it equals v's valence.
        std::vector<std::uint32_t> to_picked(n, 0);
        for (auto u : by_valence(g)) {
            if (g.degree(u) < threshold) {
                break;
            }
            // Streaming a neighbour that keeps other edges means loading it again later: take u
            // only if most of its neighbours' weight is done with once its edges are.
            std::uint64_t freed = 0;
            std::uint64_t streamed = 0;
            for (auto k = g.offset[u]; k < g.offset[u + 1]; ++k) {
                const auto v = g.adj[k];
                if (picked[v] == 0) {
                    streamed = sat_add(streamed, g.weight[v]);
                    freed = sat_add(freed, to_picked[v] + 1 == g.degree(v) ? g.weight[v] : 0);
                }
            }
            if (static_cast<double>(freed) < HV_FREED_SHARE * static_cast<double>(streamed)) {
                continue;
            }
            picked[u] = 1;
            while (h < n && picked[heavy[h]] != 0) {
                ++h;
            }
            const std::uint64_t rest = h < n ? g.weight[heavy[h]] : 0;
            if (sat_add(sat_add(sum, g.weight[u]), rest) > m_budget) {
                picked[u] = 0;
                break;
            }
            sum += g.weight[u];
            chosen.push_back(u);
            for (auto k = g.offset[u]; k < g.offset[u + 1]; ++k) {
                ++to_picked[g.adj[k]];
            }
        }
        if (chosen.empty()) {
            return false;
        }
        m_out.high_valence_nodes += chosen.size();

        // Edges among the picked nodes first, then each neighbour's edges to them, neighbours in
        // breadth-first order over the whole component from the first picked node (so that
        // neighbours near each other stream together).
        sort_adjacency(g);
        std::vector<std::uint32_t> order;
        std::vector<char> done(g.edge.size(), 0);
        for (auto p : chosen) {
            for (auto k = g.offset[p]; k < g.offset[p + 1]; ++k) {
                if (picked[g.adj[k]] != 0 && done[g.adj_edge[k]] == 0) {
                    done[g.adj_edge[k]] = 1;
                    order.push_back(g.adj_edge[k]);
                }
            }
        }
        std::vector<char> visited(n, 0);
        std::vector<std::uint32_t> queue{chosen.front()};
        visited[chosen.front()] = 1;
        for (std::size_t q = 0; q < queue.size(); ++q) {
            const std::uint32_t u = queue[q];
            if (picked[u] == 0) {
                for (auto k = g.offset[u]; k < g.offset[u + 1]; ++k) {
                    if (picked[g.adj[k]] != 0 && done[g.adj_edge[k]] == 0) {
                        done[g.adj_edge[k]] = 1;
                        order.push_back(g.adj_edge[k]);
                    }
                }
            }
            for (auto k = g.offset[u]; k < g.offset[u + 1]; ++k) {
                if (visited[g.adj[k]] == 0) {
                    visited[g.adj[k]] = 1;
                    queue.push_back(g.adj[k]);
                }
            }
        }
        push(Kind::high_valence, level, g, order, chosen);

        std::vector<std::uint32_t> rest;
        rest.reserve(g.edge.size() - order.size());
        for (std::uint32_t e = 0; e < g.edge.size(); ++e) {
            if (done[e] == 0) {
                rest.push_back(g.edge[e]);
            }
        }
        g = LocalGraph{};
        process(rest, level, Method::metis);
        return true;
    }

    // §4.2.1 item 3: METIS parts of weight <= M; the edges between parts form the cut graph, at
    // level + 1. The cut graph is not processed as a whole after all parts but in slices: the
    // parts are ordered so that each has many cut edges to the parts before it, and right after
    // part k come the cut edges between k and earlier parts (through process(), so every guarantee
    // holds), while k's boundary nodes are still resident. In the LRU simulation this takes the
    // extra loads of the cut graph from ~0.4 to ~0.25 per node byte on dense clustered layouts.
    void partition(const std::vector<std::uint32_t>& ids, std::uint32_t level) {
        LocalGraph g = build(ids);
        const std::uint32_t n = g.size();
        // METIS balances and sums vertex weights in idx_t (and float): weights are scaled to at
        // most METIS_WEIGHT_LIMIT in total, rounded to nearest, at least 1. Sizes (for the
        // volume objective) count once per neighbouring part, so they get a coarser unit.
        std::uint32_t max_degree = 1;
        for (std::uint32_t u = 0; u < n; ++u) {
            max_degree = std::max(max_degree, g.degree(u));
        }
        const std::uint64_t unit = g.total / METIS_WEIGHT_LIMIT + 1;
        const auto size_unit = static_cast<std::uint64_t>(std::ceil(
                                   static_cast<double>(g.total) * std::min(max_degree, n) /
                                   static_cast<double>(METIS_VOLUME_LIMIT))) +
                               1;
        std::vector<idx_t> xadj(g.offset.begin(), g.offset.end());
        std::vector<idx_t> adjncy(g.adj.begin(), g.adj.end());
        std::vector<idx_t> vwgt(n);
        std::vector<idx_t> vsize(n);
        for (std::uint32_t u = 0; u < n; ++u) {
            vwgt[u] =
                static_cast<idx_t>(std::max<std::uint64_t>(1, (g.weight[u] + unit / 2) / unit));
            vsize[u] = static_cast<idx_t>(
                std::max<std::uint64_t>(1, (g.weight[u] + size_unit / 2) / size_unit));
        }
        idx_t options[METIS_NOPTIONS];
        METIS_SetDefaultOptions(options);
        options[METIS_OPTION_SEED] = 1;
        options[METIS_OPTION_NUMBERING] = 0;
        // Minimize the communication volume with vertex sizes = weights: the weight of boundary
        // nodes, i.e. what the cut graph loads again (slightly better than the edge cut in the
        // LRU simulation).
        options[METIS_OPTION_OBJTYPE] = METIS_OBJTYPE_VOL;
        auto nparts = static_cast<std::uint32_t>(std::min<double>(
            n, std::max(2.0, std::ceil(static_cast<double>(g.total) /
                                       (METIS_FILL * static_cast<double>(m_budget))))));
        std::vector<idx_t> part;
        std::vector<std::uint64_t> part_weight;
        std::size_t best_kept = 0;  // edges inside parts that fit, in the best attempt so far
        std::vector<idx_t> trial(n, 0);
        std::vector<std::uint64_t> trial_weight;
        for (int attempt = 0; attempt < METIS_TRIES; ++attempt) {
            idx_t nv = static_cast<idx_t>(n);
            idx_t ncon = 1;
            idx_t np = static_cast<idx_t>(nparts);
            idx_t objective = 0;
            ++m_out.metis_calls;
            const int rc = METIS_PartGraphKway(&nv, &ncon, xadj.data(), adjncy.data(), vwgt.data(),
                                               vsize.data(), nullptr, &np, nullptr, nullptr,
                                               options, &objective, trial.data());
            if (rc != METIS_OK) {
                break;
            }
            trial_weight.assign(nparts, 0);
            for (std::uint32_t u = 0; u < n; ++u) {
                auto& w = trial_weight[static_cast<std::size_t>(trial[u])];
                w = sat_add(w, g.weight[u]);
            }
            bool fits = true;
            for (auto w : trial_weight) {
                fits = fits && w <= m_budget;
            }
            std::size_t kept = 0;
            for (const auto& [a, b] : g.ends) {
                kept += (trial[a] == trial[b] &&
                         trial_weight[static_cast<std::size_t>(trial[a])] <= m_budget)
                            ? 1
                            : 0;
            }
            // An attempt where every part fits is taken; otherwise the one keeping most edges.
            if (fits || kept > best_kept) {
                best_kept = kept;
                part = trial;
                part_weight = trial_weight;
            }
            if (fits || nparts == n) {
                break;
            }
            // METIS's balance is a target, not a bound: retry with smaller parts.
            nparts = std::min(n, nparts + std::max<std::uint32_t>(1, nparts / 4));
        }
        if (best_kept == 0) {
            greedy(std::move(g), level);
            return;
        }

        // Edges inside a part that fits form its subgraph; edges inside a part METIS left too
        // heavy (after every retry) join the cut graph.
        const std::size_t np = part_weight.size();
        std::vector<std::vector<std::uint32_t>> inside(np);
        std::vector<std::map<std::size_t, std::uint64_t>> links(np);  // cut edges between parts
        for (std::uint32_t e = 0; e < g.edge.size(); ++e) {
            const auto pa = static_cast<std::size_t>(part[g.ends[e].first]);
            const auto pb = static_cast<std::size_t>(part[g.ends[e].second]);
            if (pa == pb && part_weight[pa] <= m_budget) {
                inside[pa].push_back(g.edge[e]);
            } else if (pa != pb) {
                ++links[pa][pb];
                ++links[pb][pa];
            }
        }

        // Part order: greedily the part with the most cut edges to the parts already placed (ties
        // and disconnected starts: the smaller part number).
        std::vector<std::size_t> order;
        std::vector<std::size_t> position(np, 0);
        {
            std::vector<std::uint64_t> conn(np, 0);
            std::vector<char> placed(np, 0);
            using Entry = std::pair<std::uint64_t, std::size_t>;
            auto worse = [](const Entry& x, const Entry& y) {
                return x.first < y.first || (x.first == y.first && x.second > y.second);
            };
            std::priority_queue<Entry, std::vector<Entry>, decltype(worse)> heap(worse);
            std::size_t next_unlinked = 0;
            while (order.size() < np) {
                std::size_t p = np;
                while (!heap.empty()) {
                    const auto [c, q] = heap.top();
                    heap.pop();
                    if (placed[q] == 0 && c == conn[q]) {
                        p = q;
                        break;
                    }
                }
                if (p == np) {
                    while (placed[next_unlinked] != 0) {
                        ++next_unlinked;
                    }
                    p = next_unlinked;
                }
                placed[p] = 1;
                position[p] = order.size();
                order.push_back(p);
                for (const auto& [q, c] : links[p]) {
                    if (placed[q] == 0) {
                        conn[q] += c;
                        heap.emplace(conn[q], q);
                    }
                }
            }
        }
        std::vector<std::vector<std::uint32_t>> after(np);  // cut edges, by their later part
        std::vector<std::uint32_t> heavy;                   // edges inside too heavy parts
        for (std::uint32_t e = 0; e < g.edge.size(); ++e) {
            const auto pa = static_cast<std::size_t>(part[g.ends[e].first]);
            const auto pb = static_cast<std::size_t>(part[g.ends[e].second]);
            if (pa != pb) {
                after[position[pa] > position[pb] ? pa : pb].push_back(g.edge[e]);
            } else if (part_weight[pa] > m_budget) {
                heavy.push_back(g.edge[e]);
            }
        }
        g = LocalGraph{};
        for (auto p : order) {
            if (!inside[p].empty()) {
                emit(Kind::partition, level, build(inside[p]));
            }
            std::vector<std::uint32_t>().swap(inside[p]);
            process(after[p], level + 1, Method::high_valence);
            std::vector<std::uint32_t>().swap(after[p]);
        }
        process(heavy, level + 1, Method::high_valence);
    }

    // Guaranteed progress: edges in traversal order, cut into runs whose nodes fit M (every edge
    // alone fits: plan_schedule checked that adjacent nodes fit together).
    void greedy(LocalGraph g, std::uint32_t level) {
        const auto order = traversal(g);
        std::vector<std::uint32_t> mark(g.size(), 0);
        std::uint32_t run = 1;
        std::uint64_t weight = 0;
        std::vector<std::uint32_t> ids;
        std::vector<std::vector<std::uint32_t>> runs;
        for (auto e : order) {
            const auto [a, b] = g.ends[e];
            std::uint64_t add = 0;
            add = sat_add(add, mark[a] == run ? 0 : g.weight[a]);
            add = sat_add(add, mark[b] == run ? 0 : g.weight[b]);
            if (sat_add(weight, add) > m_budget && !ids.empty()) {
                runs.push_back(std::move(ids));
                ids.clear();
                ++run;
                weight = 0;
                add = sat_add(g.weight[a], g.weight[b]);
            }
            mark[a] = run;
            mark[b] = run;
            weight = sat_add(weight, add);
            ids.push_back(g.edge[e]);
        }
        if (!ids.empty()) {
            runs.push_back(std::move(ids));
        }
        g = LocalGraph{};
        for (const auto& r : runs) {
            emit(Kind::partition, level, build(r));
        }
    }

    const std::vector<GraphNode>& m_nodes;
    const std::vector<Edge>& m_edges;
    std::uint64_t m_budget;
    Schedule& m_out;
    const ProgressFn& m_progress;
    std::vector<std::uint32_t> m_stamp;
    std::vector<std::uint32_t> m_map;
    std::uint32_t m_generation = 0;
    std::vector<std::uint64_t> m_last_use;  // the last subgraph (m_clock) that used each node
    std::uint64_t m_clock = 0;
    std::uint64_t m_assigned = 0;
    std::uint64_t m_next_report = 0;
    std::uint64_t m_report_step = 1;
};

}  // namespace

StatusOr<Schedule> plan_schedule(const std::vector<GraphNode>& nodes, double tolerance,
                                 std::uint64_t cache_bytes, const ProgressFn& progress) {
    if (!std::isfinite(tolerance) || tolerance < 0.0) {
        return invalid_argument("plan_schedule: tolerance must be finite and >= 0, got " +
                                std::to_string(tolerance));
    }
    if (cache_bytes == 0) {
        return invalid_argument("plan_schedule: the cache budget must be positive");
    }
    if (nodes.size() > std::numeric_limits<std::uint32_t>::max()) {
        return invalid_argument("plan_schedule: " + std::to_string(nodes.size()) +
                                " nodes, at most 2^32-1 are supported");
    }
    if (progress) {
        progress({"partitioning", 0, 0, "edges"});
    }
    const auto edges = overlap_edges(nodes, tolerance);
    if (edges.size() > std::numeric_limits<std::uint32_t>::max()) {
        return Status(StatusCode::resource_exhausted,
                      "plan_schedule: " + std::to_string(edges.size()) +
                          " overlap-graph edges, at most 2^32-1 are supported");
    }
    for (const auto& [a, b] : edges) {
        const std::uint64_t wa = nodes[a].weight;
        const std::uint64_t wb = nodes[b].weight;
        if (wa > cache_bytes || wb > cache_bytes - wa) {
            return failed_precondition(
                "plan_schedule: nodes " + std::to_string(a) + " (" + std::to_string(wa) +
                " bytes) and " + std::to_string(b) + " (" + std::to_string(wb) +
                " bytes) must be tested together but exceed the cache budget M = " +
                std::to_string(cache_bytes) +
                " bytes together: re-import the model with a smaller --max-piece-bytes (at most "
                "M / 2; M / 10 is recommended)");
        }
    }

    Schedule schedule;
    schedule.tolerance = tolerance;
    schedule.cache_bytes = cache_bytes;
    schedule.node_count = nodes.size();
    schedule.edge_count = edges.size();
    {
        // Components of the whole overlap graph (nodes with at least one edge), for the statistics.
        std::vector<std::uint32_t> parent(nodes.size());
        std::iota(parent.begin(), parent.end(), 0u);
        auto find = [&](std::uint32_t x) {
            while (parent[x] != x) {
                parent[x] = parent[parent[x]];
                x = parent[x];
            }
            return x;
        };
        std::vector<char> has_edge(nodes.size(), 0);
        for (const auto& [a, b] : edges) {
            has_edge[a] = has_edge[b] = 1;
            const auto ra = find(a);
            const auto rb = find(b);
            if (ra != rb) {
                parent[std::max(ra, rb)] = std::min(ra, rb);
            }
        }
        for (std::uint32_t v = 0; v < nodes.size(); ++v) {
            schedule.components += (has_edge[v] != 0 && find(v) == v) ? 1 : 0;
        }
    }

    Planner planner(nodes, edges, cache_bytes, schedule, progress);
    std::vector<std::uint32_t> all(edges.size());
    std::iota(all.begin(), all.end(), 0u);
    planner.process(all, 0, Method::high_valence);
    planner.report(true);
    return schedule;
}

}  // namespace proxima::massive
