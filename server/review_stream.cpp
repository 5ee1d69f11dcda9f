// Review: one member of a review room on a massive model (seed 001, IMMPACT §6.5): the member's
// avatar poses answered in order, its edits applied to the room's model, and the room's events
// (other members' poses, edits, joins and leaves) written to it in order. ordered_stream.hpp runs
// the stream; rooms and their fan-out are in rooms.hpp, the conversions in proto/wire
// (massive.hpp).
#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <variant>

#include <spdlog/spdlog.h>

#include "ordered_stream.hpp"
#include "proxima/massive/avatar.hpp"
#include "proxima/mesh/mesh.hpp"
#include "proxima/wire/massive.hpp"
#include "rooms.hpp"
#include "service.hpp"
#include "service_internal.hpp"

namespace proxima::server {

namespace {

// Prefetch streams of the shared cache: one per avatar, never reused, far from the small ids.
std::atomic<std::uint64_t> g_next_avatar_id{1ull << 40};

// Requests are answered in order (joined for join, result for pose, edit_applied for edit); the
// member's Outbox (rooms.hpp) holds those answers and the room's events, written one at a time.
// The member's mutex is the stream's. The member leaves its room before the stream's status goes
// out; a member that falls behind (REVIEW_MAX_PENDING_EVENTS unread) is ended at once.
class ReviewReactor final : public OrderedStream<v1::ReviewRequest, v1::ReviewEvent>,
                            public MemberSink {
  public:
    ReviewReactor(ProximityService::Shared& shared, grpc::CallbackServerContext* context)
        : OrderedStream(shared, context, "Review", "review stream"),
          m_member(shared.rooms.make_member()) {
        {
            std::lock_guard lock(m_member->mu);
            m_member->sink = this;
        }
        // Published before open(): gRPC hands the reactor to its other threads through its own
        // queues, which ThreadSanitizer does not see, and mutex() is read before any lock is held.
        m_mu.store(&m_member->mu, std::memory_order_release);
        open();
    }

    // MemberSink: called with m_member->mu held.
    void events_ready_locked() override { answers_ready_locked(); }
    void overflowed_locked() override {
        fail_now_locked(Status(StatusCode::resource_exhausted,
                               "review member '" + m_member->name +
                                   "' fell behind: " + std::to_string(REVIEW_MAX_PENDING_EVENTS) +
                                   " events are waiting to be read; read the stream as it comes"));
    }

  private:
    std::mutex& mutex() override { return *m_mu.load(std::memory_order_acquire); }

    bool next_write_locked(v1::ReviewEvent* out, bool* answers) override {
        auto next = m_member->outbox.pop(Outbox::Clock::now());
        if (!next) {
            return false;  // empty, or peer updates waiting for company (the flusher comes back)
        }
        out->Clear();
        if (next->item) {
            wire::encode_room_event(next->item->event, out);
            *answers = next->item->own;
        } else {
            wire::encode_peer_updates(next->peers, out);
            *answers = false;
        }
        return true;
    }

    // Leave now, so the others see member_left at once and a new join under the same name
    // works; the room never saw the bad request's effects.
    void on_failed() override { leave_room(); }

    void on_closing_locked() override { m_member->closed = true; }

    std::function<void()> before_finish_locked() override {
        if (m_joined && !m_left) {
            return [this] { leave_room(); };
        }
        return {};
    }

    void on_done_locked() override {
        m_member->sink = nullptr;
        m_member->closed = true;
    }
    void on_done() override { leave_room(); }

    std::string log_subject() const override {
        if (!m_room) {
            return "room=- model=- member=-";
        }
        return "room=" + m_room->name() + " model=" + m_room->model().name +
               " member=" + m_member->name;
    }
    std::string log_extra() const override {
        return " poses=" + std::to_string(m_poses) + " edits=" + std::to_string(m_edits);
    }

    // Leaves the room (once; the others get member_left). Runs as the member's one task (or in
    // OnDone), never under the member's lock. The room, if it went with us, is freed on a worker.
    void leave_room() {
        {
            std::lock_guard lock(m_member->mu);
            if (!m_joined || m_left) {
                return;
            }
            m_left = true;
        }
        auto doomed = m_shared.rooms.leave(m_room, m_member);
        std::shared_ptr<massive::AvatarTracker> tracker(std::move(m_tracker));
        if (doomed || tracker) {
            m_shared.pool.submit([room = std::move(doomed), tracker = std::move(tracker)] {});
        }
    }

    Status handle(v1::ReviewRequest& request, std::uint64_t /*charged*/) override {
        auto decoded = wire::decode_review_request(request);
        if (!decoded.ok()) {
            return decoded.status();
        }
        if (auto* join = std::get_if<ReviewJoinRequest>(&decoded.value())) {
            return handle_join(std::move(*join));
        }
        if (!m_room) {
            return failed_precondition(
                "the first request of a review stream must be join (room, model, member, "
                "avatar)");
        }
        if (auto* pose = std::get_if<ReviewPoseRequest>(&decoded.value())) {
            return handle_pose(*pose);
        }
        return handle_edit(std::get<RoomEdit>(decoded.value()));
    }

    Status handle_join(ReviewJoinRequest join) {
        if (m_room) {
            return invalid_argument("a second join: a review stream joins one room, once");
        }
        // Everything is checked before the room changes: access, the model, the avatar.
        const auto& principal = *m_admission.principal();
        if (!principal.may_join_room(join.room)) {
            return {StatusCode::permission_denied, "token '" + principal.name() +
                                                       "' may not join review room '" + join.room +
                                                       "' (no pattern of its rooms matches)"};
        }
        auto model = find_model(m_shared, principal, join.model);
        if (!model.ok()) {
            return model.status();
        }
        if (Status s = validate_mesh(join.avatar.mesh, "join.avatar"); !s.ok()) {
            return s;
        }
        m_member->name = join.member;  // not in a room yet: nobody else reads it
        m_options.tolerance = join.tolerance;
        m_options.nearest = join.nearest;
        auto room =
            m_shared.rooms.join(join.room, model.value(), m_shared.models.cache(), m_member);
        if (!room.ok()) {
            return room.status();
        }
        m_room = room.value();
        {
            std::lock_guard lock(m_member->mu);
            m_joined = true;
        }
        auto tracker = massive::AvatarTracker::create(m_room->view(), std::move(join.avatar.mesh),
                                                      g_next_avatar_id.fetch_add(1));
        if (!tracker.ok()) {
            return tracker.status();  // (validated above) the caller leaves the room
        }
        m_tracker = std::move(tracker).value();
        spdlog::info(
            "stream start method=Review who={} peer={} room={} model={} generation={} "
            "member={} tolerance={} nearest={}",
            m_admission.who(), m_peer, m_room->name(), m_room->model().name,
            m_room->model().store->summary().generation, m_member->name, m_options.tolerance,
            m_options.nearest);
        return {};
    }

    Status handle_pose(const ReviewPoseRequest& pose) {
        const auto start = Clock::now();
        PoseResult out;
        out.sequence = pose.sequence;
        {
            // One model version for the whole pose, names included: the view's current snapshot.
            // An edit committed meanwhile makes a new one and never waits for this pose (nor
            // this pose for it, however long the edit takes to prepare).
            const auto& view = *m_room->view();
            const auto at = view.snapshot();
            out.model_version = at->version;
            auto result = m_tracker->query(pose.transform, m_options, &m_cancel, at);
            if (!result.ok()) {
                return result.status();
            }
            out.result = std::move(result).value();
            auto name = [&](std::uint32_t object) {
                auto n = view.object_name(*at, object);
                return n.ok() ? std::move(n).value() : std::string();
            };
            for (const auto& h : out.result.collisions) {
                out.collision_names.push_back(name(h.object));
            }
            for (const auto& h : out.result.within) {
                out.within_names.push_back(name(h.object));
            }
            if (out.result.nearest) {
                out.nearest_name = name(out.result.nearest->object);
            }
        }
        MemberPose summary;
        summary.has_pose = true;
        summary.sequence = pose.sequence;
        summary.transform = pose.transform;
        summary.model_version = out.model_version;
        summary.summary.collisions = static_cast<std::uint32_t>(out.result.collisions.size());
        summary.summary.within = static_cast<std::uint32_t>(out.result.within.size());
        if (out.result.nearest) {
            summary.summary.has_nearest = true;
            summary.summary.nearest_object = out.result.nearest->object;
            summary.summary.nearest_name = out.nearest_name;
            summary.summary.nearest_distance = out.result.nearest->distance;
        }
        out.server_seconds = std::chrono::duration<double>(Clock::now() - start).count();
        deliver(*m_member, std::move(out), true);
        m_room->publish_pose(*m_member, summary);
        ++m_poses;
        return {};
    }

    Status handle_edit(const RoomEdit& edit) {
        auto applied = m_room->apply_edit(*m_member, edit);
        if (!applied.ok()) {
            return applied.status();
        }
        ++m_edits;
        static constexpr const char* KIND[] = {"move", "add", "delete"};
        spdlog::info(
            "room edit room={} model={} member={} what={} object={} name=\"{}\" "
            "model_version={}",
            m_room->name(), m_room->model().name, m_member->name,
            KIND[static_cast<int>(applied->what)], applied->object, applied->object_name,
            applied->model_version);
        return {};
    }

    const std::shared_ptr<RoomMember> m_member;  // its mu guards m_joined and m_left
    std::atomic<std::mutex*> m_mu{nullptr};      // &m_member->mu, for mutex()
    bool m_joined = false;                       // in a room (m_room set)
    bool m_left = false;                         // and left it again

    // Touched only by the one worker task (and by OnDone, after the last one).
    std::shared_ptr<Room> m_room;
    std::unique_ptr<massive::AvatarTracker> m_tracker;
    massive::AvatarQueryOptions m_options;
    std::uint64_t m_poses = 0;
    std::uint64_t m_edits = 0;
};

}  // namespace

grpc::ServerBidiReactor<v1::ReviewRequest, v1::ReviewEvent>* ProximityService::Review(
    grpc::CallbackServerContext* context) {
    return new ReviewReactor(*m_shared, context);
}

}  // namespace proxima::server
