#include "common/player.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <limits>
#include <string>
#include <thread>
#include <utility>

#include "proxima/frame_pipeline.hpp"

namespace proxima::client {

namespace {

using Clock = std::chrono::steady_clock;

double ms_between(Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
}

std::size_t triangles_of(const SequenceFrame& frame) {
    std::size_t n = 0;
    for (const auto& o : frame.objects) {
        n += o.mesh.mesh.triangles.size();
    }
    return n;
}

// The answer must name only objects and triangles of the frame (the printers map triangles back
// to file triangles through these indices): a daemon answering otherwise is an error, not an
// out-of-range read.
Status check_fits(const SequenceFrame& frame, const QueryResult& r, std::size_t k) {
    const auto& objects = frame.objects;
    auto triangle_ok = [&](std::size_t object, std::uint64_t t) {
        return object < objects.size() && t < objects[object].mesh.mesh.triangles.size();
    };
    auto bad = [&](const std::string& what) {
        return Status(StatusCode::internal, "frame " + std::to_string(k) +
                                                ": the answer does not fit the frame: " + what);
    };
    for (std::size_t i = 0; i < r.separation.size(); ++i) {
        const auto& s = r.separation[i];
        if (s.other != NO_OBJECT &&
            (!triangle_ok(i, s.triangle) ||
             !triangle_ok(static_cast<std::size_t>(s.other), s.other_triangle))) {
            return bad("separation of object " + std::to_string(i));
        }
    }
    if (r.separation.size() > objects.size() || r.self.size() > objects.size()) {
        return bad("results for more objects than the frame has");
    }
    for (std::size_t i = 0; i < r.self.size(); ++i) {
        if (r.self[i].size() != objects[i].mesh.mesh.triangles.size()) {
            return bad("self distances of object " + std::to_string(i));
        }
        for (const auto& e : r.self[i]) {
            if (e.closest != NO_OBJECT && !triangle_ok(i, static_cast<std::uint64_t>(e.closest))) {
                return bad("self distances of object " + std::to_string(i));
            }
        }
    }
    for (const auto* pairs : {&r.collisions, &r.tolerance, &r.pns}) {
        for (const auto& p : *pairs) {
            if (!triangle_ok(p.object, p.triangle) || !triangle_ok(p.other, p.other_triangle)) {
                return bad("a feature pair names a triangle that does not exist");
            }
        }
    }
    return {};
}

void summarise(PlayedFrame& f) {
    f.min_separation = std::numeric_limits<double>::infinity();
    for (const auto& s : f.result.separation) {
        f.min_separation = std::min(f.min_separation, s.distance);
    }
    f.min_self_distance = std::numeric_limits<double>::infinity();
    for (const auto& obj : f.result.self) {
        for (const auto& s : obj) {
            f.min_self_distance = std::min(f.min_self_distance, s.distance);
        }
    }
    f.collision_count = f.result.collisions.size();
    f.tolerance_count = f.result.tolerance.size();
    if (f.ccd && f.ccd->earliest) {
        f.toi = f.ccd->pairs[*f.ccd->earliest].toi;
    }
    f.engine_ms = (f.result.stats.total_seconds + (f.ccd ? f.ccd->stats.total_seconds : 0.0)) * 1e3;
}

// What both modes share: the frame requests (from the scene's object ids after the previous
// frame), pacing, the checks and summaries of each answer, and the report.
class Driver {
  public:
    Driver(const Sequence& sequence, const PlayOptions& options)
        : m_seq(sequence), m_options(options) {}

    // The request of frame k, given the scene's ids after frame k-1 (frame 0: no change).
    FrameRequest request(std::size_t k, const std::vector<ObjectId>& ids, bool& topology_change) {
        FrameRequest frame;
        frame.frame = k;
        frame.queries = m_options.queries;
        topology_change = false;
        if (k > 0) {
            auto diff = diff_frames(m_seq.frames[k - 1].objects, ids, m_seq.frames[k].objects);
            frame.update = std::move(diff.update);
            topology_change = diff.topology_change;
            if (m_options.ccd && !topology_change) {
                frame.ccd = true;
                frame.ccd_request.elementary.min_distance = m_options.ccd_min_distance;
            }
        }
        return frame;
    }

    // Waits for frame k's slot (fps pacing); returns how late it is, in ms.
    double pace(std::size_t k) {
        if (k == 0) {
            m_start = Clock::now();  // frame 0's slot: now
            return 0.0;
        }
        if (m_options.fps <= 0.0) {
            return 0.0;
        }
        const auto slot =
            m_start + std::chrono::duration_cast<Clock::duration>(
                          std::chrono::duration<double>(static_cast<double>(k) / m_options.fps));
        const auto now = Clock::now();
        if (now < slot) {
            std::this_thread::sleep_until(slot);
            return 0.0;
        }
        return ms_between(slot, now);
    }

    Status finish_frame(PlayReport& report, PlayedFrame frame) {
        if (Status st = check_fits(m_seq.frames[frame.index], frame.result, frame.index);
            !st.ok()) {
            return st;
        }
        summarise(frame);
        report.topology_changes += frame.topology_change ? 1 : 0;
        if (m_options.on_frame) {
            if (Status st = m_options.on_frame(frame); !st.ok()) {
                return st;
            }
        }
        if (!m_options.keep_results) {
            frame.result = {};
            frame.ccd.reset();
        }
        report.frames.push_back(std::move(frame));
        report.wall_ms = ms_between(m_start, Clock::now());
        return {};
    }

    PlayedFrame start_frame(std::size_t k, bool topology_change) const {
        PlayedFrame f;
        f.index = k;
        f.topology_change = topology_change;
        f.object_count = m_seq.frames[k].objects.size();
        f.triangle_count = triangles_of(m_seq.frames[k]);
        return f;
    }

  private:
    const Sequence& m_seq;
    const PlayOptions& m_options;
    Clock::time_point m_start = Clock::now();
};

Status check_ids(const std::vector<ObjectId>& ids, const SequenceFrame& frame, std::size_t k,
                 const char* where) {
    if (ids.size() != frame.objects.size()) {
        return {StatusCode::internal, std::string("frame ") + std::to_string(k) + ": " + where +
                                          " has " + std::to_string(ids.size()) +
                                          " objects, the frame " +
                                          std::to_string(frame.objects.size())};
    }
    return {};
}

Status check_sequence(const Sequence& sequence) {
    if (sequence.frames.empty()) {
        return invalid_argument("the sequence has no frames");
    }
    for (std::size_t k = 0; k < sequence.frames.size(); ++k) {
        if (sequence.frames[k].objects.empty()) {
            return invalid_argument("frame " + std::to_string(k) + " has no objects");
        }
    }
    return {};
}

}  // namespace

StatusOr<PlayReport> play_local(const Sequence& sequence, const PlayOptions& options) {
    if (Status st = check_sequence(sequence); !st.ok()) {
        return st;
    }
    PlayReport report;
    ProximityEngine engine;
    if (options.prepare_engine) {
        options.prepare_engine(engine);
    }
    const auto setup = Clock::now();
    SceneUpdate initial;
    for (const auto& o : sequence.frames[0].objects) {
        initial.additions.push_back(o.mesh);
    }
    if (auto applied = engine.scene().apply(std::move(initial)); !applied.ok()) {
        return Status(applied.status().code(), "frame 0: " + applied.status().message());
    }
    report.setup_ms = ms_between(setup, Clock::now());
    Driver driver(sequence, options);
    std::vector<ObjectId> ids;
    for (const auto& o : engine.scene().objects()) {
        ids.push_back(o.id);
    }
    for (std::size_t k = 0; k < sequence.frames.size(); ++k) {
        bool topology_change = false;
        FrameRequest frame = driver.request(k, ids, topology_change);
        PlayedFrame played = driver.start_frame(k, topology_change);
        played.late_ms = driver.pace(k);
        const auto sent = Clock::now();
        auto outcome = run_frame(engine, std::move(frame), nullptr);
        played.latency_ms = ms_between(sent, Clock::now());
        if (!outcome.ok()) {
            return Status(outcome.status().code(),
                          "frame " + std::to_string(k) + ": " + outcome.status().message());
        }
        ids = outcome->object_ids;
        if (Status st = check_ids(ids, sequence.frames[k], k, "the engine's scene"); !st.ok()) {
            return st;
        }
        played.result = std::move(outcome->result);
        played.ccd = std::move(outcome->ccd);
        if (Status st = driver.finish_frame(report, std::move(played)); !st.ok()) {
            return st;
        }
    }
    return report;
}

StatusOr<PlayReport> play_remote(Client& client, const Sequence& sequence,
                                 const PlayOptions& options) {
    if (Status st = check_sequence(sequence); !st.ok()) {
        return st;
    }
    PlayReport report;
    const auto setup = Clock::now();
    std::vector<NamedMesh> meshes;
    for (const auto& o : sequence.frames[0].objects) {
        meshes.push_back(o.mesh);
    }
    auto scene = client.create_scene("proxima play " + sequence.dir, meshes);
    if (!scene.ok()) {
        return scene.status();
    }
    report.setup_ms = ms_between(setup, Clock::now());
    const std::string scene_id = scene->scene_id;
    // The scene is deleted however the run ends; a failed delete is left to the daemon's idle
    // expiry (the answer, or the run's own error, is what the caller needs).
    struct DeleteScene {
        Client& c;
        const std::string& id;
        ~DeleteScene() { (void)c.delete_scene(id); }
    } delete_scene{client, scene_id};
    if (options.on_setup) {
        if (Status st = options.on_setup(report.setup_ms); !st.ok()) {
            return st;
        }
    }

    std::vector<ObjectId> ids;
    for (const auto& o : scene->objects) {
        ids.push_back(o.id);
    }
    if (Status st = check_ids(ids, sequence.frames[0], 0, "the daemon's scene"); !st.ok()) {
        return st;
    }
    auto stream = client.open_stream(scene_id);
    if (!stream.ok()) {
        return stream.status();
    }
    auto& frames = *stream.value();
    auto broken = [&](const Status& st, std::size_t k) {
        return Status(st.code(), st.message() + " (stream to the daemon broke at frame " +
                                     std::to_string(k) + ")");
    };
    // Frames in flight: up to options.in_flight, never more than the daemon reads ahead (so a
    // send never waits on the daemon while this thread is not reading its answers).
    std::size_t window = std::max<std::size_t>(1, options.in_flight);
    if (window > 1) {
        auto info = client.server_info();
        if (!info.ok()) {
            return info.status();
        }
        window =
            std::min<std::size_t>(window, std::max<std::uint32_t>(1, info->max_frames_in_flight));
    }
    Driver driver(sequence, options);
    struct Pending {
        PlayedFrame frame;
        Clock::time_point sent;
    };
    std::deque<Pending> pending;
    // Reads the oldest answer; the scene's ids after it.
    auto receive_one = [&]() -> Status {
        Pending p = std::move(pending.front());
        pending.pop_front();
        const std::size_t k = p.frame.index;
        auto response = frames.receive();
        p.frame.latency_ms = ms_between(p.sent, Clock::now());
        if (!response.ok()) {
            return broken(response.status(), k);
        }
        ids = response->object_ids;
        if (Status st = check_ids(ids, sequence.frames[k], k, "the daemon's scene"); !st.ok()) {
            return st;
        }
        p.frame.result = std::move(response->result);
        p.frame.ccd = std::move(response->ccd);
        return driver.finish_frame(report, std::move(p.frame));
    };
    for (std::size_t k = 0; k < sequence.frames.size(); ++k) {
        // A topology change gives new objects new ids, which the next frame's update names: its
        // answer comes first. Frames that only move vertices keep the ids.
        const bool wait_for_ids = !pending.empty() && pending.back().frame.topology_change;
        while (!pending.empty() && (wait_for_ids || pending.size() >= window)) {
            if (Status st = receive_one(); !st.ok()) {
                return st;
            }
        }
        bool topology_change = false;
        FrameRequest frame = driver.request(k, ids, topology_change);
        PlayedFrame played = driver.start_frame(k, topology_change);
        played.late_ms = driver.pace(k);
        const auto sent = Clock::now();
        if (Status st = frames.send(frame); !st.ok()) {
            // The stream may have ended on an earlier frame's error: that one is the cause.
            while (!pending.empty()) {
                if (Status earlier = receive_one(); !earlier.ok()) {
                    return earlier;
                }
            }
            return broken(st, k);
        }
        pending.push_back({std::move(played), sent});
    }
    while (!pending.empty()) {
        if (Status st = receive_one(); !st.ok()) {
            return st;
        }
    }
    if (Status st = frames.finish(); !st.ok()) {
        return broken(st, sequence.frames.size());
    }
    return report;
}

LatencySpread spread(std::vector<double> v) {
    LatencySpread s;
    if (v.empty()) {
        return s;
    }
    std::sort(v.begin(), v.end());
    const std::size_t n = v.size();
    s.median = n % 2 == 1 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
    const auto rank = static_cast<std::size_t>(std::ceil(0.99 * static_cast<double>(n)));
    s.p99 = v[std::max<std::size_t>(rank, 1) - 1];
    s.max = v.back();
    return s;
}

}  // namespace proxima::client
