#pragma once
// The overlap graph (seed 001 §4.1): nodes are pieces (weighted by piece_weight: the bytes their
// geometry and hierarchy take in the cache); an edge joins two pieces of *different* objects whose
// boxes, grown by the tolerance, overlap (sorted intervals). Every edge is one proximity test.
// Its partition into localized subgraphs, the plan that orders the tests, is in partition.hpp.

#include <cstdint>
#include <utility>
#include <vector>

#include "proxima/massive/model.hpp"

namespace proxima::massive {

struct GraphNode {
    Aabb box;
    std::uint64_t weight = 0;
    std::uint32_t object = 0;  // nodes of the same object are never joined
};

// Undirected edges (a < b), sorted. Conservative: every pair of nodes of different objects whose
// boxes lie within `tolerance` of each other (tolerance widened by the rounding slack of the
// coordinates, so no pair within tolerance can be missed).
std::vector<std::pair<std::uint32_t, std::uint32_t>> overlap_edges(
    const std::vector<GraphNode>& nodes, double tolerance);

}  // namespace proxima::massive
