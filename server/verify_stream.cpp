// VerifyModel: the static verification of a massive model (seed 001, IMMPACT §4.4-§6.5),
// streamed as it runs.
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

#include "encode.hpp"
#include "proxima/massive/verify.hpp"
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
            m_final =
                stop_status(m_cancel, "verification");  // OnCancel and a failed write cancel it
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

}  // namespace

grpc::ServerWriteReactor<v1::VerifyModelEvent>* ProximityService::VerifyModel(
    grpc::CallbackServerContext* context, const v1::VerifyModelRequest* request) {
    return new VerifyReactor(*m_shared, context, request);
}

}  // namespace proxima::server
