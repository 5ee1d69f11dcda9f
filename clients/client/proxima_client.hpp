#pragma once
// C++ client library for proximad. Usable from a simulator's loop: connect once, create a scene,
// then per frame send changed positions and read the results, over one stream. Speaks engine
// types (SceneUpdate, QueryRequest, QueryResult) so results compare directly with an in-process
// ProximityEngine; no gRPC or Protobuf type appears in this header.

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/frame.hpp"
#include "proxima/massive/avatar.hpp"
#include "proxima/massive/region.hpp"
#include "proxima/massive/review.hpp"
#include "proxima/massive/verify.hpp"
#include "proxima/query/penetration.hpp"
#include "proxima/query/query.hpp"
#include "proxima/render/snapshot.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"

namespace proxima::client {

// Transport security (TLS). The daemon presents a PEM certificate, which the client verifies
// against `root_ca_pem`; for mutual TLS the client presents its own certificate and key too.
struct TlsOptions {
    // PEM root certificate(s) the daemon's certificate must chain to; empty: the system's roots.
    std::string root_ca_pem;
    // Mutual TLS: this client's PEM certificate (chain) and private key, both or neither.
    std::string client_cert_pem;
    std::string client_key_pem;
    // The name the daemon's certificate must hold (a SAN) instead of the address's host, e.g.
    // "localhost" when connecting to 127.0.0.1; empty: the host of the address.
    std::string server_name_override;
};

// The gRPC code name of a status this library returned: the engine's name ("NOT_FOUND",
// "UNAUTHENTICATED", ...), or for the gRPC codes the engine has no name for, which arrive as
// internal with "gRPC NAME: " in front of the message, that NAME ("UNIMPLEMENTED", ...).
std::string grpc_code_name(const Status& status);
// "UNAUTHENTICATED: <the daemon's message>": Status::to_string with grpc_code_name.
std::string describe_status(const Status& status);

// Reads TlsOptions from PEM files (an empty path leaves that part empty). The error names the
// file and the problem: not_found for a missing file, invalid_argument for one that holds no
// PEM certificate (or key), or for a certificate without a key (and the reverse).
StatusOr<TlsOptions> load_tls_files(const std::string& root_ca_file,
                                    const std::string& client_cert_file = {},
                                    const std::string& client_key_file = {});

// A bearer token kept in a file: its first line, surrounding whitespace trimmed. Errors (missing
// or unreadable file, an empty first line, characters that cannot travel in a gRPC header) name
// the file. When the file can be read by every user, `warning` (if given) receives a sentence
// saying so: the token is a password.
StatusOr<std::string> read_token_file(const std::string& path, std::string* warning = nullptr);

// One failed attempt that will be retried, as RetryOptions::on_retry sees it.
struct RetryEvent {
    std::string operation;  // the RPC ("GetServerInfo", "connect", "recover scene", ...)
    int attempt = 0;        // the attempt that failed, from 1
    Status status;          // its error (always unavailable)
    std::chrono::milliseconds delay{0};  // the sleep before the next attempt
};

// Reconnecting with exponential backoff and full jitter. An attempt that fails with UNAVAILABLE
// (no daemon listening, connection refused or reset, the daemon shutting down) is retried after
// a sleep drawn uniformly from [0, min(max_backoff, initial_backoff * multiplier^(attempt-1))];
// every other code (INVALID_ARGUMENT, NOT_FOUND, UNAUTHENTICATED, RESOURCE_EXHAUSTED, ...) is
// returned at once. Which calls retry is in docs/api.md ("Tokens, TLS and reconnecting"): those
// safe to repeat.
struct RetryOptions {
    // Attempts per call, the first included; 1 never retries.
    int max_attempts = 5;
    std::chrono::milliseconds initial_backoff{100};
    std::chrono::milliseconds max_backoff{5000};
    double multiplier = 2.0;
    // No retry whose sleep would end later than this after the first attempt began (0: only
    // max_attempts bounds it).
    std::chrono::milliseconds max_total{10000};
    // Full jitter spreads clients that lost one daemon over the backoff window; false sleeps
    // exactly the cap (predictable, for tests and single clients).
    bool jitter = true;
    // Called before each sleep (from the calling thread); for logs, counters and tests.
    std::function<void(const RetryEvent&)> on_retry;
};

struct ConnectOptions {
    // How long connect() waits for the channel to become ready, per attempt.
    std::chrono::milliseconds connect_timeout{5000};
    // Bearer token: every call (unary, streams, uploads, massive models) carries the metadata
    // `authorization: Bearer <token>`. Empty: no authorization header.
    std::string token;
    // TLS settings; none: a plaintext channel.
    std::optional<TlsOptions> tls;
    // Deadline for each unary call (0: none).
    std::chrono::milliseconds call_timeout{0};
    // Vertex buffers are sent as float64 by default (exact); float32 halves the bytes.
    bool float32_vertices = false;
    // Meshes larger than this many bytes are sent with the chunked UploadObject RPC.
    std::size_t inline_mesh_bytes = 1u << 20;
    // Reconnect and retry policy of connect() and of the calls that are safe to repeat.
    RetryOptions retry;
    // Routing key for a load balancer in front of several daemons (docs/deploy.md): every call
    // carries the metadata `x-proxima-route: <route>`, so HAProxy's consistent hash sends every
    // call of one scene or room to the same daemon. Pick it before creating the scene (its name,
    // for example) and use one Client per route. Empty: the Client picks a random route of its
    // own ("client-" and 16 hex digits), so all its calls still meet on one daemon, and a review
    // stream carries its room's name instead. The daemon itself ignores the header.
    std::string route;
};

// The metadata key of ConnectOptions::route.
inline constexpr const char* ROUTE_HEADER = "x-proxima-route";

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
    // Who the daemon says this client is (the token's name; "" when it checks no tokens) and
    // that token's quotas (0: unlimited).
    std::string principal;
    std::uint64_t quota_max_scenes = 0;
    std::uint64_t quota_max_objects = 0;
    std::uint64_t quota_max_triangles = 0;
    std::uint64_t quota_max_bytes_held = 0;
    std::uint64_t quota_max_bytes_in_flight = 0;
    double quota_max_frames_per_second = 0;
    std::uint64_t quota_max_streams = 0;
    bool gpu_active = false;
    std::string gpu_fallback_reason;
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

// One frame to send: the scene changes (object ids are the daemon's) and the queries to run
// (fields: frame, update, queries, self_points, ccd, ccd_request, penetration). The engine's type
// (proxima/frame.hpp), shared with the daemon and proto/wire.
using FrameRequest = ::proxima::FrameRequest;

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
    // ResilientScene only: true on the first response after the session re-created its scene on
    // a daemon that had gone away (this response's frame was re-sent on the new scene).
    bool recreated_scene = false;
};

// --- Massive models (ListModels, VerifyModel, Review) ---

struct RemoteModel {
    std::string name;  // the store's subdirectory of the daemon's --models DIR
    std::uint64_t objects = 0;
    std::uint64_t pieces = 0;
    std::uint64_t triangles = 0;
    std::uint64_t vertices = 0;
    std::uint64_t split_objects = 0;
    std::uint64_t chunks = 0;
    std::uint64_t bytes = 0;
    std::string generation;
    Aabb box;
};

struct RemoteModelList {
    std::string models_dir;  // "" when the daemon serves no models
    std::vector<RemoteModel> models;
    // Stores the daemon could not open: name and status ("DATA_LOSS: ...").
    std::vector<std::pair<std::string, std::string>> unavailable;
    std::uint64_t cache_budget_bytes = 0;
    massive::CacheStats cache;
};

// An object pair within the tolerance, with the objects' names.
struct NamedObjectPair {
    massive::ObjectPairResult pair;
    std::string name_a;
    std::string name_b;
};

struct VerifyEvent {
    enum class Kind { progress, pair };
    Kind kind = Kind::progress;
    massive::Progress progress;  // kind == progress (the latest; the daemon coalesces them)
    NamedObjectPair pair;        // kind == pair
};

struct RemoteVerifySummary {
    massive::VerifyStats stats;
    double server_seconds = 0;
};

// Joining a review room (fields: room, model, member, avatar in its own coordinates, tolerance,
// nearest = true). These review names are the engine's types (proxima/massive/review.hpp),
// shared with the daemon and proto/wire.
using ReviewJoin = massive::ReviewJoinRequest;

// What members see of each other's poses.
using ReviewPoseSummary = massive::PoseSummary;

struct ReviewMemberInfo {
    std::string name;
    bool has_pose = false;
    std::uint64_t sequence = 0;
    massive::Affine transform;
    ReviewPoseSummary summary;
};

struct ReviewJoined {
    std::string room;
    std::string model;
    std::string generation;
    std::vector<ReviewMemberInfo> members;  // this member last
    std::uint64_t model_version = 0;
    std::uint32_t object_count = 0;
};

// A pose's answer, in the engine's type (object indices are the room's: stored objects, then
// added ones), with the objects' names beside it, the edits it saw (model_version) and
// server_seconds.
using ReviewPoseResult = massive::PoseResult;

struct ReviewPeerUpdate {
    std::string member;
    std::uint64_t sequence = 0;
    massive::Affine transform;
    ReviewPoseSummary summary;
    std::uint64_t model_version = 0;
};

using ReviewEditKind = massive::EditKind;  // move, add, remove

// An edit the room applied (fields: member who edited, sequence, what, object: the moved /
// deleted object or the added object's new index, object_name, model_version).
using ReviewEditApplied = massive::EditEvent;

struct ReviewEvent {
    enum class Kind { joined, result, peer, edit_applied, member_joined, member_left };
    Kind kind = Kind::joined;
    ReviewJoined joined;      // kind == joined
    ReviewPoseResult result;  // kind == result
    ReviewPeerUpdate peer;    // kind == peer
    ReviewEditApplied edit;   // kind == edit_applied
    std::string member;       // kind == member_joined / member_left
};

// A region of a model for viewers (FetchRegion; fields: model, center, radius (0: the whole
// model), room (its edited view), objects (only these), max_triangles, float64), and what the
// daemon streams back: pieces (nearest first; vertices, triangles, each triangle's id in its
// whole object, box, distance), progress, and the summary last. The engine's types
// (proxima/massive/region.hpp), shared with the daemon and proto/wire.
using RegionRequest = massive::RegionRequest;
using RegionPiece = massive::RegionPiece;
using RegionProgress = massive::RegionProgress;
using RegionSummary = massive::RegionSummary;
using RegionEvent = massive::RegionEvent;  // a RegionPiece or a RegionProgress (or the summary)

class FrameStream;
class ReviewSession;

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
    // An offscreen PNG of the scene, results coloured (the Snapshot RPC; the scene is unchanged).
    StatusOr<render::Snapshot> snapshot(const std::string& scene_id,
                                        const render::SnapshotRequest& request);
    // An offscreen PNG of a served massive model's region (the Snapshot RPC with `model`): the
    // pieces FetchRegion would send for `region` (its model, center, radius, room and
    // max_triangles; `objects` and `float64` are ignored), coloured and drawn as for a scene. The
    // answer's `region` holds the pieces, triangles and objects drawn. With a room, the call is
    // routed by the room's name (as join_review), unless ConnectOptions::route was chosen.
    StatusOr<render::Snapshot> snapshot_region(const massive::RegionRequest& region,
                                               const render::SnapshotRequest& request);
    // Opens a frame stream on an existing scene, or, with an empty scene_id, a stream-owned scene
    // created from the first frame's additions (deleted when the stream ends).
    StatusOr<std::unique_ptr<FrameStream>> open_stream(const std::string& scene_id);

    // The daemon's massive models (it rescans its --models DIR first) and its cache counters.
    StatusOr<RemoteModelList> list_models();
    // Static verification of a model (VerifyModel). Each event (progress, then each object pair
    // as it is final) goes to `on_event` as it arrives; returning false cancels the call (the
    // answer is then `cancelled`). `timeout` 0: no deadline. Returns the summary.
    StatusOr<RemoteVerifySummary> verify_model(
        const std::string& model, double tolerance,
        const std::function<bool(const VerifyEvent&)>& on_event = {},
        std::chrono::milliseconds timeout = std::chrono::milliseconds(0));
    // A region of a model (FetchRegion). Each piece and progress event goes to `on_event` as it
    // arrives (returning false cancels the call: the answer is then `cancelled`); the summary is
    // returned. Repeated on UNAVAILABLE only until the caller has seen an event. `timeout` 0: no
    // deadline.
    StatusOr<RegionSummary> fetch_region(
        const RegionRequest& request, const std::function<bool(const RegionEvent&)>& on_event = {},
        std::chrono::milliseconds timeout = std::chrono::milliseconds(0));
    // Joins (or creates) a review room: sends the join and waits up to `timeout` for the
    // daemon's `joined` (the members and their last poses), or its error.
    StatusOr<std::unique_ptr<ReviewSession>> join_review(
        const ReviewJoin& join, std::chrono::milliseconds timeout = std::chrono::seconds(30));

    struct Impl;

  private:
    friend class ResilientScene;
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

// One member in a review room (the Review stream). Requests go out from the caller's thread;
// events are read by a thread of the session into a small bounded queue (past 64 unread events it
// stops reading, and the daemon's own bounds take over: see docs/api.md), and next() hands them
// out in order. Peer updates do not count against that bound: as in the daemon, a peer's update
// not yet taken is replaced by its newer one, moved to the end. Sends are not thread-safe with each
// other; next() may run on another thread.
class ReviewSession {
  public:
    ~ReviewSession();  // cancels the stream if it was not finished

    const ReviewJoined& joined() const;

    Status send_pose(std::uint64_t sequence, const massive::Affine& pose);
    Status move_object(std::uint64_t sequence, std::uint32_t object,
                       const massive::Affine& transform);
    Status add_object(std::uint64_t sequence, const NamedMesh& object);
    Status delete_object(std::uint64_t sequence, std::uint32_t object);

    // The next event, waiting up to `timeout`: deadline_exceeded when none came in time; once the
    // stream has ended and every event was taken, its final status (failed_precondition "the
    // review stream has ended" after a clean end).
    StatusOr<ReviewEvent> next(std::chrono::milliseconds timeout = std::chrono::seconds(30));
    // Events until the result of pose `sequence`; the others go to `other` (if set), in order.
    StatusOr<ReviewPoseResult> wait_result(
        std::uint64_t sequence, const std::function<void(const ReviewEvent&)>& other = {},
        std::chrono::milliseconds timeout = std::chrono::seconds(30));
    // Half-closes (the member leaves), drops unread events and returns the final status.
    Status finish();
    // Cancels the stream (the daemon removes the member).
    void cancel();

    struct Impl;
    explicit ReviewSession(std::unique_ptr<Impl> impl);

  private:
    std::unique_ptr<Impl> m_impl;
};

// What a ResilientScene tells its caller when it re-created its scene.
struct SceneRecreation {
    std::string old_scene_id;
    std::string new_scene_id;
    std::uint64_t recreations = 0;  // this one included
    std::size_t resent_frames = 0;  // frames in flight, re-sent on the new scene
    Status cause;                   // the unavailable status that started the recovery
    // The new daemon numbered the objects differently: the session now translates ids both
    // ways, so the caller keeps using the ids it knows.
    bool ids_remapped = false;
};

struct ResilientSceneOptions {
    // Reconnecting after the daemon went away; longer than a call's default, since a daemon
    // being restarted (systemd, a supervisor) takes a moment to listen again.
    RetryOptions recovery = [] {
        RetryOptions r;
        r.max_attempts = 12;
        r.max_backoff = std::chrono::milliseconds(2000);
        r.max_total = std::chrono::milliseconds(60000);
        return r;
    }();
    // Called (from the thread in send() or receive()) after each re-creation.
    std::function<void(const SceneRecreation&)> on_recreated;
};

// A scene on the daemon with a frame stream that survives the daemon going away. It remembers
// what it sent (object names, topologies, latest positions: its own copy of the scene as of the
// last answered frame), and when the stream fails with UNAVAILABLE, or with a CANCELLED it did not
// ask for (behind HAProxy a killed daemon's stream ends "RST_STREAM error code 8", CANCELLED; the
// session's stream has no deadline and is cancelled only when the session ends), it reconnects
// with backoff,
// re-creates the scene from that copy on a new daemon scene (deleting the old one if it still
// exists), re-sends the frames that were in flight, once, and goes on. Every frame sent gets
// exactly one outcome from receive(), in order: its response (recreated_scene marks the first one
// after a re-creation) or an error; none is applied twice to the scene the caller sees, none
// dropped. Object ids are the session's: the first scene's ids, and when a re-created scene
// numbers objects differently the session translates, so the caller's ids stay valid. Other
// errors end the session like a FrameStream's; so does the daemon going away
// again before answering a re-sent frame, or running out of recovery attempts. The Client must
// outlive the session; not thread-safe.
class ResilientScene {
  public:
    static StatusOr<std::unique_ptr<ResilientScene>> create(Client& client, const std::string& name,
                                                            const std::vector<NamedMesh>& objects,
                                                            ResilientSceneOptions options = {});
    ~ResilientScene();  // cancels the stream and deletes the scene (one attempt, no retry)

    // The daemon's id of the current scene (a new one after each re-creation).
    const std::string& scene_id() const;
    // The session's object ids in result order, as of the last answered frame.
    std::vector<ObjectId> object_ids() const;
    // How many times the scene was re-created.
    std::uint64_t recreations() const;

    // Sends a frame (ids are the session's); pipelining works as on a FrameStream.
    Status send(const FrameRequest& frame);
    // The oldest unanswered frame's response (ids translated to the session's).
    StatusOr<FrameResponse> receive();
    // send() then receive().
    StatusOr<FrameResponse> step(const FrameRequest& frame);
    // Ends the stream (results not yet received are dropped) and deletes the scene.
    Status finish();

    struct Impl;
    explicit ResilientScene(std::unique_ptr<Impl> impl);

  private:
    std::unique_ptr<Impl> m_impl;
};

}  // namespace proxima::client
