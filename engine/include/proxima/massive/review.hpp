#pragma once
// Design-review rooms in engine terms (seed 001 §4.4, §6.5): what a member asks (join, pose,
// edit) and what a room tells its members. The daemon's rooms (server/rooms.hpp) run on these
// types, proto/wire converts them to and from the Review stream's messages, and the client's
// public names (ReviewPoseSummary, ReviewPoseResult, ReviewEditKind, ReviewJoin) are aliases of
// them.

#include <cstdint>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "proxima/massive/avatar.hpp"
#include "proxima/scene.hpp"

namespace proxima::massive {

// What other members see of a pose's result.
struct PoseSummary {
    std::uint32_t collisions = 0;
    std::uint32_t within = 0;
    bool has_nearest = false;
    std::uint32_t nearest_object = 0;
    std::string nearest_name;
    double nearest_distance = 0.0;
};

// A member's latest pose as the room keeps it.
struct MemberPose {
    bool has_pose = false;
    std::uint64_t sequence = 0;
    Affine transform;
    PoseSummary summary;
    std::uint64_t model_version = 0;
};

// A pose's answer, in the engine's type (object indices are the room's: stored objects, then
// added ones), with the objects' names beside it (an added object's name is the one it was added
// with).
struct PoseResult {
    std::uint64_t sequence = 0;
    AvatarResult result;
    std::vector<std::string> collision_names;
    std::vector<std::string> within_names;
    std::string nearest_name;
    std::uint64_t model_version = 0;  // the edits this pose saw
    double server_seconds = 0.0;
};

enum class EditKind { move, add, remove };

// --- Requests ---

// Joining (or creating) a room.
struct ReviewJoinRequest {
    std::string room;
    std::string model;
    std::string member;
    NamedMesh avatar;  // in its own coordinates; poses place it
    double tolerance = 0.0;
    bool nearest = true;
};
struct ReviewPoseRequest {
    std::uint64_t sequence = 0;
    Affine transform;
};
struct ReviewEditRequest {
    std::uint64_t sequence = 0;
    EditKind what = EditKind::move;
    std::uint32_t object = 0;  // move, remove
    Affine transform;          // move
    NamedMesh added;           // add
};
using ReviewRequest = std::variant<ReviewJoinRequest, ReviewPoseRequest, ReviewEditRequest>;

// --- Events a room sends its members ---

struct JoinedEvent {
    std::string room;
    std::string model;
    std::string generation;
    std::vector<std::pair<std::string, MemberPose>> members;  // join order, the new one last
    std::uint64_t model_version = 0;
    std::uint32_t object_count = 0;
};
struct PeerEvent {
    std::string member;
    MemberPose pose;
};
struct EditEvent {
    std::string member;  // who edited
    std::uint64_t sequence = 0;
    EditKind what = EditKind::move;
    std::uint32_t object = 0;  // moved / deleted object, or the added object's new index
    std::string object_name;
    std::uint64_t model_version = 0;
    Affine transform;  // a move's new transform (of stored coordinates); identity otherwise
};
struct MemberJoinedEvent {
    std::string member;
};
struct MemberLeftEvent {
    std::string member;
};
using RoomEvent =
    std::variant<JoinedEvent, PoseResult, PeerEvent, EditEvent, MemberJoinedEvent, MemberLeftEvent>;

}  // namespace proxima::massive
