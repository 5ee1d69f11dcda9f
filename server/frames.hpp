#pragma once
// What every RPC that changes a scene shares: validate a whole change against the scene and the
// limits, apply it (all or nothing), run the frame's queries. Service methods are thin adapters
// around these.

#include <functional>
#include <string>
#include <vector>

#include "config.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"
#include "proxima/v1/proxima.pb.h"
#include "scene_registry.hpp"

namespace proxima::server {

// Checks everything an update could get wrong against this scene, before any change: known and
// distinct object ids (not_found / invalid_argument), vertex counts, index ranges and finite
// coordinates (invalid_argument), the object and triangle limits (resource_exhausted). Messages
// name the request field and index ("positions[2] (object 7)"), the object, and the limit.
// `additions_field` is the request field the additions came from ("additions" in a Frame).
Status validate_update(const Scene& scene, const SceneUpdate& update, const Limits& limits,
                       const std::string& scene_id,
                       const std::string& additions_field = "additions");

// What the scene will hold once `update` (already validated) is applied, in the units of the
// per-token quotas (auth.hpp).
Holding holding_after(const Scene& scene, const SceneUpdate& update);

// The status a stopped token reports, for work refused before it starts.
Status stopped_status(const CancelToken& cancel);

// One frame on a scene: decode, then with the scene's mutex held validate, apply, run the
// queries, encode. A frame that fails before its changes are applied leaves the scene as it was;
// one stopped by `cancel` before applying changes nothing, one stopped during its queries keeps
// its (valid) changes. `after_apply`, when given, runs under the mutex right after the changes
// are applied (a stream registers the scene its first frame created); its failure fails the
// frame. Sets every field of `out`, stats.server_seconds included.
Status run_frame(SceneEntry& entry, const v1::Frame& frame, const Limits& limits,
                 const CancelToken* cancel, v1::FrameResult* out,
                 const std::function<Status()>& after_apply = {});

// Validates and appends objects (CreateScene's inline objects, a finished upload), all or none;
// `field` names them in error messages ("objects").
StatusOr<SceneUpdateResult> add_objects(SceneEntry& entry, std::vector<NamedMesh> meshes,
                                        const Limits& limits, const std::string& field);

}  // namespace proxima::server
