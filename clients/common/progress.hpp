#pragma once
// Progress of long CLI steps on standard error. On a terminal one line is redrawn in place (step,
// bar, percent, rate, ETA); otherwise (a log file, CI) a line is printed every ~5% of a step, so
// logs stay short. Quiet prints nothing. Callable from several threads.

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <mutex>
#include <string>

#include "proxima/massive/model.hpp"

namespace proxima::client {

class ProgressPrinter {
  public:
    explicit ProgressPrinter(bool quiet, std::FILE* out = stderr);
    // Same, with the terminal decision made by the caller (tests).
    ProgressPrinter(bool quiet, std::FILE* out, bool tty);
    ~ProgressPrinter();
    ProgressPrinter(const ProgressPrinter&) = delete;
    ProgressPrinter& operator=(const ProgressPrinter&) = delete;

    void update(const massive::Progress& progress);
    // Ends the current line (on a terminal) so that later output starts on a fresh one.
    void finish();
    // A ProgressFn that forwards here (the printer must outlive it).
    massive::ProgressFn callback();

  private:
    using Clock = std::chrono::steady_clock;
    void print_locked(const massive::Progress& p, bool final_line);

    std::mutex m_mutex;
    std::FILE* m_out;
    bool m_quiet;
    bool m_tty;
    std::string m_step;
    Clock::time_point m_step_start;
    Clock::time_point m_last_print;
    int m_last_bucket = -1;  // the last 5% bucket printed (not a terminal)
    bool m_line_open = false;
    massive::Progress m_last;
};

// "1.50 GiB", "12.0 MiB", "512 B" for bytes; "15.0M", "1.20K" for other units.
std::string format_amount(double amount, const std::string& unit);

}  // namespace proxima::client
