#pragma once
// Stopping long work: a token the caller cancels or gives a deadline, and the one status every
// layer (engine, daemon, clients) reports when a token stopped its work.

#include <atomic>
#include <chrono>
#include <limits>
#include <string_view>

#include "proxima/status.hpp"

namespace proxima {

// Lets a caller stop long work: cancellation or a deadline. Checked between work items, so a
// query stops within one object or one chunk of triangles.
// Every member may be called from any thread at any time.
class CancelToken {
  public:
    using Clock = std::chrono::steady_clock;

    void cancel() { m_cancelled.store(true, std::memory_order_relaxed); }
    void set_deadline(Clock::time_point t) {
        m_deadline.store(t.time_since_epoch().count(), std::memory_order_relaxed);
    }
    // The deadline is reached now: the work stops as it would at its deadline, and stop_status
    // says deadline_exceeded (a caller whose own deadline ended the call).
    void expire() { set_deadline(Clock::now()); }
    bool cancelled() const { return m_cancelled.load(std::memory_order_relaxed); }
    bool has_deadline() const { return m_deadline.load(std::memory_order_relaxed) != NONE; }
    Clock::time_point deadline() const {
        return Clock::time_point(Clock::duration(m_deadline.load(std::memory_order_relaxed)));
    }
    bool expired() const { return has_deadline() && Clock::now() >= deadline(); }
    bool should_stop() const { return cancelled() || expired(); }

  private:
    static constexpr Clock::rep NONE = std::numeric_limits<Clock::rep>::max();
    std::atomic<bool> m_cancelled{false};
    std::atomic<Clock::rep> m_deadline{NONE};
};

// The status of work that `cancel` stopped: deadline_exceeded ("<what> stopped: deadline
// exceeded") once the token's deadline has passed, otherwise cancelled ("<what> cancelled by the
// caller"). The deadline wins when both hold: gRPC cancels a call whose deadline passed, and the
// deadline is the reason. `what` names the work ("query", "ccd", "frame").
Status stop_status(const CancelToken& cancel, std::string_view what);

}  // namespace proxima
