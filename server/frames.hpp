#pragma once
// What every RPC that changes a scene shares, the daemon's side of it: the scene entry's mutex, the
// per-token quotas, the limits, stats.server_seconds. The frame rules themselves (validate, apply
// all or nothing, queries, penetration, CCD) are the engine's run_frame
// (proxima/frame_pipeline.hpp).

#include <functional>
#include <mutex>
#include <string>
#include <vector>

#include "config.hpp"
#include "proxima/frame_pipeline.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"
#include "proxima/v1/proxima.pb.h"
#include "scene_registry.hpp"

namespace proxima::server {

// The engine's frame limits (proxima/frame_pipeline.hpp) for the daemon's.
FrameLimits frame_limits(const Limits& limits);

// What the scene will hold once `update` (already validated) is applied, in the units of the
// per-token quotas (auth.hpp).
Holding holding_after(const Scene& scene, const SceneUpdate& update);

// One frame on a scene: decode, then with the scene's mutex held run the engine's frame pipeline
// (proxima/frame_pipeline.hpp: validate, charge the owner's quotas, apply, run the queries),
// encode. A frame that fails before its changes are applied leaves the scene as it was;
// one stopped by `cancel` before applying changes nothing, one stopped during its queries keeps
// its (valid) changes. `after_apply`, when given, runs under the mutex right after the changes
// are applied (a stream registers the scene its first frame created); its failure fails the
// frame. Sets every field of `out`, stats.server_seconds included. `held`: the scene's mutex,
// already held by the caller (a frame run on a gRPC thread, which took it without waiting); the
// frame is then decoded under it. Null: run_frame takes the mutex itself.
Status run_frame(SceneEntry& entry, const v1::Frame& frame, const Limits& limits,
                 const CancelToken* cancel, v1::FrameResult* out,
                 const std::function<Status()>& after_apply = {},
                 const std::unique_lock<std::mutex>* held = nullptr);

// Validates and appends objects (CreateScene's inline objects, a finished upload), all or none;
// `field` names them in error messages ("objects").
StatusOr<SceneUpdateResult> add_objects(SceneEntry& entry, std::vector<NamedMesh> meshes,
                                        const Limits& limits, const std::string& field);

}  // namespace proxima::server
