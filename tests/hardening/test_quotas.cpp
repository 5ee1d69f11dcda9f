// Quotas and limits per token (issue #7, item 2): each quota gives RESOURCE_EXHAUSTED naming it,
// changes nothing, and never affects another token; idle scenes expire. One daemon per test,
// with a token file holding one token per quota and an unlimited one ("free").
#include <gtest/gtest.h>

#include <string>
#include <thread>

#include "security_util.hpp"

namespace proxima::test {
namespace {

using namespace std::chrono_literals;

std::string token_of(const std::string& name) {
    return name + "-token-0123456789";
}

// A unit box holds 8 float64 vertices and 12 triangles: 8 * 24 + 12 * 12 = 336 bytes.
constexpr int BOX_BYTES = 336;

std::string quota_tokens() {
    auto entry = [](const std::string& name, const std::string& quotas) {
        return R"({"name": ")" + name + R"(", "token": ")" + token_of(name) +
               R"(", "scenes": ["*"], "quotas": {)" + quotas + "}}";
    };
    return R"({"tokens": [)" + entry("free", "") + "," + entry("scenes", R"("max-scenes": 2)") +
           "," + entry("objects", R"("max-objects": 3)") + "," +
           entry("triangles", R"("max-triangles": 30)") + "," +
           entry("bytes", R"("max-bytes-held": )" + std::to_string(2 * BOX_BYTES + 100)) + "," +
           entry("inflight", R"("max-bytes-in-flight": 2000)") + "," +
           entry("fps", R"("max-frames-per-second": 5)") + "," +
           entry("streams", R"("max-streams": 1)") + "]}";
}

struct QuotaDaemon {
    explicit QuotaDaemon(std::vector<std::string> extra = {}) : daemon(flags(extra)) {
        EXPECT_TRUE(daemon.ok()) << daemon.error();
        stub = make_stub(daemon.address());
    }
    std::vector<std::string> flags(std::vector<std::string> extra) {
        write_text(dir.file("tokens.json"), quota_tokens());
        extra.insert(extra.begin(), {"--tokens", dir.file("tokens.json")});
        return extra;
    }
    // The unlimited token is served as usual: a scene, a frame, its deletion.
    void others_carry_on() {
        const auto scene = create_scene(*stub, token_of("free"), "free", 3);
        ASSERT_FALSE(scene.empty());
        v1::FrameResult result;
        const auto s = query(*stub, token_of("free"), separation_frame(scene), &result);
        ASSERT_TRUE(s.ok()) << s.error_message();
        EXPECT_EQ(result.object_ids_size(), 3);
        auto context = context_for(token_of("free"));
        v1::DeleteSceneRequest request;
        request.set_scene_id(scene);
        v1::DeleteSceneResponse response;
        EXPECT_TRUE(stub->DeleteScene(context.get(), request, &response).ok());
    }
    ScratchDir dir;
    DaemonProcess daemon;
    std::unique_ptr<v1::Proximity::Stub> stub;
};

void expect_quota(const grpc::Status& status, const std::string& quota) {
    EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << status.error_message();
    EXPECT_NE(status.error_message().find("quota " + quota), std::string::npos)
        << status.error_message();
}

grpc::Status delete_scene(v1::Proximity::Stub& stub, const std::string& token,
                          const std::string& scene) {
    auto context = context_for(token);
    v1::DeleteSceneRequest request;
    request.set_scene_id(scene);
    v1::DeleteSceneResponse response;
    return stub.DeleteScene(context.get(), request, &response);
}

TEST(Quotas, MaxScenes) {
    QuotaDaemon fx;
    const auto t = token_of("scenes");
    const auto a = create_scene(*fx.stub, t, "a", 1);
    const auto b = create_scene(*fx.stub, t, "b", 1);
    ASSERT_FALSE(a.empty());
    ASSERT_FALSE(b.empty());
    grpc::Status s;
    EXPECT_TRUE(create_scene(*fx.stub, t, "c", 1, &s).empty());
    expect_quota(s, "max-scenes");
    // A stream-owned scene counts too.
    {
        auto context = context_for(t);
        auto stream = fx.stub->StreamFrames(context.get());
        auto frame = separation_frame("");
        set_mesh(box_at(0), frame.add_additions());
        stream->Write(frame);
        stream->WritesDone();
        v1::FrameResult result;
        EXPECT_FALSE(stream->Read(&result));
        expect_quota(stream->Finish(), "max-scenes");
    }
    fx.others_carry_on();
    // The two scenes still answer; deleting one gives its place back.
    EXPECT_TRUE(query(*fx.stub, t, separation_frame(a)).ok());
    ASSERT_TRUE(delete_scene(*fx.stub, t, a).ok());
    EXPECT_FALSE(create_scene(*fx.stub, t, "c", 1, &s).empty()) << s.error_message();
}

TEST(Quotas, MaxObjectsOverAllTheTokensScenes) {
    QuotaDaemon fx;
    const auto t = token_of("objects");
    const auto a = create_scene(*fx.stub, t, "a", 2);
    ASSERT_FALSE(a.empty());
    grpc::Status s;
    EXPECT_TRUE(create_scene(*fx.stub, t, "b", 2, &s).empty());
    expect_quota(s, "max-objects");
    // A frame adding two objects to the first scene is refused whole: the scene is unchanged.
    auto frame = separation_frame(a);
    set_mesh(box_at(10), frame.add_additions());
    set_mesh(box_at(20), frame.add_additions());
    expect_quota(query(*fx.stub, t, frame), "max-objects");
    v1::FrameResult result;
    ASSERT_TRUE(query(*fx.stub, t, separation_frame(a), &result).ok());
    EXPECT_EQ(result.object_ids_size(), 2);
    fx.others_carry_on();
    // Removing an object makes room for one more.
    auto shrink = separation_frame(a);
    shrink.add_removals(1);
    ASSERT_TRUE(query(*fx.stub, t, shrink).ok());
    EXPECT_FALSE(create_scene(*fx.stub, t, "b", 2, &s).empty()) << s.error_message();
}

TEST(Quotas, MaxTriangles) {
    QuotaDaemon fx;
    const auto t = token_of("triangles");
    ASSERT_FALSE(create_scene(*fx.stub, t, "a", 2).empty());  // 24 triangles
    grpc::Status s;
    EXPECT_TRUE(create_scene(*fx.stub, t, "b", 1, &s).empty());
    expect_quota(s, "max-triangles");
    fx.others_carry_on();
}

TEST(Quotas, MaxBytesHeldCountsUploadsToo) {
    QuotaDaemon fx;
    const auto t = token_of("bytes");
    const auto a = create_scene(*fx.stub, t, "a", 2);
    ASSERT_FALSE(a.empty());
    // A third box through the chunked upload passes max-bytes-held when it is added.
    auto context = context_for(t);
    v1::ObjectInfo object;
    auto upload = fx.stub->UploadObject(context.get(), &object);
    const auto mesh = box_at(10);
    v1::UploadChunk chunk;
    chunk.mutable_header()->set_scene_id(a);
    chunk.mutable_header()->set_type(v1::SCALAR_TYPE_FLOAT64);
    chunk.mutable_header()->set_vertex_count(8);
    chunk.mutable_header()->set_triangle_count(12);
    upload->Write(chunk);
    chunk.Clear();
    chunk.set_vertex_bytes(float64_bytes(mesh.mesh.vertices));
    upload->Write(chunk);
    chunk.Clear();
    chunk.set_index_bytes(index_bytes(mesh.mesh.triangles));
    upload->Write(chunk);
    upload->WritesDone();
    expect_quota(upload->Finish(), "max-bytes-held");
    fx.others_carry_on();
}

TEST(Quotas, MaxBytesInFlight) {
    QuotaDaemon fx;
    const auto t = token_of("inflight");
    grpc::Status s;
    // Ten boxes are ~4 KB of request: over 2,000 bytes in flight. One box is not.
    EXPECT_TRUE(create_scene(*fx.stub, t, "big", 10, &s).empty());
    expect_quota(s, "max-bytes-in-flight");
    const auto small = create_scene(*fx.stub, t, "small", 1, &s);
    EXPECT_FALSE(small.empty()) << s.error_message();
    fx.others_carry_on();
    // Nothing stays counted once calls are answered.
    auto context = context_for(t);
    v1::ServerInfo info;
    ASSERT_TRUE(fx.stub->GetServerInfo(context.get(), {}, &info).ok());
    EXPECT_EQ(info.quotas().max_bytes_in_flight(), 2000u);
}

TEST(Quotas, MaxFramesPerSecond) {
    QuotaDaemon fx;
    const auto t = token_of("fps");
    const auto scene = create_scene(*fx.stub, t, "a", 2);
    ASSERT_FALSE(scene.empty());
    auto context = context_for(t);
    auto stream = fx.stub->StreamFrames(context.get());
    // 30 frames as fast as they go: the bucket holds 5 and refills at 5/s.
    int answered = 0;
    for (int i = 0; i < 30; ++i) {
        if (!stream->Write(separation_frame(scene, i))) {
            break;
        }
        v1::FrameResult result;
        if (!stream->Read(&result)) {
            break;
        }
        ++answered;
    }
    stream->WritesDone();
    expect_quota(stream->Finish(), "max-frames-per-second");
    EXPECT_GE(answered, 5);
    EXPECT_LT(answered, 30);
    fx.others_carry_on();
    // A second later the bucket has refilled.
    std::this_thread::sleep_for(1200ms);
    EXPECT_TRUE(query(*fx.stub, t, separation_frame(scene)).ok());
}

TEST(Quotas, MaxStreams) {
    QuotaDaemon fx;
    const auto t = token_of("streams");
    const auto scene = create_scene(*fx.stub, t, "a", 2);
    ASSERT_FALSE(scene.empty());
    auto first_context = context_for(t);
    auto first = fx.stub->StreamFrames(first_context.get());
    ASSERT_TRUE(first->Write(separation_frame(scene)));
    v1::FrameResult result;
    ASSERT_TRUE(first->Read(&result));  // the first stream is open and admitted
    {
        auto context = context_for(t);
        auto second = fx.stub->StreamFrames(context.get());
        second->Write(separation_frame(scene));
        second->WritesDone();
        EXPECT_FALSE(second->Read(&result));
        expect_quota(second->Finish(), "max-streams");
    }
    fx.others_carry_on();
    first->WritesDone();
    EXPECT_TRUE(first->Finish().ok());
    // Its place is free again once it has ended.
    bool admitted = false;
    for (int attempt = 0; attempt < 50 && !admitted; ++attempt) {
        auto context = context_for(t);
        auto again = fx.stub->StreamFrames(context.get());
        again->Write(separation_frame(scene));
        admitted = again->Read(&result);
        again->WritesDone();
        while (again->Read(&result)) {
        }
        (void)again->Finish();
        if (!admitted) {
            std::this_thread::sleep_for(20ms);
        }
    }
    EXPECT_TRUE(admitted);
}

TEST(IdleScenes, ExpireAfterIdleSceneSecondsAndGiveTheirQuotaBack) {
    QuotaDaemon fx({"--idle-scene-seconds", "0.6"});
    const auto t = token_of("scenes");
    const auto idle = create_scene(*fx.stub, t, "idle", 1);
    const auto busy = create_scene(*fx.stub, t, "busy", 1);
    ASSERT_FALSE(idle.empty());
    ASSERT_FALSE(busy.empty());
    // `busy` is used every 100 ms for 1.5 s; `idle` is not.
    for (int i = 0; i < 15; ++i) {
        ASSERT_TRUE(query(*fx.stub, t, separation_frame(busy)).ok());
        std::this_thread::sleep_for(100ms);
    }
    EXPECT_EQ(query(*fx.stub, t, separation_frame(idle)).error_code(), grpc::StatusCode::NOT_FOUND);
    EXPECT_TRUE(query(*fx.stub, t, separation_frame(busy)).ok());
    // The expired scene's place among max-scenes is free.
    grpc::Status s;
    EXPECT_FALSE(create_scene(*fx.stub, t, "again", 1, &s).empty()) << s.error_message();
}

}  // namespace
}  // namespace proxima::test
