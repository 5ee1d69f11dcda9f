#include "rooms.hpp"

#include <algorithm>
#include <utility>
#include <vector>

#include <spdlog/spdlog.h>

namespace proxima::server {

// --- Outbox ----------------------------------------------------------------------------------

bool Outbox::push(RoomEvent event, bool own) {
    if (m_ordered >= m_max_ordered) {
        return false;
    }
    m_items.emplace(m_next++, Item{std::move(event), own});
    ++m_ordered;
    return true;
}

void Outbox::push_peer(PeerEvent event) {
    // The newest update takes the place of the pending one and goes to the end, so the reader
    // sees events in the order they happened, minus the stale poses it never had time to read.
    drop_peer(event.member);
    const auto slot = m_next++;
    m_peer_slot[event.member] = slot;
    m_items.emplace(slot, Item{std::move(event), false});
}

void Outbox::drop_peer(const std::string& member) {
    if (auto it = m_peer_slot.find(member); it != m_peer_slot.end()) {
        m_items.erase(it->second);
        m_peer_slot.erase(it);
    }
}

std::optional<Outbox::Next> Outbox::pop(Clock::time_point now) {
    if (m_items.empty()) {
        return std::nullopt;
    }
    Next next;
    if (!std::holds_alternative<PeerEvent>(m_items.begin()->second.event)) {
        auto node = m_items.extract(m_items.begin());
        next.item = std::move(node.mapped());
        --m_ordered;
        return next;
    }
    // Updates at the front wait for company until their interval has passed, unless an ordered
    // event waits behind them (it must not wait, and they go before it).
    if (m_ordered == 0 && now < m_peers_after) {
        return std::nullopt;
    }
    while (!m_items.empty()) {
        auto* peer = std::get_if<PeerEvent>(&m_items.begin()->second.event);
        if (peer == nullptr) {
            break;
        }
        m_peer_slot.erase(peer->member);
        next.peers.push_back(std::move(*peer));
        m_items.erase(m_items.begin());
    }
    m_peers_after = now + m_peer_interval;
    return next;
}

bool Outbox::peers_due(Clock::time_point now) const {
    return !m_peer_slot.empty() && now >= m_peers_after;
}

// --- delivery ----------------------------------------------------------------------------------

void deliver(RoomMember& member, RoomEvent event, bool own) {
    std::lock_guard lock(member.mu);
    if (member.closed || member.sink == nullptr) {
        return;
    }
    if (auto* peer = std::get_if<PeerEvent>(&event)) {
        member.outbox.push_peer(std::move(*peer));
    } else {
        if (auto* left = std::get_if<MemberLeftEvent>(&event)) {
            member.outbox.drop_peer(left->member);  // no stale pose after "left"
        }
        if (!member.outbox.push(std::move(event), own)) {
            member.closed = true;
            member.sink->overflowed_locked();
            return;
        }
    }
    member.sink->events_ready_locked();
}

// --- Room --------------------------------------------------------------------------------------

Room::Room(std::string name, std::shared_ptr<const ModelEntry> model,
           std::shared_ptr<massive::GeometryCache> cache)
    : m_name(std::move(name)),
      m_model(std::move(model)),
      m_view(std::make_shared<massive::ModelView>(m_model->store, std::move(cache))) {}

std::size_t Room::member_count() const {
    std::lock_guard lock(m_mu);
    return m_members.size();
}

void Room::publish_pose(RoomMember& from, const MemberPose& pose) {
    std::lock_guard lock(m_mu);
    from.last_pose = pose;
    for (const auto& m : m_members) {
        if (m.get() != &from) {
            deliver(*m, PeerEvent{from.name, pose}, false);
        }
    }
}

StatusOr<EditEvent> Room::apply_edit(RoomMember& editor, const RoomEdit& edit) {
    // A move's slow part first, outside the room's lock: reading the stored object (from disk
    // when the page cache lost it: up to ~0.75 s on a VM's disk), transforming and checking it.
    // Held under the lock, it queued every other member's edit behind it, each holding one of
    // the daemon's workers, and with all of them waiting no pose was served.
    std::optional<massive::ModelView::PreparedMove> move;
    if (edit.what == EditKind::move) {
        auto prepared = m_view->prepare_move(edit.object, edit.transform);
        if (!prepared.ok()) {
            return prepared.status();
        }
        move = std::move(prepared).value();
    }
    // Then one edit at a time, so edits reach every member in the order they were applied. Poses
    // go on meanwhile, each on the snapshot it took (the version its result names).
    std::lock_guard edit_lock(m_edit_mu);
    EditEvent event;
    event.member = editor.name;
    event.sequence = edit.sequence;
    event.what = edit.what;
    switch (edit.what) {
        case EditKind::move: {
            if (Status s = m_view->commit_move(std::move(*move)); !s.ok()) {
                return s;
            }
            event.object = edit.object;
            event.transform = edit.transform;
            break;
        }
        case EditKind::add: {
            auto id = m_view->add_object({edit.added.name, edit.added.mesh});
            if (!id.ok()) {
                return id.status();
            }
            event.object = id.value();
            break;
        }
        case EditKind::remove: {
            // The name first: a deleted object has none in the view any more.
            auto name = m_view->object_name(edit.object);
            if (!name.ok() || m_view->deleted(edit.object)) {
                return not_found("delete: no object " + std::to_string(edit.object) + " in room " +
                                 m_name + "'s model");
            }
            if (Status s = m_view->delete_object(edit.object); !s.ok()) {
                return s;
            }
            event.object = edit.object;
            event.object_name = std::move(name).value();
            break;
        }
    }
    if (event.object_name.empty()) {
        if (auto name = m_view->object_name(event.object); name.ok()) {
            event.object_name = std::move(name).value();
        }
    }
    event.model_version = m_view->version();
    std::lock_guard lock(m_mu);
    for (const auto& m : m_members) {
        deliver(*m, event, m.get() == &editor);
    }
    return event;
}

// --- RoomRegistry ------------------------------------------------------------------------------

RoomRegistry::RoomRegistry(std::size_t max_events, Outbox::Clock::duration peer_interval)
    : m_max_events(max_events), m_peer_interval(peer_interval) {
    if (m_peer_interval > Outbox::Clock::duration::zero()) {
        m_flusher = std::thread([this] { flush_loop(); });
    }
}

RoomRegistry::~RoomRegistry() {
    {
        std::lock_guard lock(m_flush_mu);
        m_stop = true;
    }
    m_flush_cv.notify_all();
    if (m_flusher.joinable()) {
        m_flusher.join();
    }
}

void RoomRegistry::flush_loop() {
    std::unique_lock lock(m_flush_mu);
    while (!m_stop) {
        if (m_room_count == 0) {
            // Nothing to flush until a room exists: no periodic wake-up on an idle daemon.
            m_flush_cv.wait(lock, [this] { return m_stop || m_room_count > 0; });
            continue;
        }
        if (m_flush_cv.wait_for(lock, m_peer_interval / 2, [this] { return m_stop; })) {
            break;
        }
        lock.unlock();
        flush_due();
        lock.lock();
    }
}

void RoomRegistry::rooms_changed_locked() {
    {
        std::lock_guard lock(m_flush_mu);
        m_room_count = m_rooms.size();
    }
    m_flush_cv.notify_all();
}

void RoomRegistry::flush_due() {
    // The members, not the rooms: a room whose last member leaves meanwhile is freed by the
    // leaving member's thread as leave() promises, never here.
    std::vector<std::shared_ptr<RoomMember>> members;
    {
        std::lock_guard lock(m_mu);
        for (const auto& [name, room] : m_rooms) {
            std::lock_guard room_lock(room->m_mu);
            members.insert(members.end(), room->m_members.begin(), room->m_members.end());
        }
    }
    const auto now = Outbox::Clock::now();
    for (const auto& m : members) {
        std::lock_guard lock(m->mu);
        if (!m->closed && m->sink != nullptr && m->outbox.peers_due(now)) {
            m->sink->events_ready_locked();
        }
    }
}

StatusOr<std::shared_ptr<Room>> RoomRegistry::join(
    const std::string& room_name, const std::shared_ptr<const ModelEntry>& model,
    const std::shared_ptr<massive::GeometryCache>& cache,
    const std::shared_ptr<RoomMember>& member) {
    std::lock_guard lock(m_mu);
    auto it = m_rooms.find(room_name);
    std::shared_ptr<Room> room;
    if (it != m_rooms.end()) {
        room = it->second;
        if (room->model().name != model->name) {
            return failed_precondition("room " + room_name + " reviews model '" +
                                       room->model().name + "', not '" + model->name +
                                       "' (pick another room name)");
        }
    } else {
        room = std::make_shared<Room>(room_name, model, cache);
    }
    // The edit lock: an edit is either wholly before the join (in model_version) or wholly
    // after it (and then reaches the new member as edit_applied).
    std::lock_guard edit_lock(room->m_edit_mu);
    std::lock_guard room_lock(room->m_mu);
    for (const auto& m : room->m_members) {
        if (m->name == member->name) {
            return failed_precondition("room " + room_name + " already has a member named '" +
                                       member->name + "'");
        }
    }
    JoinedEvent joined;
    joined.room = room_name;
    joined.model = room->model().name;
    joined.generation = room->model().store->summary().generation;
    for (const auto& m : room->m_members) {
        joined.members.emplace_back(m->name, m->last_pose);
    }
    joined.members.emplace_back(member->name, member->last_pose);
    joined.model_version = room->view()->version();
    joined.object_count = room->view()->object_count();
    for (const auto& m : room->m_members) {
        deliver(*m, MemberJoinedEvent{member->name}, false);
    }
    room->m_members.push_back(member);
    deliver(*member, std::move(joined), true);
    if (it == m_rooms.end()) {
        m_rooms.emplace(room_name, room);
        rooms_changed_locked();
        spdlog::info("room created room={} model={} generation={}", room_name, model->name,
                     model->store->summary().generation);
    }
    return room;
}

std::shared_ptr<Room> RoomRegistry::leave(const std::shared_ptr<Room>& room,
                                          const std::shared_ptr<RoomMember>& member) {
    std::lock_guard lock(m_mu);
    std::lock_guard room_lock(room->m_mu);
    auto& members = room->m_members;
    const auto it = std::find(members.begin(), members.end(), member);
    if (it == members.end()) {
        return nullptr;
    }
    members.erase(it);
    for (const auto& m : members) {
        deliver(*m, MemberLeftEvent{member->name}, false);
    }
    if (!members.empty()) {
        return nullptr;
    }
    if (auto r = m_rooms.find(room->name()); r != m_rooms.end() && r->second == room) {
        m_rooms.erase(r);
        rooms_changed_locked();
    }
    spdlog::info("room deleted room={} model={} (its last member left)", room->name(),
                 room->model().name);
    return room;
}

std::shared_ptr<Room> RoomRegistry::find(const std::string& room) const {
    std::lock_guard lock(m_mu);
    const auto it = m_rooms.find(room);
    return it == m_rooms.end() ? nullptr : it->second;
}

std::size_t RoomRegistry::size() const {
    std::lock_guard lock(m_mu);
    return m_rooms.size();
}

}  // namespace proxima::server
