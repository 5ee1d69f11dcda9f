#pragma once
// The frame pipeline: the one place that runs a FrameRequest on an engine's scene, for the daemon
// (after proto/wire decoded the Frame) and for the CLI's local mode alike. Its rules:
//   1. a token that already says stop refuses the frame before anything is looked at;
//   2. everything is validated before anything changes (ids, limits, vertex counts, indices,
//      finite coordinates; validate_update), and a CCD frame may only move vertices;
//   3. `before_apply` (the daemon charges its quotas) may still refuse the frame;
//   4. a CCD frame keeps a copy of the scene (its positions at t = 0), then the changes are
//      applied all or nothing and `after_apply` runs;
//   5. the queries, then penetration vectors of the collisions, then CCD from the copy to now.
// A frame refused in 1-4 leaves the scene bit-identical. One stopped or failing in 5 keeps its
// (valid) changes and reports the status.

#include <cstdint>
#include <functional>
#include <limits>
#include <string>

#include "proxima/cancel.hpp"
#include "proxima/frame.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"

namespace proxima {

// Sizes a scene may reach through a change; over one, the change is refused whole with
// resource_exhausted naming the limit (by `*_name`, the daemon's flag). Unlimited by default.
struct FrameLimits {
    std::uint64_t max_objects = std::numeric_limits<std::uint64_t>::max();
    std::uint64_t max_triangles = std::numeric_limits<std::uint64_t>::max();
    std::string max_objects_name = "max-objects-per-scene";
    std::string max_triangles_name = "max-triangles-per-scene";
};

struct FrameOptions {
    FrameLimits limits;
    // How messages name the scene ("object 7 is not in scene <scene_id>").
    std::string scene_id;
    // After validation, before any change: a failure refuses the frame with the scene unchanged.
    // Gets the scene and the (validated) update.
    std::function<Status(const Scene&, const SceneUpdate&)> before_apply;
    // When Scene::apply refuses an update that passed validation (the scene is unchanged), after
    // `before_apply` succeeded: undo what it did.
    std::function<void()> apply_failed;
    // Right after the changes are applied; a failure fails the frame (the changes stay).
    std::function<Status()> after_apply;
};

// Checks everything an update could get wrong against this scene, before any change: known and
// distinct object ids (not_found / invalid_argument), the object and triangle limits
// (resource_exhausted), vertex counts, index ranges and finite coordinates (invalid_argument).
// Messages name the request field and index ("positions[2] (object 7)"), the object, and the
// limit. `additions_field` is the request field the additions came from ("additions" in a Frame).
Status validate_update(const Scene& scene, const SceneUpdate& update, const FrameLimits& limits,
                       const std::string& scene_id,
                       const std::string& additions_field = "additions");

// Runs one frame on `engine`'s scene (the rules above). `cancel` may be null. The outcome's
// ccd is set when the request asked for CCD, its penetrations when it asked for penetration.
StatusOr<FrameOutcome> run_frame(ProximityEngine& engine, FrameRequest request,
                                 const CancelToken* cancel, const FrameOptions& options = {});

}  // namespace proxima
