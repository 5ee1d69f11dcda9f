#pragma once
// The one state machine of the daemon's server-streaming calls that run long work (VerifyModel in
// verify_stream.cpp, FetchRegion in region_stream.cpp). Private to server/.
//
// The work runs on a thread of its own, not on the worker pool: it may take minutes and may wait
// for a slow reader, and on the pool it would hold a thread that frames need. Its events go into
// a bounded queue (max_pending); when the queue is full the work thread waits until the client
// reads, so memory stays bounded however slow the reader. Progress is one slot overwritten by
// each report and written only when no queued event waits (a slow reader sees the latest, not
// every one). The summary goes last, once the work returned OK.
//
// State is guarded by m_mu. Finish is called exactly once, by write_next_locked(), after the work
// thread has set m_done (so OnDone only joins a thread that is returning); OnDone takes m_mu once
// before deleting the reactor, so the thread that called Finish has let go.
//
// A kind of call derives from BoundedWriteStream<Event>, supplies the hooks below and calls
// open() last in its constructor.

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>

#include <grpcpp/grpcpp.h>
#include <spdlog/spdlog.h>

#include "proxima/cancel.hpp"
#include "proxima/status.hpp"
#include "proxima/wire/status.hpp"
#include "service_internal.hpp"

namespace proxima::server {

// What stops the writes of events already queued: only the client going away (OnCancel, a failed
// write), or also the call's token stopping (its deadline passing), which drops what is queued.
enum class WritesStop { client_gone, token_stopped };

template <class Event>
class BoundedWriteStream : public grpc::ServerWriteReactor<Event> {
  public:
    BoundedWriteStream(const BoundedWriteStream&) = delete;
    BoundedWriteStream& operator=(const BoundedWriteStream&) = delete;

    void OnWriteDone(bool ok) final {
        std::lock_guard lock(m_mu);
        m_writing = false;
        if (!ok) {
            m_write_failed = true;  // the client is gone: stop the work
            m_cancel.cancel();
        } else {
            ++m_events_written;
        }
        m_room.notify_all();
        write_next_locked();
    }

    void OnCancel() final {
        std::lock_guard lock(m_mu);
        m_cancelled = true;
        end_by_client(m_cancel);
        m_room.notify_all();
        write_next_locked();
    }

    void OnDone() final {
        { std::lock_guard lock(m_mu); }  // the thread that called Finish has released m_mu
        if (m_thread.joinable()) {
            if (m_thread.get_id() == std::this_thread::get_id()) {
                m_thread.detach();
            } else {
                m_thread.join();
            }
        }
        m_shared.leave_call();
        log_call(m_shared, m_method, m_admission.who(), m_peer, log_subject(), m_start, m_final,
                 log_extra() + " reader_waits=" + std::to_string(m_reader_waits) +
                     " events=" + std::to_string(m_events_written),
                 spdlog::level::info);
        delete this;
    }

  protected:
    // `method` names the call in logs and metrics; `what` names the work in the CANCELLED status
    // when the client goes away (stop_status: "<what> cancelled by the caller"); `max_pending` is
    // the queue's bound.
    BoundedWriteStream(ProximityService::Shared& shared, grpc::CallbackServerContext* context,
                       const char* method, std::string what, std::size_t max_pending,
                       WritesStop writes_stop)
        : m_shared(shared),
          m_peer(context->peer()),
          m_start(Clock::now()),
          m_context(context),
          m_method(method),
          m_what(std::move(what)),
          m_max_pending(max_pending),
          m_writes_stop(writes_stop) {
        apply_deadline(m_cancel, *context);
    }
    ~BoundedWriteStream() override = default;

    // The last step of the derived constructor: counts the call (refused while draining),
    // authenticates it and starts the work thread; a refused call finishes at once, with no event.
    void open() {
        if (!m_shared.enter_call()) {
            std::lock_guard lock(m_mu);
            m_done = true;
            m_status = shutting_down();
            write_next_locked();
            return;
        }
        if (Status s = m_admission.admit(m_shared, *m_context); !s.ok()) {
            std::lock_guard lock(m_mu);
            m_done = true;
            m_status = s;
            write_next_locked();
            return;
        }
        m_thread = std::thread([this] { run(); });
    }

    // ---- What a kind of call supplies ----

    // The work, on the call's thread, off the lock. It queues its events with queue(), reports
    // progress through progress_slot_locked() / progress_updated_locked() and sets the summary
    // with summary_locked() before returning OK; an error is the call's status.
    virtual Status work() = 0;
    // The log line's subject ("model=M generation=G") and extra fields (" tolerance=T ..."; the
    // reader's waits and the events written follow). Called by OnDone, after the work thread.
    virtual std::string log_subject() const = 0;
    virtual std::string log_extra() const = 0;

    // ---- What the derived call uses ----

    // Queues an event for the client, first waiting (m_mu released) while the queue is full and
    // the call goes on. False when the writes have stopped: the event is dropped (nobody will
    // read it) and the work should stop. `lock` holds m_mu.
    bool queue(std::unique_lock<std::mutex>& lock, Event event) {
        while (m_queue.size() >= m_max_pending && !stopped_locked() && !m_cancel.should_stop()) {
            ++m_reader_waits;
            // Timed: the deadline passing wakes nobody.
            m_room.wait_for(lock, std::chrono::milliseconds(100));
        }
        if (halted_locked()) {
            return false;
        }
        m_queue.push_back(std::move(event));
        write_next_locked();
        return true;
    }
    // The progress slot, overwritten in place by the work; then progress_updated_locked(), with
    // `pending` false when the slot is not worth writing (the next event says as much). Under m_mu.
    Event& progress_slot_locked() { return m_progress; }
    void progress_updated_locked(bool pending) {
        m_progress_dirty = pending;
        write_next_locked();
    }
    // The last event, written once the work returned OK and everything before it is written.
    // Under m_mu.
    void summary_locked(Event summary) { m_summary = std::move(summary); }

    ProximityService::Shared& m_shared;
    const std::string m_peer;
    const Clock::time_point m_start;
    CancelToken m_cancel;  // deadline set before the work thread starts; cancel() is atomic
    // Set once by open(), before the work thread starts.
    StreamAdmission m_admission;
    std::mutex m_mu;  // guards this class's state and the derived call's

  private:
    bool stopped_locked() const { return m_cancelled || m_write_failed; }
    bool halted_locked() const {
        return stopped_locked() ||
               (m_writes_stop == WritesStop::token_stopped && m_cancel.should_stop());
    }

    void run() {
        Status s = guarded([&] { return work(); });
        std::lock_guard lock(m_mu);
        m_done = true;
        m_status = s;
        write_next_locked();
    }

    // Starts the next write: queued events first (in order), then the latest progress, then (once
    // the work is done) the summary; Finish when nothing is left.
    void write_next_locked() {
        if (m_writing || m_finished) {
            return;
        }
        if (!halted_locked()) {
            if (!m_queue.empty()) {
                m_write = std::move(m_queue.front());
                m_queue.pop_front();
                m_room.notify_all();
            } else if (m_progress_dirty) {
                m_write = m_progress;
                m_progress_dirty = false;
            } else if (m_done && m_status.ok() && !m_summary_sent && m_summary) {
                m_write = *m_summary;
                m_summary_sent = true;
            } else {
                m_write.Clear();
            }
            if (m_write.event_case() != Event::EVENT_NOT_SET) {
                m_writing = true;
                this->StartWrite(&m_write);
                return;
            }
        }
        if (!m_done) {
            return;
        }
        m_finished = true;
        // Work that returned OK but whose summary never went out was stopped: OnCancel and a
        // failed write cancel the token, and so may its deadline.
        if (m_status.ok() && (halted_locked() || !m_summary_sent)) {
            m_final = stop_status(m_cancel, m_what);
        } else {
            m_final = m_status;
        }
        this->Finish(wire::to_grpc(m_final));
    }

    grpc::CallbackServerContext* const m_context;  // gRPC's, valid until OnDone returns
    const char* const m_method;
    const std::string m_what;
    const std::size_t m_max_pending;
    const WritesStop m_writes_stop;
    std::thread m_thread;

    std::condition_variable m_room;  // a queue slot freed, or the call stopped
    std::deque<Event> m_queue;
    Event m_progress;
    bool m_progress_dirty = false;
    std::optional<Event> m_summary;
    bool m_summary_sent = false;
    Event m_write;  // the outstanding write's message
    bool m_writing = false;
    bool m_done = false;  // the work thread has finished; m_status is its answer
    Status m_status;
    bool m_finished = false;
    bool m_cancelled = false;
    bool m_write_failed = false;
    Status m_final;
    std::uint64_t m_reader_waits = 0;
    std::uint64_t m_events_written = 0;
};

}  // namespace proxima::server
