#pragma once
// The daemon around the service: the gRPC server (health, reflection, message size limits), the
// listening port, logging, and the graceful shutdown sequence. main() adds the signal thread.

#include <memory>
#include <mutex>
#include <string>

#include <grpcpp/grpcpp.h>

#include "config.hpp"
#include "proxima/status.hpp"
#include "service.hpp"

namespace proxima::server {

// Sets spdlog's default logger: one line per event on standard error (standard output carries
// only the `listening on` line), at `level` (validated by validate_config).
void configure_logging(const std::string& level);

class Daemon {
  public:
    explicit Daemon(ServerConfig config);
    ~Daemon();
    Daemon(const Daemon&) = delete;
    Daemon& operator=(const Daemon&) = delete;

    // Builds and starts the server. Returns the address it listens on, "HOST:PORT" with the
    // port actually bound (port 0 in the configuration picks a free one).
    StatusOr<std::string> start();
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
};

}  // namespace proxima::server
