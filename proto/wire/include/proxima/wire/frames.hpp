#pragma once
// Frames on the wire: the client encodes a FrameRequest into a Frame and the daemon decodes it;
// the daemon encodes its answer into a FrameResult and the client decodes that into a
// FrameOutcome. Both directions live here, so a round trip is testable (tests/wire).

#include <cstddef>
#include <string>

#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/frame.hpp"
#include "proxima/query/penetration.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"
#include "proxima/v1/proxima.pb.h"

namespace proxima::wire {

// --- Requests (client -> daemon) ---

void encode_query(const QueryRequest& request, bool self_points, v1::QuerySpec* out);
// The query fields of a FrameRequest (culler, tolerance, voronoi_cell, self_points, CCD,
// penetration); invalid_argument for an unknown culler or an out-of-range number.
Status decode_queries(const v1::QuerySpec& spec, FrameRequest* out);

void encode_frame(const FrameRequest& frame, const std::string& scene_id, bool float32,
                  v1::Frame* out);
// A Frame in engine terms, as the daemon runs it: SceneUpdate's vectors keep the message's
// order (error messages use these indices), and a frame that asks for penetration runs the
// collisions query too.
StatusOr<FrameRequest> decode_frame(const v1::Frame& frame);

// --- Results (daemon -> client) ---

// Fills everything of a FrameResult but scene_id, frame, penetrations, ccd and
// stats.server_seconds, which the caller knows better. `scene` is the scene the query ran on
// (for object ids in result order). With `self_points` the self entries carry their closest
// points (6 doubles per triangle).
void encode_frame_result(const Scene& scene, const SceneUpdateResult& changes,
                         const QueryResult& result, bool self_points, v1::FrameResult* out);
// The whole outcome of the engine's run_frame (ids, queries, penetrations, CCD), as
// encode_frame_result, encode_penetration and encode_ccd_result write it; no scene_id, frame or
// stats.server_seconds.
void encode_frame_outcome(const FrameOutcome& outcome, bool self_points, v1::FrameResult* out);
void encode_penetration(const Penetration& p, v1::Penetration* out);
void encode_ccd_result(const ccd::CcdResult& result, v1::CcdResult* out);

// Checks the result's internal consistency (list sizes against the object count, object indices
// in range): a malformed result is an internal error, never an out-of-range read later.
StatusOr<FrameOutcome> decode_frame_result(const v1::FrameResult& result);
// A frame's CCD result; object indices are checked against `objects`.
StatusOr<ccd::CcdResult> decode_ccd_result(const v1::CcdResult& in, std::size_t objects);
Penetration decode_penetration(const v1::Penetration& p);

}  // namespace proxima::wire
