#include "proxima/frame_pipeline.hpp"

#include <optional>
#include <unordered_set>
#include <utility>
#include <vector>

#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/mesh/mesh.hpp"
#include "proxima/query/penetration.hpp"

namespace proxima {

namespace {

std::string object_label(const std::string& field, const SceneObject& obj) {
    return field + " (object " + std::to_string(obj.id) +
           (obj.name.empty() ? "" : " '" + obj.name + "'") + ")";
}

std::string mesh_label(const std::string& field, const NamedMesh& mesh) {
    return mesh.name.empty() ? field : field + " ('" + mesh.name + "')";
}

Status limit_status(const std::string& scene_id, const char* what, std::uint64_t after,
                    const std::string& limit_name, std::uint64_t limit) {
    return {StatusCode::resource_exhausted,
            "scene " + scene_id + " would hold " + std::to_string(after) + " " + what +
                " after this change, over the limit " + limit_name + " = " + std::to_string(limit)};
}

}  // namespace

Status validate_update(const Scene& scene, const SceneUpdate& update, const FrameLimits& limits,
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
    if (objects > limits.max_objects) {
        return limit_status(scene_id, "objects", objects, limits.max_objects_name,
                            limits.max_objects);
    }
    if (triangles > limits.max_triangles) {
        return limit_status(scene_id, "triangles", triangles, limits.max_triangles_name,
                            limits.max_triangles);
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

namespace {

// CCD interpolates each vertex between its two positions: the primitives must be the same at both
// ends, so a CCD frame may only move vertices.
Status check_moves_only(const SceneUpdate& u) {
    const char* change = !u.replacements.empty() ? "topology_changes"
                         : !u.additions.empty()  ? "additions"
                         : !u.removals.empty()   ? "removals"
                                                 : nullptr;
    if (change == nullptr) {
        return {};
    }
    return invalid_argument(std::string("queries.ccd: a CCD frame may only move vertices, "
                                        "but this frame has ") +
                            change + " (send those in a frame of their own)");
}

}  // namespace

StatusOr<FrameOutcome> run_frame(ProximityEngine& engine, FrameRequest request,
                                 const CancelToken* cancel, const FrameOptions& options) {
    // A frame abandoned before it ran (while it waited for the scene) changes nothing.
    if (cancel != nullptr && cancel->should_stop()) {
        return stop_status(*cancel, "frame");
    }
    Scene& scene = engine.scene();
    if (Status s = validate_update(scene, request.update, options.limits, options.scene_id);
        !s.ok()) {
        return s;
    }
    if (request.ccd) {
        if (Status s = check_moves_only(request.update); !s.ok()) {
            return s;
        }
    }
    // Last: a hook that charges something must not be left charged by a refused frame.
    if (options.before_apply) {
        if (Status s = options.before_apply(scene, request.update); !s.ok()) {
            return s;
        }
    }
    std::optional<Scene> before;
    if (request.ccd) {
        before = scene;  // the positions at t = 0; topologies are shared, not copied
    }
    auto changes = scene.apply(std::move(request.update));
    if (!changes.ok()) {
        if (options.apply_failed) {
            options.apply_failed();
        }
        return changes.status();  // the engine's own all-or-nothing check: the scene is unchanged
    }
    if (options.after_apply) {
        if (Status s = options.after_apply(); !s.ok()) {
            return s;
        }
    }

    // Penetration implies collisions (its pairs are returned too), here as on the wire, so an
    // in-process frame answers exactly what the daemon answers.
    QueryRequest queries = request.queries;
    queries.collisions = queries.collisions || request.penetration;
    auto result = engine.query(queries, cancel);
    if (!result.ok()) {
        return result.status();
    }
    FrameOutcome outcome;
    outcome.object_ids.reserve(scene.size());
    for (const auto& obj : scene.objects()) {
        outcome.object_ids.push_back(obj.id);
    }
    outcome.added_ids = std::move(changes->added_ids);
    outcome.fragment_ids = std::move(changes->fragment_ids);
    outcome.result = std::move(result).value();
    if (request.penetration) {
        auto penetrations = penetration_depths(scene, outcome.result.collisions, cancel);
        if (!penetrations.ok()) {
            return penetrations.status();
        }
        outcome.penetrations = std::move(penetrations).value();
    }
    if (before) {
        std::vector<std::vector<Vec3>> positions;
        positions.reserve(scene.size());
        for (const auto& obj : scene.objects()) {
            positions.push_back(obj.vertices);
        }
        auto ccd = ccd::continuous_collisions(*before, positions, request.ccd_request, cancel);
        if (!ccd.ok()) {
            return ccd.status();
        }
        outcome.ccd = std::move(ccd).value();
    }
    return outcome;
}

}  // namespace proxima
