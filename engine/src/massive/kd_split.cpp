#include "massive/kd_split.hpp"

#include <algorithm>
#include <limits>

namespace proxima::massive::detail {

namespace {

struct Splitter {
    const TriangleMesh& mesh;
    std::uint64_t max_piece_bytes;
    std::vector<Vec3> centres;
    std::vector<std::uint32_t> stamp;  // per vertex: the last node that counted it
    std::uint32_t node = 0;
    std::vector<std::vector<std::uint32_t>> pieces;

    std::uint64_t vertex_count(std::span<const std::uint32_t> triangles) {
        ++node;
        std::uint64_t count = 0;
        for (auto t : triangles) {
            for (auto v : mesh.triangles[t]) {
                if (stamp[v] != node) {
                    stamp[v] = node;
                    ++count;
                }
            }
        }
        return count;
    }

    // Recursion depth is log2 of the triangle count: at most 32.
    void split(std::span<std::uint32_t> triangles) {
        const auto n = triangles.size();
        if (n == 1 || piece_weight(vertex_count(triangles), n) <= max_piece_bytes) {
            std::vector<std::uint32_t> piece(triangles.begin(), triangles.end());
            std::sort(piece.begin(), piece.end());
            pieces.push_back(std::move(piece));
            return;
        }
        Aabb box;
        for (auto t : triangles) {
            box.extend(centres[t]);
        }
        const Vec3 extent = box.extent();
        int axis = 0;
        if (extent.y > extent[axis]) {
            axis = 1;
        }
        if (extent.z > extent[axis]) {
            axis = 2;
        }
        const auto mid = n / 2;
        std::nth_element(triangles.begin(), triangles.begin() + static_cast<std::ptrdiff_t>(mid),
                         triangles.end(), [&](std::uint32_t a, std::uint32_t b) {
                             const double ca = centres[a][axis];
                             const double cb = centres[b][axis];
                             return ca < cb || (ca == cb && a < b);
                         });
        split(triangles.first(mid));
        split(triangles.subspan(mid));
    }
};

}  // namespace

std::vector<std::vector<std::uint32_t>> kd_split(const TriangleMesh& mesh,
                                                 std::uint64_t max_piece_bytes) {
    Splitter s{mesh, max_piece_bytes, {}, {}, 0, {}};
    s.centres.resize(mesh.triangles.size());
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        const auto& tri = mesh.triangles[t];
        s.centres[t] =
            (mesh.vertices[tri[0]] + mesh.vertices[tri[1]] + mesh.vertices[tri[2]]) / 3.0;
    }
    s.stamp.assign(mesh.vertices.size(), 0);
    std::vector<std::uint32_t> all(mesh.triangles.size());
    for (std::size_t t = 0; t < all.size(); ++t) {
        all[t] = static_cast<std::uint32_t>(t);
    }
    s.split(all);
    return std::move(s.pieces);
}

namespace {
constexpr auto NONE = std::numeric_limits<std::uint32_t>::max();
}  // namespace

PieceBuilder::PieceBuilder(const TriangleMesh& mesh)
    : m_mesh(mesh), m_local(mesh.vertices.size(), NONE) {}

PieceGeometry PieceBuilder::make(std::span<const std::uint32_t> triangles) {
    PieceGeometry piece;
    piece.triangles.reserve(triangles.size());
    piece.source_triangles.assign(triangles.begin(), triangles.end());
    for (auto t : triangles) {
        TriangleIndices out{};
        for (int k = 0; k < 3; ++k) {
            const auto v = m_mesh.triangles[t][k];
            if (m_local[v] == NONE) {
                m_local[v] = static_cast<std::uint32_t>(piece.vertices.size());
                piece.vertices.push_back(m_mesh.vertices[v]);
            }
            out[k] = m_local[v];
        }
        piece.triangles.push_back(out);
    }
    for (auto t : triangles) {
        for (auto v : m_mesh.triangles[t]) {
            m_local[v] = NONE;
        }
    }
    return piece;
}

}  // namespace proxima::massive::detail
