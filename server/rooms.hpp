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
// - Each pose is computed on exactly one model version: the view's snapshot when the pose began
//   (`model_version` in its result names the edits it saw). Edits are applied one at a time
//   under the room's edit lock, which poses never take: an edit commits a new snapshot, and a
//   slow one (a large object read and copied) holds up no pose.
// - Delivery never blocks the sender and never grows without bound: each member has an Outbox.
//   Ordered events (its own answers, edits, joins and leaves) queue up to a bound; a member that
//   falls that far behind is disconnected (RESOURCE_EXHAUSTED) rather than slowing the room down
//   or growing the daemon's memory. Peer pose updates coalesce: a member that has not yet taken a
//   peer's update gets the newest one in its place (at most one pending update per peer). And
//   they wait for company: a member's pending updates go out together (one `peers` message) at
//   most once per peer interval, or at once ahead of an ordered event; the registry's flusher
//   thread sends those whose interval has passed. With 64 members posing 5 times a second that
//   is ~50 messages a second per member instead of ~315.
//
// Lock order: RoomRegistry::m_mu, then Room::edit_mu, then Room::mu, then RoomMember::mu (each
// may be skipped); RoomRegistry::m_flush_mu is a leaf (nothing is taken while it is held). A
// member's stream never takes a room lock while it holds its own.

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
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
    using Clock = std::chrono::steady_clock;
    struct Item {
        RoomEvent event;
        bool own = false;  // answers one of this member's requests (join, pose, edit)
    };
    // What goes out next: an ordered event (`item`), or the peer updates queued ahead of any
    // ordered one, together, oldest first (`peers`).
    struct Next {
        std::optional<Item> item;
        std::vector<PeerEvent> peers;
    };
    // `peer_interval`: peer updates go out together at most once per this long (zero: no wait).
    explicit Outbox(std::size_t max_ordered, Clock::duration peer_interval = {})
        : m_max_ordered(max_ordered), m_peer_interval(peer_interval) {}

    // An ordered event; false (and nothing queued) when max_ordered are already waiting.
    bool push(RoomEvent event, bool own);
    // A peer's latest pose: replaces that peer's pending update, if any, and moves it to the end.
    void push_peer(PeerEvent event);
    // Forgets a peer's pending update (it left the room).
    void drop_peer(const std::string& member);
    // The next message, or nothing when the outbox is empty or holds only peer updates whose
    // interval has not passed at `now` (peers_due() tells when it has).
    std::optional<Next> pop(Clock::time_point now);
    // Peer updates wait that pop() would hand out at `now`.
    bool peers_due(Clock::time_point now) const;
    bool empty() const { return m_items.empty(); }
    std::size_t size() const { return m_items.size(); }
    std::size_t ordered() const { return m_ordered; }

  private:
    std::size_t m_max_ordered;
    Clock::duration m_peer_interval;
    Clock::time_point m_peers_after{};  // the earliest time the next batch of updates may go
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
    RoomMember(std::size_t max_events, Outbox::Clock::duration peer_interval)
        : outbox(max_events, peer_interval) {}

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
    // Edits and joins, one at a time: an edit is applied and announced to the members of that
    // moment before the next edit or join begins. Poses never take it (each queries one snapshot
    // of the view), so a slow edit (reading a large object, evicting pieces for its copy) holds
    // up no pose.
    std::mutex m_edit_mu;
    mutable std::mutex m_mu;
    std::vector<std::shared_ptr<RoomMember>> m_members;  // guarded by m_mu, join order
};

class RoomRegistry {
  public:
    // `max_events`: each member's bound on ordered events waiting to be read; `peer_interval`:
    // how often at most a member's pending peer updates go out together (zero: each at once).
    // A flusher thread sends the held ones when their interval has passed (none for zero).
    explicit RoomRegistry(std::size_t max_events, Outbox::Clock::duration peer_interval = {});
    ~RoomRegistry();
    RoomRegistry(const RoomRegistry&) = delete;
    RoomRegistry& operator=(const RoomRegistry&) = delete;

    std::shared_ptr<RoomMember> make_member() const {
        return std::make_shared<RoomMember>(m_max_events, m_peer_interval);
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
    // Tells the stream of every member whose held peer updates are due (twice per interval while
    // any room exists; the thread sleeps while there is none).
    void flush_loop();
    void flush_due();
    void rooms_changed_locked();  // with m_mu held: wakes the flusher when the first room opens

    const std::size_t m_max_events;
    const Outbox::Clock::duration m_peer_interval;
    mutable std::mutex m_mu;
    std::unordered_map<std::string, std::shared_ptr<Room>> m_rooms;  // guarded by m_mu
    std::mutex m_flush_mu;
    std::condition_variable m_flush_cv;
    bool m_stop = false;           // guarded by m_flush_mu
    std::size_t m_room_count = 0;  // guarded by m_flush_mu: m_rooms.size(), for the flusher
    std::thread m_flusher;
};

}  // namespace proxima::server
