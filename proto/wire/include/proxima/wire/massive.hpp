#pragma once
// Massive models on the wire: transforms, cache counters, VerifyModel's events, the Review
// stream (requests from the client, room events from the daemon) and FetchRegion, in both
// directions.

#include <span>
#include <string>
#include <vector>

#include "proxima/massive/region.hpp"
#include "proxima/massive/review.hpp"
#include "proxima/massive/store.hpp"
#include "proxima/massive/verify.hpp"
#include "proxima/status.hpp"
#include "proxima/v1/proxima.pb.h"

namespace proxima::wire {

// Exactly 12 finite doubles, row-major 3x4 (invalid_argument naming `what` otherwise).
void encode_transform(const massive::Affine& transform, v1::Transform* out);
StatusOr<massive::Affine> decode_transform(const v1::Transform& transform, const std::string& what);

void encode_cache_stats(const massive::CacheStats& stats, v1::CacheStats* out);
massive::CacheStats decode_cache_stats(const v1::CacheStats& stats);

void encode_progress(const massive::Progress& progress, v1::VerifyProgress* out);
massive::Progress decode_progress(const v1::VerifyProgress& progress);

// Names come from the store's objects.
void encode_object_pair(const massive::ObjectPairResult& pair, const massive::Store& store,
                        v1::ObjectPairResult* out);
massive::ObjectPairResult decode_object_pair(const v1::ObjectPairResult& pair, std::string* name_a,
                                             std::string* name_b);

void encode_verify_stats(const massive::VerifyStats& stats, double server_seconds,
                         v1::VerifyStats* out);
massive::VerifyStats decode_verify_stats(const v1::VerifyStats& stats);

// --- Review: requests (client -> daemon) ---

void encode_review_join(const massive::ReviewJoinRequest& join, bool float32,
                        v1::ReviewRequest* out);
void encode_review_pose(const massive::ReviewPoseRequest& pose, v1::ReviewRequest* out);
void encode_review_edit(const massive::ReviewEditRequest& edit, bool float32,
                        v1::ReviewRequest* out);
// The avatar and an added object are decoded as meshes (wire format); the engine validates them
// (validate_mesh) before anything changes.
StatusOr<massive::ReviewRequest> decode_review_request(const v1::ReviewRequest& request);

// --- Review: room events (daemon -> client) ---

void encode_room_event(const massive::RoomEvent& event, v1::ReviewEvent* out);
// Peer updates sent together (oldest first): one as `peer`, several as `peers`.
void encode_peer_updates(std::span<const massive::PeerEvent> peers, v1::ReviewEvent* out);
// A malformed event (empty, an unknown edit kind, a bad transform) is an internal error; so is
// a `peers` batch here (decode_room_events takes those).
StatusOr<massive::RoomEvent> decode_room_event(const v1::ReviewEvent& event);
// Every event a message holds, in order: the one event, or each update of a `peers` batch as a
// PeerEvent (an empty batch is malformed).
StatusOr<std::vector<massive::RoomEvent>> decode_room_events(const v1::ReviewEvent& event);

// --- FetchRegion ---

void encode_region_request(const massive::RegionRequest& request, v1::FetchRegionRequest* out);
// Checks what the message alone can get wrong (an unknown scalar type: invalid_argument naming
// `type`); the daemon checks the rest against the model (massive::check_region_request).
StatusOr<massive::RegionRequest> decode_region_request(const v1::FetchRegionRequest& request);

// A piece's mesh is named after its object, its vertices float32 or float64.
void encode_region_event(const massive::RegionEvent& event, bool float32, v1::RegionEvent* out);
// A malformed event (empty, bad buffers, triangle_ids not one per triangle) is an internal error.
StatusOr<massive::RegionEvent> decode_region_event(const v1::RegionEvent& event);

}  // namespace proxima::wire
