#pragma once
// Indexed triangle meshes and their connectivity. Positions change every frame; connectivity
// (MeshTopology) changes only when the topology does, so it is built once per topology and shared
// read-only between frames, cullers and threads.

#include <array>
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "proxima/geometry/vec3.hpp"
#include "proxima/status.hpp"

namespace proxima {

using TriangleIndices = std::array<std::uint32_t, 3>;

struct TriangleMesh {
    std::vector<Vec3> vertices;
    std::vector<TriangleIndices> triangles;
};

// Checks what every query relies on: at least one triangle, every index below the vertex count,
// every coordinate finite. `what` names the object in the message ("object 'cloth.ply'").
Status validate_mesh(const TriangleMesh& mesh, const std::string& what);
// Same for a new set of positions for an existing topology.
Status validate_positions(std::span<const Vec3> positions, std::size_t expected_count,
                          const std::string& what);

inline bool share_vertex(const TriangleIndices& a, const TriangleIndices& b) {
    for (auto i : a) {
        if (i == b[0] || i == b[1] || i == b[2]) {
            return true;
        }
    }
    return false;
}

// Connectivity of an indexed triangle mesh: per-vertex incident triangles, per-triangle 1-ring
// (the other triangles sharing a vertex with it: seed 000 §5.2.2) and on-demand 2-ring, and
// connected components (through shared vertex indices). Immutable once built.
class MeshTopology {
  public:
    MeshTopology(std::vector<TriangleIndices> triangles, std::size_t vertex_count);

    std::size_t triangle_count() const { return m_triangles.size(); }
    std::size_t vertex_count() const { return m_vertex_count; }
    const std::vector<TriangleIndices>& triangles() const { return m_triangles; }
    const TriangleIndices& triangle(std::uint32_t t) const { return m_triangles[t]; }

    // Triangles incident to vertex v, ascending.
    std::span<const std::uint32_t> vertex_triangles(std::uint32_t v) const;
    // Triangles sharing at least one vertex with t, t excluded, ascending.
    std::span<const std::uint32_t> one_ring(std::uint32_t t) const;
    // Triangles sharing a vertex with a triangle of the 1-ring, excluding t and its 1-ring,
    // ascending.
    std::vector<std::uint32_t> two_ring(std::uint32_t t) const;
    // Same, into a caller-owned buffer (cleared first): no allocation once it has grown.
    void two_ring(std::uint32_t t, std::vector<std::uint32_t>& out) const;
    // All 2-rings at once (CSR), built on first use and kept for the topology's lifetime: the
    // intra-object query reads them every frame, and they depend on connectivity only.
    std::span<const std::uint32_t> cached_two_ring(std::uint32_t t) const;
    // True when t and u share a vertex index or are the same triangle: such pairs are excluded
    // from intra-object queries.
    bool adjacent(std::uint32_t t, std::uint32_t u) const {
        return t == u || share_vertex(m_triangles[t], m_triangles[u]);
    }

    // Connected components through shared vertices, numbered by their smallest triangle index
    // (component 0 holds triangle 0). Vertices used by no triangle belong to no component.
    std::size_t component_count() const { return m_component_count; }
    std::uint32_t component_of(std::uint32_t t) const { return m_triangle_component[t]; }

  private:
    std::vector<TriangleIndices> m_triangles;
    std::size_t m_vertex_count;
    std::vector<std::uint32_t> m_vertex_offsets;  // CSR over vertices
    std::vector<std::uint32_t> m_vertex_tris;
    std::vector<std::uint32_t> m_ring_offsets;  // CSR over triangles
    std::vector<std::uint32_t> m_ring_tris;
    std::vector<std::uint32_t> m_triangle_component;
    std::size_t m_component_count = 0;
    struct TwoRings {
        std::vector<std::uint32_t> offsets;
        std::vector<std::uint32_t> triangles;
    };
    mutable std::once_flag m_two_rings_once;
    mutable TwoRings m_two_rings;
};

// Splits a mesh into one mesh per connected component, in component order (by smallest triangle
// index). `triangle_ids[c][k]` is the input index of triangle k of component c; vertices are
// renumbered in order of first use.
struct ComponentSplit {
    std::vector<TriangleMesh> meshes;
    std::vector<std::vector<std::uint32_t>> triangle_ids;
    std::vector<std::vector<std::uint32_t>> vertex_ids;  // component-local -> input vertex index
};
ComponentSplit split_components(const TriangleMesh& mesh);

}  // namespace proxima
