#include "config.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <iostream>
#include <iterator>
#include <limits>
#include <string_view>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "auth.hpp"
#include "proxima/io/size_text.hpp"

namespace proxima::server {

namespace {

const char* const LOG_LEVELS[] = {"trace", "debug", "info", "warn", "error", "critical", "off"};

template <class T>
Status read_unsigned(const nlohmann::json& value, const std::string& key, T& out) {
    if (!value.is_number_unsigned() &&
        !(value.is_number_integer() && value.get<std::int64_t>() >= 0)) {
        return invalid_argument("config key '" + key + "' must be a non-negative integer, got " +
                                value.dump());
    }
    const auto v = value.get<std::uint64_t>();
    if (v > std::numeric_limits<T>::max()) {
        return invalid_argument("config key '" + key + "' is too large: " + value.dump());
    }
    out = static_cast<T>(v);
    return {};
}

// A byte count: a whole number, or a string with a K, M, G or T suffix (powers of 1024, the
// command line's rule: "160M").
template <class T>
Status read_bytes(const nlohmann::json& value, const std::string& key, T& out) {
    if (!value.is_string()) {
        return read_unsigned(value, key, out);
    }
    auto v = parse_size("config key '" + key + "'", value.get<std::string>(), 1024);
    if (!v.ok()) {
        return v.status();
    }
    if (v.value() > std::numeric_limits<T>::max()) {
        return invalid_argument("config key '" + key + "' is too large: " + value.dump());
    }
    out = static_cast<T>(v.value());
    return {};
}

Status read_string(const nlohmann::json& value, const std::string& key, std::string& out) {
    if (!value.is_string()) {
        return invalid_argument("config key '" + key + "' must be a string, got " + value.dump());
    }
    out = value.get<std::string>();
    return {};
}

Status read_bool(const nlohmann::json& value, const std::string& key, bool& out) {
    if (!value.is_boolean()) {
        return invalid_argument("config key '" + key + "' must be true or false, got " +
                                value.dump());
    }
    out = value.get<bool>();
    return {};
}

// A PEM file the daemon will need: readable, and holding at least one PEM block.
Status check_pem(const std::string& path, const char* key) {
    std::ifstream in(path);
    if (!in) {
        return invalid_argument(std::string(key) + ": cannot read " + path);
    }
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (text.find("-----BEGIN ") == std::string::npos) {
        return invalid_argument(std::string(key) + ": " + path + " holds no PEM block");
    }
    return {};
}

Status read_seconds(const nlohmann::json& value, const std::string& key, double& out) {
    if (!value.is_number()) {
        return invalid_argument("config key '" + key + "' must be a number of seconds, got " +
                                value.dump());
    }
    out = value.get<double>();
    return {};
}

}  // namespace

StatusOr<ServerConfig> apply_json_config(const nlohmann::json& json, ServerConfig base) {
    if (!json.is_object()) {
        return invalid_argument("the configuration file must hold one JSON object, got " +
                                std::string(json.type_name()));
    }
    for (const auto& [key, value] : json.items()) {
        Status s;
        if (key == "listen") {
            s = read_string(value, key, base.listen);
        } else if (key == "max-scenes") {
            s = read_unsigned(value, key, base.limits.max_scenes);
        } else if (key == "max-objects-per-scene") {
            s = read_unsigned(value, key, base.limits.max_objects_per_scene);
        } else if (key == "max-triangles-per-scene") {
            s = read_unsigned(value, key, base.limits.max_triangles_per_scene);
        } else if (key == "max-message-bytes") {
            s = read_bytes(value, key, base.limits.max_message_bytes);
        } else if (key == "max-frames-in-flight") {
            s = read_unsigned(value, key, base.limits.max_frames_in_flight);
        } else if (key == "drain-seconds") {
            s = read_seconds(value, key, base.drain_seconds);
        } else if (key == "review-peer-interval") {
            s = read_seconds(value, key, base.review_peer_interval);
        } else if (key == "log-level") {
            s = read_string(value, key, base.log_level);
        } else if (key == "worker-threads") {
            s = read_unsigned(value, key, base.worker_threads);
        } else if (key == "gpu") {
            s = read_string(value, key, base.gpu);
        } else if (key == "models") {
            s = read_string(value, key, base.models_dir);
        } else if (key == "cache-bytes") {
            s = read_bytes(value, key, base.cache_bytes);
        } else if (key == "tls-cert") {
            s = read_string(value, key, base.tls_cert);
        } else if (key == "tls-key") {
            s = read_string(value, key, base.tls_key);
        } else if (key == "tls-client-ca") {
            s = read_string(value, key, base.tls_client_ca);
        } else if (key == "tokens") {
            s = read_string(value, key, base.tokens_file);
        } else if (key == "allow-insecure") {
            s = read_bool(value, key, base.allow_insecure);
        } else if (key == "idle-scene-seconds") {
            s = read_seconds(value, key, base.idle_scene_seconds);
        } else if (key == "metrics-listen") {
            s = read_string(value, key, base.metrics_listen);
        } else if (key == "log-format") {
            s = read_string(value, key, base.log_format);
        } else {
            // A misspelt key silently falling back to a default is how limits get lost.
            s = invalid_argument("unknown config key '" + key +
                                 "' (keys are the long flag names, e.g. \"max-scenes\")");
        }
        if (!s.ok()) {
            return s;
        }
    }
    return base;
}

bool is_loopback_address(const std::string& host_port) {
    const auto colon = host_port.rfind(':');
    const std::string host = colon == std::string::npos ? host_port : host_port.substr(0, colon);
    return host == "localhost" || host == "[::1]" || host.rfind("127.", 0) == 0;
}

namespace {

Status check_address(const std::string& address, const char* key) {
    const auto colon = address.rfind(':');
    if (colon == std::string::npos || colon == 0 || colon + 1 == address.size()) {
        return invalid_argument(std::string(key) + " address '" + address + "' is not HOST:PORT");
    }
    const auto port = std::string_view(address).substr(colon + 1);
    if (port.find_first_not_of("0123456789") != std::string_view::npos || port.size() > 5 ||
        std::stoul(std::string(port)) > 65535) {
        return invalid_argument(std::string(key) + " address '" + address + "': port '" +
                                std::string(port) + "' is not a number in 0..65535");
    }
    return {};
}

}  // namespace

Status validate_config(const ServerConfig& config) {
    if (Status s = check_address(config.listen, "listen"); !s.ok()) {
        return s;
    }
    if (!config.metrics_listen.empty()) {
        if (Status s = check_address(config.metrics_listen, "metrics-listen"); !s.ok()) {
            return s;
        }
    }
    const auto& l = config.limits;
    if (l.max_scenes == 0 || l.max_objects_per_scene == 0 || l.max_triangles_per_scene == 0 ||
        l.max_frames_in_flight == 0) {
        return invalid_argument(
            "limits must be at least 1 (max-scenes, max-objects-per-scene, "
            "max-triangles-per-scene, max-frames-in-flight)");
    }
    // gRPC takes message sizes as int.
    if (l.max_message_bytes < 1024 ||
        l.max_message_bytes > static_cast<std::uint64_t>(std::numeric_limits<int>::max())) {
        return invalid_argument("max-message-bytes must be in 1024..2147483647, got " +
                                std::to_string(l.max_message_bytes));
    }
    if (!std::isfinite(config.drain_seconds) || config.drain_seconds < 0) {
        return invalid_argument("drain-seconds must be a finite number >= 0");
    }
    if (!std::isfinite(config.review_peer_interval) || config.review_peer_interval < 0 ||
        config.review_peer_interval > 1) {
        return invalid_argument("review-peer-interval must be a number of seconds in 0..1");
    }
    bool level_ok = false;
    for (const char* level : LOG_LEVELS) {
        level_ok = level_ok || config.log_level == level;
    }
    if (!level_ok) {
        return invalid_argument("log-level '" + config.log_level +
                                "' is not one of trace, debug, info, warn, error, critical, off");
    }
    if (config.gpu != "auto" && config.gpu != "off") {
        return invalid_argument("gpu '" + config.gpu + "' is not one of auto, off");
    }
    // The cache must hold at least the two pieces of one test; the store's split size decides
    // whether that holds, and verification says so (FAILED_PRECONDITION) when it does not.
    if (config.cache_bytes == 0) {
        return invalid_argument("cache-bytes must be at least 1");
    }
    if (!std::isfinite(config.idle_scene_seconds) || config.idle_scene_seconds < 0) {
        return invalid_argument("idle-scene-seconds must be a finite number >= 0 (0: never)");
    }
    if (config.log_format != "text" && config.log_format != "json") {
        return invalid_argument("log-format '" + config.log_format + "' is not one of text, json");
    }
    // Security: the files must be usable now, not at the first connection.
    if (config.tls_cert.empty() != config.tls_key.empty()) {
        return invalid_argument("tls-cert and tls-key go together: give both or neither");
    }
    if (!config.tls_client_ca.empty() && config.tls_cert.empty()) {
        return invalid_argument(
            "tls-client-ca (mutual TLS) needs TLS: give tls-cert and tls-key too");
    }
    for (const auto& [path, key] :
         {std::pair{config.tls_cert, "tls-cert"}, std::pair{config.tls_key, "tls-key"},
          std::pair{config.tls_client_ca, "tls-client-ca"}}) {
        if (!path.empty()) {
            if (Status s = check_pem(path, key); !s.ok()) {
                return s;
            }
        }
    }
    if (config.tls_cert.empty() && !config.allow_insecure && !is_loopback_address(config.listen)) {
        return invalid_argument(
            "listen address '" + config.listen +
            "' is reachable from other machines but TLS is off: give tls-cert and tls-key, or "
            "allow-insecure to serve plaintext beyond loopback on purpose");
    }
    if (!config.tokens_file.empty()) {
        if (auto auth = Authenticator::from_file(config.tokens_file); !auth.ok()) {
            return invalid_argument("tokens: " + auth.status().message());
        }
    }
    return {};
}

nlohmann::json config_json(const ServerConfig& c) {
    return {{"listen", c.listen},
            {"max-scenes", c.limits.max_scenes},
            {"max-objects-per-scene", c.limits.max_objects_per_scene},
            {"max-triangles-per-scene", c.limits.max_triangles_per_scene},
            {"max-message-bytes", c.limits.max_message_bytes},
            {"max-frames-in-flight", c.limits.max_frames_in_flight},
            {"drain-seconds", c.drain_seconds},
            {"review-peer-interval", c.review_peer_interval},
            {"log-level", c.log_level},
            {"worker-threads", c.worker_threads},
            {"gpu", c.gpu},
            {"models", c.models_dir},
            {"cache-bytes", c.cache_bytes},
            {"tls-cert", c.tls_cert},
            {"tls-key", c.tls_key},
            {"tls-client-ca", c.tls_client_ca},
            {"tokens", c.tokens_file},
            {"allow-insecure", c.allow_insecure},
            {"idle-scene-seconds", c.idle_scene_seconds},
            {"metrics-listen", c.metrics_listen},
            {"log-format", c.log_format}};
}

// CLI11 reads an unsigned option with strtoull, which takes "-3" as 2^64 - 3: a negative limit
// would silently become (nearly) unlimited. Unsigned flags take digits only.
const CLI::Validator WHOLE_NUMBER(
    [](const std::string& text) -> std::string {
        if (text.empty() ||
            !std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; })) {
            return "'" + text + "' is not a whole number (0, 1, 2, ...)";
        }
        return {};
    },
    "UINT");

// A byte count with an optional K, M, G or T suffix (powers of 1024, as in proxima's options),
// rewritten to the whole number.
const CLI::Validator BYTE_SIZE(
    [](std::string& text) -> std::string {
        auto v = parse_size("", text, 1024);
        if (!v.ok()) {
            return "'" + text.substr(0, 40) +
                   "' is not a size: a positive whole number with an optional K, M, G or T "
                   "suffix (powers of 1024), e.g. 160M";
        }
        text = std::to_string(v.value());
        return {};
    },
    "SIZE (K/M/G/T = 1024^n)", "byte_size");

ConfigOutcome load_config(int argc, char** argv) {
    const ServerConfig defaults;
    ServerConfig flags;  // what the command line says; only options actually given are used
    std::string config_file;

    CLI::App app{"proximad: the proximity query daemon (gRPC service proxima.v1.Proximity)"};
    app.set_version_flag("--version", PROXIMA_VERSION);
    app.add_option("--config", config_file,
                   "JSON file with any of the options below (keys: the long flag names without "
                   "the leading dashes); flags given on the command line override it")
        ->check(CLI::ExistingFile);
    bool check_only = false;
    app.add_flag("--check-config", check_only,
                 "Validate the configuration (file and flags), print the effective configuration "
                 "as JSON with every option, and exit: 0 when valid, 2 when not");

    // Each option knows how to copy its value from `flags` into the final configuration, so a
    // flag that was given overrides the file and one that was not leaves the file's value.
    std::vector<std::pair<CLI::Option*, std::function<void(ServerConfig&)>>> options;
    auto add = [&](CLI::Option* opt, std::function<void(ServerConfig&)> copy) {
        options.emplace_back(opt, std::move(copy));
    };
    add(app.add_option("--listen", flags.listen, "HOST:PORT to listen on; port 0 picks a free one")
            ->default_str(defaults.listen),
        [&](ServerConfig& c) { c.listen = flags.listen; });
    add(app.add_option("--max-scenes", flags.limits.max_scenes, "live scenes at most")
            ->check(WHOLE_NUMBER)
            ->default_str(std::to_string(defaults.limits.max_scenes)),
        [&](ServerConfig& c) { c.limits.max_scenes = flags.limits.max_scenes; });
    add(app.add_option("--max-objects-per-scene", flags.limits.max_objects_per_scene,
                       "objects in one scene at most")
            ->check(WHOLE_NUMBER)
            ->default_str(std::to_string(defaults.limits.max_objects_per_scene)),
        [&](ServerConfig& c) {
            c.limits.max_objects_per_scene = flags.limits.max_objects_per_scene;
        });
    add(app.add_option("--max-triangles-per-scene", flags.limits.max_triangles_per_scene,
                       "triangles in one scene at most")
            ->check(WHOLE_NUMBER)
            ->default_str(std::to_string(defaults.limits.max_triangles_per_scene)),
        [&](ServerConfig& c) {
            c.limits.max_triangles_per_scene = flags.limits.max_triangles_per_scene;
        });
    add(app.add_option("--max-message-bytes", flags.limits.max_message_bytes,
                       "largest message received or sent, in bytes")
            ->transform(BYTE_SIZE)
            ->default_str(std::to_string(defaults.limits.max_message_bytes)),
        [&](ServerConfig& c) { c.limits.max_message_bytes = flags.limits.max_message_bytes; });
    add(app.add_option("--max-frames-in-flight", flags.limits.max_frames_in_flight,
                       "frames read but not yet answered per stream")
            ->check(WHOLE_NUMBER)
            ->default_str(std::to_string(defaults.limits.max_frames_in_flight)),
        [&](ServerConfig& c) {
            c.limits.max_frames_in_flight = flags.limits.max_frames_in_flight;
        });
    add(app.add_option("--drain-seconds", flags.drain_seconds,
                       "on SIGTERM/SIGINT, how long in-flight calls may finish before they are "
                       "cancelled")
            ->default_str("10"),
        [&](ServerConfig& c) { c.drain_seconds = flags.drain_seconds; });
    add(app.add_option("--review-peer-interval", flags.review_peer_interval,
                       "review rooms: a member's pending peer updates go out together at most "
                       "once per this many seconds (0..1; 0: each at once)")
            ->default_str("0.02"),
        [&](ServerConfig& c) { c.review_peer_interval = flags.review_peer_interval; });
    add(app.add_option("--log-level", flags.log_level,
                       "trace, debug, info, warn, error, critical or off (logs go to stderr)")
            ->default_str(defaults.log_level),
        [&](ServerConfig& c) { c.log_level = flags.log_level; });
    add(app.add_option("--worker-threads", flags.worker_threads,
                       "threads for engine work; 0: max(4, hardware threads)")
            ->check(WHOLE_NUMBER)
            ->default_str("0"),
        [&](ServerConfig& c) { c.worker_threads = flags.worker_threads; });
    add(app.add_option("--gpu", flags.gpu,
                       "auto: use the GPU (headless EGL) for the Voronoi culler when EGL starts, "
                       "else the CPU backend; off: CPU backend only")
            ->default_str(defaults.gpu),
        [&](ServerConfig& c) { c.gpu = flags.gpu; });

    add(app.add_option("--models", flags.models_dir,
                       "serve every model store found in a subdirectory of DIR (named by the "
                       "subdirectory); rescanned when models are listed or an unknown one is named")
            ->type_name("DIR"),
        [&](ServerConfig& c) { c.models_dir = flags.models_dir; });
    add(app.add_option("--cache-bytes", flags.cache_bytes,
                       "budget in bytes of the geometry cache shared by every model, "
                       "verification and review room")
            ->transform(BYTE_SIZE)
            ->default_str(std::to_string(defaults.cache_bytes)),
        [&](ServerConfig& c) { c.cache_bytes = flags.cache_bytes; });

    add(app.add_option("--tls-cert", flags.tls_cert,
                       "PEM certificate (chain) the daemon presents; with --tls-key turns TLS on")
            ->type_name("FILE"),
        [&](ServerConfig& c) { c.tls_cert = flags.tls_cert; });
    add(app.add_option("--tls-key", flags.tls_key, "PEM private key of --tls-cert")
            ->type_name("FILE"),
        [&](ServerConfig& c) { c.tls_key = flags.tls_key; });
    add(app.add_option("--tls-client-ca", flags.tls_client_ca,
                       "PEM CA certificates; every client must present a certificate they "
                       "signed (mutual TLS)")
            ->type_name("FILE"),
        [&](ServerConfig& c) { c.tls_client_ca = flags.tls_client_ca; });
    add(app.add_option("--tokens", flags.tokens_file,
                       "JSON token file: bearer tokens, the scenes, rooms and models each may "
                       "use, and its quotas; every call must then present a token")
            ->type_name("FILE"),
        [&](ServerConfig& c) { c.tokens_file = flags.tokens_file; });
    add(app.add_flag("--allow-insecure", flags.allow_insecure,
                     "allow listening beyond loopback without TLS"),
        [&](ServerConfig& c) { c.allow_insecure = flags.allow_insecure; });
    add(app.add_option("--idle-scene-seconds", flags.idle_scene_seconds,
                       "delete scenes no call used for this long (0: never)")
            ->default_str("3600"),
        [&](ServerConfig& c) { c.idle_scene_seconds = flags.idle_scene_seconds; });
    add(app.add_option("--metrics-listen", flags.metrics_listen,
                       "HOST:PORT of the Prometheus endpoint (GET /metrics); none when empty")
            ->type_name("HOST:PORT"),
        [&](ServerConfig& c) { c.metrics_listen = flags.metrics_listen; });
    add(app.add_option("--log-format", flags.log_format,
                       "text (key=value lines) or json (one object per line)")
            ->default_str(defaults.log_format),
        [&](ServerConfig& c) { c.log_format = flags.log_format; });
    bool hash_token = false;
    app.add_flag("--hash-token", hash_token,
                 "read a token from standard input, print its SHA-256 for the token file's "
                 "\"sha256\" key, and exit");

    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        // One line in the project's words, as proxima prints usage errors; exit status 2.
        std::fprintf(stderr, "proximad: error: %s\nRun 'proximad --help' for the options.\n",
                     e.what());
        return 2;
    }
    if (hash_token) {
        std::string token;
        std::getline(std::cin, token);
        while (!token.empty() && (token.back() == '\r' || token.back() == ' ')) {
            token.pop_back();
        }
        if (token.size() < 16) {
            std::fprintf(stderr, "proximad: error: a token needs at least 16 characters\n");
            return 2;
        }
        std::printf("%s\n", sha256_hex(token).c_str());
        return 0;
    }

    ServerConfig config = defaults;
    if (!config_file.empty()) {
        std::ifstream in(config_file);
        nlohmann::json json;
        try {
            json = nlohmann::json::parse(in);
        } catch (const nlohmann::json::exception& e) {
            std::fprintf(stderr, "proximad: error: %s: not valid JSON: %s\n", config_file.c_str(),
                         e.what());
            return 2;
        }
        auto from_file = apply_json_config(json, config);
        if (!from_file.ok()) {
            std::fprintf(stderr, "proximad: error: %s: %s\n", config_file.c_str(),
                         from_file.status().message().c_str());
            return 2;
        }
        config = std::move(from_file).value();
    }
    for (auto& [opt, copy] : options) {
        if (opt->count() > 0) {
            copy(config);
        }
    }
    if (Status s = validate_config(config); !s.ok()) {
        std::fprintf(stderr, "proximad: error: %s\n", s.message().c_str());
        return 2;
    }
    if (check_only) {
        std::printf("%s\n", config_json(config).dump(2).c_str());
        return 0;
    }
    return config;
}

}  // namespace proxima::server
