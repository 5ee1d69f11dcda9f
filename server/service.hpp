#pragma once
// The proxima.v1.Proximity service on gRPC's callback API. Each method is a thin adapter: decode
// (proto/wire), call the engine through frames.hpp with the scene's mutex held, encode, map the
// status once (wire::to_grpc). Engine work runs on a WorkerPool, never on gRPC's callback
// threads; a call's deadline and cancellation reach the engine as a proxima::CancelToken.

#include <chrono>
#include <cstddef>
#include <memory>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "config.hpp"
#include "metrics.hpp"
#include "proxima/culling/dvd.hpp"
#include "proxima/status.hpp"
#include "proxima/v1/proxima.grpc.pb.h"

namespace proxima::server {

class ProximityService final : public v1::Proximity::CallbackService {
  public:
    explicit ProximityService(const ServerConfig& config);
    ~ProximityService() override;

    grpc::ServerUnaryReactor* GetServerInfo(grpc::CallbackServerContext* context,
                                            const v1::GetServerInfoRequest* request,
                                            v1::ServerInfo* response) override;
    grpc::ServerUnaryReactor* CreateScene(grpc::CallbackServerContext* context,
                                          const v1::CreateSceneRequest* request,
                                          v1::SceneInfo* response) override;
    grpc::ServerUnaryReactor* DescribeScene(grpc::CallbackServerContext* context,
                                            const v1::DescribeSceneRequest* request,
                                            v1::SceneInfo* response) override;
    grpc::ServerUnaryReactor* DeleteScene(grpc::CallbackServerContext* context,
                                          const v1::DeleteSceneRequest* request,
                                          v1::DeleteSceneResponse* response) override;
    grpc::ServerReadReactor<v1::UploadChunk>* UploadObject(grpc::CallbackServerContext* context,
                                                           v1::ObjectInfo* response) override;
    grpc::ServerBidiReactor<v1::Frame, v1::FrameResult>* StreamFrames(
        grpc::CallbackServerContext* context) override;
    grpc::ServerUnaryReactor* Query(grpc::CallbackServerContext* context, const v1::Frame* request,
                                    v1::FrameResult* response) override;
    // An offscreen PNG of a scene (scene_calls.cpp; proxima/render/snapshot.hpp renders it).
    grpc::ServerUnaryReactor* Snapshot(grpc::CallbackServerContext* context,
                                       const v1::SnapshotRequest* request,
                                       v1::SnapshotResponse* response) override;

    // Massive models, verification, review rooms and regions (model_calls.cpp,
    // verify_stream.cpp, review_stream.cpp, region_stream.cpp).
    grpc::ServerUnaryReactor* ListModels(grpc::CallbackServerContext* context,
                                         const v1::ListModelsRequest* request,
                                         v1::ListModelsResponse* response) override;
    grpc::ServerWriteReactor<v1::VerifyModelEvent>* VerifyModel(
        grpc::CallbackServerContext* context, const v1::VerifyModelRequest* request) override;
    grpc::ServerBidiReactor<v1::ReviewRequest, v1::ReviewEvent>* Review(
        grpc::CallbackServerContext* context) override;
    grpc::ServerWriteReactor<v1::RegionEvent>* FetchRegion(
        grpc::CallbackServerContext* context, const v1::FetchRegionRequest* request) override;

    // Before the server starts: reads the token file, starts the idle-scene expiry, opens the
    // models (start_models). The daemon refuses to start on an error.
    Status start();
    // Opens the models under --models (before the server starts): unavailable when the
    // directory cannot be listed. A store that cannot be opened is logged and skipped.
    Status start_models();
    // Serves the Prometheus endpoint on `address`; returns the address bound.
    StatusOr<std::string> start_metrics(const std::string& address);
    // The metrics as GET /metrics would return them (text format).
    std::string metrics_text() const;

    // The first step of a graceful shutdown: new calls are refused with UNAVAILABLE, idle
    // streams are finished with UNAVAILABLE now, busy ones once the frames they already read are
    // answered; unary calls and uploads in flight run to completion.
    void begin_drain();
    // Waits until no call is in flight, or until `deadline`; false if calls remain (the server's
    // Shutdown then cancels them, which stops their engine work).
    bool wait_idle(std::chrono::steady_clock::time_point deadline);

    std::size_t live_scenes() const;
    std::size_t live_streams() const;
    std::size_t live_calls() const;  // streams, uploads and unary calls in flight

    // What ServerInfo reports: the cullers this daemon can run, e.g.
    // "gpu (voronoi-gpu) + cpu (voronoi-cpu, bvh, brute)", and the GL renderer ("" without one).
    std::string proximity_backend() const;
    std::string gl_renderer() const;
    // The GPU backend now, for metrics: active or why not (lost while serving, or never started),
    // jobs and kernel seconds on the GPU and on the CPU in its place.
    dvd::BackendStats gpu_stats() const;

    struct Shared;  // state the reactors share; defined in service_internal.hpp

  private:
    void sample_metrics(std::vector<Sample>& out) const;

    std::unique_ptr<Shared> m_shared;
};

}  // namespace proxima::server
