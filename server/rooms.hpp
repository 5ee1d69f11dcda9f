#pragma once
// Design-review rooms (seed 001 §4.4, §6.5): members walking avatars through one massive model
// and editing it together.
//
// - A room reviews one model and has its own massive::ModelView: edits (move, add, delete) change
//   the room's view only. Rooms on the same model share the daemon's one GeometryCache, so the
//   stored geometry is read once for all of them.
// - Every member sees the others: its own pose results, the other members' latest poses (with a
//   summary of their results), every edit (its own included, in the one order the room applied
//   them), and members joining and leaving.
// - Each pose is computed on exactly one model version: poses hold the room's edit lock shared,
//   edits hold it exclusively, so `model_version` in a result names the edits it saw.
// - Delivery never blocks the sender and never grows without bound: each member has an Outbox.
//   Ordered events (its own answers, edits, joins and leaves) queue up to a bound; a member that
//   falls that far behind is disconnected (RESOURCE_EXHAUSTED) rather than slowing the room down
//   or growing the daemon's memory. Peer pose updates coalesce: a member that has not yet taken a
//   peer's update gets the newest one in its place (at most one pending update per peer).
//
// Lock order: RoomRegistry::m_mu, then Room::edit_mu, then Room::mu, then RoomMember::mu (each
// may be skipped). A member's stream never takes a room lock while it holds its own.

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <unordered_map>
#include <variant>
#include <vector>

#include "models.hpp"
#include "proxima/massive/avatar.hpp"
#include "proxima/massive/review.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"

namespace proxima::server {

// The review types live in the engine (proxima/massive/review.hpp), shared with proto/wire and
// the client.
using massive::EditEvent;
using massive::EditKind;
using massive::JoinedEvent;
using massive::MemberJoinedEvent;
using massive::MemberLeftEvent;
using massive::MemberPose;
using massive::PeerEvent;
using massive::PoseResult;
using massive::PoseSummary;
using massive::ReviewJoinRequest;
using massive::ReviewPoseRequest;
using massive::RoomEvent;
// A decoded edit request.
using RoomEdit = massive::ReviewEditRequest;

// One member's pending events, in the order they happened. Not thread-safe: guarded by
// RoomMember::mu.
class Outbox {
  public:
    struct Item {
        RoomEvent event;
        bool own = false;  // answers one of this member's requests (join, pose, edit)
    };
    explicit Outbox(std::size_t max_ordered) : m_max_ordered(max_ordered) {}

    // An ordered event; false (and nothing queued) when max_ordered are already waiting.
    bool push(RoomEvent event, bool own);
    // A peer's latest pose: replaces that peer's pending update, if any, and moves it to the end.
    void push_peer(PeerEvent event);
    // Forgets a peer's pending update (it left the room).
    void drop_peer(const std::string& member);
    std::optional<Item> pop();
    bool empty() const { return m_items.empty(); }
    std::size_t size() const { return m_items.size(); }
    std::size_t ordered() const { return m_ordered; }

  private:
    std::size_t m_max_ordered;
    std::uint64_t m_next = 0;
    std::map<std::uint64_t, Item> m_items;  // by arrival
    std::unordered_map<std::string, std::uint64_t> m_peer_slot;
    std::size_t m_ordered = 0;
};

// The stream behind a member. Both calls happen with RoomMember::mu held and must not block.
class MemberSink {
  public:
    virtual void events_ready_locked() = 0;  // something was queued in the outbox
    virtual void overflowed_locked() = 0;    // the outbox was full: the member must go
  protected:
    ~MemberSink() = default;
};

struct RoomMember {
    explicit RoomMember(std::size_t max_events) : outbox(max_events) {}

    std::string name;  // set once, before the member joins a room

    std::mutex mu;               // guards what follows; the member's stream uses it as its lock
    Outbox outbox;               // guarded by mu
    MemberSink* sink = nullptr;  // guarded by mu; null once the stream is gone
    bool closed = false;         // guarded by mu: takes no more events (its stream is ending)

    MemberPose last_pose;  // guarded by the room's mu
};

// Queues an event for `member` and tells its stream. Drops it when the member is closed; marks
// the member overflowed (and tells its stream) when its outbox is full.
void deliver(RoomMember& member, RoomEvent event, bool own);

class Room {
  public:
    Room(std::string name, std::shared_ptr<const ModelEntry> model,
         std::shared_ptr<massive::GeometryCache> cache);

    const std::string& name() const { return m_name; }
    const ModelEntry& model() const { return *m_model; }
    const std::shared_ptr<massive::ModelView>& view() const { return m_view; }

    // Poses hold this shared for the whole query, edits exclusively.
    std::shared_mutex& edit_mutex() { return m_edit_mu; }

    // Records the member's latest pose and sends it to every other member.
    void publish_pose(RoomMember& from, const MemberPose& pose);
    // Applies the edit to the room's view (all or nothing) and sends edit_applied to every
    // member (to `editor` as its answer).
    StatusOr<EditEvent> apply_edit(RoomMember& editor, const RoomEdit& edit);

    std::size_t member_count() const;

  private:
    friend class RoomRegistry;

    const std::string m_name;
    const std::shared_ptr<const ModelEntry> m_model;
    const std::shared_ptr<massive::ModelView> m_view;
    std::shared_mutex m_edit_mu;
    mutable std::mutex m_mu;
    std::vector<std::shared_ptr<RoomMember>> m_members;  // guarded by m_mu, join order
};

class RoomRegistry {
  public:
    // `max_events`: each member's bound on ordered events waiting to be read.
    explicit RoomRegistry(std::size_t max_events) : m_max_events(max_events) {}

    std::shared_ptr<RoomMember> make_member() const {
        return std::make_shared<RoomMember>(m_max_events);
    }

    // Adds `member` (its name and sink set) to room `room`, creating the room on `model` when it
    // does not exist. Queues `joined` for the member and `member_joined` for the others.
    // FAILED_PRECONDITION when the room reviews another model or has a member of that name.
    StatusOr<std::shared_ptr<Room>> join(const std::string& room,
                                         const std::shared_ptr<const ModelEntry>& model,
                                         const std::shared_ptr<massive::GeometryCache>& cache,
                                         const std::shared_ptr<RoomMember>& member);
    // Removes the member (others get member_left); the last member's leaving deletes the room.
    // Returns the room when this deleted it (so the caller can free it off its thread).
    std::shared_ptr<Room> leave(const std::shared_ptr<Room>& room,
                                const std::shared_ptr<RoomMember>& member);

    // The room of that name, or null when there is none.
    std::shared_ptr<Room> find(const std::string& room) const;

    std::size_t size() const;

  private:
    const std::size_t m_max_events;
    mutable std::mutex m_mu;
    std::unordered_map<std::string, std::shared_ptr<Room>> m_rooms;  // guarded by m_mu
};

}  // namespace proxima::server
