#pragma once
// The Snapshot call's model-region half (region_snapshot.cpp): a served model's region rendered
// like a scene (proxima/render/region_snapshot.hpp), through the shared geometry cache.

#include <string>

#include "proxima/cancel.hpp"
#include "proxima/massive/region.hpp"
#include "proxima/render/snapshot.hpp"
#include "proxima/v1/proxima.pb.h"
#include "service.hpp"

namespace proxima::server {

class Principal;

// Finds the model and (with region.room) the room as FetchRegion does: the token must see the
// model (else NOT_FOUND, as for an unknown one) and may join the room (PERMISSION_DENIED); the
// room must exist (NOT_FOUND) and review this model (FAILED_PRECONDITION). Then renders and
// encodes the response; `extra` gets the log line's details.
Status model_region_snapshot(ProximityService::Shared& shared, const Principal& who,
                             const massive::RegionRequest& region,
                             const render::SnapshotRequest& request, const CancelToken& cancel,
                             v1::SnapshotResponse* response, std::string* extra);

}  // namespace proxima::server
