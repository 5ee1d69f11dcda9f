#include "common/local_scene.hpp"

#include <algorithm>
#include <array>
#include <map>
#include <numeric>
#include <utility>

#include "proxima/mesh/mesh.hpp"

namespace proxima::client {

void split_objects(const std::string& file, TriangleMesh mesh,
                   std::vector<std::uint32_t> file_vertex, bool split_components,
                   std::vector<InputObject>& out) {
    if (file_vertex.empty()) {
        file_vertex.resize(mesh.vertices.size());
        std::iota(file_vertex.begin(), file_vertex.end(), 0u);
    }
    if (!split_components) {
        InputObject obj;
        obj.file = file;
        obj.mesh.name = file;
        obj.file_triangle.resize(mesh.triangles.size());
        std::iota(obj.file_triangle.begin(), obj.file_triangle.end(), 0u);
        obj.file_vertex = std::move(file_vertex);
        obj.mesh.mesh = std::move(mesh);
        out.push_back(std::move(obj));
        return;
    }
    auto split = proxima::split_components(mesh);
    for (std::size_t c = 0; c < split.meshes.size(); ++c) {
        InputObject obj;
        obj.file = file;
        obj.component = static_cast<std::int64_t>(c);
        obj.mesh.name = file + "#" + std::to_string(c);
        obj.mesh.mesh = std::move(split.meshes[c]);
        obj.file_triangle = std::move(split.triangle_ids[c]);
        obj.file_vertex.reserve(split.vertex_ids[c].size());
        for (const auto v : split.vertex_ids[c]) {
            obj.file_vertex.push_back(file_vertex[v]);
        }
        out.push_back(std::move(obj));
    }
}

StatusOr<std::vector<InputObject>> load_objects(const std::vector<std::string>& files,
                                                bool split_components, WeldMode weld) {
    std::vector<InputObject> out;
    MeshReadOptions options;
    options.weld = weld;
    for (const auto& file : files) {
        std::vector<std::uint32_t> file_vertex;
        auto mesh = read_mesh(file, options, &file_vertex);
        if (!mesh.ok()) {
            return mesh.status();
        }
        split_objects(file, std::move(mesh).value(), std::move(file_vertex), split_components, out);
    }
    return out;
}

std::vector<std::vector<std::uint32_t>> file_edge_ids(const std::vector<InputObject>& objects) {
    using Edge = std::array<std::uint32_t, 2>;
    // Each object's edges in file vertex ids; a file's edge list is the union over its objects
    // (its components, or the one object), sorted. The welded-to-file vertex map is increasing,
    // so an unsplit object's own order is the file's.
    std::vector<std::vector<Edge>> edges(objects.size());
    std::map<std::string, std::vector<Edge>> per_file;
    for (std::size_t i = 0; i < objects.size(); ++i) {
        const auto& o = objects[i];
        const MeshTopology topology(o.mesh.mesh.triangles, o.mesh.mesh.vertices.size());
        for (const auto& e : ccd::mesh_edges(topology)) {
            const std::uint32_t a = o.file_vertex[e[0]];
            const std::uint32_t b = o.file_vertex[e[1]];
            edges[i].push_back({std::min(a, b), std::max(a, b)});
        }
        auto& all = per_file[o.file];
        all.insert(all.end(), edges[i].begin(), edges[i].end());
    }
    for (auto& [file, all] : per_file) {
        std::sort(all.begin(), all.end());
        all.erase(std::unique(all.begin(), all.end()), all.end());
    }
    std::vector<std::vector<std::uint32_t>> out(objects.size());
    for (std::size_t i = 0; i < objects.size(); ++i) {
        const auto& all = per_file[objects[i].file];
        out[i].reserve(edges[i].size());
        for (const auto& e : edges[i]) {
            out[i].push_back(static_cast<std::uint32_t>(
                std::lower_bound(all.begin(), all.end(), e) - all.begin()));
        }
    }
    return out;
}

ccd::CcdPair in_file_numbering(const std::vector<InputObject>& objects,
                               const std::vector<std::vector<std::uint32_t>>& file_edges,
                               const ccd::CcdPair& pair) {
    ccd::CcdPair p = pair;
    const auto& a = objects[p.object];
    const auto& b = objects[p.other];
    if (p.kind == ccd::CcdKind::vertex_face) {
        p.primitive = a.file_vertex[p.primitive];
        p.other_primitive = b.file_triangle[p.other_primitive];
    } else {
        p.primitive = file_edges[p.object][p.primitive];
        p.other_primitive = file_edges[p.other][p.other_primitive];
    }
    for (std::size_t k = 0; k < ccd::vertex_count(p.kind); ++k) {
        p.vertices[k] = a.file_vertex[p.vertices[k]];
    }
    for (std::size_t k = 0; k < ccd::other_vertex_count(p.kind); ++k) {
        p.other_vertices[k] = b.file_vertex[p.other_vertices[k]];
    }
    return p;
}

}  // namespace proxima::client
