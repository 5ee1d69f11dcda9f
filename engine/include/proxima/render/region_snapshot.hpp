#pragma once
// Snapshots of a massive model's region (the Snapshot call with `model`, `proxima snapshot
// --model`): the pieces FetchRegion would send (massive::plan_region, read through the shared
// GeometryCache), gathered into one scene object per model object, queried exactly among the
// region's triangles and rendered like a scene snapshot (render::take_snapshot's renderer and
// colours).

#include <memory>

#include "proxima/massive/cache.hpp"
#include "proxima/massive/region.hpp"
#include "proxima/massive/store.hpp"
#include "proxima/render/snapshot.hpp"

namespace proxima::render {

// `view` null: the stored model; otherwise a review room's view (its store must be `store`).
// Checks the snapshot request first (INVALID_ARGUMENT), then the region against the model
// (massive::check_region_request, whose object count `object_count` is); FAILED_PRECONDITION when
// no piece lies within the radius; RESOURCE_EXHAUSTED when the selected pieces hold more than
// MAX_SNAPSHOT_TRIANGLES (region.max_triangles cuts the nearest pieces first, as for
// FetchRegion). Snapshot::region carries the region's counts. Colliding and tolerance pairs are
// pairs of distinct model objects, each object's triangles being the region's (an object cut by
// the radius is only its selected pieces).
StatusOr<Snapshot> take_region_snapshot(const std::shared_ptr<const massive::Store>& store,
                                        massive::GeometryCache& cache,
                                        const massive::ModelView::Snapshot* view,
                                        std::uint32_t object_count,
                                        const massive::RegionRequest& region,
                                        const SnapshotRequest& request,
                                        const CancelToken* cancel = nullptr);

}  // namespace proxima::render
