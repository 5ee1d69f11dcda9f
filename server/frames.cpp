#include "frames.hpp"

#include <chrono>
#include <mutex>
#include <optional>
#include <unordered_set>
#include <utility>

#include "proxima/mesh/mesh.hpp"
#include "proxima/wire/frames.hpp"

namespace proxima::server {

namespace {

std::string object_label(const std::string& field, const SceneObject& obj) {
    return field + " (object " + std::to_string(obj.id) +
           (obj.name.empty() ? "" : " '" + obj.name + "'") + ")";
}

std::string mesh_label(const std::string& field, const NamedMesh& mesh) {
    return mesh.name.empty() ? field : field + " ('" + mesh.name + "')";
}

Status limit_status(const std::string& scene_id, const char* what, std::uint64_t after,
                    const char* limit_name, std::uint64_t limit) {
    return {StatusCode::resource_exhausted,
            "scene " + scene_id + " would hold " + std::to_string(after) + " " + what +
                " after this change, over the limit " + limit_name + " = " + std::to_string(limit)};
}

}  // namespace

Status validate_update(const Scene& scene, const SceneUpdate& update, const Limits& limits,
                       const std::string& scene_id, const std::string& additions_field) {
    // Ids first: the limits below need to know which objects go away.
    std::unordered_set<ObjectId> named;
    auto claim = [&](ObjectId id, const std::string& field) -> Status {
        if (scene.index_of(id) < 0) {
            return not_found(field + ": object " + std::to_string(id) + " is not in scene " +
                             scene_id);
        }
        if (!named.insert(id).second) {
            return invalid_argument(field + ": object " + std::to_string(id) +
                                    " is named more than once in one frame");
        }
        return {};
    };
    std::uint64_t objects = scene.size();
    std::uint64_t triangles = scene.triangle_count();
    for (std::size_t i = 0; i < update.removals.size(); ++i) {
        const auto id = update.removals[i];
        if (Status s = claim(id, "removals[" + std::to_string(i) + "]"); !s.ok()) {
            return s;
        }
        objects -= 1;
        triangles -= scene[static_cast<std::size_t>(scene.index_of(id))].triangle_count();
    }
    for (std::size_t i = 0; i < update.replacements.size(); ++i) {
        const auto& r = update.replacements[i];
        if (Status s = claim(r.object, "topology_changes[" + std::to_string(i) + "]"); !s.ok()) {
            return s;
        }
        objects = objects - 1 + r.fragments.size();
        triangles -= scene[static_cast<std::size_t>(scene.index_of(r.object))].triangle_count();
        for (const auto& f : r.fragments) {
            triangles += f.mesh.triangles.size();
        }
    }
    for (std::size_t i = 0; i < update.positions.size(); ++i) {
        if (Status s = claim(update.positions[i].object, "positions[" + std::to_string(i) + "]");
            !s.ok()) {
            return s;
        }
    }
    objects += update.additions.size();
    for (const auto& a : update.additions) {
        triangles += a.mesh.triangles.size();
    }
    // Limits before contents: no point checking a million coordinates of a frame that is refused.
    if (objects > limits.max_objects_per_scene) {
        return limit_status(scene_id, "objects", objects, "max-objects-per-scene",
                            limits.max_objects_per_scene);
    }
    if (triangles > limits.max_triangles_per_scene) {
        return limit_status(scene_id, "triangles", triangles, "max-triangles-per-scene",
                            limits.max_triangles_per_scene);
    }

    for (std::size_t i = 0; i < update.replacements.size(); ++i) {
        const auto& r = update.replacements[i];
        const auto field = "topology_changes[" + std::to_string(i) + "] (object " +
                           std::to_string(r.object) + ") fragments[";
        for (std::size_t f = 0; f < r.fragments.size(); ++f) {
            const auto label = mesh_label(field + std::to_string(f) + "]", r.fragments[f]);
            if (Status s = validate_mesh(r.fragments[f].mesh, label); !s.ok()) {
                return s;
            }
        }
    }
    for (std::size_t i = 0; i < update.positions.size(); ++i) {
        const auto& p = update.positions[i];
        const auto& obj = scene[static_cast<std::size_t>(scene.index_of(p.object))];
        const auto label = object_label("positions[" + std::to_string(i) + "]", obj);
        if (Status s = validate_positions(p.vertices, obj.vertices.size(), label); !s.ok()) {
            return s;
        }
    }
    for (std::size_t i = 0; i < update.additions.size(); ++i) {
        const auto label =
            mesh_label(additions_field + "[" + std::to_string(i) + "]", update.additions[i]);
        if (Status s = validate_mesh(update.additions[i].mesh, label); !s.ok()) {
            return s;
        }
    }
    return {};
}

Holding holding_after(const Scene& scene, const SceneUpdate& update) {
    std::uint64_t objects = scene.size();
    std::uint64_t triangles = scene.triangle_count();
    std::uint64_t vertices = 0;
    for (const auto& obj : scene.objects()) {
        vertices += obj.vertices.size();
    }
    auto drop = [&](ObjectId id) {
        const auto index = scene.index_of(id);
        if (index < 0) {
            return;
        }
        const auto& obj = scene[static_cast<std::size_t>(index)];
        objects -= 1;
        triangles -= obj.triangle_count();
        vertices -= obj.vertices.size();
    };
    auto add = [&](const NamedMesh& mesh) {
        objects += 1;
        triangles += mesh.mesh.triangles.size();
        vertices += mesh.mesh.vertices.size();
    };
    for (const auto id : update.removals) {
        drop(id);
    }
    for (const auto& r : update.replacements) {
        drop(r.object);
        for (const auto& f : r.fragments) {
            add(f);
        }
    }
    for (const auto& a : update.additions) {
        add(a);
    }
    return {objects, triangles, scene_bytes(vertices, triangles)};
}

Status stopped_status(const CancelToken& cancel) {
    if (cancel.cancelled()) {
        return {StatusCode::cancelled, "cancelled by the caller"};
    }
    return {StatusCode::deadline_exceeded, "deadline exceeded before the frame ran"};
}

Status run_frame(SceneEntry& entry, const v1::Frame& frame, const Limits& limits,
                 const CancelToken* cancel, v1::FrameResult* out,
                 const std::function<Status()>& after_apply) {
    const auto start = std::chrono::steady_clock::now();
    auto decoded = wire::decode_frame(frame);
    if (!decoded.ok()) {
        return decoded.status();
    }
    std::lock_guard lock(entry.mutex);
    if (entry.deleted.load()) {
        return not_found("scene " + entry.id + " was deleted");
    }
    // A frame abandoned while it waited for the scene changes nothing.
    if (cancel != nullptr && cancel->should_stop()) {
        return stopped_status(*cancel);
    }
    Scene& scene = entry.engine.scene();
    if (Status s = validate_update(scene, decoded->update, limits, entry.id); !s.ok()) {
        return s;
    }
    // CCD interpolates each vertex between its two positions: the primitives must be the same at
    // both ends, so such a frame may only move vertices. Checked before the owner is charged: a
    // refused frame must leave the charge as it was (fuzz_request found it charged).
    std::optional<Scene> before;
    if (decoded->ccd) {
        const auto& u = decoded->update;
        const char* change = !u.replacements.empty() ? "topology_changes"
                             : !u.additions.empty()  ? "additions"
                             : !u.removals.empty()   ? "removals"
                                                     : nullptr;
        if (change != nullptr) {
            return invalid_argument(std::string("queries.ccd: a CCD frame may only move vertices, "
                                                "but this frame has ") +
                                    change + " (send those in a frame of their own)");
        }
    }
    const Holding before_holding = entry.charged();
    const Holding after_holding = holding_after(scene, decoded->update);
    if (Status s = entry.charge(after_holding); !s.ok()) {
        return s;
    }
    if (decoded->ccd) {
        before = scene;  // the positions at t = 0; topologies are shared, not copied
    }
    auto changes = scene.apply(std::move(decoded->update));
    if (!changes.ok()) {
        (void)entry.charge(before_holding);  // shrinking back cannot fail
        return changes.status();  // the engine's own all-or-nothing check: the scene is unchanged
    }
    ++entry.frames;
    entry.publish_sizes();
    if (after_apply) {
        if (Status s = after_apply(); !s.ok()) {
            return s;
        }
    }
    auto result = entry.engine.query(decoded->queries, cancel);
    if (!result.ok()) {
        return result.status();
    }
    out->set_scene_id(entry.id);
    out->set_frame(frame.frame());
    wire::encode_frame_result(scene, changes.value(), result.value(), decoded->self_points, out);
    if (decoded->penetration) {
        auto penetrations = penetration_depths(scene, result->collisions, cancel);
        if (!penetrations.ok()) {
            return penetrations.status();
        }
        for (const auto& p : penetrations.value()) {
            wire::encode_penetration(p, out->add_penetrations());
        }
    }
    if (before) {
        std::vector<std::vector<Vec3>> positions;
        positions.reserve(scene.size());
        for (const auto& obj : scene.objects()) {
            positions.push_back(obj.vertices);
        }
        auto ccd = ccd::continuous_collisions(*before, positions, decoded->ccd_request, cancel);
        if (!ccd.ok()) {
            return ccd.status();
        }
        wire::encode_ccd_result(ccd.value(), out->mutable_ccd());
    }
    // gRPC would refuse to send it anyway; saying why here gives the client something to act on.
    if (const auto bytes = out->ByteSizeLong(); bytes > limits.max_message_bytes) {
        return {StatusCode::resource_exhausted,
                "the result of frame " + std::to_string(frame.frame()) + " is " +
                    std::to_string(bytes) + " bytes, over the limit max-message-bytes = " +
                    std::to_string(limits.max_message_bytes) +
                    " (request fewer queries, no self_points, or raise the limit)"};
    }
    out->mutable_stats()->set_server_seconds(
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    return {};
}

StatusOr<SceneUpdateResult> add_objects(SceneEntry& entry, std::vector<NamedMesh> meshes,
                                        const Limits& limits, const std::string& field) {
    std::lock_guard lock(entry.mutex);
    if (entry.deleted.load()) {
        return not_found("scene " + entry.id + " was deleted");
    }
    SceneUpdate update;
    update.additions = std::move(meshes);
    Scene& scene = entry.engine.scene();
    if (Status s = validate_update(scene, update, limits, entry.id, field); !s.ok()) {
        return s;
    }
    const Holding before_holding = entry.charged();
    if (Status s = entry.charge(holding_after(scene, update)); !s.ok()) {
        return s;
    }
    auto changes = scene.apply(std::move(update));
    if (changes.ok()) {
        entry.publish_sizes();
    } else {
        (void)entry.charge(before_holding);
    }
    return changes;
}

}  // namespace proxima::server
