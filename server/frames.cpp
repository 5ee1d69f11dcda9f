#include "frames.hpp"

#include <chrono>
#include <mutex>
#include <utility>

#include "proxima/wire/frames.hpp"

namespace proxima::server {

FrameLimits frame_limits(const Limits& limits) {
    FrameLimits out;
    out.max_objects = limits.max_objects_per_scene;
    out.max_triangles = limits.max_triangles_per_scene;
    return out;
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

Status run_frame(SceneEntry& entry, const v1::Frame& frame, const Limits& limits,
                 const CancelToken* cancel, v1::FrameResult* out,
                 const std::function<Status()>& after_apply,
                 const std::unique_lock<std::mutex>* held) {
    const auto start = std::chrono::steady_clock::now();
    auto decoded = wire::decode_frame(frame);
    if (!decoded.ok()) {
        return decoded.status();
    }
    const bool self_points = decoded->self_points;
    std::unique_lock lock(entry.mutex, std::defer_lock);
    if (held == nullptr) {
        lock.lock();
    } else if (held->mutex() != &entry.mutex || !held->owns_lock()) {
        return {StatusCode::internal, "run_frame: the lock held is not scene " + entry.id + "'s"};
    }
    if (entry.deleted.load()) {
        return not_found("scene " + entry.id + " was deleted");
    }
    // The engine's pipeline validates everything first; the owner is charged last, so a refused
    // frame leaves the charge as it was (fuzz_request found it charged).
    FrameOptions options;
    options.limits = frame_limits(limits);
    options.scene_id = entry.id;
    const Holding before_holding = entry.charged();
    options.before_apply = [&](const Scene& scene, const SceneUpdate& update) {
        return entry.charge(holding_after(scene, update));
    };
    options.apply_failed = [&] { (void)entry.charge(before_holding); };  // shrinking cannot fail
    options.after_apply = [&]() -> Status {
        ++entry.frames;
        entry.publish_sizes();
        return after_apply ? after_apply() : Status{};
    };
    auto outcome = proxima::run_frame(entry.engine, std::move(decoded).value(), cancel, options);
    if (!outcome.ok()) {
        return outcome.status();
    }
    out->set_scene_id(entry.id);
    out->set_frame(frame.frame());
    wire::encode_frame_outcome(outcome.value(), self_points, out);
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
    if (Status s = validate_update(scene, update, frame_limits(limits), entry.id, field); !s.ok()) {
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
