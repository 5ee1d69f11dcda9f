#pragma once
// Stopping long work: a token the caller cancels or gives a deadline, and the one status every
// layer (engine, daemon, clients) reports when a token stopped its work.

#include <atomic>
#include <chrono>
#include <optional>
#include <string_view>

#include "proxima/status.hpp"

namespace proxima {

// Lets a caller stop long work: cancellation or a deadline. Checked between work items, so a
// query stops within one object or one chunk of triangles.
class CancelToken {
  public:
    void cancel() { m_cancelled.store(true, std::memory_order_relaxed); }
    void set_deadline(std::chrono::steady_clock::time_point t) { m_deadline = t; }
    bool cancelled() const { return m_cancelled.load(std::memory_order_relaxed); }
    bool expired() const { return m_deadline && std::chrono::steady_clock::now() >= *m_deadline; }
    bool should_stop() const { return cancelled() || expired(); }

  private:
    std::atomic<bool> m_cancelled{false};
    std::optional<std::chrono::steady_clock::time_point> m_deadline;
};

// The status of work that `cancel` stopped: cancelled ("<what> cancelled by the caller") when the
// token was cancelled, otherwise deadline_exceeded ("<what> stopped: deadline exceeded").
// Cancellation wins when both hold. `what` names the work ("query", "ccd", "frame").
Status stop_status(const CancelToken& cancel, std::string_view what);

}  // namespace proxima
