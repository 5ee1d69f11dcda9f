#include "proxima/wire/frames.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include "proxima/wire/buffers.hpp"

namespace proxima::wire {

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

v1::Culler encode_culler(CullerKind culler) {
    switch (culler) {
        case CullerKind::automatic:
            return v1::CULLER_AUTO;
        case CullerKind::brute:
            return v1::CULLER_BRUTE;
        case CullerKind::bvh:
            return v1::CULLER_BVH;
        case CullerKind::voronoi_cpu:
            return v1::CULLER_VORONOI_CPU;
        case CullerKind::voronoi_gpu:
            return v1::CULLER_VORONOI_GPU;
    }
    return v1::CULLER_AUTO;
}

Status malformed(const std::string& what) {
    return {StatusCode::internal, "malformed FrameResult from the server: " + what};
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

Status decode_pairs(const google::protobuf::RepeatedPtrField<v1::FeaturePair>& pairs,
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

void encode_stats(const QueryStats& s, v1::Stats* st) {
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

QueryStats decode_stats(const v1::Stats& s) {
    QueryStats q;
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
    return q;
}

}  // namespace

// --- Requests ----------------------------------------------------------------------------------

void encode_query(const QueryRequest& request, bool self_points, v1::QuerySpec* out) {
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
    out->set_culler(encode_culler(request.culler));
    out->set_self_points(self_points);
}

Status decode_queries(const v1::QuerySpec& q, FrameRequest* out) {
    auto culler = decode_culler(q.culler());
    if (!culler.ok()) {
        return culler.status();
    }
    out->queries.separation = q.separation();
    out->queries.self = q.self();
    out->queries.collisions = q.collisions();
    out->queries.pns = q.pns();
    out->queries.culler = culler.value();
    if (q.has_tolerance()) {
        if (Status s = check_tolerance(q.tolerance(), "queries.tolerance"); !s.ok()) {
            return s;
        }
        out->queries.tolerance = q.tolerance();
    }
    if (q.has_voronoi_cell()) {
        if (!std::isfinite(q.voronoi_cell()) || q.voronoi_cell() <= 0.0) {
            return invalid_argument("queries.voronoi_cell must be a finite size > 0, got " +
                                    std::to_string(q.voronoi_cell()));
        }
        out->queries.voronoi_cell = q.voronoi_cell();
    }
    out->self_points = q.self_points();
    out->ccd = q.ccd();
    out->penetration = q.penetration();
    out->queries.collisions = out->queries.collisions || out->penetration;
    if (q.has_ccd_min_distance()) {
        if (Status s = check_tolerance(q.ccd_min_distance(), "queries.ccd_min_distance"); !s.ok()) {
            return s;
        }
        out->ccd_request.elementary.min_distance = q.ccd_min_distance();
    }
    return {};
}

void encode_frame(const FrameRequest& frame, const std::string& scene_id, bool float32,
                  v1::Frame* out) {
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

StatusOr<FrameRequest> decode_frame(const v1::Frame& frame) {
    FrameRequest out;
    out.frame = frame.frame();
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

    if (Status s = decode_queries(frame.queries(), &out); !s.ok()) {
        return s;
    }
    return out;
}

// --- Results -----------------------------------------------------------------------------------

namespace {

void encode_ids(const std::vector<ObjectId>& added_ids,
                const std::vector<std::vector<ObjectId>>& fragment_ids, v1::FrameResult* out) {
    for (auto id : added_ids) {
        out->add_added_ids(id);
    }
    for (const auto& ids : fragment_ids) {
        auto* f = out->add_fragment_ids();
        for (auto id : ids) {
            f->add_ids(id);
        }
    }
}

void encode_query_result(const QueryResult& result, bool self_points, v1::FrameResult* out);

}  // namespace

void encode_frame_result(const Scene& scene, const SceneUpdateResult& changes,
                         const QueryResult& result, bool self_points, v1::FrameResult* out) {
    out->mutable_object_ids()->Reserve(static_cast<int>(scene.size()));
    for (const auto& obj : scene.objects()) {
        out->add_object_ids(obj.id);
    }
    encode_ids(changes.added_ids, changes.fragment_ids, out);
    encode_query_result(result, self_points, out);
}

void encode_frame_outcome(const FrameOutcome& outcome, bool self_points, v1::FrameResult* out) {
    out->mutable_object_ids()->Add(outcome.object_ids.begin(), outcome.object_ids.end());
    encode_ids(outcome.added_ids, outcome.fragment_ids, out);
    encode_query_result(outcome.result, self_points, out);
    for (const auto& p : outcome.penetrations) {
        encode_penetration(p, out->add_penetrations());
    }
    if (outcome.ccd) {
        encode_ccd_result(*outcome.ccd, out->mutable_ccd());
    }
}

namespace {

void encode_query_result(const QueryResult& result, bool self_points, v1::FrameResult* out) {
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
    encode_stats(result.stats, out->mutable_stats());
}

}  // namespace

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

Penetration decode_penetration(const v1::Penetration& p) {
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
    return e;
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
        for (std::size_t k = 0; k < ccd::vertex_count(p.kind); ++k) {
            r->add_vertices(p.vertices[k]);
        }
        for (std::size_t k = 0; k < ccd::other_vertex_count(p.kind); ++k) {
            r->add_other_vertices(p.other_vertices[k]);
        }
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

StatusOr<ccd::CcdResult> decode_ccd_result(const v1::CcdResult& in, std::size_t objects) {
    ccd::CcdResult out;
    out.pairs.reserve(static_cast<std::size_t>(in.pairs_size()));
    for (const auto& p : in.pairs()) {
        if (p.object() >= objects || p.other() >= objects) {
            return malformed("CCD pair names objects " + std::to_string(p.object()) + " and " +
                             std::to_string(p.other()) + " of " + std::to_string(objects));
        }
        ccd::CcdPair e;
        e.kind =
            p.kind() == v1::CCD_EDGE_EDGE ? ccd::CcdKind::edge_edge : ccd::CcdKind::vertex_face;
        e.object = p.object();
        e.primitive = p.primitive();
        e.other = p.other();
        e.other_primitive = p.other_primitive();
        e.toi = p.toi();
        e.capped = p.capped();
        if (static_cast<std::size_t>(p.vertices_size()) != ccd::vertex_count(e.kind) ||
            static_cast<std::size_t>(p.other_vertices_size()) != ccd::other_vertex_count(e.kind)) {
            return malformed("CCD pair " + std::to_string(out.pairs.size()) + " names " +
                             std::to_string(p.vertices_size()) + " and " +
                             std::to_string(p.other_vertices_size()) + " vertices (" +
                             std::string(ccd::ccd_kind_name(e.kind)) + " needs " +
                             std::to_string(ccd::vertex_count(e.kind)) + " and " +
                             std::to_string(ccd::other_vertex_count(e.kind)) + ")");
        }
        for (int k = 0; k < p.vertices_size(); ++k) {
            e.vertices[static_cast<std::size_t>(k)] = p.vertices(k);
        }
        for (int k = 0; k < p.other_vertices_size(); ++k) {
            e.other_vertices[static_cast<std::size_t>(k)] = p.other_vertices(k);
        }
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

StatusOr<FrameOutcome> decode_frame_result(const v1::FrameResult& result) {
    FrameOutcome out;
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
        out.penetrations.push_back(decode_penetration(p));
    }
    if (result.has_ccd()) {
        auto ccd = decode_ccd_result(result.ccd(), n);
        if (!ccd.ok()) {
            return ccd.status();
        }
        out.ccd = std::move(ccd).value();
    }
    r.stats = decode_stats(result.stats());
    return out;
}

}  // namespace proxima::wire
