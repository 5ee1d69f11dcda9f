// proximad: the proximity query daemon. Configuration, the signal thread, and the daemon's
// lifetime; everything else is in the proxima_server library.
#include <algorithm>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <thread>
#include <variant>

#include <malloc.h>
#include <pthread.h>
#include <spdlog/spdlog.h>

#include "config.hpp"
#include "daemon.hpp"

namespace {

// glibc gives each thread that contends for malloc an arena of its own, up to 8 per core. The
// daemon's threads (gRPC's, the workers, the cache's prefetcher) allocate and free pieces,
// hierarchy blocks and messages of every size across threads, and memory freed into many arenas
// is reused poorly: under a review load on a churning cache the RSS kept rising by ~15 MiB a
// minute with the default and stayed flat with one arena per core (docs/massive.md, "Memory").
// MALLOC_ARENA_MAX in the environment still decides when it is set.
void limit_malloc_arenas() {
    if (std::getenv("MALLOC_ARENA_MAX") != nullptr) {
        return;
    }
    const int cores = static_cast<int>(std::max(2u, std::thread::hardware_concurrency()));
    mallopt(M_ARENA_MAX, cores);
}

int run(int argc, char** argv) {
    using namespace proxima::server;
    limit_malloc_arenas();

    // SIGTERM and SIGINT are blocked in every thread and taken by one thread with sigwait, so
    // shutdown runs as ordinary code, not in a signal handler. The mask is inherited, so it must
    // be set before gRPC, oneTBB or the worker pool start threads.
    sigset_t shutdown_signals;
    sigemptyset(&shutdown_signals);
    sigaddset(&shutdown_signals, SIGTERM);
    sigaddset(&shutdown_signals, SIGINT);
    pthread_sigmask(SIG_BLOCK, &shutdown_signals, nullptr);

    auto outcome = load_config(argc, argv);
    if (const int* exit_code = std::get_if<int>(&outcome)) {
        return *exit_code;
    }
    const auto& config = std::get<ServerConfig>(outcome);
    configure_logging(config.log_level, config.log_format);

    Daemon daemon(config);
    auto address = daemon.start();
    if (!address.ok()) {
        spdlog::critical("{}", address.status().message());
        return 1;
    }
    // The contract with scripts and tests: the first line of standard output, flushed.
    std::printf("listening on %s\n", address.value().c_str());
    if (!daemon.metrics_address().empty()) {
        std::printf("metrics on %s\n", daemon.metrics_address().c_str());
    }
    std::fflush(stdout);

    std::thread signal_thread([&] {
        int signal = 0;
        sigwait(&shutdown_signals, &signal);
        daemon.shutdown(signal == SIGTERM ? "SIGTERM" : "SIGINT");
    });
    daemon.wait();
    signal_thread.join();
    return 0;
}

}  // namespace

// Whatever escapes the daemon (an allocation failure at start-up, a library throwing) ends it with
// a message and exit status 1, never with std::terminate's abort.
int main(int argc, char** argv) {
    try {
        return run(argc, argv);
    } catch (const std::exception& e) {
        std::fprintf(stderr, "proximad: fatal: %s\n", e.what());
    } catch (...) {
        std::fprintf(stderr, "proximad: fatal: unknown exception\n");
    }
    return 1;
}
