// Metrics and logs (issue #7, item 6): the Prometheus endpoint counts calls by method and status,
// frames, exact tests, quota rejections and authentication failures, and shows live state (scenes,
// the GPU backend, each token's usage); JSON log lines an operator's collector can parse.
#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <thread>

#include <nlohmann/json.hpp>

#include "daemon.hpp"
#include "security_util.hpp"

namespace proxima::test {
namespace {

using namespace std::chrono_literals;

// GET http://HOST:PORT/metrics over a plain socket: the body, "" on failure.
std::string http_get_metrics(const std::string& address) {
    const auto colon = address.rfind(':');
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(static_cast<std::uint16_t>(std::stoi(address.substr(colon + 1))));
    inet_pton(AF_INET, address.substr(0, colon).c_str(), &addr.sin_addr);
    const int fd = socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0 || connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0) {
        if (fd >= 0) {
            close(fd);
        }
        return {};
    }
    const std::string request =
        "GET /metrics HTTP/1.1\r\nHost: " + address + "\r\nConnection: close\r\n\r\n";
    if (write(fd, request.data(), request.size()) != static_cast<ssize_t>(request.size())) {
        close(fd);
        return {};
    }
    std::string response;
    std::array<char, 4096> buffer{};
    for (ssize_t n; (n = read(fd, buffer.data(), buffer.size())) > 0;) {
        response.append(buffer.data(), static_cast<std::size_t>(n));
    }
    close(fd);
    const auto body = response.find("\r\n\r\n");
    return body == std::string::npos ? "" : response.substr(body + 4);
}

// The value of the series `name` whose labels include every one of `labels`; -1 when absent.
double metric(const std::string& text, const std::string& name,
              const std::map<std::string, std::string>& labels = {}) {
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);) {
        if (line.empty() || line[0] == '#' || line.rfind(name, 0) != 0) {
            continue;
        }
        const auto after = line.substr(name.size());
        if (after.empty() || (after[0] != '{' && after[0] != ' ')) {
            continue;  // a longer name with this prefix
        }
        bool all = true;
        for (const auto& [k, v] : labels) {
            all = all && after.find(k + "=\"" + v + "\"") != std::string::npos;
        }
        if (all) {
            return std::stod(line.substr(line.rfind(' ') + 1));
        }
    }
    return -1;
}

const std::string ALICE = "alice-token-0123456789";
const std::string TIGHT = "tight-token-0123456789";

TEST(Metrics, PrometheusEndpointCountsCallsFramesQuotasAndState) {
    ScratchDir dir;
    write_text(dir.file("tokens.json"),
               R"({"tokens": [{"name": "alice", "token": ")" + ALICE +
                   R"(", "scenes": ["*"]},
                   {"name": "tight", "token": ")" +
                   TIGHT + R"(", "scenes": ["*"], "quotas": {"max-scenes": 1}}]})");
    DaemonProcess daemon({"--tokens", dir.file("tokens.json"), "--metrics-listen", "127.0.0.1:0"});
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    const auto second = daemon.next_line(5s);
    ASSERT_TRUE(second.has_value());
    ASSERT_EQ(second->rfind("metrics on 127.0.0.1:", 0), 0u) << *second;
    const std::string address = second->substr(std::string("metrics on ").size());
    auto stub = make_stub(daemon.address());

    const auto scene = create_scene(*stub, ALICE, "a", 2);
    ASSERT_FALSE(scene.empty());
    for (int i = 0; i < 3; ++i) {
        ASSERT_TRUE(query(*stub, ALICE, separation_frame(scene, i)).ok());
    }
    ASSERT_FALSE(create_scene(*stub, TIGHT, "t1", 1).empty());
    grpc::Status refused;
    EXPECT_TRUE(create_scene(*stub, TIGHT, "t2", 1, &refused).empty());
    EXPECT_EQ(refused.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    {
        auto context = context_for("");
        v1::ServerInfo info;
        EXPECT_EQ(stub->GetServerInfo(context.get(), {}, &info).error_code(),
                  grpc::StatusCode::UNAUTHENTICATED);
    }

    // Calls are counted when they finish: the last one may still be logging.
    std::string text;
    for (int i = 0; i < 50; ++i) {
        text = http_get_metrics(address);
        if (metric(text, "proxima_requests_total",
                   {{"method", "GetServerInfo"}, {"code", "UNAUTHENTICATED"}}) == 1) {
            break;
        }
        std::this_thread::sleep_for(20ms);
    }
    ASSERT_FALSE(text.empty()) << "no answer from " << address;
    EXPECT_EQ(metric(text, "proxima_requests_total", {{"method", "CreateScene"}, {"code", "OK"}}),
              2);
    EXPECT_EQ(metric(text, "proxima_requests_total",
                     {{"method", "CreateScene"}, {"code", "RESOURCE_EXHAUSTED"}}),
              1);
    EXPECT_EQ(metric(text, "proxima_requests_total", {{"method", "Query"}, {"code", "OK"}}), 3);
    EXPECT_EQ(metric(text, "proxima_request_duration_seconds_count",
                     {{"method", "Query"}, {"code", "OK"}}),
              3);
    EXPECT_EQ(metric(text, "proxima_frames_total"), 3);
    EXPECT_GT(metric(text, "proxima_exact_tests_total"), 0);
    EXPECT_EQ(metric(text, "proxima_quota_rejections_total",
                     {{"quota", "max-scenes"}, {"principal", "tight"}}),
              1);
    EXPECT_EQ(metric(text, "proxima_auth_failures_total"), 1);
    EXPECT_EQ(metric(text, "proxima_live_scenes"), 2);
    EXPECT_EQ(metric(text, "proxima_principal_scenes", {{"principal", "alice"}}), 1);
    EXPECT_EQ(metric(text, "proxima_principal_triangles", {{"principal", "alice"}}), 24);
    EXPECT_EQ(metric(text, "proxima_principal_bytes_held", {{"principal", "tight"}}), 336);
    // The GPU backend's state is always there (1 on llvmpipe, 0 where EGL cannot start).
    EXPECT_GE(metric(text, "proxima_gpu_active"), 0);
    EXPECT_GE(metric(text, "proxima_dvd_kernel_seconds_total", {{"backend", "cpu"}}), 0);
    // The process's own resources, under Prometheus' client-library names (proxima load
    // samples them).
    EXPECT_GT(metric(text, "process_resident_memory_bytes"), 1 << 20);
    EXPECT_GT(metric(text, "process_cpu_seconds_total"), 0);
}

// Issue #18: a stream whose client cancels it (or whose deadline passes) while the daemon is
// idle was logged and counted status=OK (the end of its reads read as a half-close). The log line
// and the metric now carry what the client saw.
TEST(Metrics, StreamsEndedByTheClientAreCountedAsSuch) {
    DaemonProcess daemon({"--metrics-listen", "127.0.0.1:0"});
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    const auto second = daemon.next_line(5s);
    ASSERT_TRUE(second.has_value());
    const std::string address = second->substr(std::string("metrics on ").size());
    auto stub = make_stub(daemon.address());
    const auto scene = create_scene(*stub, "", "a", 2);
    ASSERT_FALSE(scene.empty());

    {  // Cancelled after one answered frame.
        auto context = context_for("");
        auto stream = stub->StreamFrames(context.get());
        ASSERT_TRUE(stream->Write(separation_frame(scene, 1)));
        v1::FrameResult result;
        ASSERT_TRUE(stream->Read(&result));
        context->TryCancel();
        EXPECT_EQ(stream->Finish().error_code(), grpc::StatusCode::CANCELLED);
    }
    {  // Idle past its deadline.
        auto context = context_for("", 1500ms);
        auto stream = stub->StreamFrames(context.get());
        ASSERT_TRUE(stream->Write(separation_frame(scene, 1)));
        v1::FrameResult result;
        ASSERT_TRUE(stream->Read(&result));
        std::this_thread::sleep_for(2500ms);
        EXPECT_EQ(stream->Finish().error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
    }
    std::string text;
    for (int i = 0; i < 100; ++i) {
        text = http_get_metrics(address);
        if (metric(text, "proxima_requests_total",
                   {{"method", "StreamFrames"}, {"code", "DEADLINE_EXCEEDED"}}) == 1) {
            break;
        }
        std::this_thread::sleep_for(20ms);
    }
    EXPECT_EQ(
        metric(text, "proxima_requests_total", {{"method", "StreamFrames"}, {"code", "CANCELLED"}}),
        1);
    EXPECT_EQ(metric(text, "proxima_requests_total",
                     {{"method", "StreamFrames"}, {"code", "DEADLINE_EXCEEDED"}}),
              1);
    EXPECT_EQ(metric(text, "proxima_requests_total", {{"method", "StreamFrames"}, {"code", "OK"}}),
              -1);
}

TEST(Logs, JsonMessagesKeepEveryKeyAndTypedValues) {
    const auto j = nlohmann::json::parse(server::log_message_json(
        "rejected method=Query who=alice peer=ipv4:127.0.0.1:4000 scene=5c0f status=NOT_FOUND "
        "duration_ms=0.210 message=\"scene 5c0f does not exist (name \"x\")\""));
    EXPECT_EQ(j["event"], "rejected");
    EXPECT_EQ(j["method"], "Query");
    EXPECT_EQ(j["who"], "alice");
    EXPECT_EQ(j["peer"], "ipv4:127.0.0.1:4000");
    EXPECT_EQ(j["status"], "NOT_FOUND");
    EXPECT_DOUBLE_EQ(j["duration_ms"].get<double>(), 0.210);
    EXPECT_EQ(j["message"], "scene 5c0f does not exist (name \"x\")");

    const auto g = nlohmann::json::parse(server::log_message_json(
        "gpu backend=cpu reason=\"EGL unavailable: no display\" (the Voronoi culler runs on the "
        "CPU)"));
    EXPECT_EQ(g["event"], "gpu");
    EXPECT_EQ(g["reason"], "EGL unavailable: no display");
    EXPECT_EQ(g["note"], "(the Voronoi culler runs on the CPU)");

    const auto plain = nlohmann::json::parse(server::log_message_json("shutdown complete"));
    EXPECT_EQ(plain["event"], "shutdown complete");
}

TEST(Logs, TheDaemonWritesOneJsonObjectPerLine) {
    // A daemon that cannot start (no such models directory) still logs, then exits 1.
    const std::string command = std::string(PROXIMAD_PATH) +
                                " --listen 127.0.0.1:0 --log-format json --gpu off "
                                "--models /nonexistent/proxima-models 2>&1 >/dev/null";
    FILE* pipe = popen(command.c_str(), "r");
    ASSERT_NE(pipe, nullptr);
    std::array<char, 4096> buffer{};
    int lines = 0;
    bool critical = false;
    while (fgets(buffer.data(), buffer.size(), pipe) != nullptr) {
        const auto line = nlohmann::json::parse(buffer.data(), nullptr, false);
        ASSERT_FALSE(line.is_discarded()) << "not JSON: " << buffer.data();
        EXPECT_TRUE(line.contains("time") && line.contains("level") && line.contains("event"))
            << buffer.data();
        critical = critical || line["level"] == "critical";
        ++lines;
    }
    const int status = pclose(pipe);
    EXPECT_EQ(WEXITSTATUS(status), 1);
    EXPECT_GE(lines, 1);
    EXPECT_TRUE(critical);
}

}  // namespace
}  // namespace proxima::test
