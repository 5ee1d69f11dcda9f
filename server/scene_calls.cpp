// The unary scene calls of ProximityService: CreateScene, DescribeScene, DeleteScene and Query
// (one frame, answered once; frames.hpp runs it), and Snapshot (an offscreen PNG of a scene).
#include <mutex>
#include <string>
#include <utility>

#include <spdlog/spdlog.h>

#include "encode.hpp"
#include "frames.hpp"
#include "proxima/render/snapshot.hpp"
#include "proxima/wire/buffers.hpp"
#include "proxima/wire/snapshot.hpp"
#include "region_snapshot.hpp"
#include "scene_registry.hpp"
#include "service.hpp"
#include "service_internal.hpp"

namespace proxima::server {

grpc::ServerUnaryReactor* ProximityService::CreateScene(grpc::CallbackServerContext* context,
                                                        const v1::CreateSceneRequest* request,
                                                        v1::SceneInfo* response) {
    auto* call = new UnaryCall(*m_shared, context, "CreateScene", "", request->ByteSizeLong());
    if (call->refused()) {
        return call;
    }
    m_shared->pool.submit([this, call, request, response] {
        std::string extra;
        Status s = guarded([&]() -> Status {
            auto& shared = *m_shared;
            const auto& principal = call->principal();
            if (!principal->may_create_scene(request->name())) {
                return {StatusCode::permission_denied,
                        "token '" + principal->name() + "' may not create a scene named '" +
                            request->name() + "' (no pattern of its scenes matches)"};
            }
            if (Status full = shared.scenes.check_capacity(); !full.ok()) {
                return full;
            }
            auto meshes = wire::decode_meshes(request->objects(), "objects");
            if (!meshes.ok()) {
                return meshes.status();
            }
            auto entry = shared.scenes.make_entry(request->name(), false, principal);
            call->set_scene(entry->id);
            auto added =
                add_objects(*entry, std::move(meshes).value(), shared.config.limits, "objects");
            if (!added.ok()) {
                return added.status();
            }
            {
                std::lock_guard lock(entry->mutex);
                encode_scene(entry->id, entry->name, entry->engine.scene(), entry->frames,
                             response);
            }
            extra = " objects=" + std::to_string(response->objects_size()) +
                    " triangles=" + std::to_string(response->triangle_count());
            return shared.scenes.insert(entry);
        });
        if (s.ok()) {
            spdlog::info("scene created method=CreateScene who={} scene={}{}",
                         call->principal()->log_name(), response->scene_id(), extra);
        }
        call->complete(s, extra);
    });
    return call;
}

grpc::ServerUnaryReactor* ProximityService::DescribeScene(grpc::CallbackServerContext* context,
                                                          const v1::DescribeSceneRequest* request,
                                                          v1::SceneInfo* response) {
    auto* call = new UnaryCall(*m_shared, context, "DescribeScene", request->scene_id());
    if (call->refused()) {
        return call;
    }
    // Off the callback thread: it waits for the scene's mutex while a frame runs.
    m_shared->pool.submit([this, call, request, response] {
        call->complete(guarded([&]() -> Status {
            auto entry = m_shared->scenes.find(request->scene_id(), *call->principal());
            if (!entry) {
                return unknown_scene(request->scene_id());
            }
            std::lock_guard lock(entry->mutex);
            encode_scene(entry->id, entry->name, entry->engine.scene(), entry->frames, response);
            return {};
        }));
    });
    return call;
}

grpc::ServerUnaryReactor* ProximityService::DeleteScene(grpc::CallbackServerContext* context,
                                                        const v1::DeleteSceneRequest* request,
                                                        v1::DeleteSceneResponse*) {
    auto* call = new UnaryCall(*m_shared, context, "DeleteScene", request->scene_id());
    if (call->refused()) {
        return call;
    }
    Status s;
    auto entry = m_shared->scenes.find(request->scene_id(), *call->principal());
    // Unknown, or deleted by someone else meanwhile: the same NOT_FOUND.
    if (entry && m_shared->scenes.erase(entry->id)) {
        spdlog::info("scene deleted method=DeleteScene who={} scene={}",
                     call->principal()->log_name(), entry->id);
    } else {
        s = unknown_scene(request->scene_id());
    }
    // Freeing a large engine takes a while: let a worker do it, not gRPC's callback thread. (A
    // frame still holding the scene frees it when it ends instead.)
    if (entry) {
        m_shared->pool.submit([doomed = std::move(entry)] {});
    }
    call->complete(s);
    return call;
}

grpc::ServerUnaryReactor* ProximityService::Query(grpc::CallbackServerContext* context,
                                                  const v1::Frame* request,
                                                  v1::FrameResult* response) {
    auto* call =
        new UnaryCall(*m_shared, context, "Query", request->scene_id(), request->ByteSizeLong());
    if (call->refused()) {
        return call;
    }
    m_shared->pool.submit([this, call, request, response] {
        call->complete(guarded([&]() -> Status {
            if (Status s = call->principal()->admit_frame(); !s.ok()) {
                return s;
            }
            auto entry = m_shared->scenes.find(request->scene_id(), *call->principal());
            if (!entry) {
                return unknown_scene(request->scene_id());
            }
            Status s =
                run_frame(*entry, *request, m_shared->config.limits, &call->cancel(), response);
            if (s.ok()) {
                m_shared->metrics.add_frames(1, response->stats().exact_tests());
            }
            return s;
        }));
    });
    return call;
}

grpc::ServerUnaryReactor* ProximityService::Snapshot(grpc::CallbackServerContext* context,
                                                     const v1::SnapshotRequest* request,
                                                     v1::SnapshotResponse* response) {
    auto* call = new UnaryCall(*m_shared, context, "Snapshot", request->scene_id());
    if (call->refused()) {
        return call;
    }
    // On a worker: it waits for the scene's mutex, runs the queries and renders. The renderer
    // serializes every snapshot of the process on its own EGL context (one at a time), apart
    // from the Voronoi culler's context thread.
    m_shared->pool.submit([this, call, request, response] {
        std::string extra;
        Status s = guarded([&]() -> Status {
            // Size, camera and tolerance first: a bad request is INVALID_ARGUMENT whatever the
            // scene.
            auto decoded = wire::decode_snapshot_request(*request);
            if (!decoded.ok()) {
                return decoded.status();
            }
            auto region = wire::decode_snapshot_region(*request);
            if (!region.ok()) {
                return region.status();
            }
            if (region->has_value()) {
                // A massive model's region, through the shared geometry cache (no scene mutex).
                return model_region_snapshot(*m_shared, *call->principal(), **region, *decoded,
                                             call->cancel(), response, &extra);
            }
            auto entry = m_shared->scenes.find(request->scene_id(), *call->principal());
            if (!entry) {
                return unknown_scene(request->scene_id());
            }
            std::lock_guard lock(entry->mutex);
            auto snapshot = render::take_snapshot(entry->engine, *decoded, &call->cancel());
            if (!snapshot.ok()) {
                return snapshot.status();
            }
            wire::encode_snapshot(*snapshot, response);
            extra = " width=" + std::to_string(snapshot->width) +
                    " height=" + std::to_string(snapshot->height) +
                    " png_bytes=" + std::to_string(snapshot->png.size());
            return {};
        });
        call->complete(s, extra);
    });
    return call;
}

}  // namespace proxima::server
