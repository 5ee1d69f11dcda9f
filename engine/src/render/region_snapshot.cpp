#include "proxima/render/region_snapshot.hpp"

#include <cstdint>
#include <map>
#include <string>
#include <utility>

#include "proxima/cancel.hpp"
#include "proxima/query/query.hpp"

namespace proxima::render {

StatusOr<Snapshot> take_region_snapshot(const std::shared_ptr<const massive::Store>& store,
                                        massive::GeometryCache& cache,
                                        const massive::ModelView::Snapshot* view,
                                        std::uint32_t object_count,
                                        const massive::RegionRequest& region,
                                        const SnapshotRequest& request, const CancelToken* cancel) {
    if (Status s = validate_snapshot_request(request); !s.ok()) {
        return s;
    }
    if (Status s = massive::check_region_request(region, object_count); !s.ok()) {
        return s;
    }
    const massive::RegionPlan plan = massive::plan_region(*store, view, region);
    if (plan.pieces.empty()) {
        return failed_precondition("model " + region.model + ": no piece lies within radius " +
                                   std::to_string(region.radius) + " of the center");
    }
    if (plan.triangles > MAX_SNAPSHOT_TRIANGLES) {
        return Status(StatusCode::resource_exhausted,
                      "model " + region.model + ": the region holds " +
                          std::to_string(plan.triangles) +
                          " triangles, more than a snapshot draws (" +
                          std::to_string(MAX_SNAPSHOT_TRIANGLES) +
                          "); lower the radius or set max_triangles");
    }
    // One scene object per model object, its pieces' triangles in plan order (each piece's
    // vertices appended: pieces of one object are never tested against each other).
    std::map<std::uint32_t, NamedMesh> objects;
    for (const auto& ref : plan.pieces) {
        if (cancel != nullptr && cancel->should_stop()) {
            return stop_status(*cancel, "snapshot");
        }
        auto piece = massive::read_region_piece(store, cache, view, ref);
        if (!piece.ok()) {
            return piece.status();
        }
        NamedMesh& named = objects[piece->object];
        if (named.name.empty()) {
            named.name = piece->object_name;
        }
        const auto offset = static_cast<std::uint32_t>(named.mesh.vertices.size());
        named.mesh.vertices.insert(named.mesh.vertices.end(), piece->vertices.begin(),
                                   piece->vertices.end());
        for (const auto& t : piece->triangles) {
            named.mesh.triangles.push_back({t[0] + offset, t[1] + offset, t[2] + offset});
        }
    }
    ProximityEngine engine;
    for (auto& [index, named] : objects) {
        if (named.name.empty()) {
            named.name = "object " + std::to_string(index);
        }
        auto added = engine.scene().add_object(std::move(named));
        if (!added.ok()) {
            return added.status();
        }
    }
    auto snapshot = take_snapshot(engine, request, cancel);
    if (!snapshot.ok()) {
        return snapshot.status();
    }
    SnapshotRegion counts;
    counts.pieces = plan.pieces.size();
    counts.triangles = plan.triangles;
    counts.objects = objects.size();
    counts.truncated = plan.truncated;
    counts.model_version = view != nullptr ? view->version : 0;
    counts.generation = store->summary().generation;
    snapshot->region = std::move(counts);
    return snapshot;
}

}  // namespace proxima::render
