#include <cstdio>

#include "cli/commands.hpp"

namespace proxima::cli {

StatusOr<client::FrameResponse> query_in_temporary_scene(
    client::Client& c, const std::string& scene_name,
    const std::vector<client::InputObject>& objects,
    const std::function<void(client::FrameRequest&, const client::RemoteScene&)>& fill) {
    std::vector<NamedMesh> meshes;
    meshes.reserve(objects.size());
    for (const auto& obj : objects) {
        meshes.push_back(obj.mesh);
    }
    auto scene = c.create_scene(scene_name, meshes);
    if (!scene.ok()) {
        return scene.status();
    }
    client::FrameRequest frame;
    fill(frame, scene.value());
    auto response = c.query(scene->scene_id, frame);
    if (Status deleted = c.delete_scene(scene->scene_id); !deleted.ok()) {
        // The answer is still good; the stale scene is the daemon operator's to notice.
        std::fprintf(stderr, "proxima: warning: could not delete scene %s: %s\n",
                     scene->scene_id.c_str(), deleted.to_string().c_str());
    }
    return response;
}

}  // namespace proxima::cli
