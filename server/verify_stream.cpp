// VerifyModel: the static verification of a massive model (seed 001, IMMPACT §4.4-§6.5),
// streamed as it runs.
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <utility>

#include <spdlog/spdlog.h>

#include "bounded_write_stream.hpp"
#include "encode.hpp"
#include "proxima/massive/verify.hpp"
#include "proxima/wire/buffers.hpp"
#include "proxima/wire/massive.hpp"
#include "proxima/wire/status.hpp"
#include "service.hpp"
#include "service_internal.hpp"

namespace proxima::server {

namespace {

// Pair events a verification may have encoded but not yet written; past that the traversal
// waits for the reader (its other threads wait with it, on the engine's result lock).
constexpr std::size_t VERIFY_MAX_PENDING_PAIRS = 256;

// VerifyModel on BoundedWriteStream: the traversal runs on the call's own thread (a large model
// takes minutes, and it may wait for a slow reader: on the worker pool it would hold a thread that
// frames need). Pairs go into the bounded queue (VERIFY_MAX_PENDING_PAIRS); when it is full the
// engine's on_pair waits, which stalls the traversal until the client reads: memory stays bounded
// however slow the reader. Progress is the one slot overwritten by each report, written when
// nothing else is waiting. The deadline passing does not drop the pairs already queued: the
// traversal returns its own status after them.
class VerifyReactor final : public BoundedWriteStream<v1::VerifyModelEvent> {
  public:
    VerifyReactor(ProximityService::Shared& shared, grpc::CallbackServerContext* context,
                  const v1::VerifyModelRequest* request)
        : BoundedWriteStream(shared, context, "VerifyModel", "verification",
                             VERIFY_MAX_PENDING_PAIRS, WritesStop::client_gone),
          m_model_name(request->model()),
          m_tolerance(request->tolerance()) {
        open();
    }

  private:
    Status work() override {
        if (Status t = wire::check_tolerance(m_tolerance, "tolerance"); !t.ok()) {
            return t;
        }
        auto model = find_model(m_shared, *m_admission.principal(), m_model_name);
        if (!model.ok()) {
            return model.status();
        }
        const auto store = model.value()->store;
        {
            std::lock_guard lock(m_mu);
            m_generation = store->summary().generation;
        }
        spdlog::info(
            "verify start method=VerifyModel who={} peer={} model={} generation={} "
            "tolerance={} objects={} pieces={}",
            m_admission.who(), m_peer, m_model_name, store->summary().generation, m_tolerance,
            store->summary().objects, store->summary().pieces);
        massive::VerifyOptions options;
        options.tolerance = m_tolerance;
        auto on_pair = [&](const massive::ObjectPairResult& pair) {
            v1::VerifyModelEvent event;
            wire::encode_object_pair(pair, *store, event.mutable_pair());
            std::unique_lock lock(m_mu);
            if (!queue(lock, std::move(event))) {
                return;  // nobody will read it; the traversal stops at its next pair
            }
        };
        auto on_progress = [&](const massive::Progress& p) {
            std::lock_guard lock(m_mu);
            wire::encode_progress(p, progress_slot_locked().mutable_progress());
            progress_updated_locked(true);
        };
        auto stats = massive::verify_static(store, *m_shared.models.cache(), options, on_pair,
                                            nullptr, on_progress, &m_cancel);
        if (!stats.ok()) {
            return stats.status();
        }
        v1::VerifyModelEvent summary;
        wire::encode_verify_stats(stats.value(),
                                  std::chrono::duration<double>(Clock::now() - m_start).count(),
                                  summary.mutable_summary());
        std::lock_guard lock(m_mu);
        m_pairs_found = stats->pairs_found;
        m_edges = stats->edges;
        summary_locked(std::move(summary));
        return {};
    }

    std::string log_subject() const override {
        std::string subject = "model=" + (m_model_name.empty() ? "-" : m_model_name);
        if (m_generation) {
            subject += " generation=" + *m_generation;
        }
        return subject;
    }

    std::string log_extra() const override {
        return " tolerance=" + std::to_string(m_tolerance) +
               " pairs=" + std::to_string(m_pairs_found) + " edges=" + std::to_string(m_edges);
    }

    const std::string m_model_name;
    const double m_tolerance;
    // Guarded by m_mu.
    std::optional<std::string> m_generation;
    std::uint64_t m_pairs_found = 0;
    std::uint64_t m_edges = 0;
};

}  // namespace

grpc::ServerWriteReactor<v1::VerifyModelEvent>* ProximityService::VerifyModel(
    grpc::CallbackServerContext* context, const v1::VerifyModelRequest* request) {
    return new VerifyReactor(*m_shared, context, request);
}

}  // namespace proxima::server
