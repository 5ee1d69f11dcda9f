#pragma once
// The one state machine of the daemon's bidirectional streams (StreamFrames in
// frame_stream.cpp, Review in review_stream.cpp). Private to server/.
//
// Requests are read while fewer than max_frames_in_flight are read but unanswered (backpressure:
// past that, no read is started, so gRPC's flow control pushes back on the client instead of the
// daemon buffering). One worker task at a time handles the stream's requests in order; what it
// answers (and, for a review member, what the room sends) is written in order, one write
// outstanding. A small request that finds the stream idle (no task running, nothing queued) may
// be handled at once on the gRPC thread that read it, without the hop to a worker and back, when
// the derived stream says it is cheap and can run without waiting (StreamFrames: a frame that
// only moves a few vertices; handle_inline); the stream's task is then that thread, so the order
// and every rule below are the same. A stream ends with OK when the client half-closed and
// everything read is answered, with UNAVAILABLE when the daemon drains, with the first error of a
// request (after the answers already made are written), or CANCELLED when the client went away.
//
// Every state change happens under the stream's mutex (mutex()). Finish is called exactly once,
// by maybe_finish_locked(), and only when no worker task runs and no write is outstanding
// (except for a stream failed by fail_now_locked(), whose client may never read that write);
// OnDone takes the mutex once before deleting the reactor, so the thread that called Finish has
// let go.
//
// A kind of stream derives from OrderedStream<Request, Response>, supplies the hooks below and
// calls open() last in its constructor.

#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <utility>

#include <grpcpp/grpcpp.h>
#include <spdlog/spdlog.h>

#include "proxima/cancel.hpp"
#include "proxima/status.hpp"
#include "proxima/wire/status.hpp"
#include "service_internal.hpp"

namespace proxima::server {

template <class Request, class Response>
class OrderedStream : public grpc::ServerBidiReactor<Request, Response>, public DrainableStream {
  public:
    OrderedStream(const OrderedStream&) = delete;
    OrderedStream& operator=(const OrderedStream&) = delete;

    void OnReadDone(bool ok) final {
        std::unique_lock lock(mutex());
        m_reading = false;
        if (!ok) {
            m_read_done = true;  // half-close (or the call is going away)
            maybe_finish_locked();
            return;
        }
        if (m_finished || stopped_locked()) {
            return;
        }
        auto charged = on_read_locked(m_incoming);
        if (!charged.ok()) {
            m_error = charged.status();
            drop_requests_locked();
            maybe_finish_locked();
            return;
        }
        m_requests.push_back({std::move(m_incoming), charged.value()});
        m_incoming.Clear();
        ++m_in_flight;
        start_read_if_room_locked();
        if (!m_processing) {
            m_processing = true;
            // Idle: the request just queued is the only one.
            if (inline_candidate_locked(m_requests.front().request, m_requests.front().charged)) {
                lock.unlock();
                process_inline();
                return;
            }
            m_shared.pool.submit([this] { process(); });
        }
    }

    void OnWriteDone(bool ok) final {
        std::lock_guard lock(mutex());
        m_writing = false;
        if (!ok) {
            // The client is gone: stop the request that may be running and drop the rest.
            m_write_failed = true;
            m_cancel.cancel();
            on_closing_locked();
            drop_requests_locked();
            maybe_finish_locked();
            return;
        }
        if (m_out_answers && m_in_flight > 0) {
            --m_in_flight;
        }
        start_read_if_room_locked();
        if (!m_finished && !m_cancelled && !m_overflowed && write_next_locked()) {
            return;
        }
        maybe_finish_locked();
    }

    void OnCancel() final {
        std::lock_guard lock(mutex());
        m_cancelled = true;
        end_by_client(m_cancel);
        on_closing_locked();
        drop_requests_locked();
        maybe_finish_locked();
    }

    void OnDone() final {
        {
            std::lock_guard lock(mutex());  // the thread that called Finish has let go
            drop_requests_locked();
            on_done_locked();
        }
        const std::string subject = log_subject();
        const std::string extra = log_extra();
        on_done();
        m_shared.leave_call(this);
        // The status the client saw: a stream whose client went away (cancelled it, was killed,
        // ran out of time) before its status was sent is logged as such, even when the daemon had
        // taken the end of its reads for a half-close and finished with OK.
        Status logged = m_final;
        if (logged.ok() && m_context->IsCancelled()) {
            end_by_client(m_cancel);
            logged = stop_status(m_cancel, m_what);
        }
        log_call(m_shared, m_method, m_admission.who(), m_peer, subject, m_start, logged, extra,
                 spdlog::level::info);
        delete this;
    }

    // Shutdown: read no more; finish once what was read is answered (now, when idle).
    void drain() final {
        std::lock_guard lock(mutex());
        m_draining = true;
        maybe_finish_locked();
    }

  protected:
    // `method` names the call in logs and metrics; `what` names the work in the CANCELLED status
    // when the client goes away (stop_status: "<what> cancelled by the caller").
    OrderedStream(ProximityService::Shared& shared, grpc::CallbackServerContext* context,
                  const char* method, std::string what)
        : m_shared(shared),
          m_peer(context->peer()),
          m_start(Clock::now()),
          m_context(context),
          m_method(method),
          m_what(std::move(what)) {
        apply_deadline(m_cancel, *context);
    }
    ~OrderedStream() override = default;

    // The last step of the derived constructor: counts the call (refused while draining),
    // authenticates it and starts the first read.
    void open() {
        const bool accepted = m_shared.enter_call(this);
        std::lock_guard lock(mutex());
        m_draining = m_draining || !accepted;
        if (accepted) {
            if (Status s = m_admission.admit(m_shared, *m_context); !s.ok()) {
                m_error = s;
            }
        }
        start_read_if_room_locked();
        maybe_finish_locked();
    }

    // ---- What a kind of stream supplies ----

    // Guards the state of this class and the derived stream's.
    virtual std::mutex& mutex() = 0;
    // A request was read: charge it (StreamFrames: the principal's max-bytes-in-flight) and
    // return what was charged, handed back to handle() or on_dropped_locked(). An error ends the
    // stream with it. Under the lock.
    virtual StatusOr<std::uint64_t> on_read_locked(const Request& /*request*/) {
        return std::uint64_t{0};
    }
    // Requests read but never handled give back what they were charged (the sum). Under the lock.
    virtual void on_dropped_locked(std::uint64_t /*charged*/) {}
    // One request, on the stream's one worker task, off the lock. Its answers are queued by the
    // derived stream under the lock, followed by answers_ready_locked(). An error ends the
    // stream with it (after the answers already queued are written).
    virtual Status handle(Request& request, std::uint64_t charged) = 0;
    // Whether a request that finds the stream idle is worth trying on the gRPC thread that read
    // it (handle_inline): only for work that is small and bounded. `charged`: what
    // on_read_locked charged for it. Under the lock.
    virtual bool inline_candidate_locked(const Request& /*request*/, std::uint64_t /*charged*/) {
        return false;
    }
    // handle() on a gRPC thread, which must never wait (for another call's lock, say): nullopt
    // when it would, having changed nothing (the request then goes to a worker's handle()).
    virtual std::optional<Status> handle_inline(Request& /*request*/, std::uint64_t /*charged*/) {
        return std::nullopt;
    }
    // A request failed: runs off the lock before the error is recorded (Review leaves its room
    // at once, so the others see it go).
    virtual void on_failed() {}
    // The next message to write, moved into `out`; `answers` is true when it answers one of the
    // stream's requests (its place in the read window is freed once written). False when nothing
    // waits. Under the lock.
    virtual bool next_write_locked(Response* out, bool* answers) = 0;
    // The stream takes no more events (client gone, an error, the end). Under the lock.
    virtual void on_closing_locked() {}
    // Work that must be done, off the lock, before the final status goes out (Review: leave the
    // room, so that a client that has seen its stream end never finds itself in it); empty when
    // there is none. Runs as the stream's worker task. Under the lock.
    virtual std::function<void()> before_finish_locked() { return {}; }
    // OnDone's steps: under the lock, then off it (the derived stream frees what it holds).
    virtual void on_done_locked() {}
    virtual void on_done() {}
    // The log line's subject ("scene=ID", "room=R model=M member=N") and extra fields.
    virtual std::string log_subject() const = 0;
    virtual std::string log_extra() const = 0;

    // ---- What the derived stream calls ----

    // New answers (or events) are queued: starts a write unless one is outstanding or the
    // stream is going away. Under the lock.
    void answers_ready_locked() {
        if (!m_writing && !m_finished && !m_cancelled && !m_write_failed) {
            write_next_locked();
        }
    }
    // Ends the stream now with `status`, even with a write outstanding (Review: a member that
    // fell behind, whose client may never read it). Under the lock.
    void fail_now_locked(Status status) {
        if (!m_error) {
            m_error = std::move(status);
        }
        m_overflowed = true;
        m_cancel.cancel();
        drop_requests_locked();
        maybe_finish_locked();
    }

    ProximityService::Shared& m_shared;
    const std::string m_peer;
    const Clock::time_point m_start;
    CancelToken m_cancel;  // deadline set before any task runs; cancel() is atomic
    // Set once by open(), before any other callback can run.
    StreamAdmission m_admission;

  private:
    struct Queued {
        Request request;
        std::uint64_t charged = 0;
    };

    bool stopped_locked() const { return m_cancelled || m_write_failed || m_error.has_value(); }

    void drop_requests_locked() {
        std::uint64_t charged = 0;
        for (const auto& q : m_requests) {
            charged += q.charged;
        }
        m_requests.clear();
        if (charged != 0) {
            on_dropped_locked(charged);
        }
    }

    void start_read_if_room_locked() {
        if (m_reading || m_read_done || m_finished || m_draining || stopped_locked() ||
            m_in_flight >= m_shared.config.limits.max_frames_in_flight) {
            return;
        }
        m_reading = true;
        this->StartRead(&m_incoming);
    }

    bool write_next_locked() {
        bool answers = false;
        if (!next_write_locked(&m_out, &answers)) {
            return false;
        }
        m_out_answers = answers;
        m_writing = true;
        this->StartWrite(&m_out);
        return true;
    }

    void maybe_finish_locked() {
        if (m_finished || m_processing || (m_writing && !m_overflowed)) {
            return;
        }
        Status final;
        if (m_cancelled || m_write_failed) {
            final = stop_status(m_cancel, m_what);  // cancelled: both paths cancel the token
        } else if (m_error) {
            // A bad request: what was answered before it still reaches the client (unless the
            // stream was failed at once); nothing new is queued meanwhile.
            on_closing_locked();
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
        on_closing_locked();
        if (auto work = before_finish_locked()) {
            // Counted as processing, so that nothing finishes meanwhile; the status is decided
            // again afterwards.
            m_processing = true;
            m_shared.pool.submit([this, work = std::move(work)] {
                work();
                std::lock_guard lock(mutex());
                m_processing = false;
                maybe_finish_locked();
            });
            return;
        }
        m_finished = true;
        m_final = final;
        this->Finish(wire::to_grpc(final));
    }

    // The stream's task on a worker: the queued requests in order, until none is left or the
    // stream stops.
    void process() {
        for (;;) {
            Queued next;
            {
                std::lock_guard lock(mutex());
                if (m_requests.empty() || stopped_locked()) {
                    stop_processing_locked();
                    return;
                }
                next = std::move(m_requests.front());
                m_requests.pop_front();
            }
            const Status s = guarded([&] { return handle(next.request, next.charged); });
            if (!s.ok()) {
                fail(s);
                return;
            }
        }
    }

    // The stream's task on the gRPC thread that read the one request queued
    // (inline_candidate_locked): tried with handle_inline; a request it would have had to wait
    // for goes back to the front of the queue, and whatever is queued after it goes to a worker.
    void process_inline() {
        Queued next;
        {
            std::lock_guard lock(mutex());
            if (m_requests.empty() || stopped_locked()) {
                stop_processing_locked();
                return;
            }
            next = std::move(m_requests.front());
            m_requests.pop_front();
        }
        std::optional<Status> done;
        Status s = guarded([&] {
            done = handle_inline(next.request, next.charged);
            return Status{};
        });
        if (s.ok() && done) {
            s = *done;
        }
        if (!s.ok()) {
            fail(s);
            return;
        }
        std::lock_guard lock(mutex());
        if (stopped_locked()) {
            if (!done) {
                on_dropped_locked(next.charged);
            }
            stop_processing_locked();
            return;
        }
        if (!done) {
            m_requests.push_front(std::move(next));
        }
        if (m_requests.empty()) {
            stop_processing_locked();
            return;
        }
        m_shared.pool.submit([this] { process(); });
    }

    void stop_processing_locked() {
        m_processing = false;
        maybe_finish_locked();
    }

    // A request failed: the stream ends with its status; the rest is dropped.
    void fail(const Status& s) {
        on_failed();
        std::lock_guard lock(mutex());
        if (!m_error) {
            m_error = s;
        }
        on_closing_locked();
        drop_requests_locked();
        stop_processing_locked();
    }

    grpc::CallbackServerContext* const m_context;  // gRPC's, valid until OnDone returns
    const char* const m_method;
    const std::string m_what;

    Request m_incoming;             // target of the outstanding read
    std::deque<Queued> m_requests;  // read, not yet handled
    std::size_t m_in_flight = 0;    // read, answer not yet written
    Response m_out;                 // the outstanding write's message
    bool m_out_answers = false;     // it answers a request
    bool m_reading = false;
    bool m_read_done = false;
    bool m_writing = false;
    bool m_processing = false;
    bool m_finished = false;
    bool m_cancelled = false;
    bool m_write_failed = false;
    bool m_draining = false;
    bool m_overflowed = false;
    std::optional<Status> m_error;
    Status m_final;
};

}  // namespace proxima::server
