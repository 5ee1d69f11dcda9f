#pragma once
// Plays a recorded sequence (common/sequence.hpp) through the engine in this process or through
// a proximad daemon, frame by frame, and measures each frame: `proxima play` prints what this
// returns, and the load harness can drive a daemon with it as a simulator client would.
//
// Remote: the first frame's objects create a scene (CreateScene; large meshes are uploaded in
// chunks), one frame stream carries every frame (in lockstep by default, send then read its
// answer; PlayOptions::in_flight pipelines), and the scene is deleted at the end. Local: a
// ProximityEngine holds the first frame's objects and every frame goes through run_frame, the
// pipeline the daemon runs, so both modes give the same answers. Frame k is diff_frames(frame k-1,
// frame k): positions only, or a topology change. Result object indices are positions in the
// frame's own object list (the update keeps that order; the player checks that the daemon's scene
// has exactly those objects).

#include <cstddef>
#include <functional>
#include <optional>
#include <vector>

#include "client/proxima_client.hpp"
#include "common/sequence.hpp"
#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/query/query.hpp"

namespace proxima::client {

struct PlayedFrame;

struct PlayOptions {
    // The discrete queries of every frame (separation, self, collisions, tolerance, culler).
    QueryRequest queries;
    // Continuous collisions from frame k-1 to frame k, on frames that only move vertices (a
    // frame with a topology change, and the first frame, get no CCD).
    bool ccd = false;
    double ccd_min_distance = 0.0;
    // Pacing: frame k is sent at start + k / fps (never before; at once when the previous answer
    // came later); 0 sends each frame as soon as the previous one is answered.
    double fps = 0.0;
    // play_remote: frames sent before the oldest is answered (pipelining), at most the daemon's
    // max_frames_in_flight; 1 is lockstep. A frame after a topology change waits for that frame's
    // answer (the new objects' ids). Latency is then send to answer, queueing included.
    std::size_t in_flight = 1;
    // Keep every frame's full result in the report (else only the summaries; on_frame still sees
    // the full frame).
    bool keep_results = true;
    // play_local: called on the engine before the first frame (a GPU backend, ...).
    std::function<void(ProximityEngine&)> prepare_engine;
    // play_remote: called once the scene holds the first frame's objects, with the time that
    // took (PlayReport::setup_ms); a failure stops the run with that status.
    std::function<Status(double setup_ms)> on_setup;
    // Called after each frame, in order; a failure stops the run with that status.
    std::function<Status(const PlayedFrame&)> on_frame;
};

struct PlayedFrame {
    std::size_t index = 0;  // in Sequence::frames
    bool topology_change = false;
    std::size_t object_count = 0;
    std::size_t triangle_count = 0;
    QueryResult result;  // object indices: the frame's objects; triangles: the objects' meshes
    std::optional<ccd::CcdResult> ccd;
    // Summaries of `result` (kept when the result is not).
    double min_separation = 0;  // +inf without separation or with one object
    std::size_t collision_count = 0;
    std::size_t tolerance_count = 0;
    double min_self_distance = 0;  // +inf without self
    std::optional<double> toi;     // the earliest CCD contact of the frame
    // Milliseconds: send to answer (remote) or the run_frame call (local); the engine's time for
    // the queries and CCD; how late the frame was sent after its slot (fps pacing, else 0).
    double latency_ms = 0;
    double engine_ms = 0;
    double late_ms = 0;
};

struct PlayReport {
    std::vector<PlayedFrame> frames;
    std::size_t topology_changes = 0;
    double setup_ms = 0;  // creating the scene with the first frame's objects
    double wall_ms = 0;   // from the first frame sent to the last answer
};

StatusOr<PlayReport> play_local(const Sequence& sequence, const PlayOptions& options);
StatusOr<PlayReport> play_remote(Client& client, const Sequence& sequence,
                                 const PlayOptions& options);

// Median, 99th percentile (nearest rank) and maximum of a list of values.
struct LatencySpread {
    double median = 0;
    double p99 = 0;
    double max = 0;
};
LatencySpread spread(std::vector<double> values);

}  // namespace proxima::client
