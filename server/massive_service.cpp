// The massive-model RPCs of ProximityService: ListModels, VerifyModel and Review (seed 001,
// IMMPACT §4.4–§6.5). Models and the shared geometry cache are in models.hpp, rooms and their
// fan-out in rooms.hpp, every proto conversion in proto/wire (massive.hpp).
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <thread>
#include <utility>

#include <spdlog/spdlog.h>

#include "encode.hpp"
#include "proxima/massive/avatar.hpp"
#include "proxima/massive/verify.hpp"
#include "proxima/mesh/mesh.hpp"
#include "proxima/wire/buffers.hpp"
#include "proxima/wire/massive.hpp"
#include "proxima/wire/status.hpp"
#include "service.hpp"
#include "service_internal.hpp"

namespace proxima::server {

namespace {

// Pair events a verification may have encoded but not yet written; past that the traversal
// waits for the reader (its other threads wait with it, on the engine's result lock).
constexpr std::size_t VERIFY_MAX_PENDING_PAIRS = 256;

// Prefetch streams of the shared cache: one per avatar, never reused, far from the small ids.
std::atomic<std::uint64_t> g_next_avatar_id{1ull << 40};

// VerifyModel. The traversal runs on a thread of its own (a large model takes minutes, and it
// may wait for a slow reader: on the worker pool it would hold a thread that frames need). Pairs
// go into a bounded queue (VERIFY_MAX_PENDING_PAIRS); when it is full the engine's on_pair waits,
// which stalls the traversal until the client reads: memory stays bounded however slow the
// reader. Progress is one slot overwritten by each report, written when nothing else is waiting.
//
// State is guarded by m_mu. Finish is called once, by write_next_locked(), after the traversal
// thread has set m_done (so OnDone only joins a thread that is returning).
class VerifyReactor final : public grpc::ServerWriteReactor<v1::VerifyModelEvent> {
  public:
    VerifyReactor(ProximityService::Shared& shared, grpc::CallbackServerContext* context,
                  const v1::VerifyModelRequest* request)
        : m_shared(shared),
          m_peer(context->peer()),
          m_model_name(request->model()),
          m_tolerance(request->tolerance()),
          m_start(Clock::now()) {
        apply_deadline(m_cancel, *context);
        if (!m_shared.enter_call()) {
            std::lock_guard lock(m_mu);
            m_done = true;
            m_status = shutting_down();
            write_next_locked();
            return;
        }
        if (Status s = m_admission.admit(m_shared, *context); !s.ok()) {
            std::lock_guard lock(m_mu);
            m_done = true;
            m_status = s;
            write_next_locked();
            return;
        }
        m_thread = std::thread([this] { run(); });
    }

    void OnWriteDone(bool ok) override {
        std::lock_guard lock(m_mu);
        m_writing = false;
        if (!ok) {
            m_write_failed = true;  // the client is gone: stop the traversal
            m_cancel.cancel();
        } else {
            ++m_events_written;
        }
        m_room.notify_all();
        write_next_locked();
    }

    void OnCancel() override {
        std::lock_guard lock(m_mu);
        m_cancelled = true;
        m_cancel.cancel();
        m_room.notify_all();
        write_next_locked();
    }

    void OnDone() override {
        { std::lock_guard lock(m_mu); }  // the thread that called Finish has released m_mu
        if (m_thread.joinable()) {
            if (m_thread.get_id() == std::this_thread::get_id()) {
                m_thread.detach();
            } else {
                m_thread.join();
            }
        }
        m_shared.leave_call();
        std::string subject = "model=" + (m_model_name.empty() ? "-" : m_model_name);
        if (m_generation) {
            subject += " generation=" + *m_generation;
        }
        log_call(m_shared, "VerifyModel", m_admission.who(), m_peer, subject, m_start, m_final,
                 " tolerance=" + std::to_string(m_tolerance) + " pairs=" +
                     std::to_string(m_pairs_found) + " edges=" + std::to_string(m_edges) +
                     " reader_waits=" + std::to_string(m_reader_waits) +
                     " events=" + std::to_string(m_events_written),
                 spdlog::level::info);
        delete this;
    }

  private:
    bool stopped_locked() const { return m_cancelled || m_write_failed; }

    void run() {
        Status s = guarded([&]() -> Status {
            if (Status t = wire::check_tolerance(m_tolerance, "tolerance"); !t.ok()) {
                return t;
            }
            auto model = find_model(m_shared, *m_admission.principal(), m_model_name);
            if (!model.ok()) {
                return model.status();
            }
            const auto store = model.value()->store;
            {
                std::lock_guard lock(m_mu);
                m_generation = store->summary().generation;
            }
            spdlog::info(
                "verify start method=VerifyModel who={} peer={} model={} generation={} "
                "tolerance={} objects={} pieces={}",
                m_admission.who(), m_peer, m_model_name, store->summary().generation, m_tolerance,
                store->summary().objects, store->summary().pieces);
            massive::VerifyOptions options;
            options.tolerance = m_tolerance;
            auto on_pair = [&](const massive::ObjectPairResult& pair) {
                v1::VerifyModelEvent event;
                wire::encode_object_pair(pair, *store, event.mutable_pair());
                std::unique_lock lock(m_mu);
                while (m_pairs.size() >= VERIFY_MAX_PENDING_PAIRS && !stopped_locked() &&
                       !m_cancel.should_stop()) {
                    ++m_reader_waits;
                    // Timed: the deadline passing wakes nobody.
                    m_room.wait_for(lock, std::chrono::milliseconds(100));
                }
                if (stopped_locked()) {
                    return;  // nobody will read it; the traversal stops at its next pair
                }
                m_pairs.push_back(std::move(event));
                write_next_locked();
            };
            auto on_progress = [&](const massive::Progress& p) {
                std::lock_guard lock(m_mu);
                wire::encode_progress(p, m_progress.mutable_progress());
                m_progress_dirty = true;
                write_next_locked();
            };
            auto stats = massive::verify_static(store, *m_shared.models.cache(), options, on_pair,
                                                nullptr, on_progress, &m_cancel);
            if (!stats.ok()) {
                return stats.status();
            }
            std::lock_guard lock(m_mu);
            m_pairs_found = stats->pairs_found;
            m_edges = stats->edges;
            wire::encode_verify_stats(stats.value(),
                                      std::chrono::duration<double>(Clock::now() - m_start).count(),
                                      m_summary.mutable_summary());
            return {};
        });
        std::lock_guard lock(m_mu);
        m_done = true;
        m_status = s;
        write_next_locked();
    }

    // Starts the next write: pairs first (in order), then the latest progress, then (once the
    // traversal is done) the summary; Finish when nothing is left.
    void write_next_locked() {
        if (m_writing || m_finished) {
            return;
        }
        if (!stopped_locked()) {
            if (!m_pairs.empty()) {
                m_write = std::move(m_pairs.front());
                m_pairs.pop_front();
                m_room.notify_all();
            } else if (m_progress_dirty) {
                m_write = m_progress;
                m_progress_dirty = false;
            } else if (m_done && m_status.ok() && !m_summary_sent) {
                m_write = m_summary;
                m_summary_sent = true;
            } else {
                m_write.Clear();
            }
            if (m_write.event_case() != v1::VerifyModelEvent::EVENT_NOT_SET) {
                m_writing = true;
                StartWrite(&m_write);
                return;
            }
        }
        if (!m_done) {
            return;
        }
        m_finished = true;
        if (stopped_locked() && m_status.ok()) {
            m_final = {StatusCode::cancelled, "verification cancelled by the client"};
        } else {
            m_final = m_status;
        }
        Finish(wire::to_grpc(m_final));
    }

    ProximityService::Shared& m_shared;
    const std::string m_peer;
    const std::string m_model_name;
    const double m_tolerance;
    const Clock::time_point m_start;
    CancelToken m_cancel;
    std::thread m_thread;

    std::mutex m_mu;
    std::condition_variable m_room;  // a pair slot freed, or the call stopped
    std::deque<v1::VerifyModelEvent> m_pairs;
    v1::VerifyModelEvent m_progress;
    bool m_progress_dirty = false;
    v1::VerifyModelEvent m_summary;
    bool m_summary_sent = false;
    v1::VerifyModelEvent m_write;  // the outstanding write's message
    bool m_writing = false;
    bool m_done = false;  // the traversal thread has finished; m_status is its answer
    Status m_status;
    bool m_finished = false;
    bool m_cancelled = false;
    bool m_write_failed = false;
    Status m_final;
    std::optional<std::string> m_generation;
    std::uint64_t m_pairs_found = 0;
    std::uint64_t m_edges = 0;
    std::uint64_t m_reader_waits = 0;
    std::uint64_t m_events_written = 0;
    StreamAdmission m_admission;
};

// Review: one member of a room. Requests are read while fewer than max_frames_in_flight are
// unanswered (an answer is written: joined for join, result for pose, edit_applied for edit),
// processed in order by one worker task at a time, and the member's Outbox (rooms.hpp) is
// written one event at a time. Every state change happens under the member's mutex; Finish is
// called once, by maybe_finish_locked(), after the member has left its room, when no task runs
// and no write is outstanding (for a member that fell behind: even with one).
class ReviewReactor final : public grpc::ServerBidiReactor<v1::ReviewRequest, v1::ReviewEvent>,
                            public DrainableStream,
                            public MemberSink {
  public:
    ReviewReactor(ProximityService::Shared& shared, grpc::CallbackServerContext* context)
        : m_shared(shared),
          m_peer(context->peer()),
          m_start(Clock::now()),
          m_member(shared.rooms.make_member()) {
        apply_deadline(m_cancel, *context);
        const bool accepted = m_shared.enter_call(this);
        std::lock_guard lock(m_member->mu);
        m_member->sink = this;
        m_draining = !accepted;
        if (accepted) {
            if (Status s = m_admission.admit(m_shared, *context); !s.ok()) {
                m_error = s;
            }
        }
        start_read_if_room_locked();
        maybe_finish_locked();
    }

    void OnReadDone(bool ok) override {
        std::lock_guard lock(m_member->mu);
        m_reading = false;
        if (!ok) {
            m_read_done = true;  // half-close: the member is leaving
            maybe_finish_locked();
            return;
        }
        if (m_finished || stopped_locked()) {
            return;
        }
        m_requests.push_back(std::move(m_incoming));
        m_incoming.Clear();
        ++m_in_flight;
        start_read_if_room_locked();
        if (!m_processing) {
            m_processing = true;
            m_shared.pool.submit([this] { process(); });
        }
    }

    void OnWriteDone(bool ok) override {
        std::lock_guard lock(m_member->mu);
        m_writing = false;
        if (!ok) {
            m_write_failed = true;
            m_cancel.cancel();
            m_requests.clear();
            m_member->closed = true;
            maybe_finish_locked();
            return;
        }
        if (m_out_own && m_in_flight > 0) {
            --m_in_flight;
        }
        start_read_if_room_locked();
        if (!m_finished && !m_cancelled && !m_overflowed && write_next_locked()) {
            return;
        }
        maybe_finish_locked();
    }

    void OnCancel() override {
        std::lock_guard lock(m_member->mu);
        m_cancelled = true;
        m_cancel.cancel();
        m_requests.clear();
        m_member->closed = true;
        maybe_finish_locked();
    }

    void OnDone() override {
        {
            std::lock_guard lock(m_member->mu);  // the thread that called Finish has let go
            m_member->sink = nullptr;
            m_member->closed = true;
        }
        leave_room();
        m_shared.leave_call(this);
        log_call(m_shared, "Review", m_admission.who(), m_peer, subject(), m_start, m_final,
                 " poses=" + std::to_string(m_poses) + " edits=" + std::to_string(m_edits),
                 spdlog::level::info);
        delete this;
    }

    void drain() override {
        std::lock_guard lock(m_member->mu);
        m_draining = true;
        maybe_finish_locked();
    }

    // MemberSink: called with m_member->mu held.
    void events_ready_locked() override {
        if (!m_writing && !m_finished && !m_cancelled && !m_write_failed) {
            write_next_locked();
        }
    }
    void overflowed_locked() override {
        if (!m_error) {
            m_error = Status(StatusCode::resource_exhausted,
                             "review member '" + m_member->name +
                                 "' fell behind: " + std::to_string(REVIEW_MAX_PENDING_EVENTS) +
                                 " events are waiting to be read; read the stream as it comes");
        }
        m_overflowed = true;
        m_cancel.cancel();
        m_requests.clear();
        maybe_finish_locked();  // leaves the room now, without waiting for the stuck write
    }

  private:
    bool stopped_locked() const { return m_cancelled || m_write_failed || m_error.has_value(); }

    std::string subject() const {
        if (!m_room) {
            return "room=- model=- member=-";
        }
        return "room=" + m_room->name() + " model=" + m_room->model().name +
               " member=" + m_member->name;
    }

    void start_read_if_room_locked() {
        if (m_reading || m_read_done || m_finished || m_draining || stopped_locked() ||
            m_in_flight >= m_shared.config.limits.max_frames_in_flight) {
            return;
        }
        m_reading = true;
        StartRead(&m_incoming);
    }

    bool write_next_locked() {
        auto item = m_member->outbox.pop();
        if (!item) {
            return false;
        }
        m_out.Clear();
        wire::encode_room_event(item->event, &m_out);
        m_out_own = item->own;
        m_writing = true;
        StartWrite(&m_out);
        return true;
    }

    void maybe_finish_locked() {
        // A member that fell behind is finished even with a write outstanding (its client may
        // never read it); gRPC sends the status after that write and runs OnDone after both.
        if (m_finished || m_processing || (m_writing && !m_overflowed)) {
            return;
        }
        Status final;
        if (m_cancelled || m_write_failed) {
            final = {StatusCode::cancelled, "review stream cancelled by the client"};
        } else if (m_error) {
            // A bad request: what was answered before it still reaches the client (the room
            // sends nothing new: the member is closed). A member that fell behind gets nothing
            // more.
            m_member->closed = true;
            if (!m_overflowed && write_next_locked()) {
                return;
            }
            final = *m_error;
        } else if (m_requests.empty() && m_in_flight == 0 && m_read_done) {
            final = {};
        } else if (m_requests.empty() && m_in_flight == 0 && m_draining) {
            final = shutting_down();
        } else {
            return;
        }
        m_member->closed = true;
        if (m_joined && !m_left) {
            // Leave the room before the status goes out, so that a client that has seen its
            // stream end (and the other members, through member_left) never finds it in the
            // room. Leaving takes the room's locks, which must not be taken under ours: a
            // worker does it, counted as processing so that nothing finishes meanwhile.
            m_processing = true;
            m_shared.pool.submit([this] {
                leave_room();
                std::lock_guard lock(m_member->mu);
                m_processing = false;
                maybe_finish_locked();
            });
            return;
        }
        m_finished = true;
        m_final = final;
        Finish(wire::to_grpc(final));
    }

    // Worker task: the member's requests in order, until none is left or the stream stops.
    void process() {
        for (;;) {
            v1::ReviewRequest request;
            {
                std::lock_guard lock(m_member->mu);
                if (m_requests.empty() || stopped_locked()) {
                    m_processing = false;
                    maybe_finish_locked();
                    return;
                }
                request = std::move(m_requests.front());
                m_requests.pop_front();
            }
            Status s = guarded([&] { return handle(request); });
            if (!s.ok()) {
                // Leave now, so the others see member_left at once and a new join under the
                // same name works; the room never saw the bad request's effects.
                leave_room();
                std::lock_guard lock(m_member->mu);
                if (!m_error) {
                    m_error = s;
                }
                m_member->closed = true;
                m_requests.clear();
                m_processing = false;
                maybe_finish_locked();
                return;
            }
        }
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

    Status handle(const v1::ReviewRequest& request) {
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
            // Shared: edits wait for this pose, so it sees exactly one model version.
            std::shared_lock edit_lock(m_room->edit_mutex());
            const auto& view = *m_room->view();
            out.model_version = view.version();
            auto result = m_tracker->query(pose.transform, m_options, &m_cancel);
            if (!result.ok()) {
                return result.status();
            }
            out.result = std::move(result).value();
            auto name = [&](std::uint32_t object) {
                auto n = view.object_name(object);
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

    ProximityService::Shared& m_shared;
    const std::string m_peer;
    const Clock::time_point m_start;
    CancelToken m_cancel;
    const std::shared_ptr<RoomMember> m_member;  // its mu guards the state below

    v1::ReviewRequest m_incoming;  // target of the outstanding read
    std::deque<v1::ReviewRequest> m_requests;
    std::size_t m_in_flight = 0;  // read, answer not yet written
    v1::ReviewEvent m_out;        // the outstanding write's message
    bool m_out_own = false;
    bool m_reading = false;
    bool m_read_done = false;
    bool m_writing = false;
    bool m_processing = false;
    bool m_finished = false;
    bool m_cancelled = false;
    bool m_write_failed = false;
    bool m_draining = false;
    bool m_overflowed = false;
    bool m_joined = false;  // in a room (m_room set)
    bool m_left = false;    // and left it again
    std::optional<Status> m_error;
    Status m_final;

    // Touched only by the one worker task (and by OnDone, after the last one).
    std::shared_ptr<Room> m_room;
    std::unique_ptr<massive::AvatarTracker> m_tracker;
    massive::AvatarQueryOptions m_options;
    std::uint64_t m_poses = 0;
    std::uint64_t m_edits = 0;
    // Set once in the constructor, before any other callback can run.
    StreamAdmission m_admission;
};

}  // namespace

Status ProximityService::start_models() {
    return m_shared->models.start();
}

grpc::ServerUnaryReactor* ProximityService::ListModels(grpc::CallbackServerContext* context,
                                                       const v1::ListModelsRequest*,
                                                       v1::ListModelsResponse* response) {
    auto* call = new UnaryCall(*m_shared, context, "ListModels", "");
    if (call->refused()) {
        return call;
    }
    // Off the callback thread: the rescan reads the models directory and opens new stores.
    m_shared->pool.submit([this, call, response] {
        std::string extra;
        call->complete(guarded([&]() -> Status {
                           // Only the models this token may use: the others do not exist for it.
                           auto& models = m_shared->models;
                           const auto& who = *call->principal();
                           for (const auto& m : models.list()) {
                               if (who.may_use_model(m->name)) {
                                   encode_model(*m, response->add_models());
                               }
                           }
                           for (const auto& u : models.unavailable()) {
                               if (who.may_use_model(u.name)) {
                                   encode_unavailable_model(u, response->add_unavailable());
                               }
                           }
                           response->set_cache_budget_bytes(models.cache()->budget());
                           wire::encode_cache_stats(models.cache()->stats(),
                                                    response->mutable_cache());
                           response->set_models_dir(models.dir());
                           extra = " models=" + std::to_string(response->models_size()) +
                                   " unavailable=" + std::to_string(response->unavailable_size());
                           return {};
                       }),
                       extra);
    });
    return call;
}

grpc::ServerWriteReactor<v1::VerifyModelEvent>* ProximityService::VerifyModel(
    grpc::CallbackServerContext* context, const v1::VerifyModelRequest* request) {
    return new VerifyReactor(*m_shared, context, request);
}

grpc::ServerBidiReactor<v1::ReviewRequest, v1::ReviewEvent>* ProximityService::Review(
    grpc::CallbackServerContext* context) {
    return new ReviewReactor(*m_shared, context);
}

}  // namespace proxima::server
