#include "daemon.hpp"

#include <chrono>
#include <utility>

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>
#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>

namespace proxima::server {

void configure_logging(const std::string& level) {
    auto logger = spdlog::stderr_logger_mt("proximad");
    // ISO time, level, then key=value pairs: easy for people and for log collectors.
    logger->set_pattern("%Y-%m-%dT%H:%M:%S.%e%z %l %v");
    logger->set_level(spdlog::level::from_str(level));
    logger->flush_on(spdlog::level::trace);
    spdlog::set_default_logger(std::move(logger));
}

Daemon::Daemon(ServerConfig config)
    : m_config(std::move(config)), m_service(std::make_unique<ProximityService>(m_config)) {}

Daemon::~Daemon() {
    if (m_server) {
        shutdown("daemon destroyed");
        m_server->Wait();
        m_server.reset();
    }
}

StatusOr<std::string> Daemon::start() {
    if (Status s = m_service->start_models(); !s.ok()) {
        return s;
    }
    // Both apply to servers built afterwards; the health service answers grpc.health.v1 for ""
    // and for proxima.v1.Proximity.
    grpc::EnableDefaultHealthCheckService(true);
    grpc::reflection::InitProtoReflectionServerBuilderPlugin();

    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort(m_config.listen, grpc::InsecureServerCredentials(), &port);
    // gRPC sets SO_REUSEPORT by default: a second daemon on a busy port would then start and
    // share the port's connections with the first. A busy port must be an error.
    builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
    // Explicit in both directions: a frame of a large scene is big, but not unboundedly so.
    const int max_bytes = static_cast<int>(m_config.limits.max_message_bytes);
    builder.SetMaxReceiveMessageSize(max_bytes);
    builder.SetMaxSendMessageSize(max_bytes);
    builder.RegisterService(m_service.get());
    m_server = builder.BuildAndStart();
    if (!m_server || port == 0) {
        m_server.reset();
        return Status(StatusCode::unavailable,
                      "cannot listen on " + m_config.listen +
                          " (port in use, address not on this machine, or not HOST:PORT)");
    }
    if (auto* health = m_server->GetHealthCheckService()) {
        health->SetServingStatus("", true);
        health->SetServingStatus("proxima.v1.Proximity", true);
    }
    const auto host = m_config.listen.substr(0, m_config.listen.rfind(':'));
    const auto address = host + ":" + std::to_string(port);
    const auto& l = m_config.limits;
    spdlog::info(
        "proximad {} serving proxima.v1 on {} backend=\"{}\" gl_renderer=\"{}\" "
        "max_scenes={} max_objects_per_scene={} max_triangles_per_scene={} "
        "max_message_bytes={} max_frames_in_flight={} drain_seconds={} models=\"{}\" "
        "cache_bytes={}",
        PROXIMA_VERSION, address, m_service->proximity_backend(),
        m_service->gl_renderer().empty() ? "none" : m_service->gl_renderer(), l.max_scenes,
        l.max_objects_per_scene, l.max_triangles_per_scene, l.max_message_bytes,
        l.max_frames_in_flight, m_config.drain_seconds, m_config.models_dir, m_config.cache_bytes);
    return address;
}

void Daemon::wait() {
    if (m_server) {
        m_server->Wait();
    }
}

void Daemon::shutdown(const std::string& reason) {
    std::call_once(m_shutdown_once, [&] {
        if (!m_server) {
            return;
        }
        const auto start = std::chrono::steady_clock::now();
        spdlog::info("shutdown reason={} live_streams={} live_scenes={} drain_seconds={}", reason,
                     m_service->live_streams(), m_service->live_scenes(), m_config.drain_seconds);
        if (auto* health = m_server->GetHealthCheckService()) {
            health->Shutdown();  // NOT_SERVING for every service, and it stays so
        }
        // The drain is ours, not Server::Shutdown(deadline)'s: gRPC's graceful shutdown also
        // waits for idle client connections to close, which can take the whole deadline when
        // nothing is left to do. While draining, new calls get UNAVAILABLE and health checks
        // NOT_SERVING, so load balancers move on.
        m_service->begin_drain();
        const auto deadline = std::chrono::steady_clock::now() +
                              std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                  std::chrono::duration<double>(m_config.drain_seconds));
        if (!m_service->wait_idle(deadline)) {
            spdlog::warn("shutdown drain deadline passed with {} calls in flight; cancelling them",
                         m_service->live_calls());
        }
        // Stops accepting and cancels whatever is left (reactors see OnCancel, which stops the
        // engine through their CancelToken), then closes the connections.
        m_server->Shutdown(std::chrono::system_clock::now());
        spdlog::info(
            "shutdown complete duration_ms={:.3f}",
            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                .count());
    });
}

}  // namespace proxima::server
