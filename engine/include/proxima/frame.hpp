#pragma once
// A frame in engine terms, as both ends of the wire see it: what a client asks for (FrameRequest)
// and what the daemon answers (FrameOutcome). proto/wire converts both to and from the messages;
// the client's public header and the daemon use these types, so neither declares its own copy.

#include <cstdint>
#include <optional>
#include <vector>

#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/query/penetration.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scene.hpp"

namespace proxima {

// One frame: the scene changes (object ids are the daemon's) and the queries to run.
// SceneUpdate's vectors keep the message's order, so index k of `update.positions` is
// `positions[k]` of the request (the daemon's error messages use these indices).
struct FrameRequest {
    std::uint64_t frame = 0;
    SceneUpdate update;
    QueryRequest queries;
    bool self_points = false;
    // Continuous collisions from the positions before this frame to those after it (the frame
    // may then only move vertices). ccd.elementary.min_distance is sent; the other CcdRequest
    // fields are the daemon's defaults.
    bool ccd = false;
    ccd::CcdRequest ccd_request;
    // Local penetration vectors of intersecting objects (collisions are returned too).
    bool penetration = false;
};

// A frame's answer: the scene's object ids after the frame and the query results, whose object
// indices are positions in `object_ids` (result order).
struct FrameOutcome {
    std::vector<ObjectId> object_ids;                 // result order
    std::vector<ObjectId> added_ids;                  // this frame's additions
    std::vector<std::vector<ObjectId>> fragment_ids;  // per topology change
    QueryResult result;
    std::optional<ccd::CcdResult> ccd;      // when the frame asked for it
    std::vector<Penetration> penetrations;  // when the frame asked for them
};

}  // namespace proxima
