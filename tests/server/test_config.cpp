// proximad's configuration (server/config.hpp): defaults, the JSON file's keys, flags over the
// file, validation, and the exit codes of load_config. The daemon's end-to-end behaviour with
// these options is in tests/integration and tests/hardening.
#include <gtest/gtest.h>

#include <unistd.h>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <variant>
#include <vector>

#include <nlohmann/json.hpp>

#include "config.hpp"

namespace proxima::server {
namespace {

namespace fs = std::filesystem;

// load_config over an argument list (argv[0] is added).
ConfigOutcome load(std::vector<std::string> args) {
    args.insert(args.begin(), "proximad");
    std::vector<char*> argv;
    for (auto& a : args) {
        argv.push_back(a.data());
    }
    argv.push_back(nullptr);
    return load_config(static_cast<int>(args.size()), argv.data());
}

int exit_code(const ConfigOutcome& o) {
    return std::holds_alternative<int>(o) ? std::get<int>(o) : -1;
}

fs::path write_file(const std::string& name, const std::string& text) {
    const fs::path dir =
        fs::temp_directory_path() / ("proxima-config-test-" + std::to_string(::getpid()));
    fs::create_directories(dir);
    const fs::path p = dir / name;
    std::ofstream(p) << text;
    return p;
}

TEST(ServerConfig, DefaultsAreValidAndLoopback) {
    const ServerConfig c;
    EXPECT_TRUE(validate_config(c).ok());
    EXPECT_TRUE(is_loopback_address(c.listen));
    EXPECT_EQ(c.limits.max_scenes, 64u);
    EXPECT_EQ(c.gpu, "auto");
}

TEST(ServerConfig, LoopbackAddresses) {
    EXPECT_TRUE(is_loopback_address("127.0.0.1:1"));
    EXPECT_TRUE(is_loopback_address("127.3.2.1:50051"));
    EXPECT_TRUE(is_loopback_address("localhost:80"));
    EXPECT_TRUE(is_loopback_address("[::1]:50051"));
    EXPECT_FALSE(is_loopback_address("0.0.0.0:50051"));
    EXPECT_FALSE(is_loopback_address("10.0.0.1:50051"));
    EXPECT_FALSE(is_loopback_address("[::]:50051"));
}

TEST(ServerConfig, JsonKeysOverlayTheBase) {
    auto c = apply_json_config(nlohmann::json::parse(R"({"max-scenes": 7, "log-level": "warn",
                                   "gpu": "off", "cache-bytes": 1048576, "drain-seconds": 2.5})"),
                               ServerConfig{});
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    EXPECT_EQ(c->limits.max_scenes, 7u);
    EXPECT_EQ(c->log_level, "warn");
    EXPECT_EQ(c->gpu, "off");
    EXPECT_EQ(c->cache_bytes, 1048576u);
    EXPECT_EQ(c->drain_seconds, 2.5);
    // Keys not given keep the base's values.
    EXPECT_EQ(c->listen, ServerConfig{}.listen);
}

TEST(ServerConfig, JsonErrorsNameTheKey) {
    const std::vector<std::pair<std::string, std::string>> bad = {
        {R"({"max-scene": 7})", "max-scene"},          // unknown (misspelt) key
        {R"({"max-scenes": "seven"})", "max-scenes"},  // wrong type
        {R"({"max-scenes": -3})", "max-scenes"},       // negative for an unsigned limit
        {R"({"max-scenes": 1.5})", "max-scenes"},      // not whole
        {R"({"cache-bytes": -1})", "cache-bytes"},
        {R"({"log-level": 3})", "log-level"},
        {R"({"review-peer-interval": "fast"})", "review-peer-interval"},
        {R"([1, 2])", ""},  // not an object
    };
    for (const auto& [text, key] : bad) {
        auto c = apply_json_config(nlohmann::json::parse(text), ServerConfig{});
        ASSERT_FALSE(c.ok()) << text;
        EXPECT_EQ(c.status().code(), StatusCode::invalid_argument) << text;
        EXPECT_NE(c.status().message().find(key), std::string::npos)
            << text << ": " << c.status().message();
    }
}

TEST(ServerConfig, ValidationRefusesBadValues) {
    ServerConfig c;
    c.log_level = "loud";
    EXPECT_FALSE(validate_config(c).ok());
    c = {};
    c.gpu = "sometimes";
    EXPECT_FALSE(validate_config(c).ok());
    c = {};
    c.listen = "no-port";
    EXPECT_FALSE(validate_config(c).ok());
    c = {};
    c.limits.max_scenes = 0;
    EXPECT_FALSE(validate_config(c).ok());
    c = {};
    c.limits.max_frames_in_flight = 0;
    EXPECT_FALSE(validate_config(c).ok());
    c = {};
    c.log_format = "xml";
    EXPECT_FALSE(validate_config(c).ok());
    for (double interval : {-0.01, 1.5, std::nan("")}) {
        c = {};
        c.review_peer_interval = interval;
        const Status s = validate_config(c);
        EXPECT_FALSE(s.ok()) << interval;
        EXPECT_NE(s.message().find("review-peer-interval"), std::string::npos) << s.message();
    }
    c = {};
    c.review_peer_interval = 0;  // each update at once
    EXPECT_TRUE(validate_config(c).ok());
}

TEST(ServerConfig, ConfigJsonRoundTrips) {
    ServerConfig c;
    c.limits.max_scenes = 9;
    c.log_level = "debug";
    c.cache_bytes = 12345;
    c.idle_scene_seconds = 0;
    c.log_format = "json";
    const auto json = config_json(c);
    auto back = apply_json_config(json, ServerConfig{});
    ASSERT_TRUE(back.ok()) << back.status().to_string();
    EXPECT_EQ(config_json(back.value()), json);
}

TEST(ServerConfig, FlagsBeatTheFileAndTheFileBeatsDefaults) {
    const auto file = write_file("flags.json", R"({"max-scenes": 5, "log-level": "warn"})");
    auto o = load({"--config", file.string(), "--max-scenes", "11"});
    ASSERT_TRUE(std::holds_alternative<ServerConfig>(o)) << exit_code(o);
    const auto& c = std::get<ServerConfig>(o);
    EXPECT_EQ(c.limits.max_scenes, 11u);  // the flag
    EXPECT_EQ(c.log_level, "warn");       // the file
    EXPECT_EQ(c.gpu, "auto");             // the default
}

TEST(ServerConfig, ExitCodes) {
    EXPECT_EQ(exit_code(load({"--help"})), 0);
    EXPECT_EQ(exit_code(load({"--no-such-flag"})), 2);
    EXPECT_EQ(exit_code(load({"--max-scenes", "lots"})), 2);
    EXPECT_EQ(exit_code(load({"--config", "/nonexistent/proximad.json"})), 2);
    EXPECT_EQ(exit_code(load({"--config", write_file("bad.json", "{not json").string()})), 2);
    EXPECT_EQ(exit_code(load({"--config", write_file("key.json", R"({"nope": 1})").string()})), 2);
    EXPECT_EQ(exit_code(load({"--log-level", "loud"})), 2);
}

// CLI11 reads unsigned options with strtoull, which wraps "-3" to 2^64 - 3: a negative limit
// must be refused, not turned into "unlimited".
TEST(ServerConfig, NegativeUnsignedFlagsAreRefused) {
    for (const char* flag :
         {"--max-scenes", "--max-objects-per-scene", "--max-triangles-per-scene",
          "--max-message-bytes", "--max-frames-in-flight", "--worker-threads", "--cache-bytes"}) {
        EXPECT_EQ(exit_code(load({flag, "-3"})), 2) << flag;
        EXPECT_EQ(exit_code(load({flag, "+3"})), 2) << flag;
        EXPECT_EQ(exit_code(load({flag, " 3"})), 2) << flag;
    }
    auto o = load({"--max-scenes", "3", "--cache-bytes", "1048576"});
    ASSERT_TRUE(std::holds_alternative<ServerConfig>(o));
    EXPECT_EQ(std::get<ServerConfig>(o).limits.max_scenes, 3u);
    EXPECT_EQ(std::get<ServerConfig>(o).cache_bytes, 1048576u);
}

// Byte options take the command line's size rule (K, M, G, T: powers of 1024), on the command
// line and in the configuration file, and refuse anything else.
TEST(ServerConfig, ByteSizesTakeSuffixes) {
    auto o = load({"--cache-bytes", "160M", "--max-message-bytes", "64KiB"});
    ASSERT_TRUE(std::holds_alternative<ServerConfig>(o));
    EXPECT_EQ(std::get<ServerConfig>(o).cache_bytes, 160ull << 20);
    EXPECT_EQ(std::get<ServerConfig>(o).limits.max_message_bytes, 64u << 10);
    for (const char* bad : {"160Q", "nan", "inf", "-1M", "0", "M", "1e9"}) {
        EXPECT_EQ(exit_code(load({"--cache-bytes", bad})), 2) << bad;
    }
    auto c = apply_json_config(
        nlohmann::json::parse(R"({"cache-bytes": "1.5G", "max-message-bytes": "1M"})"),
        ServerConfig{});
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    EXPECT_EQ(c->cache_bytes, 3ull << 29);
    EXPECT_EQ(c->limits.max_message_bytes, 1u << 20);
    auto bad =
        apply_json_config(nlohmann::json::parse(R"({"cache-bytes": "lots"})"), ServerConfig{});
    ASSERT_FALSE(bad.ok());
    EXPECT_NE(bad.status().message().find("cache-bytes"), std::string::npos);
}

}  // namespace
}  // namespace proxima::server
