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
    auto model = find_model(shared, who, region.model);
    if (!model.ok()) {
        return model.status();
    }
    std::shared_ptr<const massive::Store> store = model.value()->store;
    std::shared_ptr<const massive::ModelView::Snapshot> view;
    auto object_count = static_cast<std::uint32_t>(store->objects().size());
    if (!region.room.empty()) {
        if (!who.may_join_room(region.room)) {
            return {StatusCode::permission_denied, "token '" + who.name() +
                                                       "' may not see review room '" + region.room +
                                                       "' (no pattern of its rooms matches)"};
        }
        const std::shared_ptr<Room> room = shared.rooms.find(region.room);
        if (!room) {
            return not_found("room " + region.room +
                             " does not exist (a room lives while it has members)");
        }
        if (room->model().name != region.model) {
            return failed_precondition("room " + region.room + " reviews model '" +
                                       room->model().name + "', not '" + region.model + "'");
        }
        // The room's store (the generation its members see) and one version of its view.
        store = room->view()->store();
        view = room->view()->snapshot();
        object_count = static_cast<std::uint32_t>(store->objects().size());
        for (const auto& o : view->overlay) {
            object_count = std::max(object_count, o.object + 1);
        }
    }
    auto snapshot = render::take_region_snapshot(store, *shared.models.cache(), view.get(),
                                                 object_count, region, request, &cancel);
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
