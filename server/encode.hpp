#pragma once
// The daemon's own messages: what it says about its scenes, limits, quotas and models, from the
// server's types (config.hpp, auth.hpp, models.hpp). Every conversion between proto messages and
// engine types, in both directions, and the status mapping are proto/wire's (proxima::wire);
// the rest of server/ speaks engine types plus the message objects gRPC hands it.

#include <cstdint>
#include <string>

#include "auth.hpp"
#include "config.hpp"
#include "models.hpp"
#include "proxima/scene.hpp"
#include "proxima/v1/proxima.pb.h"

namespace proxima::server {

void encode_object(const SceneObject& object, v1::ObjectInfo* out);
void encode_scene(const std::string& scene_id, const std::string& name, const Scene& scene,
                  std::uint64_t frames, v1::SceneInfo* out);
void encode_limits(const Limits& limits, v1::Limits* out);
// A principal's quotas (0: unlimited).
void encode_quotas(const Quotas& quotas, v1::Quotas* out);
void encode_model(const ModelEntry& model, v1::ModelInfo* out);
void encode_unavailable_model(const UnavailableModel& model, v1::UnavailableModel* out);

}  // namespace proxima::server
