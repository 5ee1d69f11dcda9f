#include "common/local_scene.hpp"

#include <numeric>

#include "proxima/io/mesh_io.hpp"

namespace proxima::client {

StatusOr<std::vector<InputObject>> load_objects(const std::vector<std::string>& files,
                                                bool split_components,
                                                const MeshReadOptions& read_options) {
    std::vector<InputObject> out;
    for (const auto& file : files) {
        auto mesh = read_mesh(file, read_options);
        if (!mesh.ok()) {
            return mesh.status();
        }
        if (!split_components) {
            InputObject obj;
            obj.file = file;
            obj.mesh.name = file;
            obj.file_triangle.resize(mesh->triangles.size());
            std::iota(obj.file_triangle.begin(), obj.file_triangle.end(), 0u);
            obj.mesh.mesh = std::move(mesh).value();
            out.push_back(std::move(obj));
            continue;
        }
        auto split = proxima::split_components(mesh.value());
        for (std::size_t c = 0; c < split.meshes.size(); ++c) {
            InputObject obj;
            obj.file = file;
            obj.component = static_cast<std::int64_t>(c);
            obj.mesh.name = file + "#" + std::to_string(c);
            obj.mesh.mesh = std::move(split.meshes[c]);
            obj.file_triangle = std::move(split.triangle_ids[c]);
            out.push_back(std::move(obj));
        }
    }
    return out;
}

}  // namespace proxima::client
