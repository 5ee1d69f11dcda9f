#include "convert.hpp"

#include <bit>
#include <cmath>
#include <cstring>
#include <utility>

namespace proxima::server {

// The wire format is little-endian; decoding by memcpy is only right on a little-endian host.
static_assert(std::endian::native == std::endian::little,
              "convert.cpp decodes packed little-endian buffers by memcpy");

namespace {

grpc::StatusCode grpc_code(StatusCode code) {
    switch (code) {
        case StatusCode::ok:
            return grpc::StatusCode::OK;
        case StatusCode::invalid_argument:
            return grpc::StatusCode::INVALID_ARGUMENT;
        case StatusCode::not_found:
            return grpc::StatusCode::NOT_FOUND;
        case StatusCode::failed_precondition:
            return grpc::StatusCode::FAILED_PRECONDITION;
        case StatusCode::resource_exhausted:
            return grpc::StatusCode::RESOURCE_EXHAUSTED;
        case StatusCode::cancelled:
            return grpc::StatusCode::CANCELLED;
        case StatusCode::deadline_exceeded:
            return grpc::StatusCode::DEADLINE_EXCEEDED;
        case StatusCode::unavailable:
            return grpc::StatusCode::UNAVAILABLE;
        case StatusCode::internal:
            return grpc::StatusCode::INTERNAL;
        case StatusCode::data_loss:
            return grpc::StatusCode::DATA_LOSS;
        case StatusCode::unauthenticated:
            return grpc::StatusCode::UNAUTHENTICATED;
        case StatusCode::permission_denied:
            return grpc::StatusCode::PERMISSION_DENIED;
    }
    return grpc::StatusCode::UNKNOWN;
}

}  // namespace

grpc::Status to_grpc_status(const Status& status) {
    if (status.ok()) {
        return grpc::Status::OK;
    }
    return {grpc_code(status.code()), status.message()};
}

std::size_t vertex_stride(v1::ScalarType type) {
    switch (type) {
        case v1::SCALAR_TYPE_FLOAT32:
            return 3 * sizeof(float);
        case v1::SCALAR_TYPE_FLOAT64:
            return 3 * sizeof(double);
        default:
            return 0;
    }
}

StatusOr<std::vector<Vec3>> decode_vertex_bytes(v1::ScalarType type, std::string_view bytes,
                                                const std::string& what) {
    const std::size_t stride = vertex_stride(type);
    if (stride == 0) {
        return invalid_argument(what +
                                ": vertex scalar type must be SCALAR_TYPE_FLOAT32 or "
                                "SCALAR_TYPE_FLOAT64, got " +
                                std::to_string(static_cast<int>(type)));
    }
    if (bytes.size() % stride != 0) {
        return invalid_argument(what + ": vertex buffer is " + std::to_string(bytes.size()) +
                                " bytes, not a multiple of " + std::to_string(stride) +
                                " (x, y, z as " + (stride == 12 ? "float32" : "float64") +
                                " per vertex)");
    }
    std::vector<Vec3> out(bytes.size() / stride);
    const char* p = bytes.data();
    if (type == v1::SCALAR_TYPE_FLOAT64) {
        static_assert(sizeof(Vec3) == 24);
        if (!bytes.empty()) {  // memcpy from/to null (an empty vector's data()) is undefined
            std::memcpy(out.data(), p, bytes.size());
        }
    } else {
        for (auto& v : out) {
            float xyz[3];
            std::memcpy(xyz, p, sizeof(xyz));
            p += sizeof(xyz);
            v = {xyz[0], xyz[1], xyz[2]};
        }
    }
    return out;
}

StatusOr<std::vector<Vec3>> decode_vertices(const v1::VertexBuffer& buffer,
                                            const std::string& what) {
    return decode_vertex_bytes(buffer.type(), buffer.data(), what);
}

StatusOr<std::vector<TriangleIndices>> decode_indices(std::string_view bytes,
                                                      const std::string& what) {
    constexpr std::size_t stride = sizeof(TriangleIndices);
    static_assert(stride == 12);
    if (bytes.size() % stride != 0) {
        return invalid_argument(what + ": index buffer is " + std::to_string(bytes.size()) +
                                " bytes, not a multiple of 12 (three uint32 per triangle)");
    }
    std::vector<TriangleIndices> out(bytes.size() / stride);
    if (!bytes.empty()) {  // memcpy from/to null (an empty vector's data()) is undefined
        std::memcpy(out.data(), bytes.data(), bytes.size());
    }
    return out;
}

StatusOr<NamedMesh> decode_mesh(const v1::Mesh& mesh, const std::string& what) {
    const std::string label = mesh.name().empty() ? what : what + " ('" + mesh.name() + "')";
    auto vertices = decode_vertices(mesh.vertices(), label);
    if (!vertices.ok()) {
        return vertices.status();
    }
    auto triangles = decode_indices(mesh.indices(), label);
    if (!triangles.ok()) {
        return triangles.status();
    }
    NamedMesh out;
    out.name = mesh.name();
    out.mesh.vertices = std::move(vertices).value();
    out.mesh.triangles = std::move(triangles).value();
    return out;
}

StatusOr<std::vector<NamedMesh>> decode_meshes(
    const google::protobuf::RepeatedPtrField<v1::Mesh>& meshes, const std::string& field) {
    std::vector<NamedMesh> out;
    out.reserve(static_cast<std::size_t>(meshes.size()));
    for (int i = 0; i < meshes.size(); ++i) {
        auto mesh = decode_mesh(meshes[i], field + "[" + std::to_string(i) + "]");
        if (!mesh.ok()) {
            return mesh.status();
        }
        out.push_back(std::move(mesh).value());
    }
    return out;
}

namespace {

StatusOr<CullerKind> decode_culler(v1::Culler culler) {
    switch (culler) {
        case v1::CULLER_AUTO:
            return CullerKind::automatic;
        case v1::CULLER_BRUTE:
            return CullerKind::brute;
        case v1::CULLER_BVH:
            return CullerKind::bvh;
        case v1::CULLER_VORONOI_CPU:
            return CullerKind::voronoi_cpu;
        case v1::CULLER_VORONOI_GPU:
            return CullerKind::voronoi_gpu;
        default:
            return invalid_argument(
                "queries.culler: unknown culler " + std::to_string(static_cast<int>(culler)) +
                " (CULLER_AUTO, CULLER_BRUTE, CULLER_BVH, CULLER_VORONOI_CPU or "
                "CULLER_VORONOI_GPU)");
    }
}

void encode_vec3(const Vec3& v, v1::Vec3* out) {
    out->set_x(v.x);
    out->set_y(v.y);
    out->set_z(v.z);
}

void encode_pairs(const std::vector<FeaturePair>& pairs,
                  google::protobuf::RepeatedPtrField<v1::FeaturePair>* out) {
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

}  // namespace

StatusOr<DecodedFrame> decode_frame(const v1::Frame& frame) {
    DecodedFrame out;
    auto& u = out.update;
    u.removals.assign(frame.removals().begin(), frame.removals().end());

    u.replacements.reserve(static_cast<std::size_t>(frame.topology_changes_size()));
    for (int i = 0; i < frame.topology_changes_size(); ++i) {
        const auto& change = frame.topology_changes(i);
        const std::string field = "topology_changes[" + std::to_string(i) + "] (object " +
                                  std::to_string(change.object_id()) + ")";
        auto fragments = decode_meshes(change.fragments(), field + " fragments");
        if (!fragments.ok()) {
            return fragments.status();
        }
        u.replacements.push_back({change.object_id(), std::move(fragments).value()});
    }

    u.positions.reserve(static_cast<std::size_t>(frame.positions_size()));
    for (int i = 0; i < frame.positions_size(); ++i) {
        const auto& p = frame.positions(i);
        auto vertices =
            decode_vertices(p.vertices(), "positions[" + std::to_string(i) + "] (object " +
                                              std::to_string(p.object_id()) + ")");
        if (!vertices.ok()) {
            return vertices.status();
        }
        u.positions.push_back({p.object_id(), std::move(vertices).value()});
    }

    auto additions = decode_meshes(frame.additions(), "additions");
    if (!additions.ok()) {
        return additions.status();
    }
    u.additions = std::move(additions).value();

    const auto& q = frame.queries();
    auto culler = decode_culler(q.culler());
    if (!culler.ok()) {
        return culler.status();
    }
    out.queries.separation = q.separation();
    out.queries.self = q.self();
    out.queries.collisions = q.collisions();
    out.queries.pns = q.pns();
    out.queries.culler = culler.value();
    if (q.has_tolerance()) {
        if (!std::isfinite(q.tolerance()) || q.tolerance() < 0.0) {
            return invalid_argument("queries.tolerance must be a finite distance >= 0, got " +
                                    std::to_string(q.tolerance()));
        }
        out.queries.tolerance = q.tolerance();
    }
    if (q.has_voronoi_cell()) {
        if (!std::isfinite(q.voronoi_cell()) || q.voronoi_cell() <= 0.0) {
            return invalid_argument("queries.voronoi_cell must be a finite size > 0, got " +
                                    std::to_string(q.voronoi_cell()));
        }
        out.queries.voronoi_cell = q.voronoi_cell();
    }
    out.self_points = q.self_points();
    out.ccd = q.ccd();
    out.penetration = q.penetration();
    out.queries.collisions = out.queries.collisions || out.penetration;
    if (q.has_ccd_min_distance()) {
        if (!std::isfinite(q.ccd_min_distance()) || q.ccd_min_distance() < 0.0) {
            return invalid_argument(
                "queries.ccd_min_distance must be a finite distance >= 0, got " +
                std::to_string(q.ccd_min_distance()));
        }
        out.ccd_request.elementary.min_distance = q.ccd_min_distance();
    }
    return out;
}

void encode_penetration(const Penetration& p, v1::Penetration* out) {
    out->set_object(p.object);
    out->set_other(p.other);
    encode_vec3(p.direction, out->mutable_direction());
    out->set_depth(p.depth);
    encode_vec3(p.vector, out->mutable_vector());
    out->mutable_triangles()->Add(p.triangles.begin(), p.triangles.end());
    out->mutable_other_triangles()->Add(p.other_triangles.begin(), p.other_triangles.end());
    out->set_triangle(p.triangle);
    out->set_other_triangle(p.other_triangle);
    out->set_isolated(p.isolated);
    out->set_closed(p.closed);
    out->set_normal_fallback(p.normal_fallback);
    out->set_sides_split(p.sides_split);
}

void encode_ccd_result(const ccd::CcdResult& result, v1::CcdResult* out) {
    out->mutable_pairs()->Reserve(static_cast<int>(result.pairs.size()));
    for (const auto& p : result.pairs) {
        auto* r = out->add_pairs();
        r->set_kind(p.kind == ccd::CcdKind::vertex_face ? v1::CCD_VERTEX_FACE : v1::CCD_EDGE_EDGE);
        r->set_object(p.object);
        r->set_primitive(p.primitive);
        r->set_other(p.other);
        r->set_other_primitive(p.other_primitive);
        r->set_toi(p.toi);
        r->set_capped(p.capped);
    }
    for (const auto& o : result.object_pairs) {
        auto* r = out->add_object_pairs();
        r->set_object(o.object);
        r->set_other(o.other);
        r->set_toi(o.toi);
        r->set_pair(static_cast<std::uint32_t>(o.pair));
    }
    if (result.earliest) {
        out->set_has_earliest(true);
        out->set_earliest(static_cast<std::uint32_t>(*result.earliest));
    }
    const auto& s = result.stats;
    out->set_candidate_pairs(s.candidate_pairs);
    out->set_elementary_tests(s.elementary_tests);
    out->set_capped_tests(s.capped_tests);
    out->set_brute_force_tests(s.brute_force_tests);
    out->set_object_pairs_tested(s.object_pairs_tested);
    out->set_broad_phase_seconds(s.broad_phase_seconds);
    out->set_narrow_phase_seconds(s.narrow_phase_seconds);
    out->set_total_seconds(s.total_seconds);
}

void encode_frame_result(const Scene& scene, const SceneUpdateResult& changes,
                         const QueryResult& result, bool self_points, v1::FrameResult* out) {
    out->mutable_object_ids()->Reserve(static_cast<int>(scene.size()));
    for (const auto& obj : scene.objects()) {
        out->add_object_ids(obj.id);
    }
    for (auto id : changes.added_ids) {
        out->add_added_ids(id);
    }
    for (const auto& ids : changes.fragment_ids) {
        auto* f = out->add_fragment_ids();
        for (auto id : ids) {
            f->add_ids(id);
        }
    }

    out->mutable_separation()->Reserve(static_cast<int>(result.separation.size()));
    for (const auto& s : result.separation) {
        auto* r = out->add_separation();
        r->set_distance(s.distance);
        if (s.other == NO_OBJECT) {
            continue;  // has_other false, distance +inf
        }
        r->set_has_other(true);
        r->set_other(static_cast<std::uint32_t>(s.other));
        r->set_triangle(s.triangle);
        r->set_other_triangle(s.other_triangle);
        encode_vec3(s.point, r->mutable_point());
        encode_vec3(s.other_point, r->mutable_other_point());
    }

    out->mutable_self()->Reserve(static_cast<int>(result.self.size()));
    for (const auto& per_object : result.self) {
        auto* r = out->add_self();
        r->mutable_closest()->Reserve(static_cast<int>(per_object.size()));
        r->mutable_distance()->Reserve(static_cast<int>(per_object.size()));
        if (self_points) {
            r->mutable_points()->Reserve(static_cast<int>(6 * per_object.size()));
        }
        for (const auto& d : per_object) {
            r->add_closest(d.closest);
            r->add_distance(d.distance);
            if (self_points) {
                for (const Vec3* p : {&d.point, &d.other_point}) {
                    r->add_points(p->x);
                    r->add_points(p->y);
                    r->add_points(p->z);
                }
            }
        }
    }

    encode_pairs(result.collisions, out->mutable_collisions());
    encode_pairs(result.tolerance, out->mutable_tolerance());
    encode_pairs(result.pns, out->mutable_pns());

    const auto& s = result.stats;
    auto* st = out->mutable_stats();
    st->set_culler(s.culler);
    st->set_prepare_seconds(s.prepare_seconds);
    st->set_broad_phase_seconds(s.broad_phase_seconds);
    st->set_separation_seconds(s.separation_seconds);
    st->set_self_seconds(s.self_seconds);
    st->set_collision_seconds(s.collision_seconds);
    st->set_tolerance_seconds(s.tolerance_seconds);
    st->set_total_seconds(s.total_seconds);
    st->set_exact_tests(s.exact_tests);
    st->set_brute_force_tests(s.brute_force_tests);
    st->set_object_pairs_tested(s.object_pairs_tested);
    st->set_pns_pairs(s.pns_pairs);
    st->set_voronoi_seconds(s.voronoi_seconds);
    st->set_dvd_seconds(s.dvd_seconds);
    st->set_dvd_samples(s.dvd_samples);
    st->set_dvd_cell(s.dvd_cell);
    st->set_voronoi_culled(s.voronoi_culled);
    st->set_dvd_epsilon(s.dvd_epsilon);
}

void encode_object(const SceneObject& object, v1::ObjectInfo* out) {
    out->set_id(object.id);
    out->set_name(object.name);
    out->set_vertex_count(static_cast<std::uint32_t>(object.vertices.size()));
    out->set_triangle_count(static_cast<std::uint32_t>(object.triangle_count()));
}

void encode_scene(const std::string& scene_id, const std::string& name, const Scene& scene,
                  std::uint64_t frames, v1::SceneInfo* out) {
    out->set_scene_id(scene_id);
    out->set_name(name);
    out->mutable_objects()->Reserve(static_cast<int>(scene.size()));
    for (const auto& obj : scene.objects()) {
        encode_object(obj, out->add_objects());
    }
    out->set_frames(frames);
    out->set_triangle_count(scene.triangle_count());
}

void encode_limits(const Limits& limits, v1::Limits* out) {
    out->set_max_scenes(limits.max_scenes);
    out->set_max_objects_per_scene(limits.max_objects_per_scene);
    out->set_max_triangles_per_scene(limits.max_triangles_per_scene);
    out->set_max_message_bytes(limits.max_message_bytes);
    out->set_max_frames_in_flight(limits.max_frames_in_flight);
}

void encode_quotas(const Quotas& quotas, v1::Quotas* out) {
    out->set_max_scenes(quotas.max_scenes);
    out->set_max_objects(quotas.max_objects);
    out->set_max_triangles(quotas.max_triangles);
    out->set_max_bytes_held(quotas.max_bytes_held);
    out->set_max_bytes_in_flight(quotas.max_bytes_in_flight);
    out->set_max_frames_per_second(quotas.max_frames_per_second);
    out->set_max_streams(quotas.max_streams);
}

// --- Massive models ----------------------------------------------------------------------------

StatusOr<massive::Affine> decode_transform(const v1::Transform& transform,
                                           const std::string& what) {
    massive::Affine out;
    if (transform.m_size() != 12) {
        return invalid_argument(what +
                                ": a transform is 12 numbers (row-major 3x4: a00 a01 a02 tx "
                                "a10 a11 a12 ty a20 a21 a22 tz), got " +
                                std::to_string(transform.m_size()));
    }
    for (int i = 0; i < 12; ++i) {
        if (!std::isfinite(transform.m(i))) {
            return invalid_argument(what + ": transform entry " + std::to_string(i) +
                                    " is not finite (NaN or Inf)");
        }
        out.m[static_cast<std::size_t>(i)] = transform.m(i);
    }
    return out;
}

void encode_transform(const massive::Affine& transform, v1::Transform* out) {
    out->mutable_m()->Reserve(12);
    for (double v : transform.m) {
        out->add_m(v);
    }
}

Status check_tolerance(double tolerance, const std::string& what) {
    if (!std::isfinite(tolerance) || tolerance < 0.0) {
        return invalid_argument(what + " must be a finite distance >= 0, got " +
                                std::to_string(tolerance));
    }
    return {};
}

void encode_cache_stats(const massive::CacheStats& s, v1::CacheStats* out) {
    out->set_budget_bytes(s.budget_bytes);
    out->set_resident_bytes(s.resident_bytes);
    out->set_peak_bytes(s.peak_bytes);
    out->set_loads(s.loads);
    out->set_triangles_loaded(s.triangles_loaded);
    out->set_bytes_loaded(s.bytes_loaded);
    out->set_hits(s.hits);
    out->set_misses(s.misses);
    out->set_waits(s.waits);
    out->set_evictions(s.evictions);
    out->set_prefetch_loads(s.prefetch_loads);
    out->set_blocked_seconds(s.blocked_seconds);
}

void encode_model(const ModelEntry& model, v1::ModelInfo* out) {
    const auto& s = model.store->summary();
    out->set_name(model.name);
    out->set_objects(s.objects);
    out->set_pieces(s.pieces);
    out->set_triangles(s.triangles);
    out->set_generation(s.generation);
    if (!model.box.empty()) {
        encode_vec3(model.box.lo, out->mutable_box()->mutable_lo());
        encode_vec3(model.box.hi, out->mutable_box()->mutable_hi());
    }
    out->set_vertices(s.vertices);
    out->set_split_objects(s.split_objects);
    out->set_chunks(s.chunks);
    out->set_bytes(s.bytes);
}

void encode_unavailable_model(const UnavailableModel& model, v1::UnavailableModel* out) {
    out->set_name(model.name);
    out->set_status(model.status.to_string());
}

void encode_progress(const massive::Progress& p, v1::VerifyProgress* out) {
    out->set_step(p.step);
    out->set_done(p.done);
    out->set_total(p.total);
    out->set_unit(p.unit);
}

void encode_object_pair(const massive::ObjectPairResult& p, const massive::Store& store,
                        v1::ObjectPairResult* out) {
    const auto& objects = store.objects();
    out->set_object_a(p.object_a);
    out->set_object_b(p.object_b);
    if (p.object_a < objects.size()) {
        out->set_name_a(objects[p.object_a].name);
    }
    if (p.object_b < objects.size()) {
        out->set_name_b(objects[p.object_b].name);
    }
    out->set_distance(p.distance);
    out->set_triangle_a(p.triangle_a);
    out->set_triangle_b(p.triangle_b);
    encode_vec3(p.point_a, out->mutable_point_a());
    encode_vec3(p.point_b, out->mutable_point_b());
}

void encode_verify_stats(const massive::VerifyStats& s, double server_seconds,
                         v1::VerifyStats* out) {
    out->set_objects(s.objects);
    out->set_pieces(s.pieces);
    out->set_model_triangles(s.model_triangles);
    out->set_subgraphs(s.subgraphs);
    out->set_edges(s.edges);
    out->set_object_pairs(s.object_pairs);
    out->set_pairs_found(s.pairs_found);
    out->set_exact_tests(s.exact_tests);
    out->set_plan_seconds(s.plan_seconds);
    out->set_seconds(s.seconds);
    out->set_schedule_from_store(s.schedule_from_store);
    encode_cache_stats(s.cache, out->mutable_cache());
    out->set_server_seconds(server_seconds);
}

StatusOr<ReviewRequest> decode_review_request(const v1::ReviewRequest& request) {
    switch (request.request_case()) {
        case v1::ReviewRequest::kJoin: {
            const auto& j = request.join();
            if (j.room().empty() || j.member().empty()) {
                return invalid_argument("join: room and member must be non-empty names");
            }
            if (!j.has_avatar()) {
                return invalid_argument("join: avatar (a Mesh) is required");
            }
            if (Status s = check_tolerance(j.tolerance(), "join.tolerance"); !s.ok()) {
                return s;
            }
            auto avatar = decode_mesh(j.avatar(), "join.avatar");
            if (!avatar.ok()) {
                return avatar.status();
            }
            ReviewJoinRequest out;
            out.room = j.room();
            out.model = j.model();
            out.member = j.member();
            out.avatar = std::move(avatar).value();
            out.tolerance = j.tolerance();
            out.nearest = j.nearest();
            return ReviewRequest(std::move(out));
        }
        case v1::ReviewRequest::kPose: {
            const auto& p = request.pose();
            const std::string what = "pose " + std::to_string(p.sequence());
            if (!p.has_transform()) {
                return invalid_argument(what + ": transform is required (12 numbers)");
            }
            auto t = decode_transform(p.transform(), what);
            if (!t.ok()) {
                return t.status();
            }
            return ReviewRequest(ReviewPoseRequest{p.sequence(), t.value()});
        }
        case v1::ReviewRequest::kEdit: {
            const auto& e = request.edit();
            const std::string what = "edit " + std::to_string(e.sequence());
            RoomEdit out;
            out.sequence = e.sequence();
            switch (e.edit_case()) {
                case v1::ReviewEdit::kMove: {
                    out.what = EditKind::move;
                    out.object = e.move().object();
                    auto t = decode_transform(e.move().transform(), what + " (move)");
                    if (!t.ok()) {
                        return t.status();
                    }
                    out.transform = t.value();
                    break;
                }
                case v1::ReviewEdit::kAdd: {
                    out.what = EditKind::add;
                    auto mesh = decode_mesh(e.add(), what + " (add)");
                    if (!mesh.ok()) {
                        return mesh.status();
                    }
                    out.added = std::move(mesh).value();
                    break;
                }
                case v1::ReviewEdit::kRemove:
                    out.what = EditKind::remove;
                    out.object = e.remove().object();
                    break;
                default:
                    return invalid_argument(what + ": empty edit (set move, add or remove)");
            }
            return ReviewRequest(std::move(out));
        }
        default:
            return invalid_argument("empty review request (set join, pose or edit)");
    }
}

namespace {

void encode_hit(const massive::AvatarHit& h, const std::string& name, v1::AvatarHit* out) {
    out->set_object(h.object);
    out->set_object_name(name);
    out->set_distance(h.distance);
    out->set_object_triangle(h.object_triangle);
    out->set_avatar_triangle(h.avatar_triangle);
    encode_vec3(h.object_point, out->mutable_object_point());
    encode_vec3(h.avatar_point, out->mutable_avatar_point());
}

void encode_summary(const PoseSummary& s, v1::PeerSummary* out) {
    out->set_collisions(s.collisions);
    out->set_within(s.within);
    out->set_has_nearest(s.has_nearest);
    if (s.has_nearest) {
        out->set_nearest_object(s.nearest_object);
        out->set_nearest_name(s.nearest_name);
        out->set_nearest_distance(s.nearest_distance);
    }
}

v1::EditKind edit_kind(EditKind k) {
    switch (k) {
        case EditKind::move:
            return v1::EDIT_MOVE;
        case EditKind::add:
            return v1::EDIT_ADD;
        case EditKind::remove:
            return v1::EDIT_DELETE;
    }
    return v1::EDIT_MOVE;
}

}  // namespace

void encode_room_event(const RoomEvent& event, v1::ReviewEvent* out) {
    if (const auto* e = std::get_if<JoinedEvent>(&event)) {
        auto* j = out->mutable_joined();
        j->set_room(e->room);
        j->set_model(e->model);
        j->set_generation(e->generation);
        for (const auto& [name, pose] : e->members) {
            auto* m = j->add_members();
            m->set_name(name);
            m->set_has_pose(pose.has_pose);
            if (pose.has_pose) {
                m->set_sequence(pose.sequence);
                encode_transform(pose.transform, m->mutable_transform());
                encode_summary(pose.summary, m->mutable_summary());
            }
        }
        j->set_model_version(e->model_version);
        j->set_object_count(e->object_count);
    } else if (const auto* e = std::get_if<PoseResult>(&event)) {
        auto* r = out->mutable_result();
        const auto& a = e->result;
        r->set_sequence(e->sequence);
        for (std::size_t i = 0; i < a.collisions.size(); ++i) {
            encode_hit(a.collisions[i],
                       i < e->collision_names.size() ? e->collision_names[i] : std::string(),
                       r->add_collisions());
        }
        for (std::size_t i = 0; i < a.within.size(); ++i) {
            encode_hit(a.within[i], i < e->within_names.size() ? e->within_names[i] : std::string(),
                       r->add_within());
        }
        if (a.nearest) {
            encode_hit(*a.nearest, e->nearest_name, r->mutable_nearest());
        }
        auto* st = r->mutable_stats();
        st->set_candidate_pieces(a.candidate_pieces);
        st->set_pieces_tested(a.pieces_tested);
        st->set_exact_tests(a.exact_tests);
        st->set_prefetch_hints(a.prefetch_hints);
        st->set_seconds(a.seconds);
        st->set_server_seconds(e->server_seconds);
        r->set_model_version(e->model_version);
    } else if (const auto* e = std::get_if<PeerEvent>(&event)) {
        auto* p = out->mutable_peer();
        p->set_member(e->member);
        p->set_sequence(e->pose.sequence);
        encode_transform(e->pose.transform, p->mutable_transform());
        encode_summary(e->pose.summary, p->mutable_summary());
        p->set_model_version(e->pose.model_version);
    } else if (const auto* e = std::get_if<EditEvent>(&event)) {
        auto* a = out->mutable_edit_applied();
        a->set_member(e->member);
        a->set_sequence(e->sequence);
        a->set_what(edit_kind(e->what));
        a->set_object(e->object);
        a->set_object_name(e->object_name);
        a->set_model_version(e->model_version);
    } else if (const auto* e = std::get_if<MemberJoinedEvent>(&event)) {
        out->mutable_member_joined()->set_member(e->member);
    } else if (const auto* e = std::get_if<MemberLeftEvent>(&event)) {
        out->mutable_member_left()->set_member(e->member);
    }
}

}  // namespace proxima::server
