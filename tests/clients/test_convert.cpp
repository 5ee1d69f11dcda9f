// The client's conversion layer, without a daemon: engine types -> proto -> engine types is
// lossless for float64 (bit for bit, through serialized bytes), malformed buffers and results are
// rejected with a message naming the culprit, and gRPC codes map to engine codes by name.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

#include "client/convert.hpp"
#include "proxima/query/query.hpp"
#include "support/random_scenes.hpp"

namespace proxima::client {
namespace {

namespace pb = detail::pb;

// Through the wire format: what the peer parses is what we compare.
template <class Message>
Message reparse(const Message& m) {
    Message out;
    EXPECT_TRUE(out.ParseFromString(m.SerializeAsString()));
    return out;
}

std::uint64_t bits(double d) {
    return std::bit_cast<std::uint64_t>(d);
}

void expect_same(const Vec3& a, const Vec3& b) {
    EXPECT_EQ(bits(a.x), bits(b.x));
    EXPECT_EQ(bits(a.y), bits(b.y));
    EXPECT_EQ(bits(a.z), bits(b.z));
}

void expect_same(const std::vector<Vec3>& a, const std::vector<Vec3>& b) {
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(Vec3)), 0);
}

void expect_same(const NamedMesh& a, const NamedMesh& b) {
    EXPECT_EQ(a.name, b.name);
    expect_same(a.mesh.vertices, b.mesh.vertices);
    EXPECT_EQ(a.mesh.triangles, b.mesh.triangles);
}

void expect_same(const std::vector<FeaturePair>& a, const std::vector<FeaturePair>& b) {
    ASSERT_EQ(a.size(), b.size());
    for (std::size_t i = 0; i < a.size(); ++i) {
        EXPECT_EQ(std::tie(a[i].object, a[i].triangle, a[i].other, a[i].other_triangle),
                  std::tie(b[i].object, b[i].triangle, b[i].other, b[i].other_triangle));
        EXPECT_EQ(bits(a[i].distance), bits(b[i].distance));
    }
}

void expect_same(const QueryResult& a, const QueryResult& b) {
    ASSERT_EQ(a.separation.size(), b.separation.size());
    for (std::size_t i = 0; i < a.separation.size(); ++i) {
        const auto& x = a.separation[i];
        const auto& y = b.separation[i];
        EXPECT_EQ(x.other, y.other);
        EXPECT_EQ(x.triangle, y.triangle);
        EXPECT_EQ(x.other_triangle, y.other_triangle);
        EXPECT_EQ(bits(x.distance), bits(y.distance));
        expect_same(x.point, y.point);
        expect_same(x.other_point, y.other_point);
    }
    ASSERT_EQ(a.self.size(), b.self.size());
    for (std::size_t i = 0; i < a.self.size(); ++i) {
        ASSERT_EQ(a.self[i].size(), b.self[i].size());
        for (std::size_t t = 0; t < a.self[i].size(); ++t) {
            EXPECT_EQ(a.self[i][t].closest, b.self[i][t].closest);
            EXPECT_EQ(bits(a.self[i][t].distance), bits(b.self[i][t].distance));
            expect_same(a.self[i][t].point, b.self[i][t].point);
            expect_same(a.self[i][t].other_point, b.self[i][t].other_point);
        }
    }
    expect_same(a.collisions, b.collisions);
    expect_same(a.tolerance, b.tolerance);
    expect_same(a.pns, b.pns);
    EXPECT_EQ(a.stats.culler, b.stats.culler);
    EXPECT_EQ(bits(a.stats.total_seconds), bits(b.stats.total_seconds));
    EXPECT_EQ(bits(a.stats.prepare_seconds), bits(b.stats.prepare_seconds));
    EXPECT_EQ(a.stats.exact_tests, b.stats.exact_tests);
    EXPECT_EQ(a.stats.brute_force_tests, b.stats.brute_force_tests);
    EXPECT_EQ(a.stats.object_pairs_tested, b.stats.object_pairs_tested);
    EXPECT_EQ(a.stats.pns_pairs, b.stats.pns_pairs);
}

// Coordinates no decimal round trip would keep: the wire must carry the exact bits.
NamedMesh awkward_mesh() {
    test::Rng rng(7);
    NamedMesh m{"awkward", test::sphere(rng, 5, 7, 1.0, 0.2)};
    m.mesh.vertices[0] = {0.1, -1.0 / 3.0, std::nextafter(1.0, 2.0)};
    m.mesh.vertices[1] = {std::numeric_limits<double>::denorm_min(), -0.0, 1e300};
    return m;
}

TEST(ClientConvert, MeshRoundTripIsBitExactInFloat64) {
    const auto mesh = awkward_mesh();
    pb::Mesh wire;
    detail::encode_mesh(mesh, false, &wire);
    EXPECT_EQ(wire.vertices().type(), pb::SCALAR_TYPE_FLOAT64);
    EXPECT_EQ(wire.vertices().data().size(), mesh.mesh.vertices.size() * 24);
    EXPECT_EQ(wire.indices().size(), mesh.mesh.triangles.size() * 12);
    EXPECT_GE(detail::encoded_mesh_bytes(mesh, false), wire.ByteSizeLong());
    auto back = detail::decode_mesh(reparse(wire), "object");
    ASSERT_TRUE(back.ok()) << back.status().to_string();
    expect_same(mesh, back.value());
}

TEST(ClientConvert, PackedBuffersAreLittleEndian) {
    const std::vector<Vec3> v{{1.0, -2.0, 0.5}};
    const auto f64 = detail::pack_vertices(v, false);
    ASSERT_EQ(f64.size(), 24u);
    // 1.0 = 0x3FF0000000000000: the most significant byte comes last.
    EXPECT_EQ(static_cast<unsigned char>(f64[7]), 0x3Fu);
    EXPECT_EQ(static_cast<unsigned char>(f64[6]), 0xF0u);
    EXPECT_EQ(static_cast<unsigned char>(f64[0]), 0x00u);
    const auto f32 = detail::pack_vertices(v, true);
    ASSERT_EQ(f32.size(), 12u);
    // 1.0f = 0x3F800000.
    EXPECT_EQ(static_cast<unsigned char>(f32[3]), 0x3Fu);
    EXPECT_EQ(static_cast<unsigned char>(f32[2]), 0x80u);
    const std::vector<TriangleIndices> t{{1, 0x01020304u, 7}};
    const auto idx = detail::pack_triangles(t);
    ASSERT_EQ(idx.size(), 12u);
    EXPECT_EQ(static_cast<unsigned char>(idx[0]), 1u);
    EXPECT_EQ(static_cast<unsigned char>(idx[4]), 0x04u);
    EXPECT_EQ(static_cast<unsigned char>(idx[7]), 0x01u);
}

TEST(ClientConvert, Float32RoundsEachCoordinateToNearest) {
    const auto mesh = awkward_mesh();
    pb::Mesh wire;
    detail::encode_mesh(mesh, true, &wire);
    EXPECT_EQ(wire.vertices().type(), pb::SCALAR_TYPE_FLOAT32);
    EXPECT_EQ(wire.vertices().data().size(), mesh.mesh.vertices.size() * 12);
    auto back = detail::decode_mesh(reparse(wire), "object");
    ASSERT_TRUE(back.ok());
    ASSERT_EQ(back->mesh.vertices.size(), mesh.mesh.vertices.size());
    for (std::size_t i = 0; i < mesh.mesh.vertices.size(); ++i) {
        for (int k = 0; k < 3; ++k) {
            const double want = static_cast<float>(mesh.mesh.vertices[i][k]);
            EXPECT_EQ(bits(back->mesh.vertices[i][k]), bits(want)) << i << " " << k;
        }
    }
    EXPECT_EQ(back->mesh.triangles, mesh.mesh.triangles);
}

TEST(ClientConvert, FrameRoundTripKeepsEveryChangeAndQuery) {
    test::Rng rng(11);
    FrameRequest f;
    f.frame = 42;
    f.update.removals = {3, 9};
    f.update.replacements.push_back(
        {5, {{"frag0", test::box({0, 0, 0}, {1, 1, 1})}, awkward_mesh()}});
    f.update.positions.push_back({7, test::jitter(rng, awkward_mesh().mesh.vertices, 0.1)});
    f.update.additions.push_back({"added", test::sheet(rng, 3, 2, 0.1)});
    f.queries.separation = false;
    f.queries.self = true;
    f.queries.collisions = true;
    f.queries.tolerance = 0.125;
    f.queries.pns = true;
    f.queries.culler = CullerKind::brute;
    f.self_points = true;

    pb::Frame wire;
    detail::encode_frame(f, "scene-1", false, &wire);
    EXPECT_EQ(wire.scene_id(), "scene-1");
    auto back = detail::decode_frame(reparse(wire));
    ASSERT_TRUE(back.ok()) << back.status().to_string();
    const auto& g = back.value();
    EXPECT_EQ(g.frame, 42u);
    EXPECT_EQ(g.update.removals, f.update.removals);
    ASSERT_EQ(g.update.replacements.size(), 1u);
    EXPECT_EQ(g.update.replacements[0].object, 5u);
    ASSERT_EQ(g.update.replacements[0].fragments.size(), 2u);
    expect_same(g.update.replacements[0].fragments[0], f.update.replacements[0].fragments[0]);
    expect_same(g.update.replacements[0].fragments[1], f.update.replacements[0].fragments[1]);
    ASSERT_EQ(g.update.positions.size(), 1u);
    EXPECT_EQ(g.update.positions[0].object, 7u);
    expect_same(g.update.positions[0].vertices, f.update.positions[0].vertices);
    ASSERT_EQ(g.update.additions.size(), 1u);
    expect_same(g.update.additions[0], f.update.additions[0]);
    EXPECT_FALSE(g.queries.separation);
    EXPECT_TRUE(g.queries.self);
    EXPECT_TRUE(g.queries.collisions);
    ASSERT_TRUE(g.queries.tolerance.has_value());
    EXPECT_EQ(*g.queries.tolerance, 0.125);
    EXPECT_TRUE(g.queries.pns);
    EXPECT_EQ(g.queries.culler, CullerKind::brute);
    EXPECT_TRUE(g.self_points);

    // No tolerance stays no tolerance (proto3 `optional`), and every culler survives.
    for (auto kind : {CullerKind::automatic, CullerKind::brute, CullerKind::bvh}) {
        QueryRequest q;
        q.culler = kind;
        pb::QuerySpec spec;
        detail::encode_query(q, false, &spec);
        auto r = detail::decode_query(reparse(spec));
        ASSERT_TRUE(r.ok());
        EXPECT_EQ(r->culler, kind);
        EXPECT_FALSE(r->tolerance.has_value());
        EXPECT_TRUE(r->separation);
    }
}

// A real engine answer, with every query on, through the wire and back: bit for bit, and the
// engine run on the decoded meshes gives the same answer as on the originals.
TEST(ClientConvert, ResultRoundTripIsLossless) {
    for (std::uint64_t seed = 1; seed <= 20; ++seed) {
        test::Rng rng(seed);
        auto objects = test::random_scene(rng);
        objects.push_back({"box", test::box({0.5, 0.5, 0.5}, {1.5, 1.5, 1.5})});

        ProximityEngine original;
        ProximityEngine decoded;
        SceneUpdate a;
        SceneUpdate b;
        for (const auto& o : objects) {
            a.additions.push_back(o);
            pb::Mesh wire;
            detail::encode_mesh(o, false, &wire);
            b.additions.push_back(detail::decode_mesh(reparse(wire), "object").value());
        }
        ASSERT_TRUE(original.scene().apply(a).ok());
        ASSERT_TRUE(decoded.scene().apply(b).ok());
        QueryRequest q;
        q.self = true;
        q.collisions = true;
        q.tolerance = 0.05;
        q.pns = true;
        auto r = original.query(q);
        auto s = decoded.query(q);
        ASSERT_TRUE(r.ok() && s.ok());
        s->stats = r->stats;  // timings differ run to run; everything else must not
        expect_same(r.value(), s.value());

        FrameResponse response;
        response.scene_id = "s";
        response.frame = seed;
        for (const auto& obj : original.scene().objects()) {
            response.object_ids.push_back(obj.id);
        }
        response.added_ids = response.object_ids;
        response.fragment_ids = {{4, 5}, {}};
        response.result = r.value();
        response.server_seconds = 0.25;
        pb::FrameResult wire;
        detail::encode_result(response, true, &wire);
        auto back = detail::decode_result(reparse(wire));
        ASSERT_TRUE(back.ok()) << back.status().to_string();
        EXPECT_EQ(back->scene_id, "s");
        EXPECT_EQ(back->frame, seed);
        EXPECT_EQ(back->object_ids, response.object_ids);
        EXPECT_EQ(back->added_ids, response.added_ids);
        EXPECT_EQ(back->fragment_ids, response.fragment_ids);
        EXPECT_EQ(back->server_seconds, 0.25);
        expect_same(r.value(), back->result);
    }
}

TEST(ClientConvert, LoneObjectAndUnpairedTrianglesKeepTheEngineConventions) {
    ProximityEngine engine;
    // Two triangles sharing a vertex: each has no non-adjacent other (closest -1, distance +inf).
    TriangleMesh m;
    m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 1}, {2, 0, 1}};
    m.triangles = {{0, 1, 2}, {0, 3, 4}};
    ASSERT_TRUE(engine.scene().add_object({"fan", m}).ok());
    QueryRequest q;
    q.self = true;
    auto r = engine.query(q);
    ASSERT_TRUE(r.ok());
    ASSERT_EQ(r->separation[0].other, NO_OBJECT);
    ASSERT_EQ(r->self[0][0].closest, NO_OBJECT);

    FrameResponse response;
    response.object_ids = {engine.scene()[0].id};
    response.result = r.value();
    pb::FrameResult wire;
    detail::encode_result(response, false, &wire);
    EXPECT_FALSE(wire.separation(0).has_other());
    auto back = detail::decode_result(reparse(wire));
    ASSERT_TRUE(back.ok());
    EXPECT_EQ(back->result.separation[0].other, NO_OBJECT);
    EXPECT_TRUE(std::isinf(back->result.separation[0].distance));
    EXPECT_EQ(back->result.self[0][1].closest, NO_OBJECT);
    EXPECT_TRUE(std::isinf(back->result.self[0][1].distance));
}

void expect_error(const Status& st, StatusCode code, std::initializer_list<const char*> words) {
    EXPECT_EQ(st.code(), code) << st.to_string();
    for (const char* w : words) {
        EXPECT_NE(st.message().find(w), std::string::npos) << st.to_string() << " lacks " << w;
    }
}

TEST(ClientConvert, MalformedBuffersAreRejectedWithTheCulprit) {
    pb::Mesh mesh;
    mesh.set_name("a.off");
    mesh.mutable_vertices()->set_type(pb::SCALAR_TYPE_FLOAT64);
    mesh.mutable_vertices()->set_data(std::string(25, '\0'));
    mesh.set_indices(std::string(12, '\0'));
    expect_error(detail::decode_mesh(mesh, "object").status(), StatusCode::invalid_argument,
                 {"a.off", "25 bytes", "24-byte"});

    mesh.mutable_vertices()->set_type(pb::SCALAR_TYPE_FLOAT32);
    mesh.mutable_vertices()->set_data(std::string(24, '\0'));
    mesh.set_indices(std::string(13, '\0'));
    expect_error(detail::decode_mesh(mesh, "object").status(), StatusCode::invalid_argument,
                 {"a.off", "index buffer of 13 bytes"});

    mesh.mutable_vertices()->set_type(pb::SCALAR_TYPE_UNSPECIFIED);
    mesh.set_indices(std::string(12, '\0'));
    expect_error(detail::decode_mesh(mesh, "object").status(), StatusCode::invalid_argument,
                 {"a.off", "scalar type"});

    // An empty buffer is well formed (zero vertices): emptiness is the engine's check.
    pb::VertexBuffer empty;
    empty.set_type(pb::SCALAR_TYPE_FLOAT64);
    auto v = detail::unpack_vertices(empty, "x");
    ASSERT_TRUE(v.ok());
    EXPECT_TRUE(v->empty());

    pb::Frame frame;
    auto* pos = frame.add_positions();
    pos->set_object_id(17);
    pos->mutable_vertices()->set_type(pb::SCALAR_TYPE_FLOAT64);
    pos->mutable_vertices()->set_data(std::string(23, '\0'));
    expect_error(detail::decode_frame(frame).status(), StatusCode::invalid_argument, {"object 17"});

    pb::QuerySpec spec;
    spec.set_culler(static_cast<pb::Culler>(9));
    expect_error(detail::decode_query(spec).status(), StatusCode::invalid_argument, {"culler 9"});
}

TEST(ClientConvert, MalformedResultsAreInternalErrors) {
    auto base = [] {
        pb::FrameResult r;
        r.add_object_ids(1);
        r.add_object_ids(2);
        for (int i = 0; i < 2; ++i) {
            auto* s = r.add_separation();
            s->set_has_other(true);
            s->set_other(1 - i);
            auto* self = r.add_self();
            self->add_closest(-1);
            self->add_distance(std::numeric_limits<double>::infinity());
        }
        return r;
    };
    ASSERT_TRUE(detail::decode_result(base()).ok());

    auto r = base();
    r.add_separation();
    expect_error(detail::decode_result(r).status(), StatusCode::internal, {"3 separations"});
    r = base();
    r.mutable_separation(0)->set_other(2);
    expect_error(detail::decode_result(r).status(), StatusCode::internal, {"object 2 of 2"});
    r = base();
    r.mutable_self(1)->add_distance(1.0);
    expect_error(detail::decode_result(r).status(), StatusCode::internal, {"object 1"});
    r = base();
    r.mutable_self(0)->add_points(1.0);
    expect_error(detail::decode_result(r).status(), StatusCode::internal, {"point coordinates"});
    r = base();
    r.mutable_self(0)->set_closest(0, -2);
    expect_error(detail::decode_result(r).status(), StatusCode::internal, {"closest -2"});
    r = base();
    r.add_collisions()->set_other(5);
    expect_error(detail::decode_result(r).status(), StatusCode::internal, {"collision", "5"});
    r = base();
    r.add_tolerance()->set_object(2);
    expect_error(detail::decode_result(r).status(), StatusCode::internal, {"tolerance"});
}

TEST(ClientConvert, StatusCodesMapByName) {
    struct Case {
        grpc::StatusCode grpc;
        StatusCode engine;
    };
    const Case named[] = {
        {grpc::StatusCode::INVALID_ARGUMENT, StatusCode::invalid_argument},
        {grpc::StatusCode::NOT_FOUND, StatusCode::not_found},
        {grpc::StatusCode::FAILED_PRECONDITION, StatusCode::failed_precondition},
        {grpc::StatusCode::RESOURCE_EXHAUSTED, StatusCode::resource_exhausted},
        {grpc::StatusCode::CANCELLED, StatusCode::cancelled},
        {grpc::StatusCode::DEADLINE_EXCEEDED, StatusCode::deadline_exceeded},
        {grpc::StatusCode::UNAVAILABLE, StatusCode::unavailable},
        {grpc::StatusCode::INTERNAL, StatusCode::internal},
        {grpc::StatusCode::DATA_LOSS, StatusCode::data_loss},  // a corrupt massive-model chunk
        {grpc::StatusCode::UNAUTHENTICATED, StatusCode::unauthenticated},  // tokens (issue #7)
        {grpc::StatusCode::PERMISSION_DENIED, StatusCode::permission_denied},
    };
    for (const auto& c : named) {
        const auto st = detail::from_grpc({c.grpc, "object 'a.off': triangle 3 index 9"});
        EXPECT_EQ(st.code(), c.engine);
        EXPECT_EQ(st.message(), "object 'a.off': triangle 3 index 9");  // kept as the server said
        const auto back = detail::to_grpc(st);
        EXPECT_EQ(back.error_code(), c.grpc);
        EXPECT_EQ(back.error_message(), st.message());
        // The names agree, which is what "one-to-one by name" means.
        EXPECT_EQ(st.to_string().rfind(status_code_name(c.engine), 0), 0u);
    }
    EXPECT_TRUE(detail::from_grpc(grpc::Status::OK).ok());
    EXPECT_TRUE(detail::to_grpc(Status()).ok());

    const std::pair<grpc::StatusCode, const char*> unnamed[] = {
        {grpc::StatusCode::UNKNOWN, "UNKNOWN"},
        {grpc::StatusCode::ALREADY_EXISTS, "ALREADY_EXISTS"},
        {grpc::StatusCode::ABORTED, "ABORTED"},
        {grpc::StatusCode::OUT_OF_RANGE, "OUT_OF_RANGE"},
        {grpc::StatusCode::UNIMPLEMENTED, "UNIMPLEMENTED"},
        {static_cast<grpc::StatusCode>(20), "UNKNOWN"},  // a code from a newer gRPC
    };
    for (const auto& [code, name] : unnamed) {
        const auto st = detail::from_grpc({code, "why"});
        EXPECT_EQ(st.code(), StatusCode::internal);
        EXPECT_EQ(st.message(), std::string("gRPC ") + name + ": why");
        // What the command line prints: the gRPC name, not INTERNAL.
        EXPECT_EQ(grpc_code_name(st), name);
        EXPECT_EQ(describe_status(st), std::string(name) + ": why");
    }
    // Named codes print as Status::to_string does; a message that merely looks like the prefix
    // under another code is left alone.
    const auto named_st = detail::from_grpc({grpc::StatusCode::UNAUTHENTICATED, "no token"});
    EXPECT_EQ(grpc_code_name(named_st), "UNAUTHENTICATED");
    EXPECT_EQ(describe_status(named_st), "UNAUTHENTICATED: no token");
    const Status lookalike(StatusCode::not_found, "gRPC ABORTED: x");
    EXPECT_EQ(grpc_code_name(lookalike), "NOT_FOUND");
    EXPECT_EQ(describe_status(lookalike), "NOT_FOUND: gRPC ABORTED: x");
}

TEST(ClientConvert, InfoMessagesDecodeEveryField) {
    pb::ServerInfo info;
    info.set_version("0.1.0");
    info.set_api("proxima.v1");
    info.set_proximity_backend("cpu: brute, bvh");
    info.set_live_scenes(3);
    info.set_live_streams(2);
    info.mutable_limits()->set_max_scenes(64);
    info.mutable_limits()->set_max_objects_per_scene(1000);
    info.mutable_limits()->set_max_triangles_per_scene(5000000);
    info.mutable_limits()->set_max_message_bytes(64 << 20);
    info.mutable_limits()->set_max_frames_in_flight(4);
    info.set_principal("simulator-7");
    info.mutable_quotas()->set_max_scenes(2);
    info.mutable_quotas()->set_max_objects(30);
    info.mutable_quotas()->set_max_triangles(4000);
    info.mutable_quotas()->set_max_bytes_held(1 << 20);
    info.mutable_quotas()->set_max_bytes_in_flight(1 << 16);
    info.mutable_quotas()->set_max_frames_per_second(60.5);
    info.mutable_quotas()->set_max_streams(3);
    info.set_gpu_fallback_reason("EGL context lost");
    const auto i = detail::decode_server_info(reparse(info));
    EXPECT_EQ(i.principal, "simulator-7");
    EXPECT_EQ(i.quota_max_scenes, 2u);
    EXPECT_EQ(i.quota_max_objects, 30u);
    EXPECT_EQ(i.quota_max_triangles, 4000u);
    EXPECT_EQ(i.quota_max_bytes_held, 1u << 20);
    EXPECT_EQ(i.quota_max_bytes_in_flight, 1u << 16);
    EXPECT_EQ(i.quota_max_frames_per_second, 60.5);
    EXPECT_EQ(i.quota_max_streams, 3u);
    EXPECT_FALSE(i.gpu_active);
    EXPECT_EQ(i.gpu_fallback_reason, "EGL context lost");
    EXPECT_EQ(i.version, "0.1.0");
    EXPECT_EQ(i.api, "proxima.v1");
    EXPECT_EQ(i.proximity_backend, "cpu: brute, bvh");
    EXPECT_EQ(i.gl_renderer, "");
    EXPECT_EQ(i.live_scenes, 3u);
    EXPECT_EQ(i.live_streams, 2u);
    EXPECT_EQ(i.max_scenes, 64u);
    EXPECT_EQ(i.max_objects_per_scene, 1000u);
    EXPECT_EQ(i.max_triangles_per_scene, 5000000u);
    EXPECT_EQ(i.max_message_bytes, 64u << 20);
    EXPECT_EQ(i.max_frames_in_flight, 4u);

    pb::SceneInfo scene;
    scene.set_scene_id("abc");
    scene.set_name("n");
    scene.set_frames(5);
    scene.set_triangle_count(24);
    auto* o = scene.add_objects();
    o->set_id(9);
    o->set_name("box");
    o->set_vertex_count(8);
    o->set_triangle_count(12);
    const auto s = detail::decode_scene(reparse(scene));
    EXPECT_EQ(s.scene_id, "abc");
    EXPECT_EQ(s.name, "n");
    EXPECT_EQ(s.frames, 5u);
    EXPECT_EQ(s.triangle_count, 24u);
    ASSERT_EQ(s.objects.size(), 1u);
    EXPECT_EQ(s.objects[0].id, 9u);
    EXPECT_EQ(s.objects[0].name, "box");
    EXPECT_EQ(s.objects[0].vertex_count, 8u);
    EXPECT_EQ(s.objects[0].triangle_count, 12u);
}

TEST(ClientConvert, MassiveModelMessagesDecode) {
    // Transforms: exactly 12 numbers each way.
    massive::Affine a;
    for (std::size_t k = 0; k < 12; ++k) {
        a.m[k] = 0.1 * static_cast<double>(k) - 0.3;
    }
    pb::Transform t;
    detail::encode_transform(a, &t);
    auto back = detail::decode_transform(t, "pose");
    ASSERT_TRUE(back.ok());
    EXPECT_EQ(back->m, a.m);
    t.mutable_m()->RemoveLast();
    EXPECT_EQ(detail::decode_transform(t, "pose").status().code(), StatusCode::internal);

    pb::ListModelsResponse list;
    list.set_models_dir("/srv/models");
    auto* m = list.add_models();
    m->set_name("plant");
    m->set_objects(3);
    m->set_pieces(5);
    m->set_generation("gen-000002");
    m->mutable_box()->mutable_hi()->set_z(2.5);
    list.add_unavailable()->set_name("old");
    list.mutable_unavailable(0)->set_status("DATA_LOSS: bad");
    list.set_cache_budget_bytes(1024);
    list.mutable_cache()->set_evictions(7);
    const auto models = detail::decode_model_list(list);
    ASSERT_EQ(models.models.size(), 1u);
    EXPECT_EQ(models.models[0].name, "plant");
    EXPECT_EQ(models.models[0].pieces, 5u);
    EXPECT_EQ(models.models[0].box.hi.z, 2.5);
    EXPECT_EQ(models.unavailable.at(0).second, "DATA_LOSS: bad");
    EXPECT_EQ(models.cache.evictions, 7u);

    pb::ReviewEvent event;
    auto* r = event.mutable_result();
    r->set_sequence(9);
    auto* hit = r->add_collisions();
    hit->set_object(4);
    hit->set_object_name("tank");
    hit->set_distance(0.0);
    hit->mutable_object_point()->set_x(1.5);
    r->mutable_nearest()->set_object(4);
    r->mutable_nearest()->set_object_name("tank");
    r->set_model_version(3);
    auto decoded = detail::decode_review_event(event);
    ASSERT_TRUE(decoded.ok());
    EXPECT_EQ(decoded->kind, ReviewEvent::Kind::result);
    EXPECT_EQ(decoded->result.sequence, 9u);
    ASSERT_EQ(decoded->result.result.collisions.size(), 1u);
    EXPECT_EQ(decoded->result.result.collisions[0].object, 4u);
    EXPECT_EQ(decoded->result.result.collisions[0].object_point.x, 1.5);
    EXPECT_EQ(decoded->result.collision_names, std::vector<std::string>{"tank"});
    ASSERT_TRUE(decoded->result.result.nearest.has_value());
    EXPECT_EQ(decoded->result.nearest_name, "tank");
    EXPECT_EQ(decoded->result.model_version, 3u);

    event.Clear();
    event.mutable_peer()->set_member("bob");
    EXPECT_EQ(detail::decode_review_event(event).status().code(), StatusCode::internal)
        << "a peer update without its 12-number transform is malformed";
    detail::encode_transform(a, event.mutable_peer()->mutable_transform());
    auto peer = detail::decode_review_event(event);
    ASSERT_TRUE(peer.ok());
    EXPECT_EQ(peer->peer.member, "bob");
    EXPECT_EQ(peer->peer.transform.m, a.m);

    event.Clear();
    event.mutable_edit_applied()->set_what(pb::EDIT_ADD);
    event.mutable_edit_applied()->set_object(40);
    auto edit = detail::decode_review_event(event);
    ASSERT_TRUE(edit.ok());
    EXPECT_EQ(edit->edit.what, ReviewEditKind::add);
    EXPECT_EQ(edit->edit.object, 40u);
    EXPECT_EQ(detail::decode_review_event(pb::ReviewEvent()).status().code(), StatusCode::internal);
}

}  // namespace
}  // namespace proxima::client
