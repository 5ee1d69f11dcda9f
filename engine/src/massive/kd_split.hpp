#pragma once
// Private to the store: the k-d tree decomposition of an object into pieces (seed 001 §4.2.1).

#include <cstdint>
#include <span>
#include <vector>

#include "proxima/massive/store.hpp"

namespace proxima::massive::detail {

// Splits `mesh` (already validated) until every piece's piece_weight is at most
// `max_piece_bytes`: the triangles of a node are halved at the median of their centres along the
// longest axis of the centres' box (ties by triangle index), left half first. Each piece is the
// ascending list of its triangles' indices in `mesh`. A node of one triangle is never split.
// Depends only on the mesh and the limit (the order is total), not on the standard library.
std::vector<std::vector<std::uint32_t>> kd_split(const TriangleMesh& mesh,
                                                 std::uint64_t max_piece_bytes);

// Builds pieces of one mesh: the vertices a piece's triangles use in order of first use (exact
// copies), the triangles re-indexed, and the triangles' indices as source_triangles. Keeps one
// map over the mesh's vertices, reset after each piece, so a piece costs O(its size).
class PieceBuilder {
  public:
    explicit PieceBuilder(const TriangleMesh& mesh);
    PieceGeometry make(std::span<const std::uint32_t> triangles);

  private:
    const TriangleMesh& m_mesh;
    std::vector<std::uint32_t> m_local;  // object vertex -> piece vertex, or NONE
};

}  // namespace proxima::massive::detail
