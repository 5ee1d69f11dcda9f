// proximad's principals and quotas (server/auth.hpp): token files, authentication by hash, access
// patterns, and quota reservations that take all or nothing. The daemon's use of them (NOT_FOUND
// for another token's scene, RESOURCE_EXHAUSTED over the wire) is in tests/hardening.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "auth.hpp"

namespace proxima::server {
namespace {

constexpr const char* SECRET = "a-long-random-secret-0123456789";

StatusOr<std::unique_ptr<Authenticator>> parse(const std::string& text) {
    return Authenticator::from_json(nlohmann::json::parse(text), "tokens.json");
}

TEST(ServerAuth, NoTokenFileMeansOneAnonymousPrincipal) {
    Authenticator auth;
    EXPECT_FALSE(auth.enabled());
    auto p = auth.authenticate("");
    ASSERT_TRUE(p.ok());
    EXPECT_TRUE((*p)->anonymous());
    EXPECT_EQ((*p)->log_name(), "-");
    EXPECT_TRUE((*p)->may_create_scene("anything"));
    EXPECT_TRUE((*p)->may_join_room("any-room"));
    EXPECT_TRUE((*p)->may_use_model("any-model"));
    EXPECT_TRUE((*p)->reserve_scene().ok());
}

TEST(ServerAuth, TokensAreLookedUpByHashAndNeverEchoed) {
    // sha256("password"), as in docs/server.md.
    auto auth = parse(std::string(R"({"tokens": [
        {"name": "simulator-a",
         "sha256": "5e884898da28047151d0e56f8dc6292773603d0d6aabbdd62a11ef721d1542d8"},
        {"name": "reviewer", "token": ")") +
                      SECRET + R"(", "rooms": ["design-*"],
         "models": ["plant*"], "scenes": []}]})");
    ASSERT_TRUE(auth.ok()) << auth.status().to_string();
    EXPECT_TRUE((*auth)->enabled());
    EXPECT_EQ((*auth)->size(), 2u);

    auto a = (*auth)->authenticate("Bearer password");
    ASSERT_TRUE(a.ok()) << a.status().to_string();
    EXPECT_EQ((*a)->name(), "simulator-a");
    auto r = (*auth)->authenticate(std::string("Bearer ") + SECRET);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ((*r)->name(), "reviewer");
    EXPECT_TRUE((*r)->may_join_room("design-7"));
    EXPECT_FALSE((*r)->may_join_room("ops"));
    EXPECT_TRUE((*r)->may_use_model("plant-15M"));
    EXPECT_FALSE((*r)->may_use_model("building"));
    EXPECT_FALSE((*r)->may_create_scene("x"));

    for (const std::string bad :
         {"", "Bearer", "Bearer wrong-token-0123456789", "password", "Basic cGFzc3dvcmQ="}) {
        auto s = (*auth)->authenticate(bad);
        ASSERT_FALSE(s.ok()) << bad;
        EXPECT_EQ(s.status().code(), StatusCode::unauthenticated) << bad;
        if (!bad.empty()) {
            EXPECT_EQ(s.status().message().find("wrong-token"), std::string::npos);
        }
    }
}

TEST(ServerAuth, MalformedTokenFilesNameTheEntry) {
    const std::vector<std::pair<std::string, std::string>> bad = {
        {R"({"tokens": [{"token": "a-long-random-secret-0123456789"}]})", "name"},
        {R"({"tokens": [{"name": "a"}]})", "token"},
        {R"({"tokens": [{"name": "a", "token": "short"}]})", "16"},
        {R"({"tokens": [{"name": "a", "sha256": "abc"}]})", "sha256"},
        {R"({"tokens": [{"name": "a", "token": "a-long-random-secret-0123456789",
             "sha256": "5e884898da28047151d0e56f8dc6292773603d0d6aabbdd62a11ef721d1542d8"}]})",
         "exactly one"},
        {R"({"tokens": [{"name": "a", "token": "a-long-random-secret-0123456789",
             "quotas": {"max-scene": 1}}]})",
         "max-scene"},
        {R"({"tokens": [{"name": "a", "token": "a-long-random-secret-0123456789", "colour": 1}]})",
         "colour"},
        {R"({"tokens": [{"name": "a", "token": "a-long-random-secret-0123456789"},
                        {"name": "a", "token": "another-long-secret-0123456789"}]})",
         "a"},
        {R"({"tokens": [{"name": "a", "token": "a-long-random-secret-0123456789"},
                        {"name": "b", "token": "a-long-random-secret-0123456789"}]})",
         "b"},
        {R"({"tokens": 3})", "tokens"},
    };
    for (const auto& [text, word] : bad) {
        auto auth = parse(text);
        ASSERT_FALSE(auth.ok()) << text;
        EXPECT_EQ(auth.status().code(), StatusCode::invalid_argument) << text;
        EXPECT_NE(auth.status().message().find(word), std::string::npos)
            << text << ": " << auth.status().message();
    }
}

TEST(ServerAuth, MissingTokenFileIsAnError) {
    auto auth = Authenticator::from_file("/nonexistent/tokens.json");
    ASSERT_FALSE(auth.ok());
    EXPECT_NE(auth.status().message().find("/nonexistent/tokens.json"), std::string::npos);
}

Principal limited(Quotas q) {
    return Principal("sim", q, {"*"}, {"*"}, {"*"}, false);
}

TEST(ServerAuth, QuotasTakeAllOrNothing) {
    Quotas q;
    q.max_scenes = 2;
    q.max_streams = 1;
    q.max_bytes_in_flight = 100;
    q.max_objects = 10;
    q.max_triangles = 1000;
    q.max_bytes_held = scene_bytes(100, 1000);
    Principal p = limited(q);

    EXPECT_TRUE(p.reserve_scene().ok());
    EXPECT_TRUE(p.reserve_scene().ok());
    auto s = p.reserve_scene();
    EXPECT_EQ(s.code(), StatusCode::resource_exhausted);
    EXPECT_NE(s.message().find("max-scenes"), std::string::npos) << s.message();
    EXPECT_EQ(p.scenes(), 2u);
    p.release_scene();
    EXPECT_TRUE(p.reserve_scene().ok());

    EXPECT_TRUE(p.reserve_stream().ok());
    EXPECT_EQ(p.reserve_stream().code(), StatusCode::resource_exhausted);
    p.release_stream();
    EXPECT_TRUE(p.reserve_stream().ok());

    EXPECT_TRUE(p.reserve_in_flight(60).ok());
    EXPECT_EQ(p.reserve_in_flight(41).code(), StatusCode::resource_exhausted);
    EXPECT_EQ(p.bytes_in_flight(), 60u);  // the refused reservation took nothing
    EXPECT_TRUE(p.reserve_in_flight(40).ok());
    p.release_in_flight(100);
    EXPECT_EQ(p.bytes_in_flight(), 0u);

    // A holding grows only when all three quotas allow it; a refused change takes nothing.
    EXPECT_TRUE(p.change_holding({}, {5, 500, scene_bytes(50, 500)}).ok());
    auto over = p.change_holding({}, {5, 501, scene_bytes(50, 501)});
    EXPECT_EQ(over.code(), StatusCode::resource_exhausted);
    EXPECT_NE(over.message().find("max-triangles"), std::string::npos) << over.message();
    EXPECT_EQ(p.objects(), 5u);
    EXPECT_EQ(p.triangles(), 500u);
    // Shrinking always succeeds and gives the room back.
    EXPECT_TRUE(p.change_holding({5, 500, scene_bytes(50, 500)}, {}).ok());
    EXPECT_EQ(p.triangles(), 0u);
    EXPECT_EQ(p.bytes_held(), 0u);
}

TEST(ServerAuth, ZeroQuotaIsUnlimited) {
    Principal p = limited({});
    for (int i = 0; i < 1000; ++i) {
        ASSERT_TRUE(p.reserve_scene().ok());
        ASSERT_TRUE(p.admit_frame().ok());
    }
    EXPECT_TRUE(p.change_holding({}, {1u << 30, 1u << 30, 1ull << 40}).ok());
}

TEST(ServerAuth, FrameRateIsATokenBucket) {
    Quotas q;
    q.max_frames_per_second = 5;
    Principal p = limited(q);
    // A burst of up to one second's worth passes, the next frame does not.
    int admitted = 0;
    while (admitted < 100 && p.admit_frame().ok()) {
        ++admitted;
    }
    EXPECT_GE(admitted, 5);
    EXPECT_LE(admitted, 6);
    auto s = p.admit_frame();
    EXPECT_EQ(s.code(), StatusCode::resource_exhausted);
    EXPECT_NE(s.message().find("max-frames-per-second"), std::string::npos) << s.message();
}

}  // namespace
}  // namespace proxima::server
