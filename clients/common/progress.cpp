#include "common/progress.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>

namespace proxima::client {

namespace {

std::string format_duration(double seconds) {
    if (!std::isfinite(seconds) || seconds < 0) {
        return "?";
    }
    const auto s = std::llround(seconds);
    char buf[32];
    if (s >= 3600) {
        std::snprintf(buf, sizeof buf, "%lld:%02lld:%02lld", s / 3600, (s / 60) % 60, s % 60);
    } else {
        std::snprintf(buf, sizeof buf, "%lld:%02lld", s / 60, s % 60);
    }
    return buf;
}

}  // namespace

std::string format_amount(double amount, const std::string& unit) {
    char buf[64];
    if (unit == "bytes") {
        static const char* const NAMES[] = {"B", "KiB", "MiB", "GiB", "TiB"};
        int k = 0;
        while (amount >= 1024 && k < 4) {
            amount /= 1024;
            ++k;
        }
        if (k == 0) {
            std::snprintf(buf, sizeof buf, "%.0f B", amount);
        } else {
            std::snprintf(buf, sizeof buf, "%.*f %s", amount < 10 ? 2 : 1, amount, NAMES[k]);
        }
        return buf;
    }
    static const char* const NAMES[] = {"", "K", "M", "G", "T"};
    int k = 0;
    while (amount >= 1000 && k < 4) {
        amount /= 1000;
        ++k;
    }
    if (k == 0) {
        std::snprintf(buf, sizeof buf, "%.0f", amount);
    } else {
        std::snprintf(buf, sizeof buf, "%.*f%s", amount < 10 ? 2 : 1, amount, NAMES[k]);
    }
    return buf;
}

ProgressPrinter::ProgressPrinter(bool quiet, std::FILE* out)
    : ProgressPrinter(quiet, out, ::isatty(::fileno(out)) != 0) {}

ProgressPrinter::ProgressPrinter(bool quiet, std::FILE* out, bool tty)
    : m_out(out), m_quiet(quiet), m_tty(tty) {}

ProgressPrinter::~ProgressPrinter() {
    finish();
}

massive::ProgressFn ProgressPrinter::callback() {
    return [this](const massive::Progress& p) { update(p); };
}

void ProgressPrinter::update(const massive::Progress& p) {
    if (m_quiet) {
        return;
    }
    std::lock_guard<std::mutex> lock(m_mutex);
    const auto now = Clock::now();
    if (p.step != m_step) {
        // A new step: close the previous one with its final numbers.
        if (!m_step.empty()) {
            print_locked(m_last, true);
        }
        m_step = p.step;
        m_step_start = now;
        m_last_print = now - std::chrono::hours(1);
        m_last_bucket = -1;
    }
    m_last = p;
    const bool complete = p.total > 0 && p.done >= p.total;
    if (m_tty) {
        // Redraw at most ~10 times a second; always draw the end of a step.
        if (complete || now - m_last_print >= std::chrono::milliseconds(100)) {
            m_last_print = now;
            print_locked(p, false);
        }
        return;
    }
    if (p.total > 0) {
        const int bucket =
            static_cast<int>(20.0 * static_cast<double>(p.done) / static_cast<double>(p.total));
        if (bucket > m_last_bucket) {
            m_last_bucket = bucket;
            m_last_print = now;
            print_locked(p, false);
        }
    } else if (now - m_last_print >= std::chrono::seconds(5)) {
        m_last_print = now;  // unknown total: a line every few seconds
        print_locked(p, false);
    }
}

void ProgressPrinter::print_locked(const massive::Progress& p, bool final_line) {
    const double elapsed = std::chrono::duration<double>(Clock::now() - m_step_start).count();
    // A rate of "steps" means nothing: only amounts of work get one (and an ETA).
    const double rate =
        elapsed > 0 && p.unit != "steps" ? static_cast<double>(p.done) / elapsed : 0.0;
    // Appended piece by piece: GCC 12 warns (-Wrestrict, a false positive) on "x" + string.
    std::string line = p.step;
    auto amount = [&](double v) {
        line += ' ';
        line += format_amount(v, p.unit);
    };
    auto unit = [&] {
        if (p.unit != "bytes") {
            line += ' ';
            line += p.unit;
        }
    };
    if (p.total > 0) {
        const double fraction =
            std::min(1.0, static_cast<double>(p.done) / static_cast<double>(p.total));
        if (m_tty) {
            constexpr int WIDTH = 30;
            const auto filled = static_cast<std::size_t>(fraction * WIDTH);
            line += " [";
            line.append(filled, '#');
            line.append(WIDTH - filled, '.');
            line += ']';
        }
        char pct[16];
        std::snprintf(pct, sizeof pct, " %3.0f%%", fraction * 100);
        line += pct;
        amount(static_cast<double>(p.done));
        line += " /";
        amount(static_cast<double>(p.total));
        unit();
        if (rate > 0) {
            line += ',';
            amount(rate);
            line += "/s";
            if (p.done < p.total) {
                line += ", ETA ";
                line += format_duration(static_cast<double>(p.total - p.done) / rate);
            }
        }
    } else {
        amount(static_cast<double>(p.done));
        unit();
        if (rate > 0) {
            line += ',';
            amount(rate);
            line += "/s";
        }
    }
    line += ", ";
    line += format_duration(elapsed);
    if (m_tty) {
        // \33[K clears what a longer previous line left behind.
        std::fprintf(m_out, "\r%s\33[K", line.c_str());
        m_line_open = true;
        if (final_line) {
            std::fputc('\n', m_out);
            m_line_open = false;
        }
    } else if (!final_line || m_last_bucket < 20) {
        std::fprintf(m_out, "%s\n", line.c_str());
    }
    std::fflush(m_out);
}

void ProgressPrinter::finish() {
    if (m_quiet) {
        return;
    }
    std::lock_guard<std::mutex> lock(m_mutex);
    if (!m_step.empty()) {
        print_locked(m_last, true);
        m_step.clear();
    }
    if (m_line_open) {
        std::fputc('\n', m_out);
        m_line_open = false;
    }
}

}  // namespace proxima::client
