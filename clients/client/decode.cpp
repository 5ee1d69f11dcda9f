#include "client/decode.hpp"

#include <utility>

#include "proxima/wire/buffers.hpp"
#include "proxima/wire/frames.hpp"
#include "proxima/wire/massive.hpp"

namespace proxima::client::detail {

RemoteServerInfo decode_server_info(const v1::ServerInfo& info) {
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

RemoteObject decode_object(const v1::ObjectInfo& info) {
    return {info.id(), info.name(), info.vertex_count(), info.triangle_count()};
}

RemoteScene decode_scene(const v1::SceneInfo& info) {
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

StatusOr<FrameResponse> decode_frame_response(const v1::FrameResult& result) {
    auto outcome = wire::decode_frame_result(result);
    if (!outcome.ok()) {
        return outcome.status();
    }
    auto& o = outcome.value();
    FrameResponse out;
    out.scene_id = result.scene_id();
    out.frame = result.frame();
    out.object_ids = std::move(o.object_ids);
    out.added_ids = std::move(o.added_ids);
    out.fragment_ids = std::move(o.fragment_ids);
    out.result = std::move(o.result);
    out.ccd = std::move(o.ccd);
    out.penetrations = std::move(o.penetrations);
    out.server_seconds = result.stats().server_seconds();
    return out;
}

RemoteModelList decode_model_list(const v1::ListModelsResponse& response) {
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
            r.box.lo = wire::decode_vec3(m.box().lo());
            r.box.hi = wire::decode_vec3(m.box().hi());
        }
        out.models.push_back(std::move(r));
    }
    for (const auto& u : response.unavailable()) {
        out.unavailable.emplace_back(u.name(), u.status());
    }
    out.cache_budget_bytes = response.cache_budget_bytes();
    out.cache = wire::decode_cache_stats(response.cache());
    return out;
}

NamedObjectPair decode_object_pair(const v1::ObjectPairResult& pair) {
    NamedObjectPair out;
    out.pair = wire::decode_object_pair(pair, &out.name_a, &out.name_b);
    return out;
}

RemoteVerifySummary decode_verify_summary(const v1::VerifyStats& stats) {
    RemoteVerifySummary out;
    out.stats = wire::decode_verify_stats(stats);
    out.server_seconds = stats.server_seconds();
    return out;
}

namespace {

ReviewEvent to_review_event(massive::RoomEvent& room_event) {
    ReviewEvent out;
    if (auto* e = std::get_if<massive::JoinedEvent>(&room_event)) {
        out.kind = ReviewEvent::Kind::joined;
        out.joined.room = std::move(e->room);
        out.joined.model = std::move(e->model);
        out.joined.generation = std::move(e->generation);
        for (auto& [name, pose] : e->members) {
            ReviewMemberInfo info;
            info.name = name;
            info.has_pose = pose.has_pose;
            info.sequence = pose.sequence;
            info.transform = pose.transform;
            info.summary = std::move(pose.summary);
            out.joined.members.push_back(std::move(info));
        }
        out.joined.model_version = e->model_version;
        out.joined.object_count = e->object_count;
    } else if (auto* r = std::get_if<massive::PoseResult>(&room_event)) {
        out.kind = ReviewEvent::Kind::result;
        out.result = std::move(*r);
    } else if (auto* p = std::get_if<massive::PeerEvent>(&room_event)) {
        out.kind = ReviewEvent::Kind::peer;
        out.peer.member = std::move(p->member);
        out.peer.sequence = p->pose.sequence;
        out.peer.transform = p->pose.transform;
        out.peer.summary = std::move(p->pose.summary);
        out.peer.model_version = p->pose.model_version;
    } else if (auto* a = std::get_if<massive::EditEvent>(&room_event)) {
        out.kind = ReviewEvent::Kind::edit_applied;
        out.edit = std::move(*a);
    } else if (auto* j = std::get_if<massive::MemberJoinedEvent>(&room_event)) {
        out.kind = ReviewEvent::Kind::member_joined;
        out.member = std::move(j->member);
    } else if (auto* l = std::get_if<massive::MemberLeftEvent>(&room_event)) {
        out.kind = ReviewEvent::Kind::member_left;
        out.member = std::move(l->member);
    }
    return out;
}

}  // namespace

StatusOr<ReviewEvent> decode_review_event(const v1::ReviewEvent& event) {
    auto decoded = wire::decode_room_event(event);
    if (!decoded.ok()) {
        return decoded.status();
    }
    return to_review_event(decoded.value());
}

StatusOr<std::vector<ReviewEvent>> decode_review_events(const v1::ReviewEvent& event) {
    auto decoded = wire::decode_room_events(event);
    if (!decoded.ok()) {
        return decoded.status();
    }
    std::vector<ReviewEvent> out;
    out.reserve(decoded->size());
    for (auto& e : *decoded) {
        out.push_back(to_review_event(e));
    }
    return out;
}

}  // namespace proxima::client::detail
