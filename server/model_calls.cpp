// ListModels: the massive models (seed 001) a token may use, and the shared cache. Models and
// the cache are in models.hpp; the model conversions in proto/wire (massive.hpp).
#include <string>

#include <spdlog/spdlog.h>

#include "encode.hpp"
#include "proxima/wire/massive.hpp"
#include "service.hpp"
#include "service_internal.hpp"

namespace proxima::server {

Status ProximityService::start_models() {
    return m_shared->models.start();
}

grpc::ServerUnaryReactor* ProximityService::ListModels(grpc::CallbackServerContext* context,
                                                       const v1::ListModelsRequest*,
                                                       v1::ListModelsResponse* response) {
    auto* call = new UnaryCall(*m_shared, context, "ListModels", "");
    if (call->refused()) {
        return call;
    }
    // Off the callback thread: the rescan reads the models directory and opens new stores.
    m_shared->pool.submit([this, call, response] {
        std::string extra;
        call->complete(guarded([&]() -> Status {
                           // Only the models this token may use: the others do not exist for it.
                           auto& models = m_shared->models;
                           const auto& who = *call->principal();
                           for (const auto& m : models.list()) {
                               if (who.may_use_model(m->name)) {
                                   encode_model(*m, response->add_models());
                               }
                           }
                           for (const auto& u : models.unavailable()) {
                               if (who.may_use_model(u.name)) {
                                   encode_unavailable_model(u, response->add_unavailable());
                               }
                           }
                           response->set_cache_budget_bytes(models.cache()->budget());
                           wire::encode_cache_stats(models.cache()->stats(),
                                                    response->mutable_cache());
                           response->set_models_dir(models.dir());
                           extra = " models=" + std::to_string(response->models_size()) +
                                   " unavailable=" + std::to_string(response->unavailable_size());
                           return {};
                       }),
                       extra);
    });
    return call;
}

}  // namespace proxima::server
