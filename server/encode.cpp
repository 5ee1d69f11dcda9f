#include "encode.hpp"

#include "proxima/wire/buffers.hpp"

namespace proxima::server {

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

void encode_model(const ModelEntry& model, v1::ModelInfo* out) {
    const auto& s = model.store->summary();
    out->set_name(model.name);
    out->set_objects(s.objects);
    out->set_pieces(s.pieces);
    out->set_triangles(s.triangles);
    out->set_generation(s.generation);
    if (!model.box.empty()) {
        wire::encode_vec3(model.box.lo, out->mutable_box()->mutable_lo());
        wire::encode_vec3(model.box.hi, out->mutable_box()->mutable_hi());
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

}  // namespace proxima::server
