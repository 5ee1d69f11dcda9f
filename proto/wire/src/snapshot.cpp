#include "proxima/wire/snapshot.hpp"

#include <algorithm>
#include <cstdint>
#include <optional>
#include <utility>

#include "proxima/wire/buffers.hpp"

namespace proxima::wire {

void encode_camera(const render::Camera& camera, v1::Camera* out) {
    encode_vec3(camera.eye, out->mutable_eye());
    encode_vec3(camera.target, out->mutable_target());
    encode_vec3(camera.up, out->mutable_up());
    out->set_fov_degrees(camera.fov_degrees);
}

render::Camera decode_camera(const v1::Camera& camera) {
    render::Camera out;
    out.eye = decode_vec3(camera.eye());
    out.target = decode_vec3(camera.target());
    if (camera.has_up()) {
        out.up = decode_vec3(camera.up());
    }
    if (camera.fov_degrees() != 0) {
        out.fov_degrees = camera.fov_degrees();
    }
    return out;
}

void encode_snapshot_request(const std::string& scene_id, const render::SnapshotRequest& request,
                             v1::SnapshotRequest* out) {
    out->set_scene_id(scene_id);
    if (request.render.camera) {
        encode_camera(*request.render.camera, out->mutable_camera());
    }
    out->set_width(static_cast<std::uint32_t>(std::max(request.render.width, 0)));
    out->set_height(static_cast<std::uint32_t>(std::max(request.render.height, 0)));
    out->set_collisions(request.collisions);
    if (request.tolerance) {
        out->set_tolerance(*request.tolerance);
    }
    out->set_separation(request.segments);
}

StatusOr<render::SnapshotRequest> decode_snapshot_request(const v1::SnapshotRequest& request) {
    render::SnapshotRequest out;
    if (request.width() > render::MAX_SNAPSHOT_SIDE ||
        request.height() > render::MAX_SNAPSHOT_SIDE) {
        // Checked here, in the message's own type: an int could not hold every uint32.
        return invalid_argument("snapshot: width and height must be in [1, " +
                                std::to_string(render::MAX_SNAPSHOT_SIDE) + "], not " +
                                std::to_string(request.width()) + "x" +
                                std::to_string(request.height()));
    }
    out.render.width = static_cast<int>(request.width());
    out.render.height = static_cast<int>(request.height());
    if (request.has_camera()) {
        out.render.camera = decode_camera(request.camera());
    }
    out.collisions = request.collisions();
    if (request.has_tolerance()) {
        out.tolerance = request.tolerance();
    }
    out.segments = request.separation();
    if (Status s = render::validate_snapshot_request(out); !s.ok()) {
        return s;
    }
    return out;
}

void encode_model_snapshot_request(const massive::RegionRequest& region,
                                   const render::SnapshotRequest& request,
                                   v1::SnapshotRequest* out) {
    encode_snapshot_request({}, request, out);
    out->set_model(region.model);
    encode_vec3(region.center, out->mutable_center());
    out->set_radius(region.radius);
    out->set_room(region.room);
    out->set_max_triangles(region.max_triangles);
}

StatusOr<std::optional<massive::RegionRequest>> decode_snapshot_region(
    const v1::SnapshotRequest& request) {
    if (!request.scene_id().empty() && !request.model().empty()) {
        return invalid_argument("snapshot: set one of scene_id and model, not both (scene '" +
                                request.scene_id() + "', model '" + request.model() + "')");
    }
    if (request.scene_id().empty() && request.model().empty()) {
        return invalid_argument(
            "snapshot: set scene_id (a scene) or model (a massive model's region)");
    }
    if (request.model().empty()) {
        if (!request.room().empty() || request.has_center() || request.radius() != 0 ||
            request.max_triangles() != 0) {
            return invalid_argument(
                "snapshot: center, radius, room and max_triangles are for a model region (set "
                "model, not scene_id)");
        }
        return std::optional<massive::RegionRequest>{};
    }
    massive::RegionRequest out;
    out.model = request.model();
    out.center = decode_vec3(request.center());
    out.radius = request.radius();
    out.room = request.room();
    out.max_triangles = request.max_triangles();
    return std::optional<massive::RegionRequest>(std::move(out));
}

void encode_snapshot(const render::Snapshot& snapshot, v1::SnapshotResponse* out) {
    out->set_png(snapshot.png);
    encode_camera(snapshot.camera, out->mutable_camera());
    out->set_width(static_cast<std::uint32_t>(snapshot.width));
    out->set_height(static_cast<std::uint32_t>(snapshot.height));
    out->set_gl_renderer(snapshot.renderer);
    out->set_collision_count(snapshot.collision_count);
    out->set_tolerance_count(snapshot.tolerance_count);
    out->set_segment_count(snapshot.segment_count);
    if (snapshot.region) {
        auto* region = out->mutable_region();
        region->set_pieces(snapshot.region->pieces);
        region->set_triangles(snapshot.region->triangles);
        region->set_objects(snapshot.region->objects);
        region->set_truncated(snapshot.region->truncated);
        region->set_model_version(snapshot.region->model_version);
        region->set_generation(snapshot.region->generation);
    }
}

StatusOr<render::Snapshot> decode_snapshot(const v1::SnapshotResponse& response) {
    if (response.png().empty() || response.width() == 0 || response.height() == 0 ||
        response.width() > render::MAX_SNAPSHOT_SIDE ||
        response.height() > render::MAX_SNAPSHOT_SIDE) {
        return Status(StatusCode::internal,
                      "the daemon's snapshot is malformed (no PNG or a bad size)");
    }
    render::Snapshot out;
    out.png = response.png();
    out.camera = decode_camera(response.camera());
    out.width = static_cast<int>(response.width());
    out.height = static_cast<int>(response.height());
    out.renderer = response.gl_renderer();
    out.collision_count = response.collision_count();
    out.tolerance_count = response.tolerance_count();
    out.segment_count = response.segment_count();
    if (response.has_region()) {
        render::SnapshotRegion region;
        region.pieces = response.region().pieces();
        region.triangles = response.region().triangles();
        region.objects = response.region().objects();
        region.truncated = response.region().truncated();
        region.model_version = response.region().model_version();
        region.generation = response.region().generation();
        out.region = std::move(region);
    }
    return out;
}

}  // namespace proxima::wire
