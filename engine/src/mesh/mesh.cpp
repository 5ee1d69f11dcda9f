#include "proxima/mesh/mesh.hpp"

#include <algorithm>
#include <numeric>

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

namespace proxima {

Status validate_mesh(const TriangleMesh& mesh, const std::string& what) {
    if (mesh.triangles.empty()) {
        return invalid_argument(what + ": mesh has no triangles");
    }
    if (mesh.vertices.size() > std::numeric_limits<std::uint32_t>::max()) {
        return invalid_argument(what + ": more than 2^32-1 vertices");
    }
    if (Status s = validate_positions(mesh.vertices, mesh.vertices.size(), what); !s.ok()) {
        return s;
    }
    const auto n = mesh.vertices.size();
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        for (int k = 0; k < 3; ++k) {
            if (mesh.triangles[t][k] >= n) {
                return invalid_argument(
                    what + ": triangle " + std::to_string(t) + " corner " + std::to_string(k) +
                    " has vertex index " + std::to_string(mesh.triangles[t][k]) +
                    ", out of range (the mesh has " + std::to_string(n) + " vertices)");
            }
        }
    }
    return {};
}

Status validate_positions(std::span<const Vec3> positions, std::size_t expected_count,
                          const std::string& what) {
    if (positions.size() != expected_count) {
        return invalid_argument(what + ": " + std::to_string(positions.size()) +
                                " vertex positions given, the topology has " +
                                std::to_string(expected_count) + " vertices");
    }
    for (std::size_t v = 0; v < positions.size(); ++v) {
        if (!is_finite(positions[v])) {
            return invalid_argument(what + ": vertex " + std::to_string(v) +
                                    " has a non-finite coordinate (NaN or Inf)");
        }
    }
    return {};
}

namespace {

struct UnionFind {
    std::vector<std::uint32_t> parent;
    explicit UnionFind(std::size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0u); }
    std::uint32_t find(std::uint32_t x) {
        while (parent[x] != x) {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        return x;
    }
    void unite(std::uint32_t a, std::uint32_t b) {
        a = find(a);
        b = find(b);
        if (a != b) {
            parent[std::max(a, b)] = std::min(a, b);
        }
    }
};

}  // namespace

MeshTopology::MeshTopology(std::vector<TriangleIndices> triangles, std::size_t vertex_count)
    : m_triangles(std::move(triangles)), m_vertex_count(vertex_count) {
    const auto nt = static_cast<std::uint32_t>(m_triangles.size());

    // Vertex -> triangles, CSR. Triangles are visited in order so each list is ascending.
    m_vertex_offsets.assign(vertex_count + 1, 0);
    for (const auto& tri : m_triangles) {
        for (auto v : tri) {
            ++m_vertex_offsets[v + 1];
        }
    }
    std::partial_sum(m_vertex_offsets.begin(), m_vertex_offsets.end(), m_vertex_offsets.begin());
    m_vertex_tris.resize(m_vertex_offsets.back());
    {
        std::vector<std::uint32_t> fill(m_vertex_offsets.begin(), m_vertex_offsets.end() - 1);
        for (std::uint32_t t = 0; t < nt; ++t) {
            const auto& tri = m_triangles[t];
            for (int k = 0; k < 3; ++k) {
                // A triangle listing the same vertex twice is recorded once for that vertex.
                bool repeated = false;
                for (int j = 0; j < k; ++j) {
                    repeated |= tri[j] == tri[k];
                }
                if (!repeated) {
                    m_vertex_tris[fill[tri[k]]++] = t;
                }
            }
        }
        // Repeated corners leave holes at the end of a vertex's range: compact.
        std::vector<std::uint32_t> offsets(vertex_count + 1, 0);
        std::size_t w = 0;
        for (std::size_t v = 0; v < vertex_count; ++v) {
            offsets[v] = static_cast<std::uint32_t>(w);
            for (auto i = m_vertex_offsets[v]; i < fill[v]; ++i) {
                m_vertex_tris[w++] = m_vertex_tris[i];
            }
        }
        offsets[vertex_count] = static_cast<std::uint32_t>(w);
        m_vertex_tris.resize(w);
        m_vertex_offsets = std::move(offsets);
    }

    // 1-rings, CSR.
    m_ring_offsets.assign(nt + 1, 0);
    std::vector<std::uint32_t> scratch;
    for (std::uint32_t t = 0; t < nt; ++t) {
        scratch.clear();
        for (auto v : m_triangles[t]) {
            for (auto u : vertex_triangles(v)) {
                if (u != t) {
                    scratch.push_back(u);
                }
            }
        }
        std::sort(scratch.begin(), scratch.end());
        scratch.erase(std::unique(scratch.begin(), scratch.end()), scratch.end());
        m_ring_tris.insert(m_ring_tris.end(), scratch.begin(), scratch.end());
        m_ring_offsets[t + 1] = static_cast<std::uint32_t>(m_ring_tris.size());
    }

    // Components through shared vertices, renumbered by smallest triangle index.
    UnionFind uf(vertex_count);
    for (const auto& tri : m_triangles) {
        uf.unite(tri[0], tri[1]);
        uf.unite(tri[0], tri[2]);
    }
    constexpr auto NONE = std::numeric_limits<std::uint32_t>::max();
    std::vector<std::uint32_t> label(vertex_count, NONE);
    m_triangle_component.resize(nt);
    for (std::uint32_t t = 0; t < nt; ++t) {
        auto root = uf.find(m_triangles[t][0]);
        if (label[root] == NONE) {
            label[root] = static_cast<std::uint32_t>(m_component_count++);
        }
        m_triangle_component[t] = label[root];
    }
}

std::span<const std::uint32_t> MeshTopology::vertex_triangles(std::uint32_t v) const {
    return {m_vertex_tris.data() + m_vertex_offsets[v],
            m_vertex_tris.data() + m_vertex_offsets[v + 1]};
}

std::span<const std::uint32_t> MeshTopology::one_ring(std::uint32_t t) const {
    return {m_ring_tris.data() + m_ring_offsets[t], m_ring_tris.data() + m_ring_offsets[t + 1]};
}

std::vector<std::uint32_t> MeshTopology::two_ring(std::uint32_t t) const {
    std::vector<std::uint32_t> out;
    two_ring(t, out);
    return out;
}

void MeshTopology::two_ring(std::uint32_t t, std::vector<std::uint32_t>& out) const {
    out.clear();
    const auto ring = one_ring(t);
    for (auto u : ring) {
        for (auto w : one_ring(u)) {
            if (w != t && !std::binary_search(ring.begin(), ring.end(), w)) {
                out.push_back(w);
            }
        }
    }
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
}

std::span<const std::uint32_t> MeshTopology::cached_two_ring(std::uint32_t t) const {
    std::call_once(m_two_rings_once, [this] {
        // Built in parallel chunks (the first intra-object query after a topology change waits
        // for it), then concatenated in triangle order.
        const auto nt = static_cast<std::uint32_t>(m_triangles.size());
        constexpr std::uint32_t CHUNK = 2048;
        const std::uint32_t chunks = (nt + CHUNK - 1) / CHUNK;
        std::vector<std::vector<std::uint32_t>> parts(chunks);
        std::vector<std::vector<std::uint32_t>> sizes(chunks);
        // Isolated: while this thread waits for the chunks it must not pick up an outer task that
        // calls cached_two_ring() again (a recursive call_once would deadlock).
        tbb::this_task_arena::isolate([&] {
            tbb::parallel_for(std::uint32_t{0}, chunks, [&](std::uint32_t c) {
                std::vector<std::uint32_t> scratch;
                for (std::uint32_t u = c * CHUNK; u < std::min(nt, (c + 1) * CHUNK); ++u) {
                    two_ring(u, scratch);
                    parts[c].insert(parts[c].end(), scratch.begin(), scratch.end());
                    sizes[c].push_back(static_cast<std::uint32_t>(scratch.size()));
                }
            });
        });
        m_two_rings.offsets.assign(nt + 1, 0);
        std::uint32_t t = 0;
        for (std::uint32_t c = 0; c < chunks; ++c) {
            for (auto n : sizes[c]) {
                m_two_rings.offsets[t + 1] = m_two_rings.offsets[t] + n;
                ++t;
            }
            m_two_rings.triangles.insert(m_two_rings.triangles.end(), parts[c].begin(),
                                         parts[c].end());
        }
    });
    return {m_two_rings.triangles.data() + m_two_rings.offsets[t],
            m_two_rings.triangles.data() + m_two_rings.offsets[t + 1]};
}

ComponentSplit split_components(const TriangleMesh& mesh) {
    MeshTopology topo(mesh.triangles, mesh.vertices.size());
    ComponentSplit out;
    const auto nc = topo.component_count();
    out.meshes.resize(nc);
    out.triangle_ids.resize(nc);
    out.vertex_ids.resize(nc);
    constexpr auto NONE = std::numeric_limits<std::uint32_t>::max();
    std::vector<std::uint32_t> local(mesh.vertices.size(), NONE);
    for (std::uint32_t t = 0; t < mesh.triangles.size(); ++t) {
        const auto c = topo.component_of(t);
        auto& m = out.meshes[c];
        TriangleIndices tri{};
        for (int k = 0; k < 3; ++k) {
            const auto v = mesh.triangles[t][k];
            if (local[v] == NONE) {
                local[v] = static_cast<std::uint32_t>(m.vertices.size());
                m.vertices.push_back(mesh.vertices[v]);
                out.vertex_ids[c].push_back(v);
            }
            tri[k] = local[v];
        }
        m.triangles.push_back(tri);
        out.triangle_ids[c].push_back(t);
    }
    return out;
}

}  // namespace proxima
