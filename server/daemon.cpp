#include "daemon.hpp"

#include <cctype>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <iterator>
#include <utility>

#include <grpc/support/log.h>
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>
#include <spdlog/pattern_formatter.h>
#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>
#include <nlohmann/json.hpp>

namespace proxima::server {

namespace {

bool is_number(std::string_view v) {
    if (v.empty()) {
        return false;
    }
    std::size_t i = (v[0] == '-') ? 1 : 0;
    bool digits = false;
    bool dot = false;
    for (; i < v.size(); ++i) {
        if (v[i] >= '0' && v[i] <= '9') {
            digits = true;
        } else if (v[i] == '.' && !dot) {
            dot = true;
        } else {
            return false;
        }
    }
    return digits;
}

// Where a `key=` starts at `i` (a word of [A-Za-z0-9_.-] followed by '='), its length, else 0.
std::size_t key_length(std::string_view m, std::size_t i) {
    std::size_t j = i;
    while (j < m.size() && (std::isalnum(static_cast<unsigned char>(m[j])) || m[j] == '_' ||
                            m[j] == '-' || m[j] == '.')) {
        ++j;
    }
    return (j > i && j < m.size() && m[j] == '=') ? j - i : 0;
}

// The JSON formatter: time and level, then the message's fields.
class JsonFormatter final : public spdlog::formatter {
  public:
    void format(const spdlog::details::log_msg& msg, spdlog::memory_buf_t& dest) override {
        const auto time = std::chrono::system_clock::to_time_t(msg.time);
        const auto ms =
            std::chrono::duration_cast<std::chrono::milliseconds>(msg.time.time_since_epoch())
                .count() %
            1000;
        std::tm tm{};
        gmtime_r(&time, &tm);
        char stamp[40];
        std::snprintf(stamp, sizeof(stamp), "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ",
                      tm.tm_year + 1900, tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min,
                      tm.tm_sec, static_cast<int>(ms));
        auto fields = nlohmann::json::parse(
            log_message_json(std::string_view(msg.payload.data(), msg.payload.size())));
        nlohmann::json line = {{"time", stamp},
                               {"level", spdlog::level::to_string_view(msg.level).data()}};
        line.update(fields);
        const auto text = line.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
        dest.append(text.data(), text.data() + text.size());
        dest.push_back('\n');
    }
    std::unique_ptr<spdlog::formatter> clone() const override {
        return std::make_unique<JsonFormatter>();
    }
};

}  // namespace

std::string log_message_json(std::string_view m) {
    nlohmann::json out = nlohmann::json::object();
    std::size_t i = 0;
    // The event: every word before the first key=value.
    std::string event;
    while (i < m.size()) {
        while (i < m.size() && m[i] == ' ') {
            ++i;
        }
        if (i >= m.size() || key_length(m, i) != 0) {
            break;
        }
        const auto end = std::min(m.find(' ', i), m.size());
        event += (event.empty() ? "" : " ") + std::string(m.substr(i, end - i));
        i = end;
    }
    out["event"] = event;
    std::string note;
    while (i < m.size()) {
        while (i < m.size() && m[i] == ' ') {
            ++i;
        }
        if (i >= m.size()) {
            break;
        }
        const std::size_t k = key_length(m, i);
        if (k == 0) {
            note += (note.empty() ? "" : " ") + std::string(m.substr(i));
            break;
        }
        const std::string key(m.substr(i, k));
        i += k + 1;
        std::string value;
        if (i < m.size() && m[i] == '"') {
            // A quoted value ends at the quote that ends the line or precedes ` key=`: quotes
            // inside messages ("a \"name\"") are not escaped in the text format.
            std::size_t close = std::string_view::npos;
            for (std::size_t q = m.find('"', i + 1); q != std::string_view::npos;
                 q = m.find('"', q + 1)) {
                if (q + 1 == m.size() || (m[q + 1] == ' ' && key_length(m, q + 2) != 0) ||
                    (m[q + 1] == ' ' && m.find('=', q + 2) == std::string_view::npos)) {
                    close = q;
                    break;
                }
            }
            if (close == std::string_view::npos) {
                close = m.size();
            }
            value = std::string(m.substr(i + 1, close - i - 1));
            i = std::min(close + 1, m.size());
            out[key] = value;
            continue;
        }
        const auto end = std::min(m.find(' ', i), m.size());
        value = std::string(m.substr(i, end - i));
        i = end;
        if (is_number(value)) {
            out[key] = nlohmann::json::parse(value);
        } else if (value == "true" || value == "false") {
            out[key] = value == "true";
        } else {
            out[key] = value;
        }
    }
    if (!note.empty()) {
        out["note"] = note;
    }
    return out.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

// gRPC's own log lines (gpr_log) go through the daemon's logger, as debug lines: what matters
// to an operator (a port in use, a refused call) the daemon reports itself, once, in its words;
// gRPC's internal detail (a nested error tree for a failed bind) stays available with
// --log-level debug.
namespace {
void log_grpc_line(gpr_log_func_args* args) {
    spdlog::debug("grpc severity={} where={}:{} message=\"{}\"",
                  gpr_log_severity_string(args->severity), args->file, args->line, args->message);
}
}  // namespace

void configure_logging(const std::string& level, const std::string& format) {
    auto logger = spdlog::stderr_logger_mt("proximad");
    if (format == "json") {
        logger->set_formatter(std::make_unique<JsonFormatter>());
    } else {
        // ISO time, level, then key=value pairs: easy for people and for log collectors.
        logger->set_pattern("%Y-%m-%dT%H:%M:%S.%e%z %l %v");
    }
    logger->set_level(spdlog::level::from_str(level));
    logger->flush_on(spdlog::level::trace);
    spdlog::set_default_logger(std::move(logger));
    gpr_set_log_function(log_grpc_line);
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

namespace {

StatusOr<std::string> read_file(const std::string& path, const char* what) {
    std::ifstream in(path);
    if (!in) {
        return Status(StatusCode::unavailable, std::string(what) + ": cannot read " + path);
    }
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// Insecure credentials, or TLS (mutual when a client CA is configured) from the PEM files.
StatusOr<std::shared_ptr<grpc::ServerCredentials>> server_credentials(const ServerConfig& c) {
    if (c.tls_cert.empty()) {
        return grpc::InsecureServerCredentials();
    }
    auto cert = read_file(c.tls_cert, "tls-cert");
    auto key = read_file(c.tls_key, "tls-key");
    if (!cert.ok()) {
        return cert.status();
    }
    if (!key.ok()) {
        return key.status();
    }
    grpc::SslServerCredentialsOptions options(
        c.tls_client_ca.empty() ? GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE
                                : GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY);
    options.pem_key_cert_pairs.push_back({key.value(), cert.value()});
    if (!c.tls_client_ca.empty()) {
        auto ca = read_file(c.tls_client_ca, "tls-client-ca");
        if (!ca.ok()) {
            return ca.status();
        }
        options.pem_root_certs = ca.value();
    }
    return grpc::SslServerCredentials(options);
}

}  // namespace

StatusOr<std::string> Daemon::start() {
    if (Status s = m_service->start(); !s.ok()) {
        return s;
    }
    auto credentials = server_credentials(m_config);
    if (!credentials.ok()) {
        return credentials.status();
    }
    if (!m_config.metrics_listen.empty()) {
        auto metrics = m_service->start_metrics(m_config.metrics_listen);
        if (!metrics.ok()) {
            return metrics.status();
        }
        m_metrics_address = metrics.value();
    }
    // Both apply to servers built afterwards; the health service answers grpc.health.v1 for ""
    // and for proxima.v1.Proximity.
    grpc::EnableDefaultHealthCheckService(true);
    grpc::reflection::InitProtoReflectionServerBuilderPlugin();

    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort(m_config.listen, credentials.value(), &port);
    // gRPC sets SO_REUSEPORT by default: a second daemon on a busy port would then start and
    // share the port's connections with the first. A busy port must be an error.
    builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
    // A client that vanishes without closing its connection (a host that lost power, a network
    // partition: no FIN, no RST) is found by keepalive pings within ~40 s, and its streams are
    // cancelled like any other, which frees their scenes and quotas.
    builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS, 30'000);
    builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, 10'000);
    builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
    // Clients may ping as often as every 10 s (gRPC's default minimum of 5 min would make the
    // daemon close connections of clients whose own keepalive is tighter).
    builder.AddChannelArgument(GRPC_ARG_HTTP2_MIN_RECV_PING_INTERVAL_WITHOUT_DATA_MS, 10'000);
    builder.AddChannelArgument(GRPC_ARG_HTTP2_MAX_PING_STRIKES, 0);
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
        "cache_bytes={} tls={} tokens={} idle_scene_seconds={} metrics=\"{}\"",
        PROXIMA_VERSION, address, m_service->proximity_backend(),
        m_service->gl_renderer().empty() ? "none" : m_service->gl_renderer(), l.max_scenes,
        l.max_objects_per_scene, l.max_triangles_per_scene, l.max_message_bytes,
        l.max_frames_in_flight, m_config.drain_seconds, m_config.models_dir, m_config.cache_bytes,
        m_config.tls_cert.empty() ? "off" : (m_config.tls_client_ca.empty() ? "on" : "mutual"),
        m_config.tokens_file.empty() ? "off" : "on", m_config.idle_scene_seconds,
        m_metrics_address);
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
