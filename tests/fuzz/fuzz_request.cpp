// Fuzz targets: the daemon's request path, from wire bytes to engine types and a changed scene,
// without gRPC. This file is two targets (PROXIMA_FUZZ_FRAMES selects):
//
// fuzz_request (fast: decoding and validation). The first byte chooses what the rest is:
//   0: up to 4 Frames, each a 2-byte little-endian length then that many bytes (the last one takes
//      what is left), run one after the other with run_frame on one scene that starts with two
//      small objects (ids 1 and 2): decode, validate against the scene, the limits and the owner's
//      quotas, apply. The queries are skipped (run_frame's after_apply hook stops the frame), so
//      the target stays fast enough for tens of millions of executions.
//   1: a CreateSceneRequest: decode_meshes + add_objects on an empty scene.
//   2: an UploadChunk stream's payload: a header (ScalarType, counts) then vertex and index bytes,
//      decoded as a finished upload is (decode_vertex_bytes, decode_indices, add_objects).
//   3: a ReviewRequest: decode_review_request.
// Every request the daemon accepts is also encoded again the client's way (proto/wire) and must
// decode to the same request.
//
// fuzz_frames (slow: the queries too). The input is case 0's frames, run to the end: every
// requested query on fuzzed-but-valid geometry, then the result's encoding. Its executions cost
// ~100 times more (the queries are exact), see docs/reliability.md.
//
// Small limits keep every execution fast while leaving room for several objects. After each
// frame the scene, the limits and the owner's charged holding must agree, so a wrong answer aborts
// like a crash does.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include <google/protobuf/stubs/logging.h>

#include "auth.hpp"
#include "frames.hpp"
#include "proxima/v1/proxima.pb.h"
#include "proxima/wire/buffers.hpp"
#include "proxima/wire/frames.hpp"
#include "proxima/wire/massive.hpp"
#include "scene_registry.hpp"

namespace {

using namespace proxima;
using namespace proxima::server;

void check(bool condition, const char* what) {
    if (!condition) {
        std::fprintf(stderr, "fuzz_request: broken promise: %s\n", what);
        std::abort();
    }
}

Limits small_limits() {
    Limits limits;
    limits.max_objects_per_scene = 8;
    limits.max_triangles_per_scene = 256;
    return limits;
}

// A scene owned by an anonymous principal whose quotas are below the limits, so that both the
// quota and the limit checks are reached.
std::shared_ptr<SceneEntry> make_entry() {
    Quotas quotas;
    quotas.max_scenes = 4;
    quotas.max_objects = 6;
    quotas.max_triangles = 192;
    quotas.max_bytes_held = 1 << 16;
    quotas.max_bytes_in_flight = 1 << 16;
    quotas.max_streams = 4;
    auto owner = std::make_shared<Principal>("", quotas, std::vector<std::string>{"*"},
                                             std::vector<std::string>{"*"},
                                             std::vector<std::string>{"*"}, true);
    return std::make_shared<SceneEntry>("fuzz-scene", "fuzz", false, std::move(owner));
}

// A tetrahedron, translated; two of them are the scene every frame starts from.
NamedMesh tetrahedron(const std::string& name, double dx) {
    NamedMesh mesh;
    mesh.name = name;
    mesh.mesh.vertices = {{dx, 0, 0}, {dx + 1, 0, 0}, {dx, 1, 0}, {dx, 0, 1}};
    mesh.mesh.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    return mesh;
}

void check_scene(const SceneEntry& entry, const Limits& limits) {
    const Scene& scene = entry.engine.scene();
    check(scene.size() <= limits.max_objects_per_scene, "object limit held");
    std::uint64_t triangles = 0;
    for (const SceneObject& object : scene.objects()) {
        triangles += object.triangle_count();
        for (const Vec3& v : object.vertices) {
            check(std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z),
                  "every vertex in the scene is finite");
        }
        for (std::uint32_t t = 0; t < object.triangle_count(); ++t) {
            for (const std::uint32_t i : object.triangle(t)) {
                check(i < object.vertices.size(), "every index in the scene is in range");
            }
        }
    }
    check(triangles <= limits.max_triangles_per_scene, "triangle limit held");
}

void check_result(const v1::FrameResult& result, std::size_t objects) {
    check(result.object_ids_size() == static_cast<int>(objects), "one id per object");
    for (const auto& s : result.separation()) {
        check(s.distance() >= 0.0 && !std::isnan(s.distance()), "separation distance >= 0");
        check(!s.has_other() || s.other() < objects, "separation other in range");
    }
    for (const auto* pairs : {&result.collisions(), &result.tolerance(), &result.pns()}) {
        for (const auto& p : *pairs) {
            check(p.object() < objects && p.other() < objects, "pair objects in range");
        }
    }
}

// What the owner must be charged for: the scene as it is (frames.cpp's holding_after of an empty
// update).
void check_charged(const SceneEntry& entry) {
    const Scene& scene = entry.engine.scene();
    std::uint64_t vertices = 0;
    std::uint64_t triangles = 0;
    for (const SceneObject& object : scene.objects()) {
        vertices += object.vertices.size();
        triangles += object.triangle_count();
    }
    const Holding charged = entry.charged();
    check(charged.objects == scene.size(), "charged objects = the scene's");
    check(charged.triangles == triangles, "charged triangles = the scene's");
    check(charged.bytes == scene_bytes(vertices, triangles), "charged bytes = the scene's");
}

// An accepted request, encoded the client's way (proto/wire, float64 vertices), must be accepted
// again and must come back as the same request: encoding the second decoding gives the very same
// bytes as encoding the first.
void check_reencoded(const FrameRequest& decoded, const std::string& scene_id) {
    v1::Frame once;
    wire::encode_frame(decoded, scene_id, false, &once);
    auto again = wire::decode_frame(once);
    check(again.ok(), "the client's encoding of an accepted frame is accepted");
    v1::Frame twice;
    wire::encode_frame(again.value(), scene_id, false, &twice);
    check(once.SerializeAsString() == twice.SerializeAsString(),
          "an accepted frame survives the client's encoding unchanged");
}

void check_reencoded(const massive::ReviewRequest& decoded) {
    const auto encode = [](const massive::ReviewRequest& r, v1::ReviewRequest* out) {
        if (const auto* join = std::get_if<massive::ReviewJoinRequest>(&r)) {
            wire::encode_review_join(*join, false, out);
        } else if (const auto* pose = std::get_if<massive::ReviewPoseRequest>(&r)) {
            wire::encode_review_pose(*pose, out);
        } else {
            wire::encode_review_edit(std::get<massive::ReviewEditRequest>(r), false, out);
        }
    };
    v1::ReviewRequest once;
    encode(decoded, &once);
    auto again = wire::decode_review_request(once);
    check(again.ok(), "the client's encoding of an accepted review request is accepted");
    v1::ReviewRequest twice;
    encode(again.value(), &twice);
    check(once.SerializeAsString() == twice.SerializeAsString(),
          "an accepted review request survives the client's encoding unchanged");
}

void run_frames(std::string_view rest, bool queries) {
    const Limits limits = small_limits();
    auto owned = make_entry();
    SceneEntry& entry = *owned;
    {
        std::vector<NamedMesh> start;
        start.push_back(tetrahedron("a", 0.0));
        start.push_back(tetrahedron("b", 2.0));
        check(add_objects(entry, std::move(start), limits, "objects").ok(), "the start scene");
    }
    for (int f = 0; f < 4 && !rest.empty(); ++f) {
        std::string_view bytes = rest;
        if (f < 3 && rest.size() >= 2) {
            const std::size_t length =
                static_cast<std::uint8_t>(rest[0]) | (static_cast<std::size_t>(rest[1]) << 8);
            bytes = rest.substr(2, length);
            rest.remove_prefix(std::min(rest.size(), 2 + length));
        } else {
            rest = {};
        }
        v1::Frame frame;
        if (!frame.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
            return;
        }
        if (auto decoded = wire::decode_frame(frame); decoded.ok()) {
            check_reencoded(decoded.value(), frame.scene_id());
        }
        // The daemon's own bound on a frame's work is the call's deadline; CCD between
        // degenerate (coplanar, crossing) objects may use its whole per-test work bound, so a
        // frame of this small scene can take a second under ASan. A frame past its deadline
        // must stop and leave a consistent scene (checked below), and an input slower than ~1 s
        // despite the deadline is a finding.
        CancelToken deadline;
        deadline.set_deadline(std::chrono::steady_clock::now() + std::chrono::milliseconds(100));
        v1::FrameResult result;
        bool applied = false;
        const auto stop_after_apply = [&applied] {
            applied = true;
            return Status{StatusCode::cancelled, "fuzz_request: queries skipped"};
        };
        const Status status =
            queries ? run_frame(entry, frame, limits, &deadline, &result)
                    : run_frame(entry, frame, limits, &deadline, &result, stop_after_apply);
        check_scene(entry, limits);
        check_charged(entry);
        check(!applied || !status.ok(), "after_apply's failure fails the frame");
        if (status.ok()) {
            check_result(result, entry.engine.scene().size());
        } else {
            check(!status.message().empty(), "an error says why");
        }
    }
}

[[maybe_unused]] void create_scene(std::string_view rest) {
    v1::CreateSceneRequest request;
    if (!request.ParseFromArray(rest.data(), static_cast<int>(rest.size()))) {
        return;
    }
    auto meshes = wire::decode_meshes(request.objects(), "objects");
    if (!meshes.ok()) {
        return;
    }
    const Limits limits = small_limits();
    auto owned = make_entry();
    SceneEntry& entry = *owned;
    const std::size_t count = meshes.value().size();
    const auto added = add_objects(entry, std::move(meshes).value(), limits, "objects");
    check_scene(entry, limits);
    check_charged(*owned);
    // All or none.
    check(entry.engine.scene().size() == (added.ok() ? count : 0), "additions are all or none");
}

// [type:1][vertex byte count:2 LE][vertex bytes][index bytes]
[[maybe_unused]] void upload(std::string_view rest) {
    if (rest.size() < 3) {
        return;
    }
    const auto type = static_cast<v1::ScalarType>(static_cast<std::uint8_t>(rest[0]) % 4);
    const std::size_t vertex_bytes =
        static_cast<std::uint8_t>(rest[1]) | (static_cast<std::size_t>(rest[2]) << 8);
    rest.remove_prefix(3);
    const std::string_view vertices = rest.substr(0, vertex_bytes);
    const std::string_view indices = rest.substr(vertices.size());
    auto decoded = wire::decode_vertex_bytes(type, vertices, "vertex_bytes");
    const std::size_t stride = wire::vertex_stride(type);
    if (decoded.ok()) {
        check(stride != 0 && decoded.value().size() * stride == vertices.size(),
              "vertex count matches the bytes");
    }
    auto triangles = wire::decode_indices(indices, "index_bytes");
    if (triangles.ok()) {
        check(triangles.value().size() * 12 == indices.size(), "index count matches the bytes");
    }
    if (!decoded.ok() || !triangles.ok()) {
        return;
    }
    NamedMesh mesh;
    mesh.name = "upload";
    mesh.mesh.vertices = std::move(decoded).value();
    mesh.mesh.triangles = std::move(triangles).value();
    std::vector<NamedMesh> meshes;
    meshes.push_back(std::move(mesh));
    const Limits limits = small_limits();
    auto owned = make_entry();
    SceneEntry& entry = *owned;
    (void)add_objects(entry, std::move(meshes), limits, "upload");
    check_scene(entry, limits);
    check_charged(entry);
}

[[maybe_unused]] void review(std::string_view rest) {
    v1::ReviewRequest request;
    if (!request.ParseFromArray(rest.data(), static_cast<int>(rest.size()))) {
        return;
    }
    auto decoded = wire::decode_review_request(request);
    if (decoded.ok()) {
        check_reencoded(decoded.value());
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    // Protobuf logs every string field with invalid UTF-8 to standard error: most inputs.
    static const bool quiet = [] {
        google::protobuf::SetLogHandler(nullptr);
        return true;
    }();
    (void)quiet;
#ifdef PROXIMA_FUZZ_FRAMES
    run_frames(std::string_view(reinterpret_cast<const char*>(data), size), true);
#else
    if (size == 0) {
        return 0;
    }
    const std::string_view rest(reinterpret_cast<const char*>(data) + 1, size - 1);
    switch (data[0] % 4) {
        case 0:
            run_frames(rest, false);
            break;
        case 1:
            create_scene(rest);
            break;
        case 2:
            upload(rest);
            break;
        default:
            review(rest);
            break;
    }
#endif
    return 0;
}
