#pragma once
// C++ client library for proximad. Usable from a simulator's loop: connect once, create a scene,
// then per frame send changed positions and read the results, over one stream. Speaks engine
// types (SceneUpdate, QueryRequest, QueryResult) so results compare directly with an in-process
// ProximityEngine; no gRPC or Protobuf type appears in this header.

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/query/penetration.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"

namespace proxima::client {

struct ConnectOptions {
    // How long connect() waits for the channel to become ready.
    std::chrono::milliseconds connect_timeout{5000};
    // Deadline for each unary call (0: none).
    std::chrono::milliseconds call_timeout{0};
    // Vertex buffers are sent as float64 by default (exact); float32 halves the bytes.
    bool float32_vertices = false;
    // Meshes larger than this many bytes are sent with the chunked UploadObject RPC.
    std::size_t inline_mesh_bytes = 1u << 20;
};

struct RemoteServerInfo {
    std::string version;
    std::string api;
    std::string proximity_backend;
    std::string gl_renderer;
    std::uint64_t live_scenes = 0;
    std::uint64_t live_streams = 0;
    std::uint64_t max_scenes = 0;
    std::uint64_t max_objects_per_scene = 0;
    std::uint64_t max_triangles_per_scene = 0;
    std::uint64_t max_message_bytes = 0;
    std::uint32_t max_frames_in_flight = 0;
};

struct RemoteObject {
    ObjectId id = 0;
    std::string name;
    std::uint32_t vertex_count = 0;
    std::uint32_t triangle_count = 0;
};

struct RemoteScene {
    std::string scene_id;
    std::string name;
    std::vector<RemoteObject> objects;  // result order
    std::uint64_t frames = 0;
    std::uint64_t triangle_count = 0;
};

// One frame to send: the scene changes (object ids are the daemon's) and the queries to run.
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

struct FrameResponse {
    std::string scene_id;
    std::uint64_t frame = 0;
    std::vector<ObjectId> object_ids;                 // result order
    std::vector<ObjectId> added_ids;                  // this frame's additions
    std::vector<std::vector<ObjectId>> fragment_ids;  // per topology change
    QueryResult result;                               // object indices in result order
    std::optional<ccd::CcdResult> ccd;                // when the frame asked for it
    std::vector<Penetration> penetrations;            // when the frame asked for them
    double server_seconds = 0;
};

class FrameStream;

class Client {
  public:
    // Connects to HOST:PORT; fails with unavailable when the daemon does not answer in time.
    static StatusOr<std::unique_ptr<Client>> connect(const std::string& address,
                                                     ConnectOptions options = {});
    ~Client();

    StatusOr<RemoteServerInfo> server_info();
    // Creates a scene with these objects (large meshes are uploaded in chunks).
    StatusOr<RemoteScene> create_scene(const std::string& name,
                                       const std::vector<NamedMesh>& objects);
    StatusOr<RemoteScene> describe_scene(const std::string& scene_id);
    Status delete_scene(const std::string& scene_id);
    // Adds one object through the chunked upload.
    StatusOr<RemoteObject> upload_object(const std::string& scene_id, const NamedMesh& mesh);
    // One-shot frame (the Query RPC).
    StatusOr<FrameResponse> query(const std::string& scene_id, const FrameRequest& frame);
    // Opens a frame stream on an existing scene, or, with an empty scene_id, a stream-owned scene
    // created from the first frame's additions (deleted when the stream ends).
    StatusOr<std::unique_ptr<FrameStream>> open_stream(const std::string& scene_id);

    struct Impl;

  private:
    explicit Client(std::unique_ptr<Impl> impl);
    std::unique_ptr<Impl> m_impl;
};

// A bidirectional frame stream. Lockstep use: send(), then receive(); or pipeline up to the
// server's max_frames_in_flight sends before receiving. Not thread-safe for concurrent sends.
class FrameStream {
  public:
    ~FrameStream();  // cancels the stream if it was not finished
    Status send(const FrameRequest& frame);
    StatusOr<FrameResponse> receive();
    // Half-closes, drains and returns the stream's final status.
    Status finish();
    // Cancels the stream (the daemon stops work on it).
    void cancel();

    struct Impl;
    explicit FrameStream(std::unique_ptr<Impl> impl);

  private:
    std::unique_ptr<Impl> m_impl;
};

}  // namespace proxima::client
