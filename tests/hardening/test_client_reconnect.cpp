// The client library's reconnect side of issue #7: exponential backoff with full jitter when the
// daemon cannot be reached (attempt timestamps, not wall-clock totals), which codes are retried
// and which calls repeat (against a fake Proximity service whose answers the test chooses), the
// bearer token on every kind of call, and ResilientScene surviving a proximad killed with SIGKILL
// mid-stream and restarted on the same port: the scene is re-created, the frames in flight are
// re-sent once, ids stay the caller's, and every answer equals an in-process ProximityEngine fed
// the same updates.
#include <gtest/gtest.h>

#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <bit>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <future>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "client/proxima_client.hpp"
#include "integration/daemon_process.hpp"
#include "proxima/query/query.hpp"
#include "proxima/v1/proxima.grpc.pb.h"
#include "support/random_scenes.hpp"

namespace proxima::client {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
namespace pb = ::proxima::v1;

// A loopback port nobody listens on: bound once to learn a free number, then closed.
int free_port() {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    addr.sin_port = 0;
    EXPECT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
    socklen_t len = sizeof addr;
    EXPECT_EQ(::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len), 0);
    ::close(fd);
    return ntohs(addr.sin_port);
}

// What on_retry saw, with the time it saw it.
struct Recorded {
    RetryEvent event;
    Clock::time_point at;
};

struct RetryLog {
    std::mutex mu;
    std::vector<Recorded> events;

    std::function<void(const RetryEvent&)> hook() {
        return [this](const RetryEvent& e) {
            std::lock_guard lock(mu);
            events.push_back({e, Clock::now()});
        };
    }
};

RetryOptions quick_retry(int attempts, std::chrono::milliseconds initial, bool jitter) {
    RetryOptions r;
    r.max_attempts = attempts;
    r.initial_backoff = initial;
    r.multiplier = 2.0;
    r.max_backoff = 10s;
    r.max_total = 0ms;
    r.jitter = jitter;
    return r;
}

// --- Backoff with nobody listening -------------------------------------------------------------

TEST(ClientBackoff, ConnectGivesUpAfterTheAttemptsWithGrowingDelays) {
    const std::string address = "127.0.0.1:" + std::to_string(free_port());
    RetryLog log;
    ConnectOptions options;
    options.connect_timeout = 2s;
    options.retry = quick_retry(5, 40ms, false);
    options.retry.on_retry = log.hook();
    const auto start = Clock::now();
    auto c = Client::connect(address, options);
    const auto end = Clock::now();
    ASSERT_FALSE(c.ok());
    EXPECT_EQ(c.status().code(), StatusCode::unavailable) << c.status().to_string();
    EXPECT_NE(c.status().message().find(address), std::string::npos) << c.status().to_string();
    EXPECT_NE(c.status().message().find("5 attempts"), std::string::npos) << c.status().to_string();
    // Four sleeps between five attempts, each cap doubling: 40, 80, 160, 320 ms (no jitter).
    ASSERT_EQ(log.events.size(), 4u);
    for (std::size_t i = 0; i < log.events.size(); ++i) {
        EXPECT_EQ(log.events[i].event.operation, "connect");
        EXPECT_EQ(log.events[i].event.attempt, static_cast<int>(i) + 1);
        EXPECT_EQ(log.events[i].event.status.code(), StatusCode::unavailable);
        EXPECT_EQ(log.events[i].event.delay, 40ms * (1 << i));
    }
    // Each attempt begins only after the previous one's sleep: the gaps between failures are at
    // least the sleeps in between (lower bounds only, so a slow machine cannot fail this).
    for (std::size_t i = 1; i < log.events.size(); ++i) {
        EXPECT_GE(log.events[i].at - log.events[i - 1].at, log.events[i - 1].event.delay) << i;
    }
    EXPECT_GE(end - log.events.back().at, log.events.back().event.delay);
    EXPECT_GE(end - start, 40ms + 80ms + 160ms + 320ms);
}

TEST(ClientBackoff, FullJitterStaysUnderTheCapAndMaxTotalStopsEarly) {
    const std::string address = "127.0.0.1:" + std::to_string(free_port());
    {
        RetryLog log;
        ConnectOptions options;
        options.retry = quick_retry(7, 20ms, true);
        options.retry.on_retry = log.hook();
        auto c = Client::connect(address, options);
        EXPECT_EQ(c.status().code(), StatusCode::unavailable);
        ASSERT_EQ(log.events.size(), 6u);
        bool below_cap = false;
        for (std::size_t i = 0; i < log.events.size(); ++i) {
            const auto cap = 20ms * (1 << i);
            EXPECT_LE(log.events[i].event.delay, cap) << i;
            EXPECT_GE(log.events[i].event.delay, 0ms) << i;
            below_cap = below_cap || log.events[i].event.delay < cap;
        }
        // Six uniform draws all landing on their cap has probability ~0: jitter is on.
        EXPECT_TRUE(below_cap);
    }
    {
        // Sleeps of 100 then 200 ms: the second would end past 250 ms, so two attempts only.
        RetryLog log;
        ConnectOptions options;
        options.retry = quick_retry(10, 100ms, false);
        options.retry.max_total = 250ms;
        options.retry.on_retry = log.hook();
        auto c = Client::connect(address, options);
        EXPECT_EQ(c.status().code(), StatusCode::unavailable);
        EXPECT_EQ(log.events.size(), 1u);
        EXPECT_NE(c.status().message().find("2 attempts"), std::string::npos)
            << c.status().to_string();
    }
    {
        // max_attempts 1: no retry at all, and the message is the attempt's own.
        RetryLog log;
        ConnectOptions options;
        options.retry = quick_retry(1, 100ms, false);
        options.retry.on_retry = log.hook();
        auto c = Client::connect(address, options);
        EXPECT_EQ(c.status().code(), StatusCode::unavailable);
        EXPECT_TRUE(log.events.empty());
    }
}

TEST(ClientBackoff, CallsToADaemonThatDiedRetryThenReport) {
    test::DaemonProcess daemon({"--log-level", "warn"});
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    RetryLog log;
    ConnectOptions options;
    options.retry = quick_retry(4, 30ms, false);
    options.retry.on_retry = log.hook();
    auto c = Client::connect(daemon.address(), options);
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    ASSERT_TRUE(c.value()->server_info().ok());
    EXPECT_TRUE(log.events.empty());
    // A stream open across the failure: the client replaces its failed channel below, and the
    // stream must still be usable to the end on the old one (which it keeps alive).
    auto stream = c.value()->open_stream("");
    ASSERT_TRUE(stream.ok());
    FrameRequest first;
    first.update.additions.push_back({"box", test::box({0, 0, 0}, {1, 1, 1})});
    ASSERT_TRUE(stream.value()->send(first).ok());
    ASSERT_TRUE(stream.value()->receive().ok());

    daemon.signal(SIGKILL);
    ASSERT_TRUE(daemon.wait_exit(5s).has_value());
    auto info = c.value()->server_info();
    EXPECT_EQ(info.status().code(), StatusCode::unavailable) << info.status().to_string();
    ASSERT_EQ(log.events.size(), 3u);
    for (std::size_t i = 0; i < log.events.size(); ++i) {
        EXPECT_EQ(log.events[i].event.operation, "GetServerInfo");
        EXPECT_EQ(log.events[i].event.delay, 30ms * (1 << i));
    }
    for (std::size_t i = 1; i < log.events.size(); ++i) {
        EXPECT_GE(log.events[i].at - log.events[i - 1].at, log.events[i - 1].event.delay);
    }
    (void)stream.value()->send(first);
    EXPECT_EQ(stream.value()->receive().status().code(), StatusCode::unavailable);
    EXPECT_EQ(stream.value()->finish().code(), StatusCode::unavailable);
}

// --- A fake daemon whose answers the test chooses ---------------------------------------------

// Answers GetServerInfo, CreateScene, DeleteScene and Query with the next status of a script
// (OK once the script is used up), recording when each call arrived and its authorization
// header; StreamFrames records the header and answers each frame.
class FakeProximity final : public pb::Proximity::Service {
  public:
    std::mutex mu;
    std::vector<grpc::Status> script;
    std::vector<Clock::time_point> arrivals;
    std::vector<std::string> methods;
    std::vector<std::string> authorization;

    grpc::Status next(grpc::ServerContext* context, const std::string& method) {
        std::lock_guard lock(mu);
        arrivals.push_back(Clock::now());
        methods.push_back(method);
        const auto& md = context->client_metadata();
        auto it = md.find("authorization");
        authorization.push_back(it == md.end() ? ""
                                               : std::string(it->second.data(), it->second.size()));
        if (script.empty()) {
            return grpc::Status::OK;
        }
        auto status = script.front();
        script.erase(script.begin());
        return status;
    }

    std::size_t calls() {
        std::lock_guard lock(mu);
        return arrivals.size();
    }

    grpc::Status GetServerInfo(grpc::ServerContext* context, const pb::GetServerInfoRequest*,
                               pb::ServerInfo* info) override {
        info->set_version("fake");
        info->set_principal("tester");
        return next(context, "GetServerInfo");
    }
    grpc::Status CreateScene(grpc::ServerContext* context, const pb::CreateSceneRequest* request,
                             pb::SceneInfo* info) override {
        info->set_scene_id("fake-scene");
        for (int i = 0; i < request->objects_size(); ++i) {
            auto* o = info->add_objects();
            o->set_id(static_cast<std::uint64_t>(i) + 1);
            o->set_name(request->objects(i).name());
        }
        return next(context, "CreateScene");
    }
    grpc::Status DescribeScene(grpc::ServerContext* context, const pb::DescribeSceneRequest*,
                               pb::SceneInfo* info) override {
        info->set_scene_id("fake-scene");
        return next(context, "DescribeScene");
    }
    grpc::Status DeleteScene(grpc::ServerContext* context, const pb::DeleteSceneRequest*,
                             pb::DeleteSceneResponse*) override {
        return next(context, "DeleteScene");
    }
    grpc::Status Query(grpc::ServerContext* context, const pb::Frame* frame,
                       pb::FrameResult* result) override {
        result->set_scene_id(frame->scene_id());
        result->set_frame(frame->frame());
        return next(context, "Query");
    }
    grpc::Status StreamFrames(
        grpc::ServerContext* context,
        grpc::ServerReaderWriter<pb::FrameResult, pb::Frame>* stream) override {
        if (auto st = next(context, "StreamFrames"); !st.ok()) {
            return st;
        }
        pb::Frame frame;
        while (stream->Read(&frame)) {
            pb::FrameResult result;
            result.set_scene_id("fake-scene");
            result.set_frame(frame.frame());
            stream->Write(result);
        }
        return grpc::Status::OK;
    }
};

struct FakeServer {
    FakeProximity service;
    std::unique_ptr<grpc::Server> server;
    int port = 0;

    FakeServer() {
        grpc::ServerBuilder builder;
        builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
        builder.RegisterService(&service);
        server = builder.BuildAndStart();
    }
    ~FakeServer() { server->Shutdown(std::chrono::system_clock::now() + 1s); }

    std::string address() const { return "127.0.0.1:" + std::to_string(port); }
    void set_script(std::vector<grpc::Status> statuses) {
        std::lock_guard lock(service.mu);
        service.script = std::move(statuses);
    }
};

TEST(ClientRetry, NonRetryableCodesAreReturnedAtOnce) {
    FakeServer fake;
    ASSERT_GT(fake.port, 0);
    RetryLog log;
    ConnectOptions options;
    options.retry = quick_retry(5, 10ms, false);
    options.retry.on_retry = log.hook();
    auto c = Client::connect(fake.address(), options);
    ASSERT_TRUE(c.ok()) << c.status().to_string();

    const std::pair<grpc::StatusCode, const char*> codes[] = {
        {grpc::StatusCode::INVALID_ARGUMENT, "INVALID_ARGUMENT"},
        {grpc::StatusCode::NOT_FOUND, "NOT_FOUND"},
        {grpc::StatusCode::UNAUTHENTICATED, "UNAUTHENTICATED"},
        {grpc::StatusCode::PERMISSION_DENIED, "PERMISSION_DENIED"},
        {grpc::StatusCode::RESOURCE_EXHAUSTED, "RESOURCE_EXHAUSTED"},
        {grpc::StatusCode::FAILED_PRECONDITION, "FAILED_PRECONDITION"},
        {grpc::StatusCode::INTERNAL, "INTERNAL"},
        {grpc::StatusCode::DEADLINE_EXCEEDED, "DEADLINE_EXCEEDED"},
    };
    for (const auto& [code, name] : codes) {
        // Twice the code: a retry would meet the second one and the count would show it.
        fake.set_script({{code, std::string("quota 'scenes': ") + name}, {code, "second attempt"}});
        const auto before = fake.service.calls();
        auto info = c.value()->server_info();
        ASSERT_FALSE(info.ok()) << name;
        EXPECT_EQ(grpc_code_name(info.status()), name) << info.status().to_string();
        EXPECT_EQ(describe_status(info.status()), std::string(name) + ": quota 'scenes': " + name);
        EXPECT_EQ(fake.service.calls(), before + 1) << name << " was retried";
    }
    EXPECT_TRUE(log.events.empty());
}

TEST(ClientRetry, UnavailableIsRetriedOnlyWhereRepeatingIsSafe) {
    FakeServer fake;
    ASSERT_GT(fake.port, 0);
    RetryLog log;
    ConnectOptions options;
    options.retry = quick_retry(5, 20ms, false);
    options.retry.on_retry = log.hook();
    auto connected = Client::connect(fake.address(), options);
    ASSERT_TRUE(connected.ok()) << connected.status().to_string();
    Client& c = *connected.value();
    const grpc::Status unavailable(grpc::StatusCode::UNAVAILABLE, "shutting down");

    // Read-only calls: two UNAVAILABLE answers, then the third attempt succeeds.
    for (const std::string method : {"GetServerInfo", "DescribeScene"}) {
        fake.set_script({unavailable, unavailable});
        const auto before = fake.service.calls();
        const auto logged = log.events.size();
        const Status st = method == "GetServerInfo" ? c.server_info().status()
                                                    : c.describe_scene("fake-scene").status();
        EXPECT_TRUE(st.ok()) << method << ": " << st.to_string();
        EXPECT_EQ(fake.service.calls(), before + 3) << method;
        ASSERT_EQ(log.events.size(), logged + 2) << method;
        // The daemon saw the attempts spaced by at least the sleeps (20 then 40 ms).
        std::lock_guard lock(fake.service.mu);
        const auto& at = fake.service.arrivals;
        EXPECT_GE(at[before + 1] - at[before], 20ms);
        EXPECT_GE(at[before + 2] - at[before + 1], 40ms);
        EXPECT_EQ(log.events[logged].event.operation, method);
    }

    // Persistent UNAVAILABLE: exactly max_attempts calls, then the error.
    fake.set_script(std::vector<grpc::Status>(10, unavailable));
    auto before = fake.service.calls();
    EXPECT_EQ(c.server_info().status().code(), StatusCode::unavailable);
    EXPECT_EQ(fake.service.calls(), before + 5);

    // CreateScene is not idempotent: one UNAVAILABLE after it went out is the answer.
    fake.set_script({unavailable});
    before = fake.service.calls();
    auto scene = c.create_scene("s", {{"box", test::box({0, 0, 0}, {1, 1, 1})}});
    EXPECT_EQ(scene.status().code(), StatusCode::unavailable);
    EXPECT_EQ(fake.service.calls(), before + 1);

    // Query: a frame that only moves vertices repeats; one that adds an object does not.
    FrameRequest move;
    move.update.positions.push_back({1, test::box({0, 0, 0}, {1, 1, 1}).vertices});
    fake.set_script({unavailable});
    before = fake.service.calls();
    EXPECT_TRUE(c.query("fake-scene", move).ok());
    EXPECT_EQ(fake.service.calls(), before + 2);
    FrameRequest add;
    add.update.additions.push_back({"box", test::box({0, 0, 0}, {1, 1, 1})});
    fake.set_script({unavailable});
    before = fake.service.calls();
    EXPECT_EQ(c.query("fake-scene", add).status().code(), StatusCode::unavailable);
    EXPECT_EQ(fake.service.calls(), before + 1);
    FrameRequest ccd = move;
    ccd.ccd = true;
    fake.set_script({unavailable});
    before = fake.service.calls();
    EXPECT_EQ(c.query("fake-scene", ccd).status().code(), StatusCode::unavailable);
    EXPECT_EQ(fake.service.calls(), before + 1);

    // DeleteScene repeats; NOT_FOUND on a repeat means the scene is gone, as asked.
    fake.set_script({unavailable, {grpc::StatusCode::NOT_FOUND, "no scene"}});
    before = fake.service.calls();
    EXPECT_TRUE(c.delete_scene("fake-scene").ok());
    EXPECT_EQ(fake.service.calls(), before + 2);
    // ... but a first attempt's NOT_FOUND is the caller's wrong id.
    fake.set_script({{grpc::StatusCode::NOT_FOUND, "no scene"}});
    EXPECT_EQ(c.delete_scene("fake-scene").code(), StatusCode::not_found);
}

TEST(ClientToken, EveryKindOfCallCarriesTheBearerToken) {
    FakeServer fake;
    ASSERT_GT(fake.port, 0);
    ConnectOptions options;
    options.token = "s3cret-token";
    auto connected = Client::connect(fake.address(), options);
    ASSERT_TRUE(connected.ok()) << connected.status().to_string();
    Client& c = *connected.value();
    ASSERT_TRUE(c.server_info().ok());
    auto scene = c.create_scene("s", {{"box", test::box({0, 0, 0}, {1, 1, 1})}});
    ASSERT_TRUE(scene.ok()) << scene.status().to_string();
    ASSERT_TRUE(c.query(scene->scene_id, FrameRequest{}).ok());
    auto stream = c.open_stream(scene->scene_id);
    ASSERT_TRUE(stream.ok());
    ASSERT_TRUE(stream.value()->send(FrameRequest{}).ok());
    ASSERT_TRUE(stream.value()->receive().ok());
    ASSERT_TRUE(stream.value()->finish().ok());
    ASSERT_TRUE(c.delete_scene(scene->scene_id).ok());
    {
        std::lock_guard lock(fake.service.mu);
        ASSERT_EQ(fake.service.methods.size(), 5u);
        for (std::size_t i = 0; i < fake.service.methods.size(); ++i) {
            EXPECT_EQ(fake.service.authorization[i], "Bearer s3cret-token")
                << fake.service.methods[i];
        }
    }

    // Without a token there is no authorization header at all.
    auto anonymous = Client::connect(fake.address());
    ASSERT_TRUE(anonymous.ok());
    ASSERT_TRUE(anonymous.value()->server_info().ok());
    std::lock_guard lock(fake.service.mu);
    EXPECT_EQ(fake.service.authorization.back(), "");
}

TEST(ClientToken, BadTokensAndTlsSettingsAreRefusedBeforeConnecting) {
    ConnectOptions options;
    options.token = "line\nbreak";
    EXPECT_EQ(Client::connect("127.0.0.1:1", options).status().code(),
              StatusCode::invalid_argument);
    ConnectOptions tls;
    tls.tls = TlsOptions{};
    tls.tls->client_cert_pem = "-----BEGIN CERTIFICATE-----\nAA==\n-----END CERTIFICATE-----\n";
    auto refused = Client::connect("127.0.0.1:1", tls);
    EXPECT_EQ(refused.status().code(), StatusCode::invalid_argument);
    EXPECT_NE(refused.status().message().find("private key"), std::string::npos)
        << refused.status().to_string();
    tls.tls = TlsOptions{};
    tls.tls->root_ca_pem = "not a certificate";
    EXPECT_EQ(Client::connect("127.0.0.1:1", tls).status().code(), StatusCode::invalid_argument);
    auto missing = load_tls_files("/nonexistent/ca.pem");
    EXPECT_EQ(missing.status().code(), StatusCode::not_found);
    EXPECT_NE(missing.status().message().find("/nonexistent/ca.pem"), std::string::npos);
}

// --- ResilientScene across a SIGKILL and a restart on the same port ---------------------------

std::uint64_t bits(double d) {
    return std::bit_cast<std::uint64_t>(d);
}

void expect_same_answers(const QueryResult& local, const QueryResult& remote, std::uint64_t k) {
    ASSERT_EQ(local.separation.size(), remote.separation.size()) << "frame " << k;
    for (std::size_t i = 0; i < local.separation.size(); ++i) {
        EXPECT_EQ(local.separation[i].other, remote.separation[i].other) << "frame " << k;
        EXPECT_EQ(bits(local.separation[i].distance), bits(remote.separation[i].distance))
            << "frame " << k << " object " << i;
        EXPECT_EQ(local.separation[i].triangle, remote.separation[i].triangle) << "frame " << k;
        EXPECT_EQ(local.separation[i].other_triangle, remote.separation[i].other_triangle)
            << "frame " << k;
    }
    ASSERT_EQ(local.self.size(), remote.self.size());
    for (std::size_t i = 0; i < local.self.size(); ++i) {
        ASSERT_EQ(local.self[i].size(), remote.self[i].size());
        for (std::size_t t = 0; t < local.self[i].size(); ++t) {
            EXPECT_EQ(bits(local.self[i][t].distance), bits(remote.self[i][t].distance));
        }
    }
    auto same_pairs = [&](const std::vector<FeaturePair>& a, const std::vector<FeaturePair>& b) {
        ASSERT_EQ(a.size(), b.size()) << "frame " << k;
        for (std::size_t i = 0; i < a.size(); ++i) {
            EXPECT_FALSE(a[i] < b[i] || b[i] < a[i]) << "frame " << k;
            EXPECT_EQ(bits(a[i].distance), bits(b[i].distance));
        }
    };
    same_pairs(local.collisions, remote.collisions);
    same_pairs(local.tolerance, remote.tolerance);
}

QueryRequest all_queries() {
    QueryRequest q;
    q.self = true;
    q.collisions = true;
    q.tolerance = 0.1;
    return q;
}

// The in-process reference: the same updates (in the session's ids, which are the engine's: the
// session keeps the first daemon's numbering, and that daemon numbered like the engine).
struct Reference {
    std::unique_ptr<ProximityEngine> engine = std::make_unique<ProximityEngine>();

    SceneUpdateResult apply(const SceneUpdate& update) {
        auto r = engine->scene().apply(update);
        EXPECT_TRUE(r.ok()) << r.status().to_string();
        return r.ok() ? r.value() : SceneUpdateResult{};
    }
    // What the session does on a re-creation: a new engine from the current objects. Needed
    // where triangle pairs tie exactly: which of them a query reports depends on the culler's
    // history (refitted since creation vs built now); the distances and pair sets do not.
    void rebuild() {
        std::vector<NamedMesh> objects;
        for (const auto& o : engine->scene().objects()) {
            NamedMesh m{o.name, {o.vertices, {}}};
            for (std::uint32_t t = 0; t < o.triangle_count(); ++t) {
                m.mesh.triangles.push_back(o.triangle(t));
            }
            objects.push_back(std::move(m));
        }
        engine = std::make_unique<ProximityEngine>();
        for (auto& o : objects) {
            EXPECT_TRUE(engine->scene().add_object(std::move(o)).ok());
        }
    }
    std::vector<ObjectId> ids() const {
        std::vector<ObjectId> out;
        for (const auto& o : engine->scene().objects()) {
            out.push_back(o.id);
        }
        return out;
    }
};

// A frame moving every object of the reference a little (deterministic per frame number).
FrameRequest moving_frame(const Reference& ref, std::uint64_t k) {
    FrameRequest f;
    f.frame = k;
    f.queries = all_queries();
    for (const auto& o : ref.engine->scene().objects()) {
        std::vector<Vec3> v = o.vertices;
        for (auto& p : v) {
            p.x += 0.01 * static_cast<double>(k % 3) - 0.01;
            p.z += 0.002 * static_cast<double>(k);
        }
        f.update.positions.push_back({o.id, std::move(v)});
    }
    return f;
}

TEST(ResilientScene, SurvivesSigkillAndRestartOnTheSamePort) {
    auto daemon =
        std::make_unique<test::DaemonProcess>(std::vector<std::string>{"--log-level", "warn"});
    ASSERT_TRUE(daemon->ok()) << daemon->error();
    const int port = daemon->port();
    const std::string address = daemon->address();

    RetryLog log;
    ConnectOptions options;
    options.retry = quick_retry(5, 20ms, true);
    auto connected = Client::connect(address, options);
    ASSERT_TRUE(connected.ok()) << connected.status().to_string();
    Client& c = *connected.value();

    test::Rng rng(7);
    std::vector<NamedMesh> objects;
    objects.push_back({"ball", test::sphere(rng, 6, 10, 1.0, 0.1)});
    objects.push_back({"sheet", test::sheet(rng, 8, 6, 0.2)});
    test::transform(objects.back().mesh, 1.0, {1.2, 0.0, 0.0}, 0.3);
    objects.push_back({"box", test::box({-0.5, -0.5, 1.2}, {0.5, 0.5, 1.6})});

    std::vector<SceneRecreation> recreations;
    ResilientSceneOptions ropts;
    ropts.recovery = quick_retry(40, 25ms, true);
    ropts.recovery.max_backoff = 400ms;
    ropts.recovery.on_retry = log.hook();
    ropts.on_recreated = [&](const SceneRecreation& r) { recreations.push_back(r); };
    auto created = ResilientScene::create(c, "resilient", objects, ropts);
    ASSERT_TRUE(created.ok()) << created.status().to_string();
    ResilientScene& scene = *created.value();

    Reference ref;
    for (const auto& o : objects) {
        ASSERT_TRUE(ref.engine->scene().add_object(o).ok());
    }
    ASSERT_EQ(scene.object_ids(), ref.ids());

    // Answers frame `f` on the reference and checks the session's response against it.
    auto check = [&](const FrameRequest& f, const FrameResponse& r, bool recreated) {
        const auto applied = ref.apply(f.update);
        auto local = ref.engine->query(f.queries);
        ASSERT_TRUE(local.ok());
        EXPECT_EQ(r.frame, f.frame);
        EXPECT_EQ(r.recreated_scene, recreated) << "frame " << f.frame;
        EXPECT_EQ(r.object_ids, ref.ids()) << "frame " << f.frame;
        EXPECT_EQ(r.added_ids, applied.added_ids) << "frame " << f.frame;
        EXPECT_EQ(r.fragment_ids, applied.fragment_ids) << "frame " << f.frame;
        expect_same_answers(local.value(), r.result, f.frame);
    };

    std::uint64_t k = 1;
    for (; k <= 3; ++k) {
        auto f = moving_frame(ref, k);
        auto r = scene.step(f);
        ASSERT_TRUE(r.ok()) << r.status().to_string();
        check(f, r.value(), false);
    }
    // Topology churn before the crash, so that the re-created scene numbers objects differently
    // (the session must remap): remove the sheet (id 2), add a new ball (id 4).
    {
        FrameRequest f = moving_frame(ref, k);
        std::erase_if(f.update.positions, [](const auto& p) { return p.object == 2; });
        f.update.removals.push_back(2);
        NamedMesh extra{"ball2", test::sphere(rng, 5, 8, 0.4, 0.05)};
        test::transform(extra.mesh, 1.0, {0.0, 1.6, 0.0}, 0.0);
        f.update.additions.push_back(extra);
        auto r = scene.step(f);
        ASSERT_TRUE(r.ok()) << r.status().to_string();
        check(f, r.value(), false);
        ++k;
    }
    ASSERT_EQ(scene.object_ids(), (std::vector<ObjectId>{1, 3, 4}));
    const std::string first_scene = scene.scene_id();

    // The daemon dies (SIGKILL: no drain, no goodbye) with nothing in flight, then the client
    // pipelines two frames into the void; a new daemon comes up on the same port a little later.
    daemon->signal(SIGKILL);
    ASSERT_TRUE(daemon->wait_exit(5s).has_value());
    // The restarter thread owns the new daemon until the test ends: proximad's PR_SET_PDEATHSIG
    // ties its life to the thread that started it, so that thread must not exit early.
    std::unique_ptr<test::DaemonProcess> restarted;
    std::promise<void> started;
    std::promise<void> test_done;
    std::thread restarter([&, done = test_done.get_future()] {
        std::this_thread::sleep_for(300ms);
        restarted = std::make_unique<test::DaemonProcess>(std::vector<std::string>{
            "--listen", "127.0.0.1:" + std::to_string(port), "--log-level", "warn"});
        started.set_value();
        done.wait();
        restarted.reset();
    });
    struct JoinAtExit {
        std::promise<void>& done;
        std::thread& thread;
        ~JoinAtExit() {
            done.set_value();
            thread.join();
        }
    } join_at_exit{test_done, restarter};
    const FrameRequest lost1 = moving_frame(ref, k);
    const Status sent1 = scene.send(lost1);
    // The second frame moves on from the first's positions, as a simulator's next step would.
    FrameRequest lost2 = lost1;
    lost2.frame = k + 1;
    for (auto& p : lost2.update.positions) {
        for (auto& v : p.vertices) {
            v.y += 0.003;
        }
    }
    const Status sent2 = scene.send(lost2);
    auto r1 = scene.receive();
    auto r2 = scene.receive();
    started.get_future().wait();
    ASSERT_TRUE(restarted && restarted->ok()) << (restarted ? restarted->error() : "no daemon");
    EXPECT_TRUE(sent1.ok()) << sent1.to_string();
    EXPECT_TRUE(sent2.ok()) << sent2.to_string();
    ASSERT_TRUE(r1.ok()) << r1.status().to_string();
    ASSERT_TRUE(r2.ok()) << r2.status().to_string();
    check(lost1, r1.value(), true);   // the first answer from the new scene says so
    check(lost2, r2.value(), false);  // once only
    k += 2;

    EXPECT_EQ(scene.recreations(), 1u);
    ASSERT_EQ(recreations.size(), 1u);
    EXPECT_EQ(recreations[0].old_scene_id, first_scene);
    EXPECT_EQ(recreations[0].new_scene_id, scene.scene_id());
    EXPECT_NE(scene.scene_id(), first_scene);
    EXPECT_EQ(recreations[0].resent_frames, 2u);
    EXPECT_EQ(recreations[0].cause.code(), StatusCode::unavailable);
    // The new daemon numbered the three objects 1, 2, 3; the caller still sees 1, 3, 4.
    EXPECT_TRUE(recreations[0].ids_remapped);
    EXPECT_EQ(scene.object_ids(), (std::vector<ObjectId>{1, 3, 4}));
    // The restart took a while: recovery backed off at least once, with growing caps.
    ASSERT_FALSE(log.events.empty());
    for (const auto& e : log.events) {
        EXPECT_EQ(e.event.operation, "recover scene");
        EXPECT_LE(e.event.delay, 400ms);
    }

    // Going on after the re-creation: moves by the caller's ids, another addition (whose id
    // must be the engine's next, 5, not the new daemon's 4) and a removal.
    for (int i = 0; i < 3; ++i, ++k) {
        auto f = moving_frame(ref, k);
        if (i == 1) {
            f.update.additions.push_back({"box2", test::box({2, 2, 2}, {2.5, 2.5, 2.5})});
        }
        if (i == 2) {
            std::erase_if(f.update.positions, [](const auto& p) { return p.object == 3; });
            f.update.removals.push_back(3);
        }
        auto r = scene.step(f);
        ASSERT_TRUE(r.ok()) << r.status().to_string();
        check(f, r.value(), false);
    }
    EXPECT_EQ(scene.object_ids(), (std::vector<ObjectId>{1, 4, 5}));

    // The daemon's own view agrees: one scene (the re-created one) with three objects.
    auto described = c.describe_scene(scene.scene_id());
    ASSERT_TRUE(described.ok()) << described.status().to_string();
    EXPECT_EQ(described->objects.size(), 3u);
    auto info = c.server_info();
    ASSERT_TRUE(info.ok());
    EXPECT_EQ(info->live_scenes, 1u);
    EXPECT_TRUE(scene.finish().ok());
    auto after = c.server_info();
    ASSERT_TRUE(after.ok());
    EXPECT_EQ(after->live_scenes, 0u);
}

// A daemon with tokens, stopped with SIGTERM (it drains: the stream ends UNAVAILABLE "shutting
// down") and restarted on the same port: recovery carries the token, the ids need no remapping
// (nothing was removed), and the session goes on in lockstep with the reference. Two boxes face
// each other, so many triangle pairs tie for the closest distance: the reference is re-created
// too, as the session re-creates the daemon's scene (see Reference::rebuild).
TEST(ResilientScene, SurvivesADrainedRestartWithTokens) {
    const auto dir = std::filesystem::temp_directory_path() /
                     ("proxima-resilient-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    const auto tokens = (dir / "tokens.json").string();
    {
        std::ofstream out(tokens);
        out << R"({"tokens": [{"name": "sim", "token": "resilient-token-0123456789",)"
            << R"( "scenes": ["*"]}]})";
    }
    const std::vector<std::string> flags = {"--log-level", "warn", "--tokens", tokens};
    std::vector<std::string> first_flags = flags;
    auto daemon = std::make_unique<test::DaemonProcess>(first_flags);
    ASSERT_TRUE(daemon->ok()) << daemon->error();
    const int port = daemon->port();

    ConnectOptions options;
    options.token = "resilient-token-0123456789";
    auto connected = Client::connect(daemon->address(), options);
    ASSERT_TRUE(connected.ok()) << connected.status().to_string();
    Client& c = *connected.value();
    auto info = c.server_info();
    ASSERT_TRUE(info.ok()) << info.status().to_string();
    EXPECT_EQ(info->principal, "sim");

    std::vector<NamedMesh> objects = {{"a", test::box({0, 0, 0}, {1, 1, 1})},
                                      {"b", test::box({1.5, 0, 0}, {2.5, 1, 1})}};
    ResilientSceneOptions ropts;
    ropts.recovery = quick_retry(60, 25ms, true);
    ropts.recovery.max_backoff = 300ms;
    auto created = ResilientScene::create(c, "drained", objects, ropts);
    ASSERT_TRUE(created.ok()) << created.status().to_string();
    ResilientScene& scene = *created.value();
    Reference ref;
    for (const auto& o : objects) {
        ASSERT_TRUE(ref.engine->scene().add_object(o).ok());
    }
    auto step = [&](std::uint64_t k, bool recreated) {
        auto f = moving_frame(ref, k);
        auto r = scene.step(f);
        ASSERT_TRUE(r.ok()) << "frame " << k << ": " << r.status().to_string();
        ref.apply(f.update);
        auto local = ref.engine->query(f.queries);
        ASSERT_TRUE(local.ok());
        EXPECT_EQ(r->recreated_scene, recreated) << "frame " << k;
        EXPECT_EQ(r->object_ids, ref.ids());
        expect_same_answers(local.value(), r->result, k);
    };
    step(1, false);
    step(2, false);

    daemon->signal(SIGTERM);
    ASSERT_TRUE(daemon->wait_exit(30s).has_value());
    daemon.reset();
    // Restarted from this (the test's main) thread before the next frame: PR_SET_PDEATHSIG ties
    // the child to the thread that forks it.
    std::vector<std::string> again = flags;
    again.insert(again.begin(), {"--listen", "127.0.0.1:" + std::to_string(port)});
    daemon = std::make_unique<test::DaemonProcess>(again);
    ASSERT_TRUE(daemon->ok()) << daemon->error();

    ref.rebuild();
    step(3, true);
    step(4, false);
    EXPECT_EQ(scene.recreations(), 1u);
    EXPECT_EQ(scene.object_ids(), (std::vector<ObjectId>{1, 2}));
    EXPECT_TRUE(scene.finish().ok());
    std::filesystem::remove_all(dir);
}

TEST(ResilientScene, ErrorsOtherThanUnavailableEndTheSessionFrameByFrame) {
    test::DaemonProcess daemon({"--log-level", "warn"});
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto connected = Client::connect(daemon.address());
    ASSERT_TRUE(connected.ok());
    Client& c = *connected.value();
    std::vector<NamedMesh> objects = {{"a", test::box({0, 0, 0}, {1, 1, 1})},
                                      {"b", test::box({2, 0, 0}, {3, 1, 1})}};
    auto created = ResilientScene::create(c, "errors", objects);
    ASSERT_TRUE(created.ok()) << created.status().to_string();
    ResilientScene& scene = *created.value();
    FrameRequest good;
    good.frame = 1;
    FrameRequest bad;
    bad.frame = 2;
    bad.update.positions.push_back({1, {{0, 0, 0}}});  // 1 vertex for an 8-vertex box
    FrameRequest after;
    after.frame = 3;
    ASSERT_TRUE(scene.send(good).ok());
    ASSERT_TRUE(scene.send(bad).ok());
    (void)scene.send(after);  // may already see the stream's end; its outcome comes below
    auto r1 = scene.receive();
    ASSERT_TRUE(r1.ok()) << r1.status().to_string();
    EXPECT_EQ(r1->frame, 1u);
    auto r2 = scene.receive();
    EXPECT_EQ(r2.status().code(), StatusCode::invalid_argument) << r2.status().to_string();
    auto r3 = scene.receive();
    EXPECT_EQ(r3.status().code(), StatusCode::invalid_argument) << r3.status().to_string();
    EXPECT_EQ(scene.recreations(), 0u);
    EXPECT_EQ(scene.send(good).code(), StatusCode::invalid_argument);
}

}  // namespace
}  // namespace proxima::client
