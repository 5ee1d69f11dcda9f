#include "config.hpp"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <limits>
#include <string_view>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

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

Status read_string(const nlohmann::json& value, const std::string& key, std::string& out) {
    if (!value.is_string()) {
        return invalid_argument("config key '" + key + "' must be a string, got " + value.dump());
    }
    out = value.get<std::string>();
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
            s = read_unsigned(value, key, base.limits.max_message_bytes);
        } else if (key == "max-frames-in-flight") {
            s = read_unsigned(value, key, base.limits.max_frames_in_flight);
        } else if (key == "drain-seconds") {
            s = read_seconds(value, key, base.drain_seconds);
        } else if (key == "log-level") {
            s = read_string(value, key, base.log_level);
        } else if (key == "worker-threads") {
            s = read_unsigned(value, key, base.worker_threads);
        } else if (key == "gpu") {
            s = read_string(value, key, base.gpu);
        } else if (key == "models") {
            s = read_string(value, key, base.models_dir);
        } else if (key == "cache-bytes") {
            s = read_unsigned(value, key, base.cache_bytes);
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

Status validate_config(const ServerConfig& config) {
    const auto colon = config.listen.rfind(':');
    if (colon == std::string::npos || colon == 0 || colon + 1 == config.listen.size()) {
        return invalid_argument("listen address '" + config.listen + "' is not HOST:PORT");
    }
    const auto port = std::string_view(config.listen).substr(colon + 1);
    if (port.find_first_not_of("0123456789") != std::string_view::npos || port.size() > 5 ||
        std::stoul(std::string(port)) > 65535) {
        return invalid_argument("listen address '" + config.listen + "': port '" +
                                std::string(port) + "' is not a number in 0..65535");
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
            {"log-level", c.log_level},
            {"worker-threads", c.worker_threads},
            {"gpu", c.gpu},
            {"models", c.models_dir},
            {"cache-bytes", c.cache_bytes}};
}

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
            ->default_str(std::to_string(defaults.limits.max_scenes)),
        [&](ServerConfig& c) { c.limits.max_scenes = flags.limits.max_scenes; });
    add(app.add_option("--max-objects-per-scene", flags.limits.max_objects_per_scene,
                       "objects in one scene at most")
            ->default_str(std::to_string(defaults.limits.max_objects_per_scene)),
        [&](ServerConfig& c) {
            c.limits.max_objects_per_scene = flags.limits.max_objects_per_scene;
        });
    add(app.add_option("--max-triangles-per-scene", flags.limits.max_triangles_per_scene,
                       "triangles in one scene at most")
            ->default_str(std::to_string(defaults.limits.max_triangles_per_scene)),
        [&](ServerConfig& c) {
            c.limits.max_triangles_per_scene = flags.limits.max_triangles_per_scene;
        });
    add(app.add_option("--max-message-bytes", flags.limits.max_message_bytes,
                       "largest message received or sent, in bytes")
            ->default_str(std::to_string(defaults.limits.max_message_bytes)),
        [&](ServerConfig& c) { c.limits.max_message_bytes = flags.limits.max_message_bytes; });
    add(app.add_option("--max-frames-in-flight", flags.limits.max_frames_in_flight,
                       "frames read but not yet answered per stream")
            ->default_str(std::to_string(defaults.limits.max_frames_in_flight)),
        [&](ServerConfig& c) {
            c.limits.max_frames_in_flight = flags.limits.max_frames_in_flight;
        });
    add(app.add_option("--drain-seconds", flags.drain_seconds,
                       "on SIGTERM/SIGINT, how long in-flight calls may finish before they are "
                       "cancelled")
            ->default_str("10"),
        [&](ServerConfig& c) { c.drain_seconds = flags.drain_seconds; });
    add(app.add_option("--log-level", flags.log_level,
                       "trace, debug, info, warn, error, critical or off (logs go to stderr)")
            ->default_str(defaults.log_level),
        [&](ServerConfig& c) { c.log_level = flags.log_level; });
    add(app.add_option("--worker-threads", flags.worker_threads,
                       "threads for engine work; 0: max(4, hardware threads)")
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
            ->default_str(std::to_string(defaults.cache_bytes)),
        [&](ServerConfig& c) { c.cache_bytes = flags.cache_bytes; });

    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        const int code = app.exit(e);
        return code == 0 ? 0 : 2;
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
