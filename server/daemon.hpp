#pragma once
// The daemon around the service: the gRPC server (health, reflection, message size limits), the
// listening port, logging, and the graceful shutdown sequence. main() adds the signal thread.

#include <memory>
#include <mutex>
#include <string>
#include <string_view>

#include <grpcpp/grpcpp.h>

#include "config.hpp"
#include "proxima/status.hpp"
#include "service.hpp"

namespace proxima::server {

// Sets spdlog's default logger: one line per event on standard error (standard output carries
// only the `listening on` and `metrics on` lines), at `level` (validated by validate_config).
// `format` "text": `TIME LEVEL event key=value...`; "json": the same as one JSON object per line
// ({"time", "level", "event", then every key; a number stays a number}).
void configure_logging(const std::string& level, const std::string& format = "text");

// One log line's message as a JSON object (what the "json" format writes after time and level):
// the words before the first key=value are "event", values in double quotes may hold spaces,
// text after the last pair is "note". Exposed for tests.
std::string log_message_json(std::string_view message);

class Daemon {
  public:
    explicit Daemon(ServerConfig config);
    ~Daemon();
    Daemon(const Daemon&) = delete;
    Daemon& operator=(const Daemon&) = delete;

    // Builds and starts the server. Returns the address it listens on, "HOST:PORT" with the
    // port actually bound (port 0 in the configuration picks a free one).
    StatusOr<std::string> start();
    // The Prometheus endpoint's address once start() served one ("" without --metrics-listen).
    const std::string& metrics_address() const { return m_metrics_address; }
    // Blocks until shutdown() has finished.
    void wait();
    // Graceful shutdown, from any thread, once: health reports NOT_SERVING, streams stop taking
    // frames (idle ones end with UNAVAILABLE), new calls are refused, in-flight calls get
    // drain_seconds to finish and are cancelled after that. `reason` goes to the log.
    void shutdown(const std::string& reason);

    ProximityService& service() { return *m_service; }

  private:
    ServerConfig m_config;
    std::unique_ptr<ProximityService> m_service;  // outlives m_server, as gRPC requires
    std::unique_ptr<grpc::Server> m_server;
    std::once_flag m_shutdown_once;
    std::string m_metrics_address;
};

}  // namespace proxima::server
