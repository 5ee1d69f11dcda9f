#include "proxima/wire/massive.hpp"

#include <cmath>
#include <utility>
#include <variant>

#include "proxima/wire/buffers.hpp"

namespace proxima::wire {

namespace {

Status malformed_answer(const std::string& what) {
    return {StatusCode::internal, "malformed answer from the server: " + what};
}

}  // namespace

void encode_transform(const massive::Affine& transform, v1::Transform* out) {
    out->mutable_m()->Reserve(12);
    for (double v : transform.m) {
        out->add_m(v);
    }
}

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

massive::CacheStats decode_cache_stats(const v1::CacheStats& s) {
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

void encode_progress(const massive::Progress& p, v1::VerifyProgress* out) {
    out->set_step(p.step);
    out->set_done(p.done);
    out->set_total(p.total);
    out->set_unit(p.unit);
}

massive::Progress decode_progress(const v1::VerifyProgress& p) {
    return {p.step(), p.done(), p.total(), p.unit()};
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

massive::ObjectPairResult decode_object_pair(const v1::ObjectPairResult& p, std::string* name_a,
                                             std::string* name_b) {
    massive::ObjectPairResult out;
    out.object_a = p.object_a();
    out.object_b = p.object_b();
    out.distance = p.distance();
    out.triangle_a = p.triangle_a();
    out.triangle_b = p.triangle_b();
    out.point_a = decode_vec3(p.point_a());
    out.point_b = decode_vec3(p.point_b());
    *name_a = p.name_a();
    *name_b = p.name_b();
    return out;
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

massive::VerifyStats decode_verify_stats(const v1::VerifyStats& s) {
    massive::VerifyStats st;
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
    return st;
}

// --- Review: requests --------------------------------------------------------------------------

void encode_review_join(const massive::ReviewJoinRequest& join, bool float32,
                        v1::ReviewRequest* out) {
    auto* j = out->mutable_join();
    j->set_room(join.room);
    j->set_model(join.model);
    j->set_member(join.member);
    encode_mesh(join.avatar, float32, j->mutable_avatar());
    j->set_tolerance(join.tolerance);
    j->set_nearest(join.nearest);
}

void encode_review_pose(const massive::ReviewPoseRequest& pose, v1::ReviewRequest* out) {
    out->mutable_pose()->set_sequence(pose.sequence);
    encode_transform(pose.transform, out->mutable_pose()->mutable_transform());
}

void encode_review_edit(const massive::ReviewEditRequest& edit, bool float32,
                        v1::ReviewRequest* out) {
    auto* e = out->mutable_edit();
    e->set_sequence(edit.sequence);
    switch (edit.what) {
        case massive::EditKind::move:
            e->mutable_move()->set_object(edit.object);
            encode_transform(edit.transform, e->mutable_move()->mutable_transform());
            break;
        case massive::EditKind::add:
            encode_mesh(edit.added, float32, e->mutable_add());
            break;
        case massive::EditKind::remove:
            e->mutable_remove()->set_object(edit.object);
            break;
    }
}

StatusOr<massive::ReviewRequest> decode_review_request(const v1::ReviewRequest& request) {
    using massive::EditKind;
    using massive::ReviewRequest;
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
            massive::ReviewJoinRequest out;
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
            return ReviewRequest(massive::ReviewPoseRequest{p.sequence(), t.value()});
        }
        case v1::ReviewRequest::kEdit: {
            const auto& e = request.edit();
            const std::string what = "edit " + std::to_string(e.sequence());
            massive::ReviewEditRequest out;
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

// --- Review: room events -----------------------------------------------------------------------

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

massive::AvatarHit decode_hit(const v1::AvatarHit& h, std::string* name) {
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

void encode_summary(const massive::PoseSummary& s, v1::PeerSummary* out) {
    out->set_collisions(s.collisions);
    out->set_within(s.within);
    out->set_has_nearest(s.has_nearest);
    if (s.has_nearest) {
        out->set_nearest_object(s.nearest_object);
        out->set_nearest_name(s.nearest_name);
        out->set_nearest_distance(s.nearest_distance);
    }
}

massive::PoseSummary decode_summary(const v1::PeerSummary& s) {
    massive::PoseSummary out;
    out.collisions = s.collisions();
    out.within = s.within();
    out.has_nearest = s.has_nearest();
    out.nearest_object = s.nearest_object();
    out.nearest_name = s.nearest_name();
    out.nearest_distance = s.nearest_distance();
    return out;
}

v1::EditKind encode_edit_kind(massive::EditKind k) {
    switch (k) {
        case massive::EditKind::move:
            return v1::EDIT_MOVE;
        case massive::EditKind::add:
            return v1::EDIT_ADD;
        case massive::EditKind::remove:
            return v1::EDIT_DELETE;
    }
    return v1::EDIT_MOVE;
}

// A pose the daemon sends (its transform was checked when it arrived): a bad one is the
// daemon's fault.
Status decode_pose(std::uint64_t sequence, const v1::Transform& transform,
                   const v1::PeerSummary& summary, const std::string& what,
                   massive::MemberPose* out) {
    auto t = decode_transform(transform, what);
    if (!t.ok()) {
        return malformed_answer(t.status().message());
    }
    out->has_pose = true;
    out->sequence = sequence;
    out->transform = t.value();
    out->summary = decode_summary(summary);
    return {};
}

void encode_peer(const massive::PeerEvent& e, v1::PeerUpdate* p) {
    p->set_member(e.member);
    p->set_sequence(e.pose.sequence);
    encode_transform(e.pose.transform, p->mutable_transform());
    encode_summary(e.pose.summary, p->mutable_summary());
    p->set_model_version(e.pose.model_version);
}

StatusOr<massive::PeerEvent> decode_peer(const v1::PeerUpdate& p) {
    massive::PeerEvent out;
    out.member = p.member();
    if (Status s = decode_pose(p.sequence(), p.transform(), p.summary(),
                               "peer '" + p.member() + "'", &out.pose);
        !s.ok()) {
        return s;
    }
    out.pose.model_version = p.model_version();
    return out;
}

}  // namespace

void encode_peer_updates(std::span<const massive::PeerEvent> peers, v1::ReviewEvent* out) {
    if (peers.size() == 1) {
        encode_peer(peers[0], out->mutable_peer());
        return;
    }
    auto* batch = out->mutable_peers();
    batch->mutable_updates()->Reserve(static_cast<int>(peers.size()));
    for (const auto& p : peers) {
        encode_peer(p, batch->add_updates());
    }
}

void encode_room_event(const massive::RoomEvent& event, v1::ReviewEvent* out) {
    if (const auto* e = std::get_if<massive::JoinedEvent>(&event)) {
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
    } else if (const auto* e = std::get_if<massive::PoseResult>(&event)) {
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
    } else if (const auto* e = std::get_if<massive::PeerEvent>(&event)) {
        encode_peer(*e, out->mutable_peer());
    } else if (const auto* e = std::get_if<massive::EditEvent>(&event)) {
        auto* a = out->mutable_edit_applied();
        a->set_member(e->member);
        a->set_sequence(e->sequence);
        a->set_what(encode_edit_kind(e->what));
        a->set_object(e->object);
        a->set_object_name(e->object_name);
        a->set_model_version(e->model_version);
        if (e->what == massive::EditKind::move) {
            encode_transform(e->transform, a->mutable_transform());
        }
    } else if (const auto* e = std::get_if<massive::MemberJoinedEvent>(&event)) {
        out->mutable_member_joined()->set_member(e->member);
    } else if (const auto* e = std::get_if<massive::MemberLeftEvent>(&event)) {
        out->mutable_member_left()->set_member(e->member);
    }
}

StatusOr<massive::RoomEvent> decode_room_event(const v1::ReviewEvent& event) {
    switch (event.event_case()) {
        case v1::ReviewEvent::kJoined: {
            const auto& j = event.joined();
            massive::JoinedEvent out;
            out.room = j.room();
            out.model = j.model();
            out.generation = j.generation();
            for (const auto& m : j.members()) {
                massive::MemberPose pose;
                if (m.has_pose()) {
                    if (Status s = decode_pose(m.sequence(), m.transform(), m.summary(),
                                               "joined member '" + m.name() + "'", &pose);
                        !s.ok()) {
                        return s;
                    }
                }
                out.members.emplace_back(m.name(), std::move(pose));
            }
            out.model_version = j.model_version();
            out.object_count = j.object_count();
            return massive::RoomEvent(std::move(out));
        }
        case v1::ReviewEvent::kResult: {
            const auto& r = event.result();
            massive::PoseResult o;
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
            return massive::RoomEvent(std::move(o));
        }
        case v1::ReviewEvent::kPeer: {
            auto peer = decode_peer(event.peer());
            if (!peer.ok()) {
                return peer.status();
            }
            return massive::RoomEvent(std::move(peer).value());
        }
        case v1::ReviewEvent::kPeers:
            return malformed_answer("a batch of " + std::to_string(event.peers().updates_size()) +
                                    " peer updates where one event was expected");
        case v1::ReviewEvent::kEditApplied: {
            const auto& e = event.edit_applied();
            massive::EditEvent out;
            out.member = e.member();
            out.sequence = e.sequence();
            switch (e.what()) {
                case v1::EDIT_MOVE:
                    out.what = massive::EditKind::move;
                    break;
                case v1::EDIT_ADD:
                    out.what = massive::EditKind::add;
                    break;
                case v1::EDIT_DELETE:
                    out.what = massive::EditKind::remove;
                    break;
                default:
                    return malformed_answer("edit_applied: unknown edit kind " +
                                            std::to_string(static_cast<int>(e.what())));
            }
            out.object = e.object();
            out.object_name = e.object_name();
            out.model_version = e.model_version();
            if (e.has_transform()) {
                auto transform = decode_transform(e.transform(), "edit_applied.transform");
                if (!transform.ok()) {
                    return malformed_answer(transform.status().message());
                }
                out.transform = transform.value();
            }
            return massive::RoomEvent(std::move(out));
        }
        case v1::ReviewEvent::kMemberJoined:
            return massive::RoomEvent(massive::MemberJoinedEvent{event.member_joined().member()});
        case v1::ReviewEvent::kMemberLeft:
            return massive::RoomEvent(massive::MemberLeftEvent{event.member_left().member()});
        default:
            return malformed_answer("an empty review event");
    }
}

StatusOr<std::vector<massive::RoomEvent>> decode_room_events(const v1::ReviewEvent& event) {
    std::vector<massive::RoomEvent> out;
    if (event.event_case() != v1::ReviewEvent::kPeers) {
        auto one = decode_room_event(event);
        if (!one.ok()) {
            return one.status();
        }
        out.push_back(std::move(one).value());
        return out;
    }
    if (event.peers().updates().empty()) {
        return malformed_answer("an empty batch of peer updates");
    }
    out.reserve(static_cast<std::size_t>(event.peers().updates_size()));
    for (const auto& p : event.peers().updates()) {
        auto peer = decode_peer(p);
        if (!peer.ok()) {
            return peer.status();
        }
        out.emplace_back(std::move(peer).value());
    }
    return out;
}

// --- FetchRegion ---------------------------------------------------------------------------

namespace {

void encode_aabb(const Aabb& box, v1::Aabb* out) {
    encode_vec3(box.lo, out->mutable_lo());
    encode_vec3(box.hi, out->mutable_hi());
}

Aabb decode_aabb(const v1::Aabb& box) {
    Aabb out;
    out.lo = decode_vec3(box.lo());
    out.hi = decode_vec3(box.hi());
    return out;
}

}  // namespace

void encode_region_request(const massive::RegionRequest& r, v1::FetchRegionRequest* out) {
    out->set_model(r.model);
    encode_vec3(r.center, out->mutable_center());
    out->set_radius(r.radius);
    out->set_room(r.room);
    out->mutable_objects()->Reserve(static_cast<int>(r.objects.size()));
    for (auto o : r.objects) {
        out->add_objects(o);
    }
    out->set_max_triangles(r.max_triangles);
    out->set_type(scalar_type(!r.float64));
}

StatusOr<massive::RegionRequest> decode_region_request(const v1::FetchRegionRequest& r) {
    massive::RegionRequest out;
    switch (r.type()) {
        case v1::SCALAR_TYPE_UNSPECIFIED:
        case v1::SCALAR_TYPE_FLOAT32:
            out.float64 = false;
            break;
        case v1::SCALAR_TYPE_FLOAT64:
            out.float64 = true;
            break;
        default:
            return invalid_argument("type: unknown scalar type " +
                                    std::to_string(static_cast<int>(r.type())) +
                                    " (FLOAT32 or FLOAT64)");
    }
    out.model = r.model();
    out.center = decode_vec3(r.center());
    out.radius = r.radius();
    out.room = r.room();
    out.objects.assign(r.objects().begin(), r.objects().end());
    out.max_triangles = r.max_triangles();
    return out;
}

void encode_region_event(const massive::RegionEvent& event, bool float32, v1::RegionEvent* out) {
    if (const auto* p = std::get_if<massive::RegionPiece>(&event)) {
        auto* piece = out->mutable_piece();
        piece->set_object(p->object);
        piece->set_object_name(p->object_name);
        auto* mesh = piece->mutable_mesh();
        mesh->set_name(p->object_name);
        mesh->mutable_vertices()->set_type(scalar_type(float32));
        mesh->mutable_vertices()->set_data(pack_vertices(p->vertices, float32));
        mesh->set_indices(pack_triangles(p->triangles));
        piece->mutable_triangle_ids()->Add(p->triangle_ids.begin(), p->triangle_ids.end());
        encode_aabb(p->box, piece->mutable_box());
        piece->set_distance(p->distance);
    } else if (const auto* g = std::get_if<massive::RegionProgress>(&event)) {
        auto* progress = out->mutable_progress();
        progress->set_pieces_sent(g->pieces_sent);
        progress->set_pieces_total(g->pieces_total);
        progress->set_triangles_sent(g->triangles_sent);
        progress->set_triangles_total(g->triangles_total);
    } else if (const auto* s = std::get_if<massive::RegionSummary>(&event)) {
        auto* summary = out->mutable_summary();
        summary->set_pieces(s->pieces);
        summary->set_triangles(s->triangles);
        summary->set_truncated(s->truncated);
        summary->set_model_version(s->model_version);
        summary->set_generation(s->generation);
        summary->set_server_seconds(s->server_seconds);
    }
}

StatusOr<massive::RegionEvent> decode_region_event(const v1::RegionEvent& event) {
    switch (event.event_case()) {
        case v1::RegionEvent::kPiece: {
            const auto& p = event.piece();
            massive::RegionPiece out;
            out.object = p.object();
            out.object_name = p.object_name();
            auto vertices = decode_vertices(p.mesh().vertices(), "piece.mesh");
            if (!vertices.ok()) {
                return malformed_answer(vertices.status().message());
            }
            auto triangles = decode_indices(p.mesh().indices(), "piece.mesh");
            if (!triangles.ok()) {
                return malformed_answer(triangles.status().message());
            }
            out.vertices = std::move(vertices).value();
            out.triangles = std::move(triangles).value();
            if (static_cast<std::size_t>(p.triangle_ids_size()) != out.triangles.size()) {
                return malformed_answer("piece of object " + std::to_string(p.object()) + ": " +
                                        std::to_string(p.triangle_ids_size()) +
                                        " triangle_ids for " +
                                        std::to_string(out.triangles.size()) + " triangles");
            }
            out.triangle_ids.assign(p.triangle_ids().begin(), p.triangle_ids().end());
            out.box = decode_aabb(p.box());
            out.distance = p.distance();
            return massive::RegionEvent(std::move(out));
        }
        case v1::RegionEvent::kProgress: {
            const auto& g = event.progress();
            return massive::RegionEvent(massive::RegionProgress{
                g.pieces_sent(), g.pieces_total(), g.triangles_sent(), g.triangles_total()});
        }
        case v1::RegionEvent::kSummary: {
            const auto& s = event.summary();
            massive::RegionSummary out;
            out.pieces = s.pieces();
            out.triangles = s.triangles();
            out.truncated = s.truncated();
            out.model_version = s.model_version();
            out.generation = s.generation();
            out.server_seconds = s.server_seconds();
            return massive::RegionEvent(std::move(out));
        }
        default:
            return malformed_answer("an empty region event");
    }
}

}  // namespace proxima::wire
