// StreamFrames: a simulator's frames on one scene, answered in order (ordered_stream.hpp runs the
// stream; frames.hpp runs each frame). The first frame names an existing scene, or, with an
// empty scene_id, builds a scene the stream owns and deletes when it ends.
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>

#include <spdlog/spdlog.h>

#include "frames.hpp"
#include "ordered_stream.hpp"
#include "scene_registry.hpp"
#include "service.hpp"
#include "service_internal.hpp"

namespace proxima::server {

namespace {

// A frame's bytes count against its principal's max-bytes-in-flight from when it is read until
// it is answered (or dropped).
class FrameStreamReactor final : public OrderedStream<v1::Frame, v1::FrameResult> {
  public:
    FrameStreamReactor(ProximityService::Shared& shared, grpc::CallbackServerContext* context)
        : OrderedStream(shared, context, "StreamFrames", "stream") {
        open();
    }

  private:
    std::mutex& mutex() override { return m_mu; }

    StatusOr<std::uint64_t> on_read_locked(const v1::Frame& frame) override {
        const std::uint64_t bytes = frame.ByteSizeLong();
        if (Status s = m_admission.principal()->reserve_in_flight(bytes); !s.ok()) {
            return s;
        }
        return bytes;
    }

    void on_dropped_locked(std::uint64_t bytes) override {
        m_admission.principal()->release_in_flight(bytes);
    }

    Status handle(v1::Frame& frame, std::uint64_t bytes) override {
        return answer(frame, bytes, nullptr);
    }

    // A frame that finds the stream idle is run on the gRPC thread that read it when its work is
    // small and bounded: the stream is bound to a scene of few objects (the answer lists them
    // all), the frame only moves vertices, at most INLINE_FRAME_BYTES of them, and asks no query.
    // Saves the hop to a worker and back (issue #16: the per-frame overhead of a 15K-vertex
    // frame). m_scene is only changed by the stream's task, which is not running (idle).
    static constexpr std::uint64_t INLINE_FRAME_BYTES = 512u << 10;
    static constexpr std::uint64_t INLINE_SCENE_OBJECTS = 1024;

    bool inline_candidate_locked(const v1::Frame& frame, std::uint64_t bytes) override {
        if (!m_scene || m_scene->object_count.load() > INLINE_SCENE_OBJECTS ||
            frame.additions_size() != 0 || frame.topology_changes_size() != 0 ||
            frame.removals_size() != 0 || bytes > INLINE_FRAME_BYTES) {
            return false;
        }
        const auto& q = frame.queries();
        return !q.separation() && !q.self() && !q.collisions() && !q.has_tolerance() && !q.pns() &&
               !q.ccd() && !q.penetration();
    }

    // A gRPC thread never waits: when the scene is busy (another call's frame or query), the
    // frame goes to a worker, untouched (not admitted, nothing charged or released).
    std::optional<Status> handle_inline(v1::Frame& frame, std::uint64_t bytes) override {
        std::unique_lock scene_lock(m_scene->mutex, std::try_to_lock);
        if (!scene_lock.owns_lock()) {
            return std::nullopt;
        }
        return answer(frame, bytes, &scene_lock);
    }

    // One frame answered (queued for writing), or its error. `scene_lock`: the scene's mutex,
    // held by the caller (released once the frame has run), or null.
    Status answer(v1::Frame& frame, std::uint64_t bytes, std::unique_lock<std::mutex>* scene_lock) {
        v1::FrameResult result;
        Status s = m_admission.principal()->admit_frame();
        if (s.ok()) {
            s = guarded([&] { return run(frame, &result, scene_lock); });
        }
        if (scene_lock != nullptr) {
            scene_lock->unlock();
        }
        m_admission.principal()->release_in_flight(bytes);
        if (!s.ok()) {
            return s;
        }
        m_shared.metrics.add_frames(1, result.stats().exact_tests());
        std::lock_guard lock(m_mu);
        ++m_frames_answered;
        m_results.push_back(std::move(result));
        answers_ready_locked();
        return {};
    }

    bool next_write_locked(v1::FrameResult* out, bool* answers) override {
        if (m_results.empty()) {
            return false;
        }
        *out = std::move(m_results.front());
        m_results.pop_front();
        *answers = true;
        return true;
    }

    void on_done() override {
        // The scene goes before the stream count drops, so a client that sees live_streams back
        // to its old value also sees live_scenes back.
        if (m_owns_scene && m_scene) {
            m_shared.scenes.erase(m_scene->id);
        }
        // Freeing a large engine takes a while: a worker does it, not gRPC's callback thread.
        if (m_scene) {
            m_shared.pool.submit([doomed = std::move(m_scene)] {});
        }
    }

    std::string log_subject() const override { return scene_subject(m_scene ? m_scene->id : ""); }
    std::string log_extra() const override {
        return " frames=" + std::to_string(m_frames_answered) +
               " owned_scene=" + (m_owns_scene ? "true" : "false");
    }

    // One frame, off the lock. m_scene and m_owns_scene are only touched here (one task at a
    // time) and in OnDone (after the last task).
    // `scene_lock`: the bound scene's mutex, held by the caller (handle_inline), or null.
    Status run(const v1::Frame& frame, v1::FrameResult* out,
               const std::unique_lock<std::mutex>* scene_lock) {
        const auto& limits = m_shared.config.limits;
        if (m_scene) {
            if (!frame.scene_id().empty() && frame.scene_id() != m_scene->id) {
                return invalid_argument("frame " + std::to_string(frame.frame()) + " names scene " +
                                        frame.scene_id() + " but this stream is bound to scene " +
                                        m_scene->id);
            }
            return run_frame(*m_scene, frame, limits, &m_cancel, out, {}, scene_lock);
        }
        const auto& principal = m_admission.principal();
        if (!frame.scene_id().empty()) {
            auto entry = m_shared.scenes.find(frame.scene_id(), *principal);
            if (!entry) {
                return unknown_scene(frame.scene_id());
            }
            m_scene = entry;
            spdlog::info(
                "stream start method=StreamFrames who={} peer={} scene={} owned_scene=false",
                m_admission.who(), m_peer, m_scene->id);
            return run_frame(*m_scene, frame, limits, &m_cancel, out);
        }
        // An empty scene_id on the first frame: a scene owned by this stream, built from the
        // frame's additions, registered only once they are valid and applied.
        if (!principal->may_create_scene("")) {
            return {StatusCode::permission_denied,
                    "token '" + principal->name() +
                        "' may not create stream-owned scenes (their name is \"\"; its scenes "
                        "patterns must match it, e.g. \"*\"); name a scene made by CreateScene"};
        }
        if (Status s = m_shared.scenes.check_capacity(); !s.ok()) {
            return s;
        }
        auto entry = m_shared.scenes.make_entry("", true, principal);
        return run_frame(*entry, frame, limits, &m_cancel, out, [&]() -> Status {
            if (Status s = m_shared.scenes.insert(entry); !s.ok()) {
                return s;
            }
            m_scene = entry;
            m_owns_scene = true;
            spdlog::info(
                "stream start method=StreamFrames who={} peer={} scene={} owned_scene=true",
                m_admission.who(), m_peer, m_scene->id);
            return {};
        });
    }

    std::mutex m_mu;
    std::deque<v1::FrameResult> m_results;  // answered, not yet written (guarded by m_mu)
    std::uint64_t m_frames_answered = 0;    // guarded by m_mu

    std::shared_ptr<SceneEntry> m_scene;
    bool m_owns_scene = false;
};

}  // namespace

grpc::ServerBidiReactor<v1::Frame, v1::FrameResult>* ProximityService::StreamFrames(
    grpc::CallbackServerContext* context) {
    return new FrameStreamReactor(*m_shared, context);
}

}  // namespace proxima::server
