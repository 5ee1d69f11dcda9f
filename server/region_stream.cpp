// FetchRegion: a served model's geometry near a point for viewers (the review page), nearest
// piece first, streamed one piece at a time through the shared geometry cache. The selection and
// the reads are the engine's (proxima/massive/region.hpp); the conversions proto/wire's.
#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>

#include <spdlog/spdlog.h>

#include "bounded_write_stream.hpp"
#include "proxima/massive/region.hpp"
#include "proxima/wire/massive.hpp"
#include "proxima/wire/status.hpp"
#include "service.hpp"
#include "service_internal.hpp"

namespace proxima::server {

namespace {

// Encoded pieces waiting for the client; past that the reading thread waits for the reader, so
// the daemon holds at most this many pieces (plus the one being read) per call, whatever the
// region's size and however slow the client.
constexpr std::size_t REGION_MAX_PENDING_PIECES = 4;

// FetchRegion on BoundedWriteStream, like VerifyModel: the work runs on the call's own thread (a
// whole model takes a while and may wait for a slow reader: on the worker pool it would hold a
// thread that frames need), pieces go through the bounded queue (REGION_MAX_PENDING_PIECES),
// progress is the one slot overwritten after each piece and written when no piece is waiting, the
// summary goes last. Every check runs before the first piece is read, so a bad request gets its
// status and no event. The token stopping (the deadline passing) also drops the pieces queued.
class RegionReactor final : public BoundedWriteStream<v1::RegionEvent> {
  public:
    RegionReactor(ProximityService::Shared& shared, grpc::CallbackServerContext* context,
                  const v1::FetchRegionRequest* request)
        : BoundedWriteStream(shared, context, "FetchRegion", "region fetch",
                             REGION_MAX_PENDING_PIECES, WritesStop::token_stopped),
          m_message(*request) {
        open();
    }

  private:
    Status work() override {
        auto decoded = wire::decode_region_request(m_message);
        if (!decoded.ok()) {
            return decoded.status();
        }
        const massive::RegionRequest request = std::move(decoded).value();
        const auto& who = *m_admission.principal();
        auto view = find_model_view(m_shared, who, request.model, request.room);
        if (!view.ok()) {
            return view.status();
        }
        const std::shared_ptr<const massive::Store> store = view->store;
        const std::shared_ptr<const massive::ModelView::Snapshot> snapshot = view->room_view;
        if (Status s = massive::check_region_request(request, view->object_count); !s.ok()) {
            return s;
        }
        {
            std::lock_guard lock(m_mu);
            m_generation = store->summary().generation;
        }
        const massive::RegionPlan plan = massive::plan_region(*store, snapshot.get(), request);
        spdlog::info(
            "region start method=FetchRegion who={} peer={} model={} room={} generation={} "
            "radius={} pieces={} triangles={} truncated={}",
            m_admission.who(), m_peer, request.model, request.room.empty() ? "-" : request.room,
            store->summary().generation, request.radius, plan.pieces.size(), plan.triangles,
            plan.truncated);

        massive::RegionProgress progress;
        progress.pieces_total = plan.pieces.size();
        progress.triangles_total = plan.triangles;
        auto& cache = *m_shared.models.cache();
        for (const auto& ref : plan.pieces) {
            if (m_cancel.should_stop()) {
                break;
            }
            auto piece = massive::read_region_piece(store, cache, snapshot.get(), ref);
            if (!piece.ok()) {
                return piece.status();
            }
            v1::RegionEvent event;
            wire::encode_region_event(piece.value(), !request.float64, &event);
            ++progress.pieces_sent;
            progress.triangles_sent += ref.triangles;
            std::unique_lock lock(m_mu);
            if (!queue(lock, std::move(event))) {
                break;
            }
            m_pieces_sent = progress.pieces_sent;
            m_triangles_sent = progress.triangles_sent;
            v1::RegionEvent& slot = progress_slot_locked();
            slot.Clear();
            wire::encode_region_event(progress, true, &slot);
            // After the last piece the summary says as much.
            progress_updated_locked(progress.pieces_sent < progress.pieces_total);
        }
        if (m_cancel.should_stop()) {
            return {};  // BoundedWriteStream reports how it stopped
        }
        massive::RegionSummary summary;
        summary.pieces = progress.pieces_sent;
        summary.triangles = progress.triangles_sent;
        summary.truncated = plan.truncated;
        summary.model_version = snapshot ? snapshot->version : 0;
        summary.generation = store->summary().generation;
        summary.server_seconds = std::chrono::duration<double>(Clock::now() - m_start).count();
        v1::RegionEvent event;
        wire::encode_region_event(summary, true, &event);
        std::lock_guard lock(m_mu);
        summary_locked(std::move(event));
        return {};
    }

    std::string log_subject() const override {
        std::string subject = "model=" + (m_message.model().empty() ? "-" : m_message.model());
        if (!m_message.room().empty()) {
            subject += " room=" + m_message.room();
        }
        if (m_generation) {
            subject += " generation=" + *m_generation;
        }
        return subject;
    }

    std::string log_extra() const override {
        return " radius=" + std::to_string(m_message.radius()) +
               " pieces=" + std::to_string(m_pieces_sent) +
               " triangles=" + std::to_string(m_triangles_sent);
    }

    const v1::FetchRegionRequest m_message;
    // Guarded by m_mu.
    std::optional<std::string> m_generation;
    std::uint64_t m_pieces_sent = 0;
    std::uint64_t m_triangles_sent = 0;
};

}  // namespace

grpc::ServerWriteReactor<v1::RegionEvent>* ProximityService::FetchRegion(
    grpc::CallbackServerContext* context, const v1::FetchRegionRequest* request) {
    return new RegionReactor(*m_shared, context, request);
}

}  // namespace proxima::server
