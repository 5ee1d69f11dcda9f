#pragma once
// The daemon's configuration: defaults, an optional JSON file (`--config FILE`) and command-line
// flags, in that order of precedence (a flag given on the command line beats the file). Every
// option and its default is documented in docs/server.md; keep the two in step.

#include <cstdint>
#include <string>
#include <variant>

#include <nlohmann/json_fwd.hpp>

#include "proxima/massive/model.hpp"
#include "proxima/status.hpp"

namespace proxima::server {

// Limits protect the daemon from one client's mistakes. A request that would exceed one is
// rejected whole with RESOURCE_EXHAUSTED naming the limit, before anything changes.
struct Limits {
    std::uint64_t max_scenes = 64;  // live scenes, stream-owned ones included
    std::uint64_t max_objects_per_scene = 100'000;
    std::uint64_t max_triangles_per_scene = 50'000'000;
    std::uint64_t max_message_bytes = 256ull << 20;  // each direction; gRPC's own check
    std::uint32_t max_frames_in_flight = 4;          // per stream: read but not yet answered
};

struct ServerConfig {
    // HOST:PORT; loopback by default so that a daemon started by hand is not exposed. Port 0
    // picks a free port (printed on the first line of standard output).
    std::string listen = "127.0.0.1:50051";
    Limits limits;
    // How long a SIGTERM/SIGINT waits for in-flight calls before cancelling them.
    double drain_seconds = 10.0;
    std::string log_level = "info";
    // Threads that run engine work off gRPC's callback threads; 0 picks max(4, hardware threads).
    // Each query also uses oneTBB's threads for its own parallel loops.
    unsigned worker_threads = 0;
    // "auto": start the headless EGL context for the GPU Voronoi culler, and fall back to the CPU
    // backend (logging why) when EGL cannot start; "off": CPU backend only.
    std::string gpu = "auto";
    // Massive models: every subdirectory of this directory that holds a model store (written by
    // `proxima import`) is served under the subdirectory's name; "" serves none.
    std::string models_dir;
    // The budget M of the one geometry cache shared by every model, verification and review room.
    std::uint64_t cache_bytes = massive::DEFAULT_CACHE_BYTES;
    // Review rooms: a member's pending peer updates go out together at most once per this many
    // seconds (its own answers, edits, joins and leaves at once); 0 sends each as it comes.
    double review_peer_interval = 0.02;

    // Security (docs/server.md "Security"). TLS is on when both PEM files are given; with a
    // client CA every client must present a certificate it signed (mutual TLS).
    std::string tls_cert;
    std::string tls_key;
    std::string tls_client_ca;
    // Bearer tokens with their access and quotas; "" checks no tokens (every call anonymous).
    std::string tokens_file;
    // Listening beyond loopback without TLS is refused unless this says it is meant.
    bool allow_insecure = false;
    // Scenes made by CreateScene that no call used for this long are deleted (0: never).
    double idle_scene_seconds = 3600.0;
    // Prometheus text endpoint, HOST:PORT serving GET /metrics; "" serves none.
    std::string metrics_listen;
    // "text" (key=value lines) or "json" (one JSON object per line).
    std::string log_format = "text";
};

// True for addresses only this machine can reach: 127.0.0.0/8, ::1, localhost.
bool is_loopback_address(const std::string& host_port);

// Overlays the keys of a JSON object onto `base`. Keys are the long flag names without the
// leading dashes ("max-scenes"); an unknown key, a wrong type or an out-of-range value is an
// invalid_argument status naming the key.
StatusOr<ServerConfig> apply_json_config(const nlohmann::json& json, ServerConfig base);

// Checks ranges and names (log level, listen address shape, limits > 0).
Status validate_config(const ServerConfig& config);

// The configuration as a JSON object with every key of the configuration file (the long flag
// names), e.g. for `proximad --check-config`; apply_json_config of it gives the same config.
nlohmann::json config_json(const ServerConfig& config);

// What main() should do: run with a configuration, or exit with a code (0 after --help,
// --version or a good --check-config, which prints the effective configuration as JSON; 2 after a
// bad flag or configuration file, with the message already printed).
using ConfigOutcome = std::variant<ServerConfig, int>;
ConfigOutcome load_config(int argc, char** argv);

}  // namespace proxima::server
