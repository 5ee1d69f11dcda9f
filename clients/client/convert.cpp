#include "client/convert.hpp"

#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>

namespace proxima::client::detail {

namespace {

static_assert(sizeof(Vec3) == 3 * sizeof(double) && std::is_standard_layout_v<Vec3>,
              "Vec3 must be three packed doubles for the float64 fast path");
static_assert(sizeof(TriangleIndices) == TRIANGLE_BYTES);

constexpr bool LITTLE_ENDIAN_HOST = std::endian::native == std::endian::little;

// Writes `value` little-endian at dst, whatever the host's byte order.
template <class T>
void store_le(char* dst, T value) {
    using U = std::conditional_t<sizeof(T) == 8, std::uint64_t, std::uint32_t>;
    auto bits = std::bit_cast<U>(value);
    for (std::size_t i = 0; i < sizeof(U); ++i) {
        dst[i] = static_cast<char>(static_cast<unsigned char>(bits >> (8 * i)));
    }
}

template <class T>
T load_le(const char* src) {
    using U = std::conditional_t<sizeof(T) == 8, std::uint64_t, std::uint32_t>;
    U bits = 0;
    for (std::size_t i = 0; i < sizeof(U); ++i) {
        bits |= static_cast<U>(static_cast<unsigned char>(src[i])) << (8 * i);
    }
    return std::bit_cast<T>(bits);
}

Status malformed(const std::string& what) {
    return {StatusCode::internal, "malformed FrameResult from the server: " + what};
}

void encode_vec3(const Vec3& v, pb::Vec3* out) {
    out->set_x(v.x);
    out->set_y(v.y);
    out->set_z(v.z);
}

Vec3 decode_vec3(const pb::Vec3& v) {
    return {v.x(), v.y(), v.z()};
}

void encode_pairs(const std::vector<FeaturePair>& pairs,
                  google::protobuf::RepeatedPtrField<pb::FeaturePair>* out) {
    out->Reserve(static_cast<int>(pairs.size()));
    for (const auto& p : pairs) {
        auto* q = out->Add();
        q->set_object(p.object);
        q->set_triangle(p.triangle);
        q->set_other(p.other);
        q->set_other_triangle(p.other_triangle);
        q->set_distance(p.distance);
    }
}

Status decode_pairs(const google::protobuf::RepeatedPtrField<pb::FeaturePair>& pairs,
                    std::size_t object_count, const char* what, std::vector<FeaturePair>& out) {
    out.reserve(static_cast<std::size_t>(pairs.size()));
    for (const auto& q : pairs) {
        if (q.object() >= object_count || q.other() >= object_count) {
            return malformed(std::string(what) + " pair names object " +
                             std::to_string(std::max(q.object(), q.other())) + " of " +
                             std::to_string(object_count));
        }
        out.push_back({q.object(), q.triangle(), q.other(), q.other_triangle(), q.distance()});
    }
    return {};
}

}  // namespace

Status from_grpc(const grpc::Status& status) {
    switch (status.error_code()) {
        case grpc::StatusCode::OK:
            return {};
        case grpc::StatusCode::INVALID_ARGUMENT:
            return {StatusCode::invalid_argument, status.error_message()};
        case grpc::StatusCode::NOT_FOUND:
            return {StatusCode::not_found, status.error_message()};
        case grpc::StatusCode::FAILED_PRECONDITION:
            return {StatusCode::failed_precondition, status.error_message()};
        case grpc::StatusCode::RESOURCE_EXHAUSTED:
            return {StatusCode::resource_exhausted, status.error_message()};
        case grpc::StatusCode::CANCELLED:
            return {StatusCode::cancelled, status.error_message()};
        case grpc::StatusCode::DEADLINE_EXCEEDED:
            return {StatusCode::deadline_exceeded, status.error_message()};
        case grpc::StatusCode::UNAVAILABLE:
            return {StatusCode::unavailable, status.error_message()};
        case grpc::StatusCode::INTERNAL:
            return {StatusCode::internal, status.error_message()};
        case grpc::StatusCode::DATA_LOSS:
            return {StatusCode::data_loss, status.error_message()};
        case grpc::StatusCode::UNAUTHENTICATED:
            return {StatusCode::unauthenticated, status.error_message()};
        case grpc::StatusCode::PERMISSION_DENIED:
            return {StatusCode::permission_denied, status.error_message()};
        default:
            break;
    }
    const char* name = "UNKNOWN";
    switch (status.error_code()) {
        case grpc::StatusCode::ALREADY_EXISTS:
            name = "ALREADY_EXISTS";
            break;
        case grpc::StatusCode::PERMISSION_DENIED:
            name = "PERMISSION_DENIED";
            break;
        case grpc::StatusCode::ABORTED:
            name = "ABORTED";
            break;
        case grpc::StatusCode::OUT_OF_RANGE:
            name = "OUT_OF_RANGE";
            break;
        case grpc::StatusCode::UNIMPLEMENTED:
            name = "UNIMPLEMENTED";
            break;
        case grpc::StatusCode::UNAUTHENTICATED:
            name = "UNAUTHENTICATED";
            break;
        default:
            break;
    }
    return {StatusCode::internal, std::string("gRPC ") + name + ": " + status.error_message()};
}

grpc::Status to_grpc(const Status& status) {
    grpc::StatusCode code = grpc::StatusCode::INTERNAL;
    switch (status.code()) {
        case StatusCode::ok:
            return grpc::Status::OK;
        case StatusCode::invalid_argument:
            code = grpc::StatusCode::INVALID_ARGUMENT;
            break;
        case StatusCode::not_found:
            code = grpc::StatusCode::NOT_FOUND;
            break;
        case StatusCode::failed_precondition:
            code = grpc::StatusCode::FAILED_PRECONDITION;
            break;
        case StatusCode::resource_exhausted:
            code = grpc::StatusCode::RESOURCE_EXHAUSTED;
            break;
        case StatusCode::cancelled:
            code = grpc::StatusCode::CANCELLED;
            break;
        case StatusCode::deadline_exceeded:
            code = grpc::StatusCode::DEADLINE_EXCEEDED;
            break;
        case StatusCode::unavailable:
            code = grpc::StatusCode::UNAVAILABLE;
            break;
        case StatusCode::internal:
            code = grpc::StatusCode::INTERNAL;
            break;
        case StatusCode::data_loss:
            code = grpc::StatusCode::DATA_LOSS;
            break;
        case StatusCode::unauthenticated:
            code = grpc::StatusCode::UNAUTHENTICATED;
            break;
        case StatusCode::permission_denied:
            code = grpc::StatusCode::PERMISSION_DENIED;
            break;
    }
    return {code, status.message()};
}

pb::ScalarType scalar_type(bool float32) {
    return float32 ? pb::SCALAR_TYPE_FLOAT32 : pb::SCALAR_TYPE_FLOAT64;
}

std::size_t vertex_bytes(pb::ScalarType type) {
    switch (type) {
        case pb::SCALAR_TYPE_FLOAT32:
            return FLOAT32_VERTEX_BYTES;
        case pb::SCALAR_TYPE_FLOAT64:
            return FLOAT64_VERTEX_BYTES;
        default:
            return 0;
    }
}

std::string pack_vertices(std::span<const Vec3> vertices, bool float32) {
    std::string out;
    if (!float32) {
        out.resize(vertices.size() * FLOAT64_VERTEX_BYTES);
        if constexpr (LITTLE_ENDIAN_HOST) {
            // The wire format is the host's memory layout here: one copy, no per-value work.
            if (!vertices.empty()) {
                std::memcpy(out.data(), vertices.data(), out.size());
            }
        } else {
            char* p = out.data();
            for (const auto& v : vertices) {
                store_le(p, v.x);
                store_le(p + 8, v.y);
                store_le(p + 16, v.z);
                p += FLOAT64_VERTEX_BYTES;
            }
        }
        return out;
    }
    out.resize(vertices.size() * FLOAT32_VERTEX_BYTES);
    char* p = out.data();
    for (const auto& v : vertices) {
        store_le(p, static_cast<float>(v.x));
        store_le(p + 4, static_cast<float>(v.y));
        store_le(p + 8, static_cast<float>(v.z));
        p += FLOAT32_VERTEX_BYTES;
    }
    return out;
}

std::string pack_triangles(std::span<const TriangleIndices> triangles) {
    std::string out(triangles.size() * TRIANGLE_BYTES, '\0');
    if constexpr (LITTLE_ENDIAN_HOST) {
        if (!triangles.empty()) {
            std::memcpy(out.data(), triangles.data(), out.size());
        }
    } else {
        char* p = out.data();
        for (const auto& t : triangles) {
            for (int k = 0; k < 3; ++k) {
                store_le(p + 4 * k, t[static_cast<std::size_t>(k)]);
            }
            p += TRIANGLE_BYTES;
        }
    }
    return out;
}

StatusOr<std::vector<Vec3>> unpack_vertices(pb::ScalarType type, const std::string& data,
                                            const std::string& what) {
    const std::size_t stride = vertex_bytes(type);
    if (stride == 0) {
        return invalid_argument(what + ": vertex buffer scalar type " + std::to_string(type) +
                                " is not FLOAT32 or FLOAT64");
    }
    if (data.size() % stride != 0) {
        return invalid_argument(what + ": vertex buffer of " + std::to_string(data.size()) +
                                " bytes is not a whole number of " + std::to_string(stride) +
                                "-byte vertices");
    }
    std::vector<Vec3> out(data.size() / stride);
    if (stride == FLOAT64_VERTEX_BYTES) {
        if constexpr (LITTLE_ENDIAN_HOST) {
            if (!out.empty()) {
                std::memcpy(out.data(), data.data(), data.size());
            }
            return out;
        }
        const char* p = data.data();
        for (auto& v : out) {
            v = {load_le<double>(p), load_le<double>(p + 8), load_le<double>(p + 16)};
            p += stride;
        }
        return out;
    }
    const char* p = data.data();
    for (auto& v : out) {
        v = {load_le<float>(p), load_le<float>(p + 4), load_le<float>(p + 8)};
        p += stride;
    }
    return out;
}

StatusOr<std::vector<Vec3>> unpack_vertices(const pb::VertexBuffer& buffer,
                                            const std::string& what) {
    return unpack_vertices(buffer.type(), buffer.data(), what);
}

StatusOr<std::vector<TriangleIndices>> unpack_triangles(const std::string& data,
                                                        const std::string& what) {
    if (data.size() % TRIANGLE_BYTES != 0) {
        return invalid_argument(what + ": index buffer of " + std::to_string(data.size()) +
                                " bytes is not a whole number of 12-byte triangles");
    }
    std::vector<TriangleIndices> out(data.size() / TRIANGLE_BYTES);
    if constexpr (LITTLE_ENDIAN_HOST) {
        if (!out.empty()) {
            std::memcpy(out.data(), data.data(), data.size());
        }
    } else {
        const char* p = data.data();
        for (auto& t : out) {
            t = {load_le<std::uint32_t>(p), load_le<std::uint32_t>(p + 4),
                 load_le<std::uint32_t>(p + 8)};
            p += TRIANGLE_BYTES;
        }
    }
    return out;
}

std::size_t encoded_mesh_bytes(const NamedMesh& mesh, bool float32) {
    // 32 bytes covers the tags and varint lengths of the mesh and its three fields.
    return mesh.name.size() +
           mesh.mesh.vertices.size() * (float32 ? FLOAT32_VERTEX_BYTES : FLOAT64_VERTEX_BYTES) +
           mesh.mesh.triangles.size() * TRIANGLE_BYTES + 32;
}

void encode_mesh(const NamedMesh& mesh, bool float32, pb::Mesh* out) {
    out->set_name(mesh.name);
    out->mutable_vertices()->set_type(scalar_type(float32));
    out->mutable_vertices()->set_data(pack_vertices(mesh.mesh.vertices, float32));
    out->set_indices(pack_triangles(mesh.mesh.triangles));
}

StatusOr<NamedMesh> decode_mesh(const pb::Mesh& mesh, const std::string& what) {
    const std::string who = mesh.name().empty() ? what : what + " '" + mesh.name() + "'";
    auto vertices = unpack_vertices(mesh.vertices(), who);
    if (!vertices.ok()) {
        return vertices.status();
    }
    auto triangles = unpack_triangles(mesh.indices(), who);
    if (!triangles.ok()) {
        return triangles.status();
    }
    NamedMesh out;
    out.name = mesh.name();
    out.mesh.vertices = std::move(vertices).value();
    out.mesh.triangles = std::move(triangles).value();
    return out;
}

void encode_query(const QueryRequest& request, bool self_points, pb::QuerySpec* out) {
    out->set_separation(request.separation);
    out->set_self(request.self);
    out->set_collisions(request.collisions);
    if (request.tolerance) {
        out->set_tolerance(*request.tolerance);
    }
    if (request.voronoi_cell) {
        out->set_voronoi_cell(*request.voronoi_cell);
    }
    out->set_pns(request.pns);
    switch (request.culler) {
        case CullerKind::automatic:
            out->set_culler(pb::CULLER_AUTO);
            break;
        case CullerKind::brute:
            out->set_culler(pb::CULLER_BRUTE);
            break;
        case CullerKind::bvh:
            out->set_culler(pb::CULLER_BVH);
            break;
        case CullerKind::voronoi_cpu:
            out->set_culler(pb::CULLER_VORONOI_CPU);
            break;
        case CullerKind::voronoi_gpu:
            out->set_culler(pb::CULLER_VORONOI_GPU);
            break;
    }
    out->set_self_points(self_points);
}

StatusOr<QueryRequest> decode_query(const pb::QuerySpec& spec) {
    QueryRequest out;
    out.separation = spec.separation();
    out.self = spec.self();
    out.collisions = spec.collisions();
    if (spec.has_tolerance()) {
        out.tolerance = spec.tolerance();
    }
    if (spec.has_voronoi_cell()) {
        out.voronoi_cell = spec.voronoi_cell();
    }
    out.pns = spec.pns();
    switch (spec.culler()) {
        case pb::CULLER_AUTO:
            out.culler = CullerKind::automatic;
            break;
        case pb::CULLER_BRUTE:
            out.culler = CullerKind::brute;
            break;
        case pb::CULLER_BVH:
            out.culler = CullerKind::bvh;
            break;
        case pb::CULLER_VORONOI_CPU:
            out.culler = CullerKind::voronoi_cpu;
            break;
        case pb::CULLER_VORONOI_GPU:
            out.culler = CullerKind::voronoi_gpu;
            break;
        default:
            return invalid_argument("unknown culler " + std::to_string(spec.culler()) +
                                    " (expected CULLER_AUTO, CULLER_BRUTE, CULLER_BVH, "
                                    "CULLER_VORONOI_CPU or CULLER_VORONOI_GPU)");
    }
    return out;
}

void encode_frame(const FrameRequest& frame, const std::string& scene_id, bool float32,
                  pb::Frame* out) {
    const auto& u = frame.update;
    out->set_scene_id(scene_id);
    out->set_frame(frame.frame);
    out->mutable_positions()->Reserve(static_cast<int>(u.positions.size()));
    for (const auto& p : u.positions) {
        auto* q = out->add_positions();
        q->set_object_id(p.object);
        q->mutable_vertices()->set_type(scalar_type(float32));
        q->mutable_vertices()->set_data(pack_vertices(p.vertices, float32));
    }
    for (const auto& r : u.replacements) {
        auto* q = out->add_topology_changes();
        q->set_object_id(r.object);
        for (const auto& f : r.fragments) {
            encode_mesh(f, float32, q->add_fragments());
        }
    }
    for (const auto& a : u.additions) {
        encode_mesh(a, float32, out->add_additions());
    }
    out->mutable_removals()->Add(u.removals.begin(), u.removals.end());
    encode_query(frame.queries, frame.self_points, out->mutable_queries());
    out->mutable_queries()->set_penetration(frame.penetration);
    if (frame.ccd) {
        out->mutable_queries()->set_ccd(true);
        out->mutable_queries()->set_ccd_min_distance(frame.ccd_request.elementary.min_distance);
    }
}

StatusOr<FrameRequest> decode_frame(const pb::Frame& frame) {
    FrameRequest out;
    out.frame = frame.frame();
    auto& u = out.update;
    for (const auto& p : frame.positions()) {
        auto vertices =
            unpack_vertices(p.vertices(), "positions of object " + std::to_string(p.object_id()));
        if (!vertices.ok()) {
            return vertices.status();
        }
        u.positions.push_back({p.object_id(), std::move(vertices).value()});
    }
    for (const auto& t : frame.topology_changes()) {
        SceneUpdate::Replacement r;
        r.object = t.object_id();
        for (int i = 0; i < t.fragments_size(); ++i) {
            auto mesh =
                decode_mesh(t.fragments(i), "fragment " + std::to_string(i) + " of object " +
                                                std::to_string(t.object_id()));
            if (!mesh.ok()) {
                return mesh.status();
            }
            r.fragments.push_back(std::move(mesh).value());
        }
        u.replacements.push_back(std::move(r));
    }
    for (int i = 0; i < frame.additions_size(); ++i) {
        auto mesh = decode_mesh(frame.additions(i), "addition " + std::to_string(i));
        if (!mesh.ok()) {
            return mesh.status();
        }
        u.additions.push_back(std::move(mesh).value());
    }
    u.removals.assign(frame.removals().begin(), frame.removals().end());
    auto queries = decode_query(frame.queries());
    if (!queries.ok()) {
        return queries.status();
    }
    out.queries = queries.value();
    out.self_points = frame.queries().self_points();
    out.ccd = frame.queries().ccd();
    out.penetration = frame.queries().penetration();
    if (frame.queries().has_ccd_min_distance()) {
        out.ccd_request.elementary.min_distance = frame.queries().ccd_min_distance();
    }
    return out;
}

StatusOr<ccd::CcdResult> decode_ccd(const pb::CcdResult& in, std::size_t objects) {
    ccd::CcdResult out;
    out.pairs.reserve(static_cast<std::size_t>(in.pairs_size()));
    for (const auto& p : in.pairs()) {
        if (p.object() >= objects || p.other() >= objects) {
            return malformed("CCD pair names objects " + std::to_string(p.object()) + " and " +
                             std::to_string(p.other()) + " of " + std::to_string(objects));
        }
        ccd::CcdPair e;
        e.kind =
            p.kind() == pb::CCD_EDGE_EDGE ? ccd::CcdKind::edge_edge : ccd::CcdKind::vertex_face;
        e.object = p.object();
        e.primitive = p.primitive();
        e.other = p.other();
        e.other_primitive = p.other_primitive();
        e.toi = p.toi();
        e.capped = p.capped();
        out.pairs.push_back(e);
    }
    for (const auto& o : in.object_pairs()) {
        if (o.object() >= objects || o.other() >= objects || o.pair() >= out.pairs.size()) {
            return malformed("CCD object pair (" + std::to_string(o.object()) + ", " +
                             std::to_string(o.other()) + ") names pair " +
                             std::to_string(o.pair()) + " of " + std::to_string(out.pairs.size()));
        }
        out.object_pairs.push_back({o.object(), o.other(), o.toi(), o.pair()});
    }
    if (in.has_earliest()) {
        if (in.earliest() >= out.pairs.size()) {
            return malformed("CCD earliest pair " + std::to_string(in.earliest()) + " of " +
                             std::to_string(out.pairs.size()));
        }
        out.earliest = in.earliest();
    }
    auto& s = out.stats;
    s.candidate_pairs = in.candidate_pairs();
    s.elementary_tests = in.elementary_tests();
    s.capped_tests = in.capped_tests();
    s.brute_force_tests = in.brute_force_tests();
    s.object_pairs_tested = in.object_pairs_tested();
    s.broad_phase_seconds = in.broad_phase_seconds();
    s.narrow_phase_seconds = in.narrow_phase_seconds();
    s.total_seconds = in.total_seconds();
    return out;
}

StatusOr<FrameResponse> decode_result(const pb::FrameResult& result) {
    FrameResponse out;
    out.scene_id = result.scene_id();
    out.frame = result.frame();
    out.object_ids.assign(result.object_ids().begin(), result.object_ids().end());
    out.added_ids.assign(result.added_ids().begin(), result.added_ids().end());
    for (const auto& f : result.fragment_ids()) {
        out.fragment_ids.emplace_back(f.ids().begin(), f.ids().end());
    }
    const std::size_t n = out.object_ids.size();
    auto& r = out.result;

    if (result.separation_size() != 0 && static_cast<std::size_t>(result.separation_size()) != n) {
        return malformed(std::to_string(result.separation_size()) + " separations for " +
                         std::to_string(n) + " objects");
    }
    r.separation.reserve(n);
    for (const auto& s : result.separation()) {
        Separation e;
        if (s.has_other()) {
            if (s.other() >= n) {
                return malformed("separation names object " + std::to_string(s.other()) + " of " +
                                 std::to_string(n));
            }
            e.other = s.other();
            e.distance = s.distance();
        }  // else: alone in the scene, the engine's "no other" (distance +inf)
        e.triangle = s.triangle();
        e.other_triangle = s.other_triangle();
        e.point = decode_vec3(s.point());
        e.other_point = decode_vec3(s.other_point());
        r.separation.push_back(e);
    }

    if (result.self_size() != 0 && static_cast<std::size_t>(result.self_size()) != n) {
        return malformed(std::to_string(result.self_size()) + " self lists for " +
                         std::to_string(n) + " objects");
    }
    r.self.reserve(n);
    for (int i = 0; i < result.self_size(); ++i) {
        const auto& s = result.self(i);
        const auto count = static_cast<std::size_t>(s.closest_size());
        if (static_cast<std::size_t>(s.distance_size()) != count ||
            (s.points_size() != 0 && static_cast<std::size_t>(s.points_size()) != 6 * count)) {
            return malformed("self list of object " + std::to_string(i) + " has " +
                             std::to_string(count) + " closest, " +
                             std::to_string(s.distance_size()) + " distances and " +
                             std::to_string(s.points_size()) + " point coordinates");
        }
        std::vector<SelfDistance> list(count);
        for (std::size_t t = 0; t < count; ++t) {
            auto& e = list[t];
            const auto closest = s.closest(static_cast<int>(t));
            if (closest < NO_OBJECT) {
                return malformed("self entry " + std::to_string(t) + " of object " +
                                 std::to_string(i) + " has closest " + std::to_string(closest));
            }
            e.closest = closest;
            e.distance = s.distance(static_cast<int>(t));
            if (s.points_size() != 0) {
                const double* p = s.points().data() + 6 * t;
                e.point = {p[0], p[1], p[2]};
                e.other_point = {p[3], p[4], p[5]};
            }
        }
        r.self.push_back(std::move(list));
    }

    if (auto st = decode_pairs(result.collisions(), n, "collision", r.collisions); !st.ok()) {
        return st;
    }
    if (auto st = decode_pairs(result.tolerance(), n, "tolerance", r.tolerance); !st.ok()) {
        return st;
    }
    if (auto st = decode_pairs(result.pns(), n, "PNS", r.pns); !st.ok()) {
        return st;
    }

    for (const auto& p : result.penetrations()) {
        if (p.object() >= n || p.other() >= n) {
            return malformed("penetration names objects " + std::to_string(p.object()) + " and " +
                             std::to_string(p.other()) + " of " + std::to_string(n));
        }
        Penetration e;
        e.object = p.object();
        e.other = p.other();
        e.direction = decode_vec3(p.direction());
        e.depth = p.depth();
        e.vector = decode_vec3(p.vector());
        e.triangles.assign(p.triangles().begin(), p.triangles().end());
        e.other_triangles.assign(p.other_triangles().begin(), p.other_triangles().end());
        e.triangle = p.triangle();
        e.other_triangle = p.other_triangle();
        e.isolated = p.isolated();
        e.closed = p.closed();
        e.normal_fallback = p.normal_fallback();
        e.sides_split = p.sides_split();
        out.penetrations.push_back(std::move(e));
    }
    if (result.has_ccd()) {
        auto ccd = decode_ccd(result.ccd(), n);
        if (!ccd.ok()) {
            return ccd.status();
        }
        out.ccd = std::move(ccd).value();
    }

    const auto& s = result.stats();
    auto& q = r.stats;
    q.culler = s.culler();
    q.prepare_seconds = s.prepare_seconds();
    q.broad_phase_seconds = s.broad_phase_seconds();
    q.separation_seconds = s.separation_seconds();
    q.self_seconds = s.self_seconds();
    q.collision_seconds = s.collision_seconds();
    q.tolerance_seconds = s.tolerance_seconds();
    q.total_seconds = s.total_seconds();
    q.exact_tests = s.exact_tests();
    q.brute_force_tests = s.brute_force_tests();
    q.object_pairs_tested = s.object_pairs_tested();
    q.pns_pairs = s.pns_pairs();
    q.voronoi_seconds = s.voronoi_seconds();
    q.dvd_seconds = s.dvd_seconds();
    q.dvd_samples = s.dvd_samples();
    q.dvd_cell = s.dvd_cell();
    q.voronoi_culled = s.voronoi_culled();
    q.dvd_epsilon = s.dvd_epsilon();
    out.server_seconds = s.server_seconds();
    return out;
}

void encode_result(const FrameResponse& response, bool self_points, pb::FrameResult* out) {
    out->set_scene_id(response.scene_id);
    out->set_frame(response.frame);
    out->mutable_object_ids()->Add(response.object_ids.begin(), response.object_ids.end());
    out->mutable_added_ids()->Add(response.added_ids.begin(), response.added_ids.end());
    for (const auto& f : response.fragment_ids) {
        out->add_fragment_ids()->mutable_ids()->Add(f.begin(), f.end());
    }
    const auto& r = response.result;
    for (const auto& s : r.separation) {
        auto* e = out->add_separation();
        e->set_has_other(s.other != NO_OBJECT);
        e->set_other(s.other == NO_OBJECT ? 0u : static_cast<std::uint32_t>(s.other));
        e->set_triangle(s.triangle);
        e->set_other_triangle(s.other_triangle);
        e->set_distance(s.distance);
        encode_vec3(s.point, e->mutable_point());
        encode_vec3(s.other_point, e->mutable_other_point());
    }
    for (const auto& list : r.self) {
        auto* e = out->add_self();
        e->mutable_closest()->Reserve(static_cast<int>(list.size()));
        e->mutable_distance()->Reserve(static_cast<int>(list.size()));
        for (const auto& s : list) {
            e->add_closest(s.closest);
            e->add_distance(s.distance);
        }
        if (self_points) {
            e->mutable_points()->Reserve(static_cast<int>(6 * list.size()));
            for (const auto& s : list) {
                for (const auto& p : {s.point, s.other_point}) {
                    e->add_points(p.x);
                    e->add_points(p.y);
                    e->add_points(p.z);
                }
            }
        }
    }
    encode_pairs(r.collisions, out->mutable_collisions());
    encode_pairs(r.tolerance, out->mutable_tolerance());
    encode_pairs(r.pns, out->mutable_pns());
    auto* s = out->mutable_stats();
    const auto& q = r.stats;
    s->set_culler(q.culler);
    s->set_prepare_seconds(q.prepare_seconds);
    s->set_broad_phase_seconds(q.broad_phase_seconds);
    s->set_separation_seconds(q.separation_seconds);
    s->set_self_seconds(q.self_seconds);
    s->set_collision_seconds(q.collision_seconds);
    s->set_tolerance_seconds(q.tolerance_seconds);
    s->set_total_seconds(q.total_seconds);
    s->set_exact_tests(q.exact_tests);
    s->set_brute_force_tests(q.brute_force_tests);
    s->set_object_pairs_tested(q.object_pairs_tested);
    s->set_pns_pairs(q.pns_pairs);
    s->set_voronoi_seconds(q.voronoi_seconds);
    s->set_dvd_seconds(q.dvd_seconds);
    s->set_dvd_samples(q.dvd_samples);
    s->set_dvd_cell(q.dvd_cell);
    s->set_voronoi_culled(q.voronoi_culled);
    s->set_dvd_epsilon(q.dvd_epsilon);
    s->set_server_seconds(response.server_seconds);
}

RemoteServerInfo decode_server_info(const pb::ServerInfo& info) {
    RemoteServerInfo out;
    out.version = info.version();
    out.api = info.api();
    out.proximity_backend = info.proximity_backend();
    out.gl_renderer = info.gl_renderer();
    out.live_scenes = info.live_scenes();
    out.live_streams = info.live_streams();
    const auto& l = info.limits();
    out.max_scenes = l.max_scenes();
    out.max_objects_per_scene = l.max_objects_per_scene();
    out.max_triangles_per_scene = l.max_triangles_per_scene();
    out.max_message_bytes = l.max_message_bytes();
    out.max_frames_in_flight = l.max_frames_in_flight();
    out.principal = info.principal();
    const auto& q = info.quotas();
    out.quota_max_scenes = q.max_scenes();
    out.quota_max_objects = q.max_objects();
    out.quota_max_triangles = q.max_triangles();
    out.quota_max_bytes_held = q.max_bytes_held();
    out.quota_max_bytes_in_flight = q.max_bytes_in_flight();
    out.quota_max_frames_per_second = q.max_frames_per_second();
    out.quota_max_streams = q.max_streams();
    out.gpu_active = info.gpu_active();
    out.gpu_fallback_reason = info.gpu_fallback_reason();
    return out;
}

RemoteObject decode_object(const pb::ObjectInfo& info) {
    return {info.id(), info.name(), info.vertex_count(), info.triangle_count()};
}

RemoteScene decode_scene(const pb::SceneInfo& info) {
    RemoteScene out;
    out.scene_id = info.scene_id();
    out.name = info.name();
    out.objects.reserve(static_cast<std::size_t>(info.objects_size()));
    for (const auto& o : info.objects()) {
        out.objects.push_back(decode_object(o));
    }
    out.frames = info.frames();
    out.triangle_count = info.triangle_count();
    return out;
}

// --- Massive models ----------------------------------------------------------------------------

namespace {

Status malformed_answer(const std::string& what) {
    return {StatusCode::internal, "malformed answer from the server: " + what};
}

}  // namespace

void encode_transform(const massive::Affine& transform, pb::Transform* out) {
    out->mutable_m()->Reserve(12);
    for (double v : transform.m) {
        out->add_m(v);
    }
}

StatusOr<massive::Affine> decode_transform(const pb::Transform& transform,
                                           const std::string& what) {
    if (transform.m_size() != 12) {
        return malformed_answer(what + ": a transform of " + std::to_string(transform.m_size()) +
                                " numbers (12 expected)");
    }
    massive::Affine out;
    for (int i = 0; i < 12; ++i) {
        out.m[static_cast<std::size_t>(i)] = transform.m(i);
    }
    return out;
}

massive::CacheStats decode_cache_stats(const pb::CacheStats& s) {
    massive::CacheStats out;
    out.budget_bytes = s.budget_bytes();
    out.resident_bytes = s.resident_bytes();
    out.peak_bytes = s.peak_bytes();
    out.loads = s.loads();
    out.triangles_loaded = s.triangles_loaded();
    out.bytes_loaded = s.bytes_loaded();
    out.hits = s.hits();
    out.misses = s.misses();
    out.waits = s.waits();
    out.evictions = s.evictions();
    out.prefetch_loads = s.prefetch_loads();
    out.blocked_seconds = s.blocked_seconds();
    return out;
}

RemoteModelList decode_model_list(const pb::ListModelsResponse& response) {
    RemoteModelList out;
    out.models_dir = response.models_dir();
    for (const auto& m : response.models()) {
        RemoteModel r;
        r.name = m.name();
        r.objects = m.objects();
        r.pieces = m.pieces();
        r.triangles = m.triangles();
        r.vertices = m.vertices();
        r.split_objects = m.split_objects();
        r.chunks = m.chunks();
        r.bytes = m.bytes();
        r.generation = m.generation();
        if (m.has_box()) {
            r.box.lo = decode_vec3(m.box().lo());
            r.box.hi = decode_vec3(m.box().hi());
        }
        out.models.push_back(std::move(r));
    }
    for (const auto& u : response.unavailable()) {
        out.unavailable.emplace_back(u.name(), u.status());
    }
    out.cache_budget_bytes = response.cache_budget_bytes();
    out.cache = decode_cache_stats(response.cache());
    return out;
}

NamedObjectPair decode_object_pair(const pb::ObjectPairResult& p) {
    NamedObjectPair out;
    out.pair.object_a = p.object_a();
    out.pair.object_b = p.object_b();
    out.pair.distance = p.distance();
    out.pair.triangle_a = p.triangle_a();
    out.pair.triangle_b = p.triangle_b();
    out.pair.point_a = decode_vec3(p.point_a());
    out.pair.point_b = decode_vec3(p.point_b());
    out.name_a = p.name_a();
    out.name_b = p.name_b();
    return out;
}

massive::Progress decode_progress(const pb::VerifyProgress& p) {
    return {p.step(), p.done(), p.total(), p.unit()};
}

RemoteVerifySummary decode_verify_summary(const pb::VerifyStats& s) {
    RemoteVerifySummary out;
    auto& st = out.stats;
    st.objects = s.objects();
    st.pieces = s.pieces();
    st.model_triangles = s.model_triangles();
    st.subgraphs = s.subgraphs();
    st.edges = s.edges();
    st.object_pairs = s.object_pairs();
    st.pairs_found = s.pairs_found();
    st.exact_tests = s.exact_tests();
    st.plan_seconds = s.plan_seconds();
    st.seconds = s.seconds();
    st.schedule_from_store = s.schedule_from_store();
    st.cache = decode_cache_stats(s.cache());
    out.server_seconds = s.server_seconds();
    return out;
}

void encode_review_join(const ReviewJoin& join, bool float32, pb::ReviewRequest* out) {
    auto* j = out->mutable_join();
    j->set_room(join.room);
    j->set_model(join.model);
    j->set_member(join.member);
    encode_mesh(join.avatar, float32, j->mutable_avatar());
    j->set_tolerance(join.tolerance);
    j->set_nearest(join.nearest);
}

namespace {

massive::AvatarHit decode_hit(const pb::AvatarHit& h, std::string* name) {
    massive::AvatarHit out;
    out.object = h.object();
    out.distance = h.distance();
    out.object_triangle = h.object_triangle();
    out.avatar_triangle = h.avatar_triangle();
    out.object_point = decode_vec3(h.object_point());
    out.avatar_point = decode_vec3(h.avatar_point());
    *name = h.object_name();
    return out;
}

ReviewPoseSummary decode_summary(const pb::PeerSummary& s) {
    ReviewPoseSummary out;
    out.collisions = s.collisions();
    out.within = s.within();
    out.has_nearest = s.has_nearest();
    out.nearest_object = s.nearest_object();
    out.nearest_name = s.nearest_name();
    out.nearest_distance = s.nearest_distance();
    return out;
}

}  // namespace

StatusOr<ReviewEvent> decode_review_event(const pb::ReviewEvent& event) {
    ReviewEvent out;
    switch (event.event_case()) {
        case pb::ReviewEvent::kJoined: {
            out.kind = ReviewEvent::Kind::joined;
            const auto& j = event.joined();
            out.joined.room = j.room();
            out.joined.model = j.model();
            out.joined.generation = j.generation();
            for (const auto& m : j.members()) {
                ReviewMemberInfo info;
                info.name = m.name();
                info.has_pose = m.has_pose();
                if (info.has_pose) {
                    info.sequence = m.sequence();
                    auto t = decode_transform(m.transform(), "joined member '" + m.name() + "'");
                    if (!t.ok()) {
                        return t.status();
                    }
                    info.transform = t.value();
                    info.summary = decode_summary(m.summary());
                }
                out.joined.members.push_back(std::move(info));
            }
            out.joined.model_version = j.model_version();
            out.joined.object_count = j.object_count();
            return out;
        }
        case pb::ReviewEvent::kResult: {
            out.kind = ReviewEvent::Kind::result;
            const auto& r = event.result();
            auto& o = out.result;
            o.sequence = r.sequence();
            for (const auto& h : r.collisions()) {
                o.result.collisions.push_back(decode_hit(h, &o.collision_names.emplace_back()));
            }
            for (const auto& h : r.within()) {
                o.result.within.push_back(decode_hit(h, &o.within_names.emplace_back()));
            }
            if (r.has_nearest()) {
                o.result.nearest = decode_hit(r.nearest(), &o.nearest_name);
            }
            o.result.candidate_pieces = r.stats().candidate_pieces();
            o.result.pieces_tested = r.stats().pieces_tested();
            o.result.exact_tests = r.stats().exact_tests();
            o.result.prefetch_hints = r.stats().prefetch_hints();
            o.result.seconds = r.stats().seconds();
            o.server_seconds = r.stats().server_seconds();
            o.model_version = r.model_version();
            return out;
        }
        case pb::ReviewEvent::kPeer: {
            out.kind = ReviewEvent::Kind::peer;
            const auto& p = event.peer();
            out.peer.member = p.member();
            out.peer.sequence = p.sequence();
            auto t = decode_transform(p.transform(), "peer '" + p.member() + "'");
            if (!t.ok()) {
                return t.status();
            }
            out.peer.transform = t.value();
            out.peer.summary = decode_summary(p.summary());
            out.peer.model_version = p.model_version();
            return out;
        }
        case pb::ReviewEvent::kEditApplied: {
            out.kind = ReviewEvent::Kind::edit_applied;
            const auto& e = event.edit_applied();
            out.edit.member = e.member();
            out.edit.sequence = e.sequence();
            switch (e.what()) {
                case pb::EDIT_MOVE:
                    out.edit.what = ReviewEditKind::move;
                    break;
                case pb::EDIT_ADD:
                    out.edit.what = ReviewEditKind::add;
                    break;
                case pb::EDIT_DELETE:
                    out.edit.what = ReviewEditKind::remove;
                    break;
                default:
                    return malformed_answer("edit_applied: unknown edit kind " +
                                            std::to_string(static_cast<int>(e.what())));
            }
            out.edit.object = e.object();
            out.edit.object_name = e.object_name();
            out.edit.model_version = e.model_version();
            return out;
        }
        case pb::ReviewEvent::kMemberJoined:
            out.kind = ReviewEvent::Kind::member_joined;
            out.member = event.member_joined().member();
            return out;
        case pb::ReviewEvent::kMemberLeft:
            out.kind = ReviewEvent::Kind::member_left;
            out.member = event.member_left().member();
            return out;
        default:
            return malformed_answer("an empty review event");
    }
}

}  // namespace proxima::client::detail
