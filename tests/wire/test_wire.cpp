// proto/wire between the two real ends: what the client library encodes is what the daemon
// decodes, and what the daemon encodes is what the client decodes, with the very functions each
// side calls (wire:: for both directions of every engine type, server/encode.hpp for the daemon's
// own messages, the client's private client/decode.hpp for its answer types). Frames run through
// the daemon's run_frame and are compared with an in-process engine; float64 is bit for bit,
// float32 rounds each coordinate to nearest; every status code maps both ways.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <random>
#include <span>
#include <tuple>
#include <variant>

#include "auth.hpp"
#include "client/decode.hpp"
#include "encode.hpp"
#include "frames.hpp"
#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/query/penetration.hpp"
#include "proxima/query/query.hpp"
#include "proxima/wire/buffers.hpp"
#include "proxima/wire/frames.hpp"
#include "proxima/wire/massive.hpp"
#include "proxima/wire/snapshot.hpp"
#include "proxima/wire/status.hpp"
#include "scene_registry.hpp"
#include "support/random_scenes.hpp"

namespace proxima {
namespace {

namespace detail = client::detail;

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
    if (a.empty()) {
        return;  // data() may be null: memcmp's arguments must not be, even for no bytes
    }
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

// The answers; with `same_stats` the statistics too, bit for bit (two engines that got to the same
// scene by different histories report different work counts).
void expect_same(const QueryResult& a, const QueryResult& b, bool same_stats = false) {
    ASSERT_EQ(a.separation.size(), b.separation.size());
    for (std::size_t i = 0; i < a.separation.size(); ++i) {
        const auto& x = a.separation[i];
        const auto& y = b.separation[i];
        EXPECT_EQ(x.other, y.other);
        EXPECT_EQ(bits(x.distance), bits(y.distance));
        if (x.other != NO_OBJECT) {
            EXPECT_EQ(x.triangle, y.triangle);
            EXPECT_EQ(x.other_triangle, y.other_triangle);
            expect_same(x.point, y.point);
            expect_same(x.other_point, y.other_point);
        }
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
    EXPECT_EQ(a.stats.brute_force_tests, b.stats.brute_force_tests);
    EXPECT_EQ(a.stats.pns_pairs, b.stats.pns_pairs);
    if (!same_stats) {
        return;
    }
    const auto& x = a.stats;
    const auto& y = b.stats;
    EXPECT_EQ(std::tie(x.exact_tests, x.object_pairs_tested, x.dvd_samples, x.voronoi_culled),
              std::tie(y.exact_tests, y.object_pairs_tested, y.dvd_samples, y.voronoi_culled));
    for (const auto member :
         {&QueryStats::prepare_seconds, &QueryStats::broad_phase_seconds,
          &QueryStats::separation_seconds, &QueryStats::self_seconds,
          &QueryStats::collision_seconds, &QueryStats::tolerance_seconds,
          &QueryStats::total_seconds, &QueryStats::voronoi_seconds, &QueryStats::dvd_seconds,
          &QueryStats::dvd_cell, &QueryStats::dvd_epsilon}) {
        EXPECT_EQ(bits(x.*member), bits(y.*member));
    }
}

void expect_same(const Penetration& a, const Penetration& b) {
    EXPECT_EQ(std::tie(a.object, a.other, a.triangle, a.other_triangle),
              std::tie(b.object, b.other, b.triangle, b.other_triangle));
    expect_same(a.direction, b.direction);
    EXPECT_EQ(bits(a.depth), bits(b.depth));
    expect_same(a.vector, b.vector);
    EXPECT_EQ(a.triangles, b.triangles);
    EXPECT_EQ(a.other_triangles, b.other_triangles);
    EXPECT_EQ(std::tie(a.isolated, a.closed, a.normal_fallback, a.sides_split),
              std::tie(b.isolated, b.closed, b.normal_fallback, b.sides_split));
}

void expect_same(const ccd::CcdResult& a, const ccd::CcdResult& b) {
    ASSERT_EQ(a.pairs.size(), b.pairs.size());
    for (std::size_t i = 0; i < a.pairs.size(); ++i) {
        const auto& x = a.pairs[i];
        const auto& y = b.pairs[i];
        EXPECT_EQ(std::tie(x.kind, x.object, x.primitive, x.other, x.other_primitive, x.capped),
                  std::tie(y.kind, y.object, y.primitive, y.other, y.other_primitive, y.capped));
        EXPECT_EQ(bits(x.toi), bits(y.toi));
        EXPECT_EQ(x.vertices, y.vertices);
        EXPECT_EQ(x.other_vertices, y.other_vertices);
    }
    ASSERT_EQ(a.object_pairs.size(), b.object_pairs.size());
    for (std::size_t i = 0; i < a.object_pairs.size(); ++i) {
        EXPECT_EQ(
            std::tie(a.object_pairs[i].object, a.object_pairs[i].other, a.object_pairs[i].pair),
            std::tie(b.object_pairs[i].object, b.object_pairs[i].other, b.object_pairs[i].pair));
        EXPECT_EQ(bits(a.object_pairs[i].toi), bits(b.object_pairs[i].toi));
    }
    EXPECT_EQ(a.earliest, b.earliest);
    EXPECT_EQ(a.stats.candidate_pairs, b.stats.candidate_pairs);
    EXPECT_EQ(a.stats.elementary_tests, b.stats.elementary_tests);
    EXPECT_EQ(a.stats.capped_tests, b.stats.capped_tests);
    EXPECT_EQ(a.stats.brute_force_tests, b.stats.brute_force_tests);
    EXPECT_EQ(a.stats.object_pairs_tested, b.stats.object_pairs_tested);
}

void expect_error(const Status& st, StatusCode code, std::initializer_list<const char*> words) {
    EXPECT_EQ(st.code(), code) << st.to_string();
    for (const char* w : words) {
        EXPECT_NE(st.message().find(w), std::string::npos) << st.to_string() << " lacks " << w;
    }
}

// Coordinates no decimal round trip would keep: the wire must carry the exact bits.
NamedMesh awkward_mesh() {
    test::Rng rng(7);
    NamedMesh m{"awkward", test::sphere(rng, 5, 7, 1.0, 0.2)};
    m.mesh.vertices[0] = {0.1, -1.0 / 3.0, std::nextafter(1.0, 2.0)};
    m.mesh.vertices[1] = {std::numeric_limits<double>::denorm_min(), -0.0, 1e300};
    return m;
}

// A daemon scene (no quotas) holding `objects`, and an in-process engine holding the same.
struct Scenes {
    std::shared_ptr<server::SceneEntry> entry;
    ProximityEngine local;
    server::Limits limits;
};

std::unique_ptr<Scenes> make_scenes(const std::vector<NamedMesh>& objects) {
    auto s = std::make_unique<Scenes>();
    auto owner = std::make_shared<server::Principal>(
        "", server::Quotas{}, std::vector<std::string>{"*"}, std::vector<std::string>{"*"},
        std::vector<std::string>{"*"}, true);
    s->entry = std::make_shared<server::SceneEntry>("wire-scene", "wire", false, std::move(owner));
    // The client's way of creating a scene: meshes encoded inline (CreateSceneRequest.objects).
    v1::CreateSceneRequest request;
    for (const auto& o : objects) {
        wire::encode_mesh(o, false, request.add_objects());
    }
    auto meshes = wire::decode_meshes(reparse(request).objects(), "objects");
    EXPECT_TRUE(meshes.ok()) << meshes.status().to_string();
    EXPECT_TRUE(
        server::add_objects(*s->entry, std::move(meshes).value(), s->limits, "objects").ok());
    SceneUpdate update;
    update.additions = objects;
    EXPECT_TRUE(s->local.scene().apply(std::move(update)).ok());
    return s;
}

// Client encode -> daemon run_frame -> daemon encode -> client decode.
StatusOr<client::FrameResponse> through_daemon(Scenes& s, const FrameRequest& frame, bool float32) {
    v1::Frame message;
    wire::encode_frame(frame, s.entry->id, float32, &message);
    v1::FrameResult result;
    if (Status st = server::run_frame(*s.entry, reparse(message), s.limits, nullptr, &result);
        !st.ok()) {
        return st;
    }
    return detail::decode_frame_response(reparse(result));
}

// --- Buffers -----------------------------------------------------------------------------------

TEST(Wire, MeshRoundTripIsBitExactInFloat64) {
    const auto mesh = awkward_mesh();
    v1::Mesh message;
    wire::encode_mesh(mesh, false, &message);
    EXPECT_EQ(message.vertices().type(), v1::SCALAR_TYPE_FLOAT64);
    EXPECT_EQ(message.vertices().data().size(), mesh.mesh.vertices.size() * 24);
    EXPECT_EQ(message.indices().size(), mesh.mesh.triangles.size() * 12);
    EXPECT_GE(wire::encoded_mesh_bytes(mesh, false), message.ByteSizeLong());
    auto back = wire::decode_mesh(reparse(message), "object");
    ASSERT_TRUE(back.ok()) << back.status().to_string();
    expect_same(mesh, back.value());
}

TEST(Wire, PackedBuffersAreLittleEndian) {
    const std::vector<Vec3> v{{1.0, -2.0, 0.5}};
    const auto f64 = wire::pack_vertices(v, false);
    ASSERT_EQ(f64.size(), 24u);
    // 1.0 = 0x3FF0000000000000: the most significant byte comes last.
    EXPECT_EQ(static_cast<unsigned char>(f64[7]), 0x3Fu);
    EXPECT_EQ(static_cast<unsigned char>(f64[6]), 0xF0u);
    EXPECT_EQ(static_cast<unsigned char>(f64[0]), 0x00u);
    const auto f32 = wire::pack_vertices(v, true);
    ASSERT_EQ(f32.size(), 12u);
    // 1.0f = 0x3F800000.
    EXPECT_EQ(static_cast<unsigned char>(f32[3]), 0x3Fu);
    EXPECT_EQ(static_cast<unsigned char>(f32[2]), 0x80u);
    const std::vector<TriangleIndices> t{{1, 0x01020304u, 7}};
    const auto idx = wire::pack_triangles(t);
    ASSERT_EQ(idx.size(), 12u);
    EXPECT_EQ(static_cast<unsigned char>(idx[0]), 1u);
    EXPECT_EQ(static_cast<unsigned char>(idx[4]), 0x04u);
    EXPECT_EQ(static_cast<unsigned char>(idx[7]), 0x01u);
    // The daemon's upload path decodes the same bytes.
    auto vertices = wire::decode_vertex_bytes(v1::SCALAR_TYPE_FLOAT64, f64, "upload");
    ASSERT_TRUE(vertices.ok());
    expect_same(vertices.value(), v);
    auto triangles = wire::decode_indices(idx, "upload");
    ASSERT_TRUE(triangles.ok());
    EXPECT_EQ(triangles.value(), t);
}

TEST(Wire, Float32RoundsEachCoordinateToNearest) {
    const auto mesh = awkward_mesh();
    v1::Mesh message;
    wire::encode_mesh(mesh, true, &message);
    EXPECT_EQ(message.vertices().type(), v1::SCALAR_TYPE_FLOAT32);
    EXPECT_EQ(message.vertices().data().size(), mesh.mesh.vertices.size() * 12);
    auto back = wire::decode_mesh(reparse(message), "object");
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

// The float32 buffers are packed and widened with whole-float stores (a vectorized loop): the
// bytes and values must be exactly those of one coordinate at a time, little-endian, for every
// length (the loop's remainder) and for awkward values (ties, subnormals, overflow, -0, NaN).
TEST(Wire, Float32BuffersMatchOneCoordinateAtATime) {
    std::mt19937_64 rng(16);
    std::vector<double> specials{0.0,
                                 -0.0,
                                 1.0 + std::ldexp(1.0, -24),  // a tie: rounds to even (1.0f)
                                 1.0 + 3 * std::ldexp(1.0, -24),
                                 std::ldexp(1.0, -140),  // a float subnormal
                                 std::ldexp(1.0, -160),  // rounds to zero
                                 3.5e38,                 // over FLT_MAX: +inf
                                 -3.5e38,
                                 std::numeric_limits<double>::infinity(),
                                 std::numeric_limits<double>::quiet_NaN()};
    for (const std::size_t n :
         {std::size_t{0}, std::size_t{1}, std::size_t{3}, std::size_t{1001}}) {
        std::vector<Vec3> v(n);
        std::uniform_real_distribution<double> coord(-1e3, 1e3);
        for (std::size_t i = 0; i < n; ++i) {
            for (int k = 0; k < 3; ++k) {
                const std::size_t j = 3 * i + static_cast<std::size_t>(k);
                v[i][k] = j < specials.size() ? specials[j] : coord(rng);
            }
        }
        const auto packed = wire::pack_vertices(v, true);
        ASSERT_EQ(packed.size(), 12 * n);
        for (std::size_t i = 0; i < n; ++i) {
            for (int k = 0; k < 3; ++k) {
                const auto want = std::bit_cast<std::uint32_t>(static_cast<float>(v[i][k]));
                for (std::size_t b = 0; b < 4; ++b) {
                    ASSERT_EQ(static_cast<unsigned char>(packed[12 * i + 4 * k + b]),
                              (want >> (8 * b)) & 0xFFu)
                        << n << " " << i << " " << k;
                }
            }
        }
        // Widening back: any 32-bit pattern, byte by byte.
        std::string raw(12 * n, '\0');
        for (auto& c : raw) {
            c = static_cast<char>(rng() & 0xFFu);
        }
        auto decoded = wire::decode_vertex_bytes(v1::SCALAR_TYPE_FLOAT32, raw, "positions");
        ASSERT_TRUE(decoded.ok());
        ASSERT_EQ(decoded->size(), n);
        for (std::size_t i = 0; i < n; ++i) {
            for (int k = 0; k < 3; ++k) {
                std::uint32_t pattern = 0;
                for (std::size_t b = 0; b < 4; ++b) {
                    pattern |= std::uint32_t{static_cast<unsigned char>(raw[12 * i + 4 * k + b])}
                               << (8 * b);
                }
                const double want = std::bit_cast<float>(pattern);
                EXPECT_EQ(bits((*decoded)[i][k]), bits(want)) << n << " " << i << " " << k;
            }
        }
    }
}

TEST(Wire, MalformedBuffersAreRejectedWithTheCulprit) {
    v1::Mesh mesh;
    mesh.set_name("a.off");
    mesh.mutable_vertices()->set_type(v1::SCALAR_TYPE_FLOAT64);
    mesh.mutable_vertices()->set_data(std::string(25, '\0'));
    mesh.set_indices(std::string(12, '\0'));
    expect_error(wire::decode_mesh(mesh, "object").status(), StatusCode::invalid_argument,
                 {"a.off", "25 bytes", "multiple of 24"});

    mesh.mutable_vertices()->set_type(v1::SCALAR_TYPE_FLOAT32);
    mesh.mutable_vertices()->set_data(std::string(24, '\0'));
    mesh.set_indices(std::string(13, '\0'));
    expect_error(wire::decode_mesh(mesh, "object").status(), StatusCode::invalid_argument,
                 {"a.off", "index buffer is 13 bytes"});

    mesh.mutable_vertices()->set_type(v1::SCALAR_TYPE_UNSPECIFIED);
    mesh.set_indices(std::string(12, '\0'));
    expect_error(wire::decode_mesh(mesh, "object").status(), StatusCode::invalid_argument,
                 {"a.off", "scalar type"});

    // An empty buffer is well formed (zero vertices): emptiness is the engine's check.
    v1::VertexBuffer empty;
    empty.set_type(v1::SCALAR_TYPE_FLOAT64);
    auto v = wire::decode_vertices(empty, "x");
    ASSERT_TRUE(v.ok());
    EXPECT_TRUE(v->empty());

    v1::Frame frame;
    auto* pos = frame.add_positions();
    pos->set_object_id(17);
    pos->mutable_vertices()->set_type(v1::SCALAR_TYPE_FLOAT64);
    pos->mutable_vertices()->set_data(std::string(23, '\0'));
    expect_error(wire::decode_frame(frame).status(), StatusCode::invalid_argument,
                 {"positions[0]", "object 17"});

    frame.Clear();
    frame.mutable_queries()->set_culler(static_cast<v1::Culler>(9));
    expect_error(wire::decode_frame(frame).status(), StatusCode::invalid_argument, {"culler 9"});
    frame.Clear();
    frame.mutable_queries()->set_tolerance(-1.0);
    expect_error(wire::decode_frame(frame).status(), StatusCode::invalid_argument,
                 {"queries.tolerance"});
    frame.Clear();
    frame.mutable_queries()->set_voronoi_cell(0.0);
    expect_error(wire::decode_frame(frame).status(), StatusCode::invalid_argument,
                 {"queries.voronoi_cell"});
    frame.Clear();
    frame.mutable_queries()->set_ccd_min_distance(std::nan(""));
    expect_error(wire::decode_frame(frame).status(), StatusCode::invalid_argument,
                 {"queries.ccd_min_distance"});
    for (const double bad : {-1e-9, 1.5, std::nan("")}) {
        frame.Clear();
        frame.mutable_queries()->set_ccd_toi_tolerance(bad);
        expect_error(wire::decode_frame(frame).status(), StatusCode::invalid_argument,
                     {"queries.ccd_toi_tolerance", "[0, 1]"});
    }
}

// --- Frames: client encode -> daemon decode ----------------------------------------------------

TEST(Wire, ClientFrameDecodesOnTheDaemonWithEveryChangeAndQuery) {
    test::Rng rng(11);
    FrameRequest f;
    f.frame = 42;
    f.update.removals = {3, 9};
    f.update.replacements.push_back(
        {5, {{"frag0", test::box({0, 0, 0}, {1, 1, 1})}, awkward_mesh()}});
    f.update.positions.push_back({7, test::jitter(rng, awkward_mesh().mesh.vertices, 0.1)});
    f.update.positions[0].vertices[2] = {-0.0, 1e-310, -1e300};
    f.update.additions.push_back({"added", test::sheet(rng, 3, 2, 0.1)});
    f.queries.separation = false;
    f.queries.self = true;
    f.queries.collisions = false;
    f.queries.tolerance = 0.125;
    f.queries.voronoi_cell = 0.5;
    f.queries.pns = true;
    f.queries.culler = CullerKind::brute;
    f.self_points = true;
    f.penetration = true;
    f.ccd = true;
    f.ccd_request.elementary.min_distance = 1.0 / 3.0;
    f.ccd_request.elementary.toi_tolerance = 1.0 / 1024.0;

    for (const bool float32 : {false, true}) {
        v1::Frame message;
        wire::encode_frame(f, "scene-1", float32, &message);
        EXPECT_EQ(message.scene_id(), "scene-1");
        auto back = wire::decode_frame(reparse(message));
        ASSERT_TRUE(back.ok()) << back.status().to_string();
        const auto& g = back.value();
        EXPECT_EQ(g.frame, 42u);
        EXPECT_EQ(g.update.removals, f.update.removals);
        ASSERT_EQ(g.update.replacements.size(), 1u);
        EXPECT_EQ(g.update.replacements[0].object, 5u);
        ASSERT_EQ(g.update.replacements[0].fragments.size(), 2u);
        ASSERT_EQ(g.update.positions.size(), 1u);
        EXPECT_EQ(g.update.positions[0].object, 7u);
        ASSERT_EQ(g.update.additions.size(), 1u);
        if (!float32) {
            expect_same(g.update.replacements[0].fragments[0],
                        f.update.replacements[0].fragments[0]);
            expect_same(g.update.replacements[0].fragments[1],
                        f.update.replacements[0].fragments[1]);
            expect_same(g.update.positions[0].vertices, f.update.positions[0].vertices);
            expect_same(g.update.additions[0], f.update.additions[0]);
        } else {
            const auto& want = f.update.positions[0].vertices;
            const auto& got = g.update.positions[0].vertices;
            ASSERT_EQ(got.size(), want.size());
            for (std::size_t i = 0; i < want.size(); ++i) {
                for (int k = 0; k < 3; ++k) {
                    EXPECT_EQ(bits(got[i][k]), bits(double(static_cast<float>(want[i][k]))));
                }
            }
        }
        EXPECT_FALSE(g.queries.separation);
        EXPECT_TRUE(g.queries.self);
        // The daemon runs the collisions query for penetration vectors.
        EXPECT_TRUE(g.queries.collisions);
        ASSERT_TRUE(g.queries.tolerance.has_value());
        EXPECT_EQ(*g.queries.tolerance, 0.125);
        ASSERT_TRUE(g.queries.voronoi_cell.has_value());
        EXPECT_EQ(*g.queries.voronoi_cell, 0.5);
        EXPECT_TRUE(g.queries.pns);
        EXPECT_EQ(g.queries.culler, CullerKind::brute);
        EXPECT_TRUE(g.self_points);
        EXPECT_TRUE(g.penetration);
        EXPECT_TRUE(g.ccd);
        EXPECT_EQ(bits(g.ccd_request.elementary.min_distance), bits(1.0 / 3.0));
        EXPECT_EQ(bits(g.ccd_request.elementary.toi_tolerance), bits(1.0 / 1024.0));
    }

    // No tolerance stays no tolerance (proto3 `optional`), and every culler survives.
    for (auto kind : {CullerKind::automatic, CullerKind::brute, CullerKind::bvh,
                      CullerKind::voronoi_cpu, CullerKind::voronoi_gpu}) {
        FrameRequest q;
        q.queries.culler = kind;
        v1::Frame message;
        wire::encode_frame(q, "s", false, &message);
        auto r = wire::decode_frame(reparse(message));
        ASSERT_TRUE(r.ok());
        EXPECT_EQ(r->queries.culler, kind);
        EXPECT_FALSE(r->queries.tolerance.has_value());
        EXPECT_FALSE(r->queries.voronoi_cell.has_value());
        EXPECT_TRUE(r->queries.separation);
        EXPECT_FALSE(r->ccd);
        EXPECT_FALSE(r->penetration);
    }
}

// --- Frames through the daemon: results, penetrations, CCD -------------------------------------

// Every query on, through the daemon's run_frame and back to the client: the same answer, bit
// for bit, as an in-process engine given the same frame.
TEST(Wire, FrameResultsThroughTheDaemonMatchTheEngine) {
    for (std::uint64_t seed = 1; seed <= 8; ++seed) {
        test::Rng rng(seed);
        auto objects = test::random_scene(rng);
        objects.push_back({"box", test::box({0.5, 0.5, 0.5}, {1.5, 1.5, 1.5})});
        auto s = make_scenes(objects);
        const auto ids = s->entry->engine.scene().objects();

        FrameRequest f;
        f.frame = seed;
        f.update.positions.push_back(
            {ids.back().id, test::jitter(rng, objects.back().mesh.vertices, 0.01)});
        f.queries.self = true;
        f.queries.collisions = true;
        f.queries.tolerance = 0.05;
        f.queries.pns = true;
        f.self_points = seed % 2 == 0;
        f.penetration = true;
        auto response = through_daemon(*s, f, false);
        ASSERT_TRUE(response.ok()) << response.status().to_string();
        EXPECT_EQ(response->scene_id, "wire-scene");
        EXPECT_EQ(response->frame, seed);
        EXPECT_GT(response->server_seconds, 0.0);

        auto changes = s->local.scene().apply(f.update);
        ASSERT_TRUE(changes.ok());
        auto r = s->local.query(f.queries);
        ASSERT_TRUE(r.ok());
        std::vector<ObjectId> want_ids;
        for (const auto& o : s->local.scene().objects()) {
            want_ids.push_back(o.id);
        }
        EXPECT_EQ(response->object_ids, want_ids);
        if (!f.self_points) {  // the daemon sends the self points only when asked
            for (auto& list : r->self) {
                for (auto& d : list) {
                    d.point = d.other_point = Vec3{};
                }
            }
        }
        expect_same(r.value(), response->result);
        // The statistics travel bit for bit: the local answer through the daemon's encoder.
        v1::FrameResult local;
        wire::encode_frame_result(s->local.scene(), changes.value(), r.value(), true, &local);
        auto local_back = detail::decode_frame_response(reparse(local));
        ASSERT_TRUE(local_back.ok());
        expect_same(r.value(), local_back->result, true);
        auto penetrations = penetration_depths(s->local.scene(), r->collisions);
        ASSERT_TRUE(penetrations.ok());
        ASSERT_EQ(response->penetrations.size(), penetrations->size());
        for (std::size_t i = 0; i < penetrations->size(); ++i) {
            expect_same((*penetrations)[i], response->penetrations[i]);
        }
        EXPECT_FALSE(response->ccd.has_value());
    }
}

TEST(Wire, AdditionsTopologyChangesAndRemovalsReportTheirIds) {
    test::Rng rng(3);
    auto s = make_scenes(
        {{"a", test::box({0, 0, 0}, {1, 1, 1})}, {"b", test::box({2, 0, 0}, {3, 1, 1})}});
    const ObjectId a = s->entry->engine.scene()[0].id;
    const ObjectId b = s->entry->engine.scene()[1].id;
    FrameRequest f;
    f.update.additions.push_back({"c", test::box({0, 2, 0}, {1, 3, 1})});
    f.update.replacements.push_back(
        {b,
         {{"b0", test::box({2, 0, 0}, {2.4, 1, 1})}, {"b1", test::box({2.6, 0, 0}, {3, 1, 1})}}});
    f.update.removals = {a};
    auto response = through_daemon(*s, f, true);
    ASSERT_TRUE(response.ok()) << response.status().to_string();
    ASSERT_EQ(response->added_ids.size(), 1u);
    ASSERT_EQ(response->fragment_ids.size(), 1u);
    EXPECT_EQ(response->fragment_ids[0].size(), 2u);
    EXPECT_EQ(response->object_ids.size(), 3u);
    auto changes = s->local.scene().apply(f.update);
    ASSERT_TRUE(changes.ok());
    EXPECT_EQ(response->added_ids, changes->added_ids);
    EXPECT_EQ(response->fragment_ids, changes->fragment_ids);
    // A lone object keeps the engine's conventions (no other: distance +inf).
    auto lone = make_scenes({{"fan", test::box({0, 0, 0}, {1, 1, 1})}});
    auto alone = through_daemon(*lone, FrameRequest{}, false);
    ASSERT_TRUE(alone.ok());
    EXPECT_EQ(alone->result.separation[0].other, NO_OBJECT);
    EXPECT_TRUE(std::isinf(alone->result.separation[0].distance));
}

TEST(Wire, CcdThroughTheDaemonMatchesTheEngine) {
    const std::vector<NamedMesh> objects{{"wall", test::box({0, 0, 0}, {0.2, 2, 2})},
                                         {"mover", test::box({-1.5, 0.5, 0.5}, {-1, 1, 1})}};
    auto s = make_scenes(objects);
    FrameRequest f;
    f.frame = 1;
    std::vector<Vec3> moved = objects[1].mesh.vertices;
    for (auto& v : moved) {
        v.x += 2.0 + 1.0 / 3.0;  // straight through the wall
    }
    f.update.positions.push_back({s->entry->engine.scene()[1].id, moved});
    f.ccd = true;
    f.ccd_request.elementary.min_distance = 0.01;
    auto response = through_daemon(*s, f, false);
    ASSERT_TRUE(response.ok()) << response.status().to_string();
    ASSERT_TRUE(response->ccd.has_value());
    EXPECT_FALSE(response->ccd->pairs.empty());

    const Scene before = s->local.scene();
    SceneUpdate update = f.update;
    ASSERT_TRUE(s->local.scene().apply(std::move(update)).ok());
    std::vector<std::vector<Vec3>> positions;
    for (const auto& o : s->local.scene().objects()) {
        positions.push_back(o.vertices);
    }
    ccd::CcdRequest request;
    request.elementary.min_distance = 0.01;
    auto want = ccd::continuous_collisions(before, positions, request);
    ASSERT_TRUE(want.ok());
    expect_same(want.value(), *response->ccd);
}

TEST(Wire, MalformedResultsAreInternalErrorsOnTheClient) {
    auto base = [] {
        v1::FrameResult r;
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
    ASSERT_TRUE(detail::decode_frame_response(base()).ok());

    auto r = base();
    r.add_separation();
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal,
                 {"3 separations"});
    r = base();
    r.mutable_separation(0)->set_other(2);
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal,
                 {"object 2 of 2"});
    r = base();
    r.mutable_self(1)->add_distance(1.0);
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal, {"object 1"});
    r = base();
    r.mutable_self(0)->add_points(1.0);
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal,
                 {"point coordinates"});
    r = base();
    r.mutable_self(0)->set_closest(0, -2);
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal, {"closest -2"});
    r = base();
    r.add_collisions()->set_other(5);
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal,
                 {"collision", "5"});
    r = base();
    r.add_tolerance()->set_object(2);
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal, {"tolerance"});
    r = base();
    r.add_penetrations()->set_other(3);
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal, {"penetration"});
    r = base();
    r.mutable_ccd()->add_pairs()->set_object(2);
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal, {"CCD pair"});
    r = base();
    r.mutable_ccd()->add_pairs()->add_vertices(0);  // a vf pair names 1 and 3 vertices
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal,
                 {"CCD pair 0", "vertices", "vf needs 1 and 3"});
    r = base();
    auto* vf = r.mutable_ccd()->add_pairs();
    vf->add_vertices(0);
    for (int k = 0; k < 3; ++k) {
        vf->add_other_vertices(static_cast<std::uint32_t>(k));
    }
    r.mutable_ccd()->set_has_earliest(true);
    r.mutable_ccd()->set_earliest(1);
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal, {"earliest"});
    r = base();
    r.mutable_ccd()->add_object_pairs()->set_pair(0);
    expect_error(detail::decode_frame_response(r).status(), StatusCode::internal, {"object pair"});
}

// --- Status codes ------------------------------------------------------------------------------

TEST(Wire, EveryEngineStatusCodeIsInTheTable) {
    // Walk the engine's codes until status_code_name no longer knows one: each must be mapped.
    std::size_t count = 0;
    for (int i = 0; std::string(status_code_name(static_cast<StatusCode>(i))) != "UNKNOWN"; ++i) {
        ASSERT_LT(static_cast<std::size_t>(i), wire::STATUS_CODES.size())
            << status_code_name(static_cast<StatusCode>(i)) << " is not in wire::STATUS_CODES";
        EXPECT_EQ(wire::STATUS_CODES[static_cast<std::size_t>(i)].engine,
                  static_cast<StatusCode>(i));
        ++count;
    }
    EXPECT_EQ(count, wire::STATUS_CODES.size());
}

TEST(Wire, EveryStatusCodeMapsBothWaysByName) {
    for (const auto& entry : wire::STATUS_CODES) {
        const Status engine(entry.engine, "object 'a.off': triangle 3 index 9");
        // Daemon side: engine -> gRPC.
        const grpc::Status sent = wire::to_grpc(engine);
        EXPECT_EQ(sent.error_code(), entry.grpc);
        // The names agree, which is what "one-to-one by name" means.
        EXPECT_STREQ(wire::grpc_code_name(entry.grpc), status_code_name(entry.engine));
        // Client side: gRPC -> engine.
        const Status received = wire::from_grpc(sent);
        EXPECT_EQ(received.code(), entry.engine);
        if (entry.engine == StatusCode::ok) {
            EXPECT_TRUE(sent.ok());
            EXPECT_TRUE(received.ok());
            continue;
        }
        EXPECT_EQ(sent.error_message(), engine.message());
        EXPECT_EQ(received.message(), engine.message());  // kept as the daemon said
        EXPECT_EQ(client::grpc_code_name(received), status_code_name(entry.engine));
        EXPECT_EQ(client::describe_status(received), engine.to_string());
    }

    const std::pair<grpc::StatusCode, const char*> unnamed[] = {
        {grpc::StatusCode::UNKNOWN, "UNKNOWN"},
        {grpc::StatusCode::ALREADY_EXISTS, "ALREADY_EXISTS"},
        {grpc::StatusCode::ABORTED, "ABORTED"},
        {grpc::StatusCode::OUT_OF_RANGE, "OUT_OF_RANGE"},
        {grpc::StatusCode::UNIMPLEMENTED, "UNIMPLEMENTED"},
        {static_cast<grpc::StatusCode>(20), "UNKNOWN"},  // a code from a newer gRPC
    };
    for (const auto& [code, name] : unnamed) {
        EXPECT_FALSE(wire::from_grpc_code(code).has_value());
        const auto st = wire::from_grpc({code, "why"});
        EXPECT_EQ(st.code(), StatusCode::internal);
        EXPECT_EQ(st.message(), std::string("gRPC ") + name + ": why");
        // What the command line prints: the gRPC name, not INTERNAL.
        EXPECT_EQ(client::grpc_code_name(st), name);
        EXPECT_EQ(client::describe_status(st), std::string(name) + ": why");
    }
    // A message that merely looks like the prefix under another code is left alone.
    const Status lookalike(StatusCode::not_found, "gRPC ABORTED: x");
    EXPECT_EQ(client::grpc_code_name(lookalike), "NOT_FOUND");
    EXPECT_EQ(client::describe_status(lookalike), "NOT_FOUND: gRPC ABORTED: x");
}

// --- The daemon's own messages -> the client's answer types ------------------------------------

TEST(Wire, SceneAndServerInfoDecodeEveryField) {
    auto s = make_scenes(
        {{"box", test::box({0, 0, 0}, {1, 1, 1})}, {"other", test::box({2, 0, 0}, {3, 1, 1})}});
    const Scene& scene = s->entry->engine.scene();
    v1::SceneInfo info;
    server::encode_scene("abc", "n", scene, 5, &info);
    const auto decoded = detail::decode_scene(reparse(info));
    EXPECT_EQ(decoded.scene_id, "abc");
    EXPECT_EQ(decoded.name, "n");
    EXPECT_EQ(decoded.frames, 5u);
    EXPECT_EQ(decoded.triangle_count, 24u);
    ASSERT_EQ(decoded.objects.size(), 2u);
    EXPECT_EQ(decoded.objects[0].id, scene[0].id);
    EXPECT_EQ(decoded.objects[0].name, "box");
    EXPECT_EQ(decoded.objects[0].vertex_count, 8u);
    EXPECT_EQ(decoded.objects[0].triangle_count, 12u);

    server::Limits limits;
    limits.max_scenes = 64;
    limits.max_objects_per_scene = 1000;
    limits.max_triangles_per_scene = 5000000;
    limits.max_message_bytes = 64 << 20;
    limits.max_frames_in_flight = 4;
    server::Quotas quotas;
    quotas.max_scenes = 2;
    quotas.max_objects = 30;
    quotas.max_triangles = 4000;
    quotas.max_bytes_held = 1 << 20;
    quotas.max_bytes_in_flight = 1 << 16;
    quotas.max_frames_per_second = 60.5;
    quotas.max_streams = 3;
    v1::ServerInfo server_info;
    server::encode_limits(limits, server_info.mutable_limits());
    server::encode_quotas(quotas, server_info.mutable_quotas());
    server_info.set_principal("simulator-7");
    const auto i = detail::decode_server_info(reparse(server_info));
    EXPECT_EQ(i.principal, "simulator-7");
    EXPECT_EQ(i.max_scenes, 64u);
    EXPECT_EQ(i.max_objects_per_scene, 1000u);
    EXPECT_EQ(i.max_triangles_per_scene, 5000000u);
    EXPECT_EQ(i.max_message_bytes, 64u << 20);
    EXPECT_EQ(i.max_frames_in_flight, 4u);
    EXPECT_EQ(i.quota_max_scenes, 2u);
    EXPECT_EQ(i.quota_max_objects, 30u);
    EXPECT_EQ(i.quota_max_triangles, 4000u);
    EXPECT_EQ(i.quota_max_bytes_held, 1u << 20);
    EXPECT_EQ(i.quota_max_bytes_in_flight, 1u << 16);
    EXPECT_EQ(i.quota_max_frames_per_second, 60.5);
    EXPECT_EQ(i.quota_max_streams, 3u);
}

// --- Massive models ----------------------------------------------------------------------------

massive::Affine awkward_transform() {
    massive::Affine a;
    for (std::size_t k = 0; k < 12; ++k) {
        a.m[k] = 0.1 * static_cast<double>(k) - 1.0 / 3.0;
    }
    return a;
}

TEST(Wire, TransformsAndVerifyMessages) {
    const auto a = awkward_transform();
    v1::Transform t;
    wire::encode_transform(a, &t);
    auto back = wire::decode_transform(reparse(t), "pose");
    ASSERT_TRUE(back.ok());
    EXPECT_EQ(back->m, a.m);
    t.set_m(3, std::numeric_limits<double>::infinity());
    expect_error(wire::decode_transform(t, "pose 4").status(), StatusCode::invalid_argument,
                 {"pose 4", "entry 3"});
    t.mutable_m()->RemoveLast();
    expect_error(wire::decode_transform(t, "pose 4").status(), StatusCode::invalid_argument,
                 {"12 numbers", "got 11"});

    massive::VerifyStats stats;
    stats.objects = 3;
    stats.pieces = 5;
    stats.model_triangles = 700;
    stats.subgraphs = 2;
    stats.edges = 9;
    stats.object_pairs = 4;
    stats.pairs_found = 1;
    stats.exact_tests = 99;
    stats.plan_seconds = 0.5;
    stats.seconds = 1.0 / 3.0;
    stats.schedule_from_store = true;
    stats.cache.evictions = 7;
    stats.cache.budget_bytes = 1 << 20;
    stats.cache.blocked_seconds = 0.25;
    v1::VerifyStats message;
    wire::encode_verify_stats(stats, 2.5, &message);
    const auto summary = detail::decode_verify_summary(reparse(message));
    EXPECT_EQ(summary.server_seconds, 2.5);
    EXPECT_EQ(summary.stats.objects, 3u);
    EXPECT_EQ(summary.stats.pieces, 5u);
    EXPECT_EQ(summary.stats.model_triangles, 700u);
    EXPECT_EQ(summary.stats.subgraphs, 2u);
    EXPECT_EQ(summary.stats.edges, 9u);
    EXPECT_EQ(summary.stats.object_pairs, 4u);
    EXPECT_EQ(summary.stats.pairs_found, 1u);
    EXPECT_EQ(summary.stats.exact_tests, 99u);
    EXPECT_EQ(summary.stats.plan_seconds, 0.5);
    EXPECT_EQ(bits(summary.stats.seconds), bits(1.0 / 3.0));
    EXPECT_TRUE(summary.stats.schedule_from_store);
    EXPECT_EQ(summary.stats.cache.evictions, 7u);
    EXPECT_EQ(summary.stats.cache.budget_bytes, 1u << 20);
    EXPECT_EQ(summary.stats.cache.blocked_seconds, 0.25);

    const massive::Progress progress{"traverse", 3, 10, "edges"};
    v1::VerifyProgress p;
    wire::encode_progress(progress, &p);
    const auto q = wire::decode_progress(reparse(p));
    EXPECT_EQ(q.step, "traverse");
    EXPECT_EQ(q.done, 3u);
    EXPECT_EQ(q.total, 10u);
    EXPECT_EQ(q.unit, "edges");
}

TEST(Wire, ReviewRequestsFromTheClientDecodeOnTheDaemon) {
    massive::ReviewJoinRequest join;
    join.room = "r1";
    join.model = "plant";
    join.member = "alice";
    join.avatar = awkward_mesh();
    join.tolerance = 0.125;
    join.nearest = true;
    v1::ReviewRequest message;
    wire::encode_review_join(join, false, &message);
    auto decoded = wire::decode_review_request(reparse(message));
    ASSERT_TRUE(decoded.ok()) << decoded.status().to_string();
    const auto* j = std::get_if<massive::ReviewJoinRequest>(&decoded.value());
    ASSERT_NE(j, nullptr);
    EXPECT_EQ(j->room, "r1");
    EXPECT_EQ(j->model, "plant");
    EXPECT_EQ(j->member, "alice");
    expect_same(j->avatar, join.avatar);
    EXPECT_EQ(j->tolerance, 0.125);
    EXPECT_TRUE(j->nearest);

    message.Clear();
    wire::encode_review_pose({7, awkward_transform()}, &message);
    decoded = wire::decode_review_request(reparse(message));
    ASSERT_TRUE(decoded.ok());
    const auto* pose = std::get_if<massive::ReviewPoseRequest>(&decoded.value());
    ASSERT_NE(pose, nullptr);
    EXPECT_EQ(pose->sequence, 7u);
    EXPECT_EQ(pose->transform.m, awkward_transform().m);

    for (const auto kind :
         {massive::EditKind::move, massive::EditKind::add, massive::EditKind::remove}) {
        massive::ReviewEditRequest edit;
        edit.sequence = 11;
        edit.what = kind;
        edit.object = kind == massive::EditKind::add ? 0 : 4;
        if (kind == massive::EditKind::move) {
            edit.transform = awkward_transform();
        }
        if (kind == massive::EditKind::add) {
            edit.added = awkward_mesh();
        }
        message.Clear();
        wire::encode_review_edit(edit, false, &message);
        decoded = wire::decode_review_request(reparse(message));
        ASSERT_TRUE(decoded.ok()) << decoded.status().to_string();
        const auto* e = std::get_if<massive::ReviewEditRequest>(&decoded.value());
        ASSERT_NE(e, nullptr);
        EXPECT_EQ(e->sequence, 11u);
        EXPECT_EQ(e->what, kind);
        EXPECT_EQ(e->object, edit.object);
        EXPECT_EQ(e->transform.m, edit.transform.m);
        expect_same(e->added, edit.added);
    }

    // What the daemon refuses.
    expect_error(wire::decode_review_request(v1::ReviewRequest()).status(),
                 StatusCode::invalid_argument, {"empty review request"});
    join.tolerance = -1.0;
    message.Clear();
    wire::encode_review_join(join, false, &message);
    expect_error(wire::decode_review_request(message).status(), StatusCode::invalid_argument,
                 {"join.tolerance"});
    message.Clear();
    message.mutable_edit()->set_sequence(3);
    expect_error(wire::decode_review_request(message).status(), StatusCode::invalid_argument,
                 {"edit 3", "empty edit"});
    message.Clear();
    message.mutable_pose()->set_sequence(2);
    expect_error(wire::decode_review_request(message).status(), StatusCode::invalid_argument,
                 {"pose 2", "transform is required"});
}

TEST(Wire, RoomEventsFromTheDaemonDecodeOnTheClient) {
    massive::PoseSummary summary{2, 3, true, 4, "tank", 0.25};

    // joined
    massive::JoinedEvent joined;
    joined.room = "r1";
    joined.model = "plant";
    joined.generation = "gen-000002";
    massive::MemberPose posed;
    posed.has_pose = true;
    posed.sequence = 5;
    posed.transform = awkward_transform();
    posed.summary = summary;
    joined.members.emplace_back("bob", posed);
    joined.members.emplace_back("alice", massive::MemberPose{});
    joined.model_version = 6;
    joined.object_count = 40;
    v1::ReviewEvent message;
    wire::encode_room_event(joined, &message);
    auto event = detail::decode_review_event(reparse(message));
    ASSERT_TRUE(event.ok()) << event.status().to_string();
    EXPECT_EQ(event->kind, client::ReviewEvent::Kind::joined);
    EXPECT_EQ(event->joined.room, "r1");
    EXPECT_EQ(event->joined.model, "plant");
    EXPECT_EQ(event->joined.generation, "gen-000002");
    EXPECT_EQ(event->joined.model_version, 6u);
    EXPECT_EQ(event->joined.object_count, 40u);
    ASSERT_EQ(event->joined.members.size(), 2u);
    EXPECT_EQ(event->joined.members[0].name, "bob");
    EXPECT_TRUE(event->joined.members[0].has_pose);
    EXPECT_EQ(event->joined.members[0].sequence, 5u);
    EXPECT_EQ(event->joined.members[0].transform.m, awkward_transform().m);
    EXPECT_EQ(event->joined.members[0].summary.nearest_name, "tank");
    EXPECT_EQ(event->joined.members[0].summary.collisions, 2u);
    EXPECT_EQ(event->joined.members[1].name, "alice");
    EXPECT_FALSE(event->joined.members[1].has_pose);

    // result
    massive::PoseResult result;
    result.sequence = 9;
    massive::AvatarHit hit;
    hit.object = 4;
    hit.distance = 0.0;
    hit.object_triangle = 7;
    hit.avatar_triangle = 8;
    hit.object_point = {1.5, -1.0 / 3.0, 2};
    hit.avatar_point = {1e-300, 0, -0.0};
    result.result.collisions.push_back(hit);
    hit.object = 5;
    hit.distance = 0.125;
    result.result.within.push_back(hit);
    result.result.nearest = hit;
    result.result.candidate_pieces = 12;
    result.result.pieces_tested = 6;
    result.result.exact_tests = 300;
    result.result.prefetch_hints = 2;
    result.result.seconds = 0.5;
    result.collision_names = {"tank"};
    result.within_names = {"pipe"};
    result.nearest_name = "pipe";
    result.model_version = 3;
    result.server_seconds = 0.75;
    message.Clear();
    wire::encode_room_event(result, &message);
    event = detail::decode_review_event(reparse(message));
    ASSERT_TRUE(event.ok());
    EXPECT_EQ(event->kind, client::ReviewEvent::Kind::result);
    const client::ReviewPoseResult& got = event->result;
    EXPECT_EQ(got.sequence, 9u);
    ASSERT_EQ(got.result.collisions.size(), 1u);
    EXPECT_EQ(got.result.collisions[0].object, 4u);
    EXPECT_EQ(got.result.collisions[0].object_triangle, 7u);
    EXPECT_EQ(got.result.collisions[0].avatar_triangle, 8u);
    expect_same(got.result.collisions[0].object_point, Vec3{1.5, -1.0 / 3.0, 2});
    expect_same(got.result.collisions[0].avatar_point, Vec3{1e-300, 0, -0.0});
    ASSERT_EQ(got.result.within.size(), 1u);
    EXPECT_EQ(got.result.within[0].distance, 0.125);
    ASSERT_TRUE(got.result.nearest.has_value());
    EXPECT_EQ(got.result.nearest->object, 5u);
    EXPECT_EQ(got.collision_names, std::vector<std::string>{"tank"});
    EXPECT_EQ(got.within_names, std::vector<std::string>{"pipe"});
    EXPECT_EQ(got.nearest_name, "pipe");
    EXPECT_EQ(got.result.candidate_pieces, 12u);
    EXPECT_EQ(got.result.pieces_tested, 6u);
    EXPECT_EQ(got.result.exact_tests, 300u);
    EXPECT_EQ(got.result.prefetch_hints, 2u);
    EXPECT_EQ(got.result.seconds, 0.5);
    EXPECT_EQ(got.model_version, 3u);
    EXPECT_EQ(got.server_seconds, 0.75);

    // peer
    massive::PeerEvent peer;
    peer.member = "bob";
    peer.pose = posed;
    peer.pose.model_version = 8;
    message.Clear();
    wire::encode_room_event(peer, &message);
    event = detail::decode_review_event(reparse(message));
    ASSERT_TRUE(event.ok());
    EXPECT_EQ(event->kind, client::ReviewEvent::Kind::peer);
    EXPECT_EQ(event->peer.member, "bob");
    EXPECT_EQ(event->peer.sequence, 5u);
    EXPECT_EQ(event->peer.transform.m, awkward_transform().m);
    EXPECT_EQ(event->peer.summary.within, 3u);
    EXPECT_EQ(event->peer.summary.nearest_object, 4u);
    EXPECT_EQ(event->peer.summary.nearest_distance, 0.25);
    EXPECT_EQ(event->peer.model_version, 8u);

    // peer updates sent together: one goes as `peer`, several as `peers`, and a reader takes
    // them as that many peer events in order (a single-event decode refuses a batch)
    std::vector<massive::PeerEvent> batch = {peer, peer, peer};
    batch[1].member = "carol";
    batch[1].pose.sequence = 6;
    batch[2].member = "dave";
    batch[2].pose.sequence = 7;
    message.Clear();
    wire::encode_peer_updates(std::span(batch).first(1), &message);
    EXPECT_TRUE(message.has_peer());
    message.Clear();
    wire::encode_peer_updates(batch, &message);
    ASSERT_TRUE(message.has_peers());
    EXPECT_EQ(message.peers().updates_size(), 3);
    auto events = detail::decode_review_events(reparse(message));
    ASSERT_TRUE(events.ok()) << events.status().to_string();
    ASSERT_EQ(events->size(), 3u);
    for (std::size_t k = 0; k < 3; ++k) {
        EXPECT_EQ((*events)[k].kind, client::ReviewEvent::Kind::peer);
        EXPECT_EQ((*events)[k].peer.member, batch[k].member);
        EXPECT_EQ((*events)[k].peer.sequence, batch[k].pose.sequence);
        EXPECT_EQ((*events)[k].peer.transform.m, awkward_transform().m);
        EXPECT_EQ((*events)[k].peer.model_version, 8u);
    }
    EXPECT_EQ(detail::decode_review_event(message).status().code(), StatusCode::internal);
    message.mutable_peers()->mutable_updates(1)->clear_transform();
    EXPECT_EQ(detail::decode_review_events(message).status().code(), StatusCode::internal)
        << "one malformed update spoils the batch";
    message.Clear();
    message.mutable_peers();
    EXPECT_EQ(detail::decode_review_events(message).status().code(), StatusCode::internal)
        << "an empty batch";
    // Any other event is one event.
    message.Clear();
    wire::encode_room_event(peer, &message);
    events = detail::decode_review_events(message);
    ASSERT_TRUE(events.ok());
    EXPECT_EQ(events->size(), 1u);

    // edit_applied, every kind
    for (const auto kind :
         {massive::EditKind::move, massive::EditKind::add, massive::EditKind::remove}) {
        massive::EditEvent edit{"carol", 12, kind, 41, "valve", 9};
        edit.transform.m[3] = 2.5;
        edit.transform.m[11] = -0.1;
        message.Clear();
        wire::encode_room_event(edit, &message);
        // Only a move carries its transform.
        EXPECT_EQ(message.edit_applied().has_transform(), kind == massive::EditKind::move);
        event = detail::decode_review_event(reparse(message));
        ASSERT_TRUE(event.ok());
        EXPECT_EQ(event->kind, client::ReviewEvent::Kind::edit_applied);
        EXPECT_EQ(event->edit.member, "carol");
        EXPECT_EQ(event->edit.sequence, 12u);
        EXPECT_EQ(event->edit.what, kind);
        EXPECT_EQ(event->edit.object, 41u);
        EXPECT_EQ(event->edit.object_name, "valve");
        EXPECT_EQ(event->edit.model_version, 9u);
        EXPECT_EQ(event->edit.transform.m,
                  kind == massive::EditKind::move ? edit.transform.m : massive::Affine{}.m);
    }

    // member_joined / member_left
    message.Clear();
    wire::encode_room_event(massive::MemberJoinedEvent{"dave"}, &message);
    event = detail::decode_review_event(reparse(message));
    ASSERT_TRUE(event.ok());
    EXPECT_EQ(event->kind, client::ReviewEvent::Kind::member_joined);
    EXPECT_EQ(event->member, "dave");
    message.Clear();
    wire::encode_room_event(massive::MemberLeftEvent{"dave"}, &message);
    event = detail::decode_review_event(reparse(message));
    ASSERT_TRUE(event.ok());
    EXPECT_EQ(event->kind, client::ReviewEvent::Kind::member_left);
    EXPECT_EQ(event->member, "dave");

    // What a client refuses: a daemon's malformed event is internal.
    message.Clear();
    message.mutable_peer()->set_member("bob");
    EXPECT_EQ(detail::decode_review_event(message).status().code(), StatusCode::internal)
        << "a peer update without its 12-number transform is malformed";
    message.Clear();
    message.mutable_edit_applied()->set_what(static_cast<v1::EditKind>(17));
    EXPECT_EQ(detail::decode_review_event(message).status().code(), StatusCode::internal);
    EXPECT_EQ(detail::decode_review_event(v1::ReviewEvent()).status().code(), StatusCode::internal);
}

TEST(Wire, RegionRequestsAndEventsRoundTrip) {
    massive::RegionRequest request;
    request.model = "plant";
    request.center = {0.1, -2.0 / 3.0, 1e300};
    request.radius = 0.7;
    request.room = "design-1";
    request.objects = {4, 0, 17};
    request.max_triangles = 1000;
    request.float64 = true;
    v1::FetchRegionRequest message;
    wire::encode_region_request(request, &message);
    EXPECT_EQ(message.type(), v1::SCALAR_TYPE_FLOAT64);
    auto decoded = wire::decode_region_request(reparse(message));
    ASSERT_TRUE(decoded.ok()) << decoded.status().to_string();
    EXPECT_EQ(decoded->model, "plant");
    EXPECT_EQ(decoded->center, request.center);
    EXPECT_EQ(decoded->radius, 0.7);
    EXPECT_EQ(decoded->room, "design-1");
    EXPECT_EQ(decoded->objects, request.objects);
    EXPECT_EQ(decoded->max_triangles, 1000u);
    EXPECT_TRUE(decoded->float64);
    // Unset type: float32; an unknown one is the caller's error, naming the field.
    message.clear_type();
    decoded = wire::decode_region_request(message);
    ASSERT_TRUE(decoded.ok());
    EXPECT_FALSE(decoded->float64);
    message.set_type(static_cast<v1::ScalarType>(9));
    expect_error(wire::decode_region_request(message).status(), StatusCode::invalid_argument,
                 {"type", "9"});

    // A piece, in float64 (exact) and float32 (each coordinate rounded).
    const NamedMesh mesh = awkward_mesh();
    massive::RegionPiece piece;
    piece.object = 12;
    piece.object_name = "valve";
    piece.vertices = mesh.mesh.vertices;
    piece.triangles = mesh.mesh.triangles;
    for (std::size_t t = 0; t < piece.triangles.size(); ++t) {
        piece.triangle_ids.push_back(static_cast<std::uint32_t>(100 + 3 * t));
    }
    piece.box = compute_box(piece.vertices);
    piece.distance = 0.25;
    for (const bool float32 : {false, true}) {
        v1::RegionEvent event;
        wire::encode_region_event(piece, float32, &event);
        auto back = wire::decode_region_event(reparse(event));
        ASSERT_TRUE(back.ok()) << back.status().to_string();
        const auto* p = std::get_if<massive::RegionPiece>(&back.value());
        ASSERT_NE(p, nullptr);
        EXPECT_EQ(p->object, 12u);
        EXPECT_EQ(p->object_name, "valve");
        EXPECT_EQ(event.piece().mesh().name(), "valve");
        EXPECT_EQ(p->triangles, piece.triangles);
        EXPECT_EQ(p->triangle_ids, piece.triangle_ids);
        EXPECT_EQ(p->box.lo, piece.box.lo);
        EXPECT_EQ(p->box.hi, piece.box.hi);
        EXPECT_EQ(p->distance, 0.25);
        ASSERT_EQ(p->vertices.size(), piece.vertices.size());
        for (std::size_t v = 0; v < piece.vertices.size(); ++v) {
            for (int k = 0; k < 3; ++k) {
                const double sent = piece.vertices[v][k];
                const double want = float32 ? static_cast<float>(sent) : sent;
                EXPECT_EQ(bits(p->vertices[v][k]), bits(want)) << "vertex " << v << " " << k;
            }
        }
        // triangle_ids must be one per triangle.
        event.mutable_piece()->mutable_triangle_ids()->RemoveLast();
        expect_error(wire::decode_region_event(event).status(), StatusCode::internal,
                     {"triangle_ids"});
    }

    v1::RegionEvent event;
    wire::encode_region_event(massive::RegionProgress{3, 10, 300, 1000}, true, &event);
    auto progress = wire::decode_region_event(reparse(event));
    ASSERT_TRUE(progress.ok());
    const auto* g = std::get_if<massive::RegionProgress>(&progress.value());
    ASSERT_NE(g, nullptr);
    EXPECT_EQ(g->pieces_sent, 3u);
    EXPECT_EQ(g->pieces_total, 10u);
    EXPECT_EQ(g->triangles_sent, 300u);
    EXPECT_EQ(g->triangles_total, 1000u);

    event.Clear();
    wire::encode_region_event(massive::RegionSummary{10, 1000, true, 4, "gen-000002", 0.5}, true,
                              &event);
    auto summary = wire::decode_region_event(reparse(event));
    ASSERT_TRUE(summary.ok());
    const auto* s = std::get_if<massive::RegionSummary>(&summary.value());
    ASSERT_NE(s, nullptr);
    EXPECT_EQ(s->pieces, 10u);
    EXPECT_EQ(s->triangles, 1000u);
    EXPECT_TRUE(s->truncated);
    EXPECT_EQ(s->model_version, 4u);
    EXPECT_EQ(s->generation, "gen-000002");
    EXPECT_EQ(s->server_seconds, 0.5);

    expect_error(wire::decode_region_event(v1::RegionEvent()).status(), StatusCode::internal,
                 {"empty"});
}

TEST(Wire, ModelListDecodes) {
    v1::ListModelsResponse list;
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
    massive::CacheStats cache;
    cache.evictions = 7;
    cache.hits = 70;
    wire::encode_cache_stats(cache, list.mutable_cache());
    const auto models = detail::decode_model_list(reparse(list));
    EXPECT_EQ(models.models_dir, "/srv/models");
    ASSERT_EQ(models.models.size(), 1u);
    EXPECT_EQ(models.models[0].name, "plant");
    EXPECT_EQ(models.models[0].pieces, 5u);
    EXPECT_EQ(models.models[0].box.hi.z, 2.5);
    EXPECT_EQ(models.unavailable.at(0).second, "DATA_LOSS: bad");
    EXPECT_EQ(models.cache_budget_bytes, 1024u);
    EXPECT_EQ(models.cache.evictions, 7u);
    EXPECT_EQ(models.cache.hits, 70u);

    v1::ObjectPairResult pair;
    pair.set_object_a(1);
    pair.set_object_b(2);
    pair.set_name_a("a");
    pair.set_name_b("b");
    pair.set_distance(1.0 / 3.0);
    pair.mutable_point_b()->set_y(-0.5);
    const auto named = detail::decode_object_pair(reparse(pair));
    EXPECT_EQ(named.pair.object_a, 1u);
    EXPECT_EQ(named.pair.object_b, 2u);
    EXPECT_EQ(named.name_a, "a");
    EXPECT_EQ(named.name_b, "b");
    EXPECT_EQ(bits(named.pair.distance), bits(1.0 / 3.0));
    EXPECT_EQ(named.pair.point_b.y, -0.5);
}

// Snapshot requests and answers: a round trip keeps every field; the daemon's decoding fills the
// camera's defaults and refuses bad sizes, cameras and tolerances before any scene is looked at.
// A model region's snapshot: the region's fields round-trip, exactly one of scene_id and model,
// and the answer's region counts come back.
TEST(Wire, ModelRegionSnapshotRoundTrip) {
    massive::RegionRequest region;
    region.model = "plant";
    region.center = {1.5, -2, 0.25};
    region.radius = 3;
    region.room = "r1";
    region.max_triangles = 1000;
    render::SnapshotRequest request;
    request.render.width = 64;
    request.render.height = 48;
    v1::SnapshotRequest message;
    wire::encode_model_snapshot_request(region, request, &message);
    EXPECT_TRUE(message.scene_id().empty());
    auto decoded = wire::decode_snapshot_region(message);
    ASSERT_TRUE(decoded.ok()) << decoded.status().to_string();
    ASSERT_TRUE(decoded->has_value());
    EXPECT_EQ((*decoded)->model, "plant");
    EXPECT_EQ((*decoded)->center, (Vec3{1.5, -2, 0.25}));
    EXPECT_EQ((*decoded)->radius, 3);
    EXPECT_EQ((*decoded)->room, "r1");
    EXPECT_EQ((*decoded)->max_triangles, 1000u);
    EXPECT_EQ(wire::decode_snapshot_request(message)->render.width, 64);

    v1::SnapshotRequest both = message;
    both.set_scene_id("s1");
    EXPECT_EQ(wire::decode_snapshot_region(both).status().code(), StatusCode::invalid_argument);
    v1::SnapshotRequest neither = message;
    neither.clear_model();
    EXPECT_EQ(wire::decode_snapshot_region(neither).status().code(), StatusCode::invalid_argument);
    v1::SnapshotRequest scene;
    wire::encode_snapshot_request("s1", request, &scene);
    auto scene_region = wire::decode_snapshot_region(scene);
    ASSERT_TRUE(scene_region.ok());
    EXPECT_FALSE(scene_region->has_value());
    scene.set_room("r1");
    EXPECT_EQ(wire::decode_snapshot_region(scene).status().code(), StatusCode::invalid_argument);

    render::Snapshot snapshot;
    snapshot.png = "png";
    snapshot.width = 64;
    snapshot.height = 48;
    snapshot.region = render::SnapshotRegion{7, 84, 3, true, 2, "gen-000001"};
    v1::SnapshotResponse response;
    wire::encode_snapshot(snapshot, &response);
    auto back = wire::decode_snapshot(response);
    ASSERT_TRUE(back.ok()) << back.status().to_string();
    ASSERT_TRUE(back->region.has_value());
    EXPECT_EQ(back->region->pieces, 7u);
    EXPECT_EQ(back->region->triangles, 84u);
    EXPECT_EQ(back->region->objects, 3u);
    EXPECT_TRUE(back->region->truncated);
    EXPECT_EQ(back->region->model_version, 2u);
    EXPECT_EQ(back->region->generation, "gen-000001");
    snapshot.region.reset();
    response.Clear();
    wire::encode_snapshot(snapshot, &response);
    EXPECT_FALSE(wire::decode_snapshot(response)->region.has_value());
}

TEST(Wire, SnapshotRoundTripAndValidation) {
    render::SnapshotRequest request;
    request.render.width = 320;
    request.render.height = 200;
    request.render.camera = render::Camera{{1, 2, 3}, {0, 0, 0}, {0, 1, 0}, 30};
    request.collisions = false;
    request.tolerance = 0.25;
    request.segments = true;
    v1::SnapshotRequest message;
    wire::encode_snapshot_request("s1", request, &message);
    EXPECT_EQ(message.scene_id(), "s1");
    auto decoded = wire::decode_snapshot_request(message);
    ASSERT_TRUE(decoded.ok()) << decoded.status().to_string();
    EXPECT_EQ(decoded->render.width, 320);
    EXPECT_EQ(decoded->render.height, 200);
    ASSERT_TRUE(decoded->render.camera.has_value());
    EXPECT_EQ(decoded->render.camera->eye, (Vec3{1, 2, 3}));
    EXPECT_EQ(decoded->render.camera->up, (Vec3{0, 1, 0}));
    EXPECT_EQ(decoded->render.camera->fov_degrees, 30);
    EXPECT_FALSE(decoded->collisions);
    EXPECT_EQ(decoded->tolerance, 0.25);
    EXPECT_TRUE(decoded->segments);

    // Unset up and fov: +z and 45 degrees.
    message.mutable_camera()->clear_up();
    message.mutable_camera()->set_fov_degrees(0);
    decoded = wire::decode_snapshot_request(message);
    ASSERT_TRUE(decoded.ok());
    EXPECT_EQ(decoded->render.camera->up, (Vec3{0, 0, 1}));
    EXPECT_EQ(decoded->render.camera->fov_degrees, 45);

    auto refused = [&](auto change) {
        v1::SnapshotRequest bad = message;
        change(bad);
        return wire::decode_snapshot_request(bad).status().code();
    };
    EXPECT_EQ(refused([](auto& m) { m.set_width(0); }), StatusCode::invalid_argument);
    EXPECT_EQ(refused([](auto& m) { m.set_height(4097); }), StatusCode::invalid_argument);
    EXPECT_EQ(refused([](auto& m) { m.set_width(4'000'000'000U); }), StatusCode::invalid_argument);
    EXPECT_EQ(refused([](auto& m) { m.set_tolerance(-1); }), StatusCode::invalid_argument);
    EXPECT_EQ(refused([](auto& m) { m.mutable_camera()->set_fov_degrees(180); }),
              StatusCode::invalid_argument);
    EXPECT_EQ(refused([](auto& m) { *m.mutable_camera()->mutable_target() = m.camera().eye(); }),
              StatusCode::invalid_argument);

    render::Snapshot shot;
    shot.png = "\x89PNG...";
    shot.camera = *request.render.camera;
    shot.width = 320;
    shot.height = 200;
    shot.renderer = "llvmpipe";
    shot.collision_count = 3;
    shot.tolerance_count = 4;
    shot.segment_count = 5;
    v1::SnapshotResponse response;
    wire::encode_snapshot(shot, &response);
    auto back = wire::decode_snapshot(response);
    ASSERT_TRUE(back.ok()) << back.status().to_string();
    EXPECT_EQ(back->png, shot.png);
    EXPECT_EQ(back->camera.eye, shot.camera.eye);
    EXPECT_EQ(back->width, 320);
    EXPECT_EQ(back->renderer, "llvmpipe");
    EXPECT_EQ(back->collision_count, 3U);
    EXPECT_EQ(back->tolerance_count, 4U);
    EXPECT_EQ(back->segment_count, 5U);
    response.clear_png();
    EXPECT_EQ(wire::decode_snapshot(response).status().code(), StatusCode::internal);
}

}  // namespace
}  // namespace proxima
