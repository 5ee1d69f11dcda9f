// FetchRegion: a served model's geometry near a point for viewers (the review page), nearest
// piece first, streamed one piece at a time through the shared geometry cache. The selection and
// the reads are the engine's (proxima/massive/region.hpp); the conversions proto/wire's.
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>

#include <spdlog/spdlog.h>

#include "proxima/massive/region.hpp"
#include "proxima/wire/massive.hpp"
#include "proxima/wire/status.hpp"
#include "service.hpp"
#include "service_internal.hpp"

namespace proxima::server {

namespace {

// Encoded pieces waiting for the client; past that the reading thread waits for the reader, so
// the daemon holds at most this many pieces (plus the one being read) per call, whatever the
// region's size and however slow the client.
constexpr std::size_t REGION_MAX_PENDING_PIECES = 4;

// FetchRegion. Like VerifyModel: the work runs on a thread of its own (a whole model takes a while
// and may wait for a slow reader: on the worker pool it would hold a thread that frames need),
// pieces go through a bounded queue, progress is one slot overwritten after each piece and written
// when no piece is waiting, the summary goes last. Every check runs before the first piece is
// read, so a bad request gets its status and no event.
//
// State is guarded by m_mu. Finish is called once, by write_next_locked(), after the thread has
// set m_done.
class RegionReactor final : public grpc::ServerWriteReactor<v1::RegionEvent> {
  public:
    RegionReactor(ProximityService::Shared& shared, grpc::CallbackServerContext* context,
                  const v1::FetchRegionRequest* request)
        : m_shared(shared), m_peer(context->peer()), m_message(*request), m_start(Clock::now()) {
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
            m_write_failed = true;  // the client is gone: stop reading pieces
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
        end_by_client(m_cancel);
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
        std::string subject = "model=" + (m_message.model().empty() ? "-" : m_message.model());
        if (!m_message.room().empty()) {
            subject += " room=" + m_message.room();
        }
        if (m_generation) {
            subject += " generation=" + *m_generation;
        }
        log_call(m_shared, "FetchRegion", m_admission.who(), m_peer, subject, m_start, m_final,
                 " radius=" + std::to_string(m_message.radius()) +
                     " pieces=" + std::to_string(m_pieces_sent) +
                     " triangles=" + std::to_string(m_triangles_sent) + " reader_waits=" +
                     std::to_string(m_reader_waits) + " events=" + std::to_string(m_events_written),
                 spdlog::level::info);
        delete this;
    }

  private:
    bool stopped_locked() const { return m_cancelled || m_write_failed; }

    Status fetch() {
        auto decoded = wire::decode_region_request(m_message);
        if (!decoded.ok()) {
            return decoded.status();
        }
        const massive::RegionRequest request = std::move(decoded).value();
        const auto& who = *m_admission.principal();
        auto model = find_model(m_shared, who, request.model);
        if (!model.ok()) {
            return model.status();
        }
        std::shared_ptr<const massive::Store> store = model.value()->store;
        std::shared_ptr<const massive::ModelView::Snapshot> snapshot;
        std::uint32_t object_count = static_cast<std::uint32_t>(store->objects().size());
        if (!request.room.empty()) {
            // The room's access, as for joining it (Review).
            if (!who.may_join_room(request.room)) {
                return {StatusCode::permission_denied,
                        "token '" + who.name() + "' may not see review room '" + request.room +
                            "' (no pattern of its rooms matches)"};
            }
            const std::shared_ptr<Room> room = m_shared.rooms.find(request.room);
            if (!room) {
                return not_found("room " + request.room +
                                 " does not exist (a room lives while it has members)");
            }
            if (room->model().name != request.model) {
                return failed_precondition("room " + request.room + " reviews model '" +
                                           room->model().name + "', not '" + request.model + "'");
            }
            // The room's view is on the store the room opened (the same generation its members
            // see), and one snapshot of it: every piece comes from one model version.
            store = room->view()->store();
            snapshot = room->view()->snapshot();
            object_count = static_cast<std::uint32_t>(store->objects().size());
            for (const auto& o : snapshot->overlay) {
                object_count = std::max(object_count, o.object + 1);
            }
        }
        if (Status s = massive::check_region_request(request, object_count); !s.ok()) {
            return s;
        }
        {
            std::lock_guard lock(m_mu);
            m_generation = store->summary().generation;
        }
        const massive::RegionPlan plan = massive::plan_region(*store, snapshot.get(), request);
        spdlog::info(
            "region start method=FetchRegion who={} peer={} model={} room={} generation={} "
            "radius={} pieces={} triangles={} truncated={}",
            m_admission.who(), m_peer, request.model, request.room.empty() ? "-" : request.room,
            store->summary().generation, request.radius, plan.pieces.size(), plan.triangles,
            plan.truncated);

        massive::RegionProgress progress;
        progress.pieces_total = plan.pieces.size();
        progress.triangles_total = plan.triangles;
        auto& cache = *m_shared.models.cache();
        for (const auto& ref : plan.pieces) {
            if (m_cancel.should_stop()) {
                break;
            }
            auto piece = massive::read_region_piece(store, cache, snapshot.get(), ref);
            if (!piece.ok()) {
                return piece.status();
            }
            v1::RegionEvent event;
            wire::encode_region_event(piece.value(), !request.float64, &event);
            ++progress.pieces_sent;
            progress.triangles_sent += ref.triangles;
            std::unique_lock lock(m_mu);
            while (m_pieces.size() >= REGION_MAX_PENDING_PIECES && !stopped_locked() &&
                   !m_cancel.should_stop()) {
                ++m_reader_waits;
                // Timed: the deadline passing wakes nobody.
                m_room.wait_for(lock, std::chrono::milliseconds(100));
            }
            if (stopped_locked() || m_cancel.should_stop()) {
                break;
            }
            m_pieces.push_back(std::move(event));
            m_pieces_sent = progress.pieces_sent;
            m_triangles_sent = progress.triangles_sent;
            m_progress.Clear();
            wire::encode_region_event(progress, true, &m_progress);
            m_progress_dirty = progress.pieces_sent < progress.pieces_total;
            write_next_locked();
        }
        if (m_cancel.should_stop()) {
            return {};  // write_next_locked() reports how it stopped
        }
        massive::RegionSummary summary;
        summary.pieces = progress.pieces_sent;
        summary.triangles = progress.triangles_sent;
        summary.truncated = plan.truncated;
        summary.model_version = snapshot ? snapshot->version : 0;
        summary.generation = store->summary().generation;
        summary.server_seconds = std::chrono::duration<double>(Clock::now() - m_start).count();
        std::lock_guard lock(m_mu);
        wire::encode_region_event(summary, true, &m_summary);
        return {};
    }

    void run() {
        Status s = guarded([&] { return fetch(); });
        std::lock_guard lock(m_mu);
        m_done = true;
        m_status = s;
        write_next_locked();
    }

    // Starts the next write: pieces first (in order), then the latest progress, then (once the
    // thread is done) the summary; Finish when nothing is left.
    void write_next_locked() {
        if (m_writing || m_finished) {
            return;
        }
        if (!stopped_locked() && !m_cancel.should_stop()) {
            if (!m_pieces.empty()) {
                m_write = std::move(m_pieces.front());
                m_pieces.pop_front();
                m_room.notify_all();
            } else if (m_progress_dirty) {
                m_write = m_progress;
                m_progress_dirty = false;
            } else if (m_done && m_status.ok() && !m_summary_sent &&
                       m_summary.event_case() != v1::RegionEvent::EVENT_NOT_SET) {
                m_write = m_summary;
                m_summary_sent = true;
            } else {
                m_write.Clear();
            }
            if (m_write.event_case() != v1::RegionEvent::EVENT_NOT_SET) {
                m_writing = true;
                StartWrite(&m_write);
                return;
            }
        }
        if (!m_done) {
            return;
        }
        m_finished = true;
        if (m_status.ok() && (stopped_locked() || m_cancel.should_stop() || !m_summary_sent)) {
            m_final = stop_status(m_cancel, "region fetch");
        } else {
            m_final = m_status;
        }
        Finish(wire::to_grpc(m_final));
    }

    ProximityService::Shared& m_shared;
    const std::string m_peer;
    const v1::FetchRegionRequest m_message;
    const Clock::time_point m_start;
    CancelToken m_cancel;
    std::thread m_thread;

    std::mutex m_mu;
    std::condition_variable m_room;  // a piece slot freed, or the call stopped
    std::deque<v1::RegionEvent> m_pieces;
    v1::RegionEvent m_progress;
    bool m_progress_dirty = false;
    v1::RegionEvent m_summary;
    bool m_summary_sent = false;
    v1::RegionEvent m_write;  // the outstanding write's message
    bool m_writing = false;
    bool m_done = false;  // the thread has finished; m_status is its answer
    Status m_status;
    bool m_finished = false;
    bool m_cancelled = false;
    bool m_write_failed = false;
    Status m_final;
    std::optional<std::string> m_generation;
    std::uint64_t m_pieces_sent = 0;
    std::uint64_t m_triangles_sent = 0;
    std::uint64_t m_reader_waits = 0;
    std::uint64_t m_events_written = 0;
    StreamAdmission m_admission;
};

}  // namespace

grpc::ServerWriteReactor<v1::RegionEvent>* ProximityService::FetchRegion(
    grpc::CallbackServerContext* context, const v1::FetchRegionRequest* request) {
    return new RegionReactor(*m_shared, context, request);
}

}  // namespace proxima::server
