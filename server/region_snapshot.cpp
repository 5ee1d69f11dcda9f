// Snapshot of a model region: the model and room resolved as FetchRegion resolves them, the
// pieces planned, read and rendered by the engine (render::take_region_snapshot, which uses
// massive::plan_region), the answer encoded by proto/wire.
#include "region_snapshot.hpp"

#include <algorithm>
#include <cstdint>
#include <memory>

#include "proxima/render/region_snapshot.hpp"
#include "proxima/wire/snapshot.hpp"
#include "service_internal.hpp"

namespace proxima::server {

Status model_region_snapshot(ProximityService::Shared& shared, const Principal& who,
                             const massive::RegionRequest& region,
                             const render::SnapshotRequest& request, const CancelToken& cancel,
                             v1::SnapshotResponse* response, std::string* extra) {
    auto view = find_model_view(shared, who, region.model, region.room);
    if (!view.ok()) {
        return view.status();
    }
    auto snapshot =
        render::take_region_snapshot(view->store, *shared.models.cache(), view->room_view.get(),
                                     view->object_count, region, request, &cancel);
    if (!snapshot.ok()) {
        return snapshot.status();
    }
    wire::encode_snapshot(*snapshot, response);
    *extra = " model=" + region.model + (region.room.empty() ? "" : " room=" + region.room) +
             " width=" + std::to_string(snapshot->width) +
             " height=" + std::to_string(snapshot->height) +
             " png_bytes=" + std::to_string(snapshot->png.size()) +
             " pieces=" + std::to_string(snapshot->region->pieces) +
             " triangles=" + std::to_string(snapshot->region->triangles) +
             " generation=" + snapshot->region->generation;
    return {};
}

}  // namespace proxima::server
