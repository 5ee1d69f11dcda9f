#pragma once
// The overlap graph's partition into localized subgraphs (seed 001 §4.2–§4.3, §6.3): the plan
// that orders the graph's tests (overlap_graph.hpp) so that each batch of pieces loaded together
// fits the cache budget M:
//   1. connected components; a component of weight <= M is one localized subgraph;
//   2. in a larger component, high-valence nodes whose total weight plus the heaviest other node
//      fits M are taken out: their edges form a subgraph whose neighbours are swapped through
//      the cache one at a time (§4.2.1 item 2);
//   3. the rest is split by METIS multi-level k-way partitioning into parts of weight <= M; the
//      edges inside a part form its subgraph, the edges between parts form the cut graph, which
//      goes through 1–3 again (recursively) until no edge is left.
// Within a subgraph, edges are ordered by a breadth-first traversal rooted at the node of highest
// valence, neighbours visited in descending valence (§4.3). Implemented in
// src/massive/partition.cpp.

#include <cstdint>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "proxima/massive/model.hpp"
#include "proxima/massive/overlap_graph.hpp"

namespace proxima::massive {

struct LocalizedSubgraph {
    enum class Kind : std::uint8_t { component, high_valence, partition };
    Kind kind = Kind::component;
    std::uint32_t level = 0;           // 0: the overlap graph; k: the k-th cut graph
    std::vector<std::uint32_t> nodes;  // every node an edge below touches
    std::vector<std::pair<std::uint32_t, std::uint32_t>> edges;  // traversal order (a < b)
    std::uint64_t weight = 0;                                    // sum of node weights
};

struct Schedule {
    double tolerance = 0.0;
    std::uint64_t cache_bytes = 0;
    std::uint64_t node_count = 0;
    std::uint64_t edge_count = 0;
    std::vector<LocalizedSubgraph> subgraphs;  // in processing order; each edge in exactly one
    // Statistics of the plan.
    std::uint64_t components = 0;
    std::uint64_t high_valence_nodes = 0;
    std::uint64_t metis_calls = 0;
    std::uint32_t levels = 0;  // cut-graph recursion depth
};

// FAILED_PRECONDITION when two adjacent nodes together exceed cache_bytes (the pieces were split
// for a larger cache: re-import with a smaller --max-piece-bytes). Deterministic.
StatusOr<Schedule> plan_schedule(const std::vector<GraphNode>& nodes, double tolerance,
                                 std::uint64_t cache_bytes, const ProgressFn& progress = {});

// Versioned binary form, for persisting with the store (Store::write_sidecar). Decoding checks
// sizes and indices: INVALID_ARGUMENT (never a crash) on malformed bytes.
std::string serialize_schedule(const Schedule& schedule);
StatusOr<Schedule> deserialize_schedule(std::string_view bytes);

}  // namespace proxima::massive
