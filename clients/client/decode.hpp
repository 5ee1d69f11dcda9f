#pragma once
// The client's own answer types (Remote*, FrameResponse, ReviewEvent, ...) assembled from the
// daemon's messages. Every conversion between proto messages and engine types, in both
// directions, and the status mapping are proto/wire's (proxima::wire); what is left here is the
// client-side shape of the answers. Private to proxima_client: the public header stays free of
// gRPC and Protobuf.

#include "client/proxima_client.hpp"
#include "proxima/v1/proxima.pb.h"

namespace proxima::client::detail {

RemoteServerInfo decode_server_info(const v1::ServerInfo& info);
RemoteObject decode_object(const v1::ObjectInfo& info);
RemoteScene decode_scene(const v1::SceneInfo& info);
// A FrameResult (checked by wire::decode_frame_result: a malformed one is internal).
StatusOr<FrameResponse> decode_frame_response(const v1::FrameResult& result);

RemoteModelList decode_model_list(const v1::ListModelsResponse& response);
NamedObjectPair decode_object_pair(const v1::ObjectPairResult& pair);
RemoteVerifySummary decode_verify_summary(const v1::VerifyStats& stats);
StatusOr<ReviewEvent> decode_review_event(const v1::ReviewEvent& event);
// Every event of a message: the one, or each update of a `peers` batch, in order.
StatusOr<std::vector<ReviewEvent>> decode_review_events(const v1::ReviewEvent& event);

}  // namespace proxima::client::detail
