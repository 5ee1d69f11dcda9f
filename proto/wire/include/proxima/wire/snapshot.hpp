#pragma once
// Snapshots on the wire (the Snapshot RPC): the client encodes a render::SnapshotRequest, the
// daemon decodes and validates it, and encodes its render::Snapshot back.

#include <optional>
#include <string>

#include "proxima/massive/region.hpp"
#include "proxima/render/snapshot.hpp"
#include "proxima/status.hpp"
#include "proxima/v1/proxima.pb.h"

namespace proxima::wire {

void encode_camera(const render::Camera& camera, v1::Camera* out);
// Unset `up`: +z; unset (0) fov: 45 degrees. Not validated (render::validate_camera does that).
render::Camera decode_camera(const v1::Camera& camera);

void encode_snapshot_request(const std::string& scene_id, const render::SnapshotRequest& request,
                             v1::SnapshotRequest* out);
// invalid_argument for a size outside the limits, a bad camera or tolerance
// (render::validate_snapshot_request), before the scene is looked at.
StatusOr<render::SnapshotRequest> decode_snapshot_request(const v1::SnapshotRequest& request);

// A model region's snapshot: `region`'s model, center, radius, room and max_triangles (its
// `objects` and `float64` are not part of a snapshot and are ignored) instead of a scene id.
void encode_model_snapshot_request(const massive::RegionRequest& region,
                                   const render::SnapshotRequest& request,
                                   v1::SnapshotRequest* out);
// The region a request names; invalid_argument unless exactly one of scene_id and model is set.
// nullopt for a scene's snapshot. The region itself is checked against the model by the daemon
// (massive::check_region_request).
StatusOr<std::optional<massive::RegionRequest>> decode_snapshot_region(
    const v1::SnapshotRequest& request);

void encode_snapshot(const render::Snapshot& snapshot, v1::SnapshotResponse* out);
// internal when the answer is malformed (no PNG, a size of 0).
StatusOr<render::Snapshot> decode_snapshot(const v1::SnapshotResponse& response);

}  // namespace proxima::wire
