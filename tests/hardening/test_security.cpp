// Security (issue #7, item 1): bearer tokens and what each may use, scenes invisible to other
// tokens, TLS and mutual TLS, and the refusal to serve plaintext beyond loopback. Every test
// starts its own proximad with a token file and certificates made for it.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <regex>
#include <string>
#include <thread>

#include "auth.hpp"
#include "client/proxima_client.hpp"
#include "security_util.hpp"

namespace proxima::test {
namespace {

using namespace std::chrono_literals;

const std::string ALICE = "alice-token-0123456789";
const std::string BOB = "bob-token-0123456789abcdef";
const std::string CAROL = "carol-token-0123456789";

// alice: every scene, rooms design-*, models plant*; bob (given as a hash): every scene, no room,
// no model; carol: only scenes named carol/*.
std::string token_file_json() {
    return R"({"tokens": [
  {"name": "alice", "token": ")" +
           ALICE + R"(", "scenes": ["*"], "rooms": ["design-*"], "models": ["plant*"]},
  {"name": "bob", "sha256": ")" +
           server::sha256_hex(BOB) + R"(", "scenes": ["*"]},
  {"name": "carol", "token": ")" +
           CAROL + R"(", "scenes": ["carol/*"]}
]})";
}

struct TokenDaemon {
    explicit TokenDaemon(std::vector<std::string> extra = {}) : daemon(flags(extra)) {
        EXPECT_TRUE(daemon.ok()) << daemon.error();
        stub = make_stub(daemon.address());
    }
    std::vector<std::string> flags(std::vector<std::string> extra) {
        write_text(dir.file("tokens.json"), token_file_json());
        extra.insert(extra.begin(), {"--tokens", dir.file("tokens.json")});
        return extra;
    }
    ScratchDir dir;
    DaemonProcess daemon;
    std::unique_ptr<v1::Proximity::Stub> stub;
};

// The message with every 16-hex-digit scene id replaced, to compare "not found" answers.
std::string without_ids(const std::string& message) {
    return std::regex_replace(message, std::regex("[0-9a-f]{16}"), "ID");
}

TEST(Tokens, CallsWithoutAValidTokenAreUnauthenticated) {
    TokenDaemon fx;
    v1::ServerInfo info;
    for (const std::string& header : {std::string(), std::string("Basic abc"),
                                      std::string("Bearer not-a-token-of-this-daemon")}) {
        grpc::ClientContext context;
        if (!header.empty()) {
            context.AddMetadata("authorization", header);
        }
        deadline_in(context, 10s);
        const auto s = fx.stub->GetServerInfo(&context, {}, &info);
        EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAUTHENTICATED) << header;
        EXPECT_EQ(s.error_message().find("not-a-token"), std::string::npos)
            << "the token must never be echoed: " << s.error_message();
    }
    // Streams too: the first read never happens.
    {
        auto context = context_for("");
        auto stream = fx.stub->StreamFrames(context.get());
        stream->Write(separation_frame(""));
        stream->WritesDone();
        v1::FrameResult result;
        EXPECT_FALSE(stream->Read(&result));
        EXPECT_EQ(stream->Finish().error_code(), grpc::StatusCode::UNAUTHENTICATED);
    }
    // A known token is its principal, with its quotas (none here).
    auto context = context_for(ALICE);
    ASSERT_TRUE(fx.stub->GetServerInfo(context.get(), {}, &info).ok());
    EXPECT_EQ(info.principal(), "alice");
    EXPECT_EQ(info.quotas().max_scenes(), 0u);
    // Health checks need no token: load balancers probe them.
    EXPECT_EQ(health_check(fx.daemon.address(), ""), 1);
}

TEST(Tokens, AnotherTokenCannotSeeOrTouchAScene) {
    TokenDaemon fx;
    const auto scene = create_scene(*fx.stub, ALICE, "alices", 2);
    ASSERT_FALSE(scene.empty());
    // What bob gets for alice's scene is exactly what he gets for an id that never existed.
    const std::string never = "0123456789abcdef";
    auto describe = [&](const std::string& token, const std::string& id, v1::SceneInfo* info) {
        auto context = context_for(token);
        v1::DescribeSceneRequest request;
        request.set_scene_id(id);
        return fx.stub->DescribeScene(context.get(), request, info);
    };
    v1::SceneInfo info;
    const auto bob_sees = describe(BOB, scene, &info);
    const auto nobody = describe(BOB, never, &info);
    EXPECT_EQ(bob_sees.error_code(), grpc::StatusCode::NOT_FOUND);
    EXPECT_EQ(without_ids(bob_sees.error_message()), without_ids(nobody.error_message()));

    {  // delete
        auto context = context_for(BOB);
        v1::DeleteSceneRequest request;
        request.set_scene_id(scene);
        v1::DeleteSceneResponse response;
        EXPECT_EQ(fx.stub->DeleteScene(context.get(), request, &response).error_code(),
                  grpc::StatusCode::NOT_FOUND);
    }
    {  // query, moving a vertex of alice's object 1
        auto frame = separation_frame(scene);
        auto* positions = frame.add_positions();
        positions->set_object_id(1);
        auto moved = box_at(5.0).mesh.vertices;
        set_vertices(moved, positions->mutable_vertices());
        EXPECT_EQ(query(*fx.stub, BOB, frame).error_code(), grpc::StatusCode::NOT_FOUND);
    }
    {  // a stream bound to it
        auto context = context_for(BOB);
        auto stream = fx.stub->StreamFrames(context.get());
        stream->Write(separation_frame(scene));
        stream->WritesDone();
        v1::FrameResult result;
        EXPECT_FALSE(stream->Read(&result));
        EXPECT_EQ(stream->Finish().error_code(), grpc::StatusCode::NOT_FOUND);
    }
    {  // an upload into it
        auto context = context_for(BOB);
        v1::ObjectInfo object;
        auto upload = fx.stub->UploadObject(context.get(), &object);
        v1::UploadChunk chunk;
        chunk.mutable_header()->set_scene_id(scene);
        chunk.mutable_header()->set_type(v1::SCALAR_TYPE_FLOAT64);
        chunk.mutable_header()->set_vertex_count(8);
        chunk.mutable_header()->set_triangle_count(12);
        upload->Write(chunk);
        upload->WritesDone();
        EXPECT_EQ(upload->Finish().error_code(), grpc::StatusCode::NOT_FOUND);
    }
    // Alice's scene is as she left it: two objects, no frame applied, then hers to delete.
    ASSERT_TRUE(describe(ALICE, scene, &info).ok());
    EXPECT_EQ(info.objects_size(), 2);
    EXPECT_EQ(info.frames(), 0u);
    v1::FrameResult result;
    ASSERT_TRUE(query(*fx.stub, ALICE, separation_frame(scene), &result).ok());
    EXPECT_EQ(result.scene_id(), scene);
    auto context = context_for(ALICE);
    v1::DeleteSceneRequest request;
    request.set_scene_id(scene);
    v1::DeleteSceneResponse response;
    EXPECT_TRUE(fx.stub->DeleteScene(context.get(), request, &response).ok());
}

TEST(Tokens, ScenePatternsLimitWhatATokenMayCreate) {
    TokenDaemon fx;
    grpc::Status status;
    EXPECT_TRUE(create_scene(*fx.stub, CAROL, "elsewhere", 1, &status).empty());
    EXPECT_EQ(status.error_code(), grpc::StatusCode::PERMISSION_DENIED);
    EXPECT_NE(status.error_message().find("elsewhere"), std::string::npos);
    EXPECT_FALSE(create_scene(*fx.stub, CAROL, "carol/run-1", 1, &status).empty())
        << status.error_message();
    // A stream-owned scene is named "": not carol's.
    auto context = context_for(CAROL);
    auto stream = fx.stub->StreamFrames(context.get());
    v1::Frame frame = separation_frame("");
    set_mesh(box_at(0), frame.add_additions());
    stream->Write(frame);
    stream->WritesDone();
    v1::FrameResult result;
    EXPECT_FALSE(stream->Read(&result));
    EXPECT_EQ(stream->Finish().error_code(), grpc::StatusCode::PERMISSION_DENIED);
}

// Runs the CLI; its exit status.
int run_cli(const std::vector<std::string>& args) {
    std::string command = PROXIMA_CLI_PATH;
    for (const auto& a : args) {
        command += " '" + a + "'";
    }
    const int status = std::system((command + " >/dev/null 2>&1").c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(Tokens, RoomsAndModelsNeedTheirAccess) {
    ScratchDir models;
    // Two small generated models: alice may use plant-a (plant*), not other; bob neither.
    ASSERT_EQ(run_cli({"import", "--store", models.file("plant-a"), "--plant", "10K"}), 0);
    ASSERT_EQ(run_cli({"import", "--store", models.file("other"), "--plant", "10K"}), 0);
    TokenDaemon fx({"--models", models.path().string()});

    auto list = [&](const std::string& token) {
        auto context = context_for(token);
        v1::ListModelsResponse response;
        EXPECT_TRUE(fx.stub->ListModels(context.get(), {}, &response).ok());
        std::vector<std::string> names;
        for (const auto& m : response.models()) {
            names.push_back(m.name());
        }
        return names;
    };
    EXPECT_EQ(list(ALICE), std::vector<std::string>{"plant-a"});
    EXPECT_TRUE(list(BOB).empty());

    auto verify = [&](const std::string& token, const std::string& model) {
        auto context = context_for(token, 60s);
        v1::VerifyModelRequest request;
        request.set_model(model);
        request.set_tolerance(0.01);
        auto reader = fx.stub->VerifyModel(context.get(), request);
        v1::VerifyModelEvent event;
        while (reader->Read(&event)) {
        }
        return reader->Finish();
    };
    EXPECT_TRUE(verify(ALICE, "plant-a").ok());
    // A model the token may not use is answered as one that does not exist.
    const auto forbidden = verify(ALICE, "other");
    const auto missing = verify(ALICE, "plant-missing");
    EXPECT_EQ(forbidden.error_code(), grpc::StatusCode::NOT_FOUND);
    EXPECT_EQ(std::regex_replace(forbidden.error_message(), std::regex("'other'"), "'M'"),
              std::regex_replace(missing.error_message(), std::regex("'plant-missing'"), "'M'"));

    // Review rooms: joined only with the room's access.
    auto join = [&](const std::string& token, const std::string& room, const std::string& model) {
        auto context = context_for(token, 60s);
        auto stream = fx.stub->Review(context.get());
        v1::ReviewRequest request;
        auto* j = request.mutable_join();
        j->set_room(room);
        j->set_model(model);
        j->set_member("m");
        j->set_tolerance(0.05);
        set_mesh(box_at(0, "avatar"), j->mutable_avatar());
        stream->Write(request);
        v1::ReviewEvent event;
        const bool joined = stream->Read(&event) && event.has_joined();
        stream->WritesDone();
        while (stream->Read(&event)) {
        }
        const auto status = stream->Finish();
        return joined ? grpc::Status::OK : status;
    };
    EXPECT_EQ(join(BOB, "design-1", "plant-a").error_code(), grpc::StatusCode::PERMISSION_DENIED);
    EXPECT_EQ(join(ALICE, "ops-1", "plant-a").error_code(), grpc::StatusCode::PERMISSION_DENIED);
    EXPECT_EQ(join(ALICE, "design-1", "other").error_code(), grpc::StatusCode::NOT_FOUND);
    const auto ok = join(ALICE, "design-1", "plant-a");
    EXPECT_TRUE(ok.ok()) << ok.error_message();

    // FetchRegion: the model's access as VerifyModel, a room's as joining it.
    auto region = [&](const std::string& token, const std::string& model, const std::string& room) {
        auto context = context_for(token, 60s);
        v1::FetchRegionRequest request;
        request.set_model(model);
        request.set_room(room);
        request.set_max_triangles(100);
        auto reader = fx.stub->FetchRegion(context.get(), request);
        v1::RegionEvent event;
        int summaries = 0;
        while (reader->Read(&event)) {
            summaries += event.has_summary() ? 1 : 0;
        }
        auto status = reader->Finish();
        EXPECT_TRUE(!status.ok() || summaries == 1);
        return status;
    };
    EXPECT_TRUE(region(ALICE, "plant-a", "").ok());
    EXPECT_EQ(region(ALICE, "other", "").error_code(), grpc::StatusCode::NOT_FOUND);
    EXPECT_EQ(region(BOB, "plant-a", "").error_code(), grpc::StatusCode::NOT_FOUND);
    EXPECT_EQ(region(ALICE, "plant-a", "ops-1").error_code(), grpc::StatusCode::PERMISSION_DENIED);
    EXPECT_EQ(region("", "plant-a", "").error_code(), grpc::StatusCode::UNAUTHENTICATED);
}

class Tls : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        s_dir = new ScratchDir();
        s_ready = make_certificates(*s_dir);
    }
    static void TearDownTestSuite() {
        delete s_dir;
        s_dir = nullptr;
    }
    void SetUp() override {
        ASSERT_TRUE(s_ready) << "the openssl command could not make certificates";
    }
    static std::string pem(const std::string& name) { return read_text(s_dir->file(name)); }
    static std::string file(const std::string& name) { return s_dir->file(name); }

    static bool info_ok(const std::shared_ptr<grpc::Channel>& channel,
                        grpc::StatusCode* code = nullptr) {
        auto stub = v1::Proximity::NewStub(channel);
        grpc::ClientContext context;
        deadline_in(context, 5s);
        v1::ServerInfo info;
        const auto s = stub->GetServerInfo(&context, {}, &info);
        if (code != nullptr) {
            *code = s.error_code();
        }
        return s.ok();
    }

    static inline ScratchDir* s_dir = nullptr;
    static inline bool s_ready = false;
};

TEST_F(Tls, TlsClientsConnectAndPlaintextClientsDoNot) {
    DaemonProcess daemon({"--tls-cert", file("server.pem"), "--tls-key", file("server.key")});
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    EXPECT_TRUE(info_ok(make_tls_channel(daemon.address(), {pem("ca.pem"), "", ""})));
    grpc::StatusCode code{};
    EXPECT_FALSE(info_ok(make_channel(daemon.address()), &code)) << "plaintext to a TLS port";
    EXPECT_EQ(code, grpc::StatusCode::UNAVAILABLE);
    // A client that does not trust the daemon's CA refuses it.
    EXPECT_FALSE(info_ok(make_tls_channel(daemon.address(), {pem("stranger-ca.pem"), "", ""})));
}

TEST_F(Tls, MutualTlsNeedsAClientCertificateFromTheClientCa) {
    DaemonProcess daemon({"--tls-cert", file("server.pem"), "--tls-key", file("server.key"),
                          "--tls-client-ca", file("ca.pem")});
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    EXPECT_TRUE(info_ok(
        make_tls_channel(daemon.address(), {pem("ca.pem"), pem("client.pem"), pem("client.key")})));
    EXPECT_FALSE(info_ok(make_tls_channel(daemon.address(), {pem("ca.pem"), "", ""})))
        << "no client certificate";
    EXPECT_FALSE(info_ok(make_tls_channel(
        daemon.address(), {pem("ca.pem"), pem("stranger.pem"), pem("stranger.key")})))
        << "a client certificate from another CA";
    EXPECT_FALSE(info_ok(make_channel(daemon.address()))) << "plaintext";
}

// The client library over mutual TLS with a token: a scene, a frame, the answer.
TEST_F(Tls, ClientLibraryWithMutualTlsAndAToken) {
    ScratchDir tokens;
    write_text(tokens.file("tokens.json"), token_file_json());
    DaemonProcess daemon({"--tls-cert", file("server.pem"), "--tls-key", file("server.key"),
                          "--tls-client-ca", file("ca.pem"), "--tokens",
                          tokens.file("tokens.json")});
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    client::ConnectOptions options;
    auto tls = client::load_tls_files(file("ca.pem"), file("client.pem"), file("client.key"));
    ASSERT_TRUE(tls.ok()) << tls.status().to_string();
    options.tls = tls.value();
    options.token = ALICE;
    auto c = client::Client::connect(daemon.address(), options);
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    auto info = c.value()->server_info();
    ASSERT_TRUE(info.ok()) << info.status().to_string();
    EXPECT_EQ(info->principal, "alice");
    auto scene = c.value()->create_scene("over-tls", {box_at(0, "a"), box_at(3, "b")});
    ASSERT_TRUE(scene.ok()) << scene.status().to_string();

    options.token = "wrong-token-0123456789";
    auto intruder = client::Client::connect(daemon.address(), options);
    if (intruder.ok()) {
        auto refused = intruder.value()->server_info();
        ASSERT_FALSE(refused.ok());
        EXPECT_EQ(refused.status().code(), StatusCode::unauthenticated);
    }
}

// `proximad ... --check-config`: its exit status and standard error.
std::pair<int, std::string> check_config(const std::vector<std::string>& args) {
    std::string command = std::string(PROXIMAD_PATH) + " --check-config";
    for (const auto& a : args) {
        command += " '" + a + "'";
    }
    command += " 2>&1 >/dev/null";
    std::string output;
    FILE* pipe = popen(command.c_str(), "r");
    std::array<char, 512> buffer{};
    while (pipe != nullptr && fgets(buffer.data(), buffer.size(), pipe) != nullptr) {
        output += buffer.data();
    }
    const int status = pipe != nullptr ? pclose(pipe) : -1;
    return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, output};
}

TEST_F(Tls, ListeningBeyondLoopbackNeedsTlsOrAnExplicitAllowInsecure) {
    auto [code, message] = check_config({"--listen", "0.0.0.0:50051"});
    EXPECT_EQ(code, 2);
    EXPECT_NE(message.find("TLS is off"), std::string::npos) << message;
    EXPECT_EQ(check_config({"--listen", "0.0.0.0:50051", "--allow-insecure"}).first, 0);
    EXPECT_EQ(check_config({"--listen", "0.0.0.0:50051", "--tls-cert", file("server.pem"),
                            "--tls-key", file("server.key")})
                  .first,
              0);
    EXPECT_EQ(check_config({"--listen", "127.0.0.1:50051"}).first, 0);
    EXPECT_EQ(check_config({"--listen", "[::1]:50051"}).first, 0);
    // TLS settings must be whole and readable.
    EXPECT_EQ(check_config({"--tls-cert", file("server.pem")}).first, 2);
    EXPECT_EQ(check_config({"--tls-cert", file("server.pem"), "--tls-key", file("nope.key")}).first,
              2);
    EXPECT_EQ(check_config({"--tls-client-ca", file("ca.pem")}).first, 2);
}

TEST(TokenFile, MistakesAreRefusedAtStartNamingTheEntry) {
    ScratchDir dir;
    auto check = [&](const std::string& json) {
        write_text(dir.file("t.json"), json);
        return check_config({"--tokens", dir.file("t.json")});
    };
    EXPECT_EQ(check(token_file_json()).first, 0);
    auto [code, message] = check(R"({"tokens": [{"name": "a", "token": "aaaaaaaaaaaaaaaaaaaa",
                              "quotas": {"max-scene": 3}}]})");
    EXPECT_EQ(code, 2);
    EXPECT_NE(message.find("max-scene"), std::string::npos) << message;
    EXPECT_EQ(check(R"({"tokens": [{"name": "a", "token": "short"}]})").first, 2);
    EXPECT_EQ(check(R"({"tokens": [{"name": "a", "token": "aaaaaaaaaaaaaaaaaaaa"},
                                  {"name": "b", "token": "aaaaaaaaaaaaaaaaaaaa"}]})")
                  .first,
              2);
    EXPECT_EQ(check(R"({"tokens": []})").first, 2);
    EXPECT_EQ(check("not json").first, 2);
    // --hash-token prints what the "sha256" key wants.
    FILE* pipe = popen(("echo " + BOB + " | " + PROXIMAD_PATH + " --hash-token").c_str(), "r");
    std::array<char, 128> buffer{};
    ASSERT_NE(fgets(buffer.data(), buffer.size(), pipe), nullptr);
    pclose(pipe);
    EXPECT_EQ(std::string(buffer.data()), server::sha256_hex(BOB) + "\n");
}

}  // namespace
}  // namespace proxima::test
