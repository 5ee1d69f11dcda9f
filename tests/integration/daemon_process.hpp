#pragma once
// A proximad child process for one test: started on 127.0.0.1:0, its port read from the first
// line of its standard output, and always gone when the guard is: SIGKILL and reaped in the
// destructor, and PR_SET_PDEATHSIG so that even a crashed test leaves no daemon behind.

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <optional>
#include <string>
#include <thread>
#include <vector>

namespace proxima::test {

class DaemonProcess {
  public:
    // Starts `PROXIMAD_PATH --listen 127.0.0.1:0 extra...` and waits (up to `timeout`) for the
    // `listening on` line. On failure `ok()` is false and `error()` says why.
    explicit DaemonProcess(std::vector<std::string> extra = {},
                           std::chrono::milliseconds timeout = std::chrono::seconds(10)) {
        // `--listen` in `extra` (a fixed port, to restart a daemon on the same address) replaces
        // the default free loopback port.
        std::vector<std::string> args = {PROXIMAD_PATH};
        if (std::find(extra.begin(), extra.end(), "--listen") == extra.end()) {
            args.insert(args.end(), {"--listen", "127.0.0.1:0"});
        }
        args.insert(args.end(), extra.begin(), extra.end());
        int out[2];
        if (pipe2(out, O_CLOEXEC) != 0) {
            m_error = "pipe failed";
            return;
        }
        // Built before fork: the child of a multithreaded process may only make
        // async-signal-safe calls (no allocation) until execv.
        std::vector<char*> argv;
        for (auto& a : args) {
            argv.push_back(a.data());
        }
        argv.push_back(nullptr);
        const pid_t parent = getpid();
        m_pid = fork();
        if (m_pid < 0) {
            m_error = "fork failed";
            return;
        }
        if (m_pid == 0) {
            // Child: dies with the test process, whatever happens to it.
            prctl(PR_SET_PDEATHSIG, SIGKILL);
            if (getppid() != parent) {
                _exit(127);
            }
            dup2(out[1], STDOUT_FILENO);
            execv(argv[0], argv.data());
            _exit(127);
        }
        close(out[1]);
        m_stdout = out[0];
        read_first_line(timeout);
    }

    ~DaemonProcess() {
        if (m_pid > 0 && !m_exit_status) {
            kill(m_pid, SIGKILL);
            int status = 0;
            waitpid(m_pid, &status, 0);
        }
        if (m_stdout >= 0) {
            close(m_stdout);
        }
    }

    DaemonProcess(const DaemonProcess&) = delete;
    DaemonProcess& operator=(const DaemonProcess&) = delete;

    bool ok() const { return m_port > 0; }
    const std::string& error() const { return m_error; }
    const std::string& first_line() const { return m_first_line; }
    int port() const { return m_port; }
    std::string address() const { return "127.0.0.1:" + std::to_string(m_port); }
    pid_t pid() const { return m_pid; }

    void signal(int sig) const {
        if (m_pid > 0 && !m_exit_status) {
            kill(m_pid, sig);
        }
    }

    // The raw wait status once the child exited within `timeout`; nullopt if it is still running.
    std::optional<int> wait_exit(std::chrono::milliseconds timeout) {
        const auto until = std::chrono::steady_clock::now() + timeout;
        while (!m_exit_status) {
            int status = 0;
            const pid_t r = waitpid(m_pid, &status, WNOHANG);
            if (r == m_pid) {
                m_exit_status = status;
                break;
            }
            if (std::chrono::steady_clock::now() >= until) {
                break;
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(10));
        }
        return m_exit_status;
    }

    bool running() { return m_pid > 0 && !wait_exit(std::chrono::milliseconds(0)).has_value(); }

    // The next line of the daemon's standard output (e.g. `metrics on HOST:PORT`, the second
    // line with --metrics-listen), or nullopt when none comes within `timeout`.
    std::optional<std::string> next_line(std::chrono::milliseconds timeout) {
        std::string line;
        if (!read_line(timeout, line)) {
            return std::nullopt;
        }
        return line;
    }

  private:
    // One line without its newline; false (with what came so far in `line`) on timeout or EOF.
    bool read_line(std::chrono::milliseconds timeout, std::string& line) {
        const auto until = std::chrono::steady_clock::now() + timeout;
        for (;;) {
            const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                until - std::chrono::steady_clock::now());
            if (left.count() <= 0) {
                return false;
            }
            pollfd p{m_stdout, POLLIN, 0};
            if (poll(&p, 1, static_cast<int>(left.count())) <= 0) {
                continue;
            }
            char c = 0;
            const ssize_t n = read(m_stdout, &c, 1);
            if (n <= 0) {
                return false;
            }
            if (c == '\n') {
                return true;
            }
            line += c;
        }
    }

    void read_first_line(std::chrono::milliseconds timeout) {
        std::string line;
        if (!read_line(timeout, line)) {
            m_error =
                "no full `listening on` line within the timeout (or standard output closed); "
                "got '" +
                line + "'";
            return;
        }
        m_first_line = line;
        const std::string prefix = "listening on 127.0.0.1:";
        if (line.rfind(prefix, 0) != 0) {
            m_error = "first line is '" + line + "', not 'listening on 127.0.0.1:PORT'";
            return;
        }
        m_port = std::atoi(line.c_str() + prefix.size());
        if (m_port <= 0) {
            m_error = "bad port in '" + line + "'";
        }
    }

    pid_t m_pid = -1;
    int m_stdout = -1;
    int m_port = 0;
    std::string m_first_line;
    std::string m_error;
    std::optional<int> m_exit_status;
};

}  // namespace proxima::test
