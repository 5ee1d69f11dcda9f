// proxima: the command-line tool. `distance` runs the engine in-process on mesh files (--local,
// the default) or on a proximad daemon (--server); `demo` streams a built-in deforming scene
// through the engine, or through a daemon's frame stream, and prints per-frame results; `info`
// shows what a daemon reports about itself. Both modes build the same QueryResult and print it
// through the same code, so their outputs differ only in timings.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "cli/commands.hpp"
#include "cli/id_map.hpp"
#include "client/proxima_client.hpp"
#include "common/json_output.hpp"
#include "common/local_scene.hpp"
#include "proxima/frame_pipeline.hpp"
#include "proxima/gpu/egl_backend.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scenes/procedural.hpp"

namespace {

using namespace proxima;

using proxima::cli::fail;

double milliseconds_since(std::chrono::steady_clock::time_point start) {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
        .count();
}

StatusOr<std::unique_ptr<client::Client>> connect(const std::string& address,
                                                  const cli::ServerFlags& flags,
                                                  std::size_t inline_mesh_bytes = 1u << 20) {
    client::ConnectOptions options;
    // float64 vertices (the default) keep server answers bit-identical to local ones.
    options.inline_mesh_bytes = inline_mesh_bytes;
    return cli::connect_server(address, flags, options);
}

struct DistanceArgs {
    bool local = false;
    std::string server;
    cli::ServerFlags server_flags;
    std::size_t inline_mesh_bytes = 1u << 20;
    bool split_components = false;
    bool weld = false;
    bool self = false;
    bool collisions = false;
    bool pns = false;
    cli::JsonOutput output;
    double tolerance = -1.0;
    bool penetration = false;
    std::string culler = "auto";
    double voronoi_cell = 0.0;  // 0: the engine picks
    std::vector<std::string> files;
};

// A distance run's answers: the query result and, with --penetration, the penetration vectors.
struct DistanceAnswer {
    QueryResult result;
    std::vector<Penetration> penetrations;
};

void print_text(const std::vector<client::InputObject>& objects, const QueryResult& r,
                const std::vector<Penetration>& penetrations, const DistanceArgs& args) {
    for (std::size_t i = 0; i < objects.size(); ++i) {
        const auto& s = r.separation[i];
        if (s.other == NO_OBJECT) {
            std::printf("%-40s  no other object\n", objects[i].mesh.name.c_str());
        } else {
            std::printf("%-40s  distance %.9g to %s (triangle %u - %u)\n",
                        objects[i].mesh.name.c_str(), s.distance,
                        objects[static_cast<std::size_t>(s.other)].mesh.name.c_str(),
                        objects[i].file_triangle[s.triangle],
                        objects[static_cast<std::size_t>(s.other)].file_triangle[s.other_triangle]);
        }
    }
    if (args.self) {
        for (std::size_t i = 0; i < r.self.size(); ++i) {
            double best = std::numeric_limits<double>::infinity();
            for (const auto& e : r.self[i]) {
                best = std::min(best, e.distance);
            }
            std::printf("%-40s  closest non-adjacent self distance %.9g\n",
                        objects[i].mesh.name.c_str(), best);
        }
    }
    if (args.collisions) {
        std::printf("collisions: %zu intersecting triangle pairs\n", r.collisions.size());
    }
    if (args.tolerance >= 0.0) {
        std::printf("tolerance %.9g: %zu triangle pairs within\n", args.tolerance,
                    r.tolerance.size());
    }
    for (const auto& p : penetrations) {
        std::printf("penetration %s - %s: depth %.9g along (%.6g, %.6g, %.6g)%s%s\n",
                    objects[p.object].mesh.name.c_str(), objects[p.other].mesh.name.c_str(),
                    p.depth, p.direction.x, p.direction.y, p.direction.z,
                    p.isolated ? "" : ", not isolated (several contact regions)",
                    p.closed ? "" : ", open surface (intersecting triangles only)");
    }
    std::printf("culler %s, %llu exact tests (brute force: %llu), %.3f ms\n",
                r.stats.culler.c_str(), static_cast<unsigned long long>(r.stats.exact_tests),
                static_cast<unsigned long long>(r.stats.brute_force_tests),
                r.stats.total_seconds * 1e3);
}

// With --culler voronoi-gpu a local engine starts its own headless EGL context (as the daemon
// does once at start-up); without it the request fails with EGL's reason.
void attach_gpu_if_asked(ProximityEngine& engine, CullerKind culler) {
    if (culler != CullerKind::voronoi_gpu) {
        return;
    }
    auto backend = gpu::make_egl_backend();
    if (backend.ok()) {
        engine.set_gpu_backend(std::move(backend).value());
    } else {
        engine.set_gpu_unavailable_reason("EGL unavailable: " + backend.status().message());
    }
}

StatusOr<DistanceAnswer> query_local(const std::vector<client::InputObject>& objects,
                                     const QueryRequest& request, bool penetration) {
    ProximityEngine engine;
    attach_gpu_if_asked(engine, request.culler);
    SceneUpdate update;
    for (const auto& obj : objects) {
        update.additions.push_back(obj.mesh);
    }
    if (auto applied = engine.scene().apply(std::move(update)); !applied.ok()) {
        return applied.status();
    }
    // The objects are the scene (as CreateScene makes it remotely); one frame queries it, through
    // the same pipeline the daemon runs.
    FrameRequest frame;
    frame.queries = request;
    frame.penetration = penetration;
    auto outcome = run_frame(engine, std::move(frame), nullptr);
    if (!outcome.ok()) {
        return outcome.status();
    }
    return DistanceAnswer{std::move(outcome->result), std::move(outcome->penetrations)};
}

// The printers index file triangle maps with the result's indices: a daemon answering with indices
// outside the objects we sent must be an error message, not an out-of-range read.
Status check_remote_result(const std::vector<client::InputObject>& objects,
                           const client::FrameResponse& response, const QueryRequest& request) {
    const auto n = objects.size();
    auto bad = [](const std::string& what) {
        return Status(StatusCode::internal, "the daemon's answer does not fit the input: " + what);
    };
    auto triangle_ok = [&](std::size_t object, std::uint32_t t) {
        return object < n && t < objects[object].file_triangle.size();
    };
    if (response.object_ids.size() != n) {
        return bad(std::to_string(response.object_ids.size()) + " objects for " +
                   std::to_string(n) + " sent");
    }
    const auto& r = response.result;
    if (request.separation && r.separation.size() != n) {
        return bad("separation for " + std::to_string(r.separation.size()) + " objects");
    }
    for (std::size_t i = 0; i < r.separation.size(); ++i) {
        const auto& s = r.separation[i];
        if (s.other != NO_OBJECT &&
            (!triangle_ok(i, s.triangle) ||
             !triangle_ok(static_cast<std::size_t>(s.other), s.other_triangle))) {
            return bad("separation of object " + std::to_string(i));
        }
    }
    if (request.self && r.self.size() != n) {
        return bad("self distances for " + std::to_string(r.self.size()) + " objects");
    }
    for (std::size_t i = 0; i < r.self.size(); ++i) {
        if (r.self[i].size() != objects[i].file_triangle.size()) {
            return bad("self distances of object " + std::to_string(i));
        }
        for (const auto& e : r.self[i]) {
            if (e.closest != NO_OBJECT && !triangle_ok(i, static_cast<std::uint32_t>(e.closest))) {
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
    for (const auto& p : response.penetrations) {
        bool ok = triangle_ok(p.object, p.triangle) && triangle_ok(p.other, p.other_triangle);
        for (auto t : p.triangles) {
            ok = ok && triangle_ok(p.object, t);
        }
        for (auto t : p.other_triangles) {
            ok = ok && triangle_ok(p.other, t);
        }
        if (!ok) {
            return bad("a penetration names a triangle that does not exist");
        }
    }
    return {};
}

// Creates a scene on the daemon with the objects in input order, runs one Query and deletes the
// scene: the daemon's scene order is the input order, so result indices mean the same as locally.
StatusOr<DistanceAnswer> query_remote(const DistanceArgs& args,
                                      const std::vector<client::InputObject>& objects,
                                      const QueryRequest& request) {
    auto remote = connect(args.server, args.server_flags, args.inline_mesh_bytes);
    if (!remote.ok()) {
        return remote.status();
    }
    auto response =
        cli::query_in_temporary_scene(*remote.value(), "proxima distance", objects,
                                      [&](client::FrameRequest& frame, const client::RemoteScene&) {
                                          frame.queries = request;
                                          frame.penetration = args.penetration;
                                      });
    if (!response.ok()) {
        return response.status();
    }
    if (auto st = check_remote_result(objects, response.value(), request); !st.ok()) {
        return st;
    }
    return DistanceAnswer{std::move(response->result), std::move(response->penetrations)};
}

int run_distance(const DistanceArgs& args) {
    auto culler = parse_culler(args.culler);
    if (!culler.ok()) {
        return fail(culler.status());
    }
    auto objects =
        client::load_objects(args.files, args.split_components, cli::weld_mode(args.weld));
    if (!objects.ok()) {
        return fail(objects.status());
    }
    QueryRequest request;
    request.self = args.self;
    request.collisions = args.collisions || args.penetration;
    request.pns = args.pns;
    request.culler = culler.value();
    if (args.voronoi_cell > 0.0) {
        request.voronoi_cell = args.voronoi_cell;
    }
    if (args.tolerance >= 0.0) {
        request.tolerance = args.tolerance;
    }
    auto answer = args.server.empty() ? query_local(objects.value(), request, args.penetration)
                                      : query_remote(args, objects.value(), request);
    if (!answer.ok()) {
        return fail(answer.status());
    }
    const auto& result = answer->result;
    if (args.output.wanted()) {
        client::OutputOptions opts{args.self, request.collisions, args.tolerance >= 0.0, args.pns};
        auto j = client::distance_json(objects.value(), result, opts);
        if (args.penetration) {
            j["penetrations"] = client::penetrations_json(objects.value(), answer->penetrations);
        }
        return cli::emit_json(j, args.output,
                              "distance: " + std::to_string(objects->size()) + " objects, " +
                                  std::to_string(result.stats.exact_tests) + " exact tests");
    }
    print_text(objects.value(), result, answer->penetrations, args);
    return 0;
}

struct DemoArgs {
    std::string scene = "cloth-ball";
    std::size_t frames = 8;
    bool json = false;
    std::string out;            // --out FILE: the JSON lines go there instead of stdout
    std::FILE* sink = nullptr;  // where the JSON lines go (set by run_demo)
    std::string culler = "auto";
    std::string server;
    cli::ServerFlags server_flags;
};

// One demo frame's line. `round_trip_ms` is set in server mode only (send to result received).
void print_demo_frame(const DemoArgs& args, std::size_t k, std::size_t objects,
                      std::size_t triangles, const QueryResult& result,
                      std::optional<double> round_trip_ms) {
    double min_sep = std::numeric_limits<double>::infinity();
    for (const auto& s : result.separation) {
        min_sep = std::min(min_sep, s.distance);
    }
    double min_self = std::numeric_limits<double>::infinity();
    for (const auto& obj : result.self) {
        for (const auto& s : obj) {
            min_self = std::min(min_self, s.distance);
        }
    }
    const auto& st = result.stats;
    if (args.json) {
        nlohmann::json j = {
            {"frame", k},
            {"object_count", objects},
            {"triangle_count", triangles},
            {"min_separation", std::isfinite(min_sep) ? nlohmann::json(min_sep) : nlohmann::json()},
            {"min_self_distance",
             std::isfinite(min_self) ? nlohmann::json(min_self) : nlohmann::json()},
            {"collision_count", result.collisions.size()},
            {"stats", client::stats_json(st)}};
        if (round_trip_ms) {
            j["round_trip_ms"] = *round_trip_ms;
        }
        // One line per frame, as it completes.
        const std::string line = j.dump() + "\n";
        std::fwrite(line.data(), 1, line.size(), args.sink != nullptr ? args.sink : stdout);
        std::fflush(args.sink != nullptr ? args.sink : stdout);
        return;
    }
    std::printf("%5zu %7zu %9zu %12.6g %12.6g %10zu %12llu %9.2f", k, objects, triangles, min_sep,
                min_self, result.collisions.size(), static_cast<unsigned long long>(st.exact_tests),
                st.total_seconds * 1e3);
    if (round_trip_ms) {
        std::printf(" %9.2f", *round_trip_ms);
    }
    std::printf("\n");
    // Lines go out as frames complete, also when stdout is a pipe (demo.sh, tee).
    std::fflush(stdout);
}

// Per-frame time spread of a stream, over frames 1.. (frame 0 builds the scene): median, p99
// (nearest rank) and max, and their ratios to the median. A frame far above the median is a stall
// the client sees (issue #14: no frame may cost more than 1.5x the median by the service's choice).
struct Spread {
    double median = 0, p99 = 0, max = 0;
};

Spread spread_of(std::vector<double> v) {
    Spread s;
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

void print_demo_spread(const DemoArgs& args, const char* what, const std::vector<double>& ms) {
    if (args.json || ms.size() < 2) {
        return;
    }
    const Spread s = spread_of({ms.begin() + 1, ms.end()});
    std::printf(
        "%s per frame, frames 1..%zu: median %.2f ms, p99 %.2f ms (p99/median %.2f), max %.2f ms "
        "(max/median %.2f)\n",
        what, ms.size() - 1, s.median, s.p99, s.p99 / s.median, s.max, s.max / s.median);
}

void print_demo_header(const DemoArgs& args, const scenes::ProceduralScene& scene) {
    if (args.json) {
        return;
    }
    if (args.server.empty()) {
        std::printf("scene %s: %s\n", scene.name.c_str(), scene.description.c_str());
    } else {
        std::printf(
            "scene %s: %s\nstreamed to proximad at %s (ms: engine time on the daemon, "
            "rtt-ms: round trip)\n",
            scene.name.c_str(), scene.description.c_str(), args.server.c_str());
    }
    std::printf("%5s %7s %9s %12s %12s %10s %12s %9s", "frame", "objects", "triangles",
                "min-separ.", "min-self", "collisions", "exact-tests", "ms");
    if (!args.server.empty()) {
        std::printf(" %9s", "rtt-ms");
    }
    std::printf("\n");
}

int run_demo_local(const DemoArgs& args, scenes::ProceduralScene& scene,
                   const QueryRequest& request) {
    ProximityEngine engine;
    attach_gpu_if_asked(engine, request.culler);
    print_demo_header(args, scene);
    std::vector<double> engine_ms;
    for (std::size_t k = 0; k < scene.frame_count; ++k) {
        FrameRequest frame;
        frame.frame = k;
        if (k == 0) {
            frame.update.additions = scene.initial;
        } else {
            frame.update = scene.step(k, engine.scene());
        }
        frame.queries = request;
        auto outcome = run_frame(engine, std::move(frame), nullptr);
        if (!outcome.ok()) {
            return fail(outcome.status());
        }
        print_demo_frame(args, k, engine.scene().size(), engine.scene().triangle_count(),
                         outcome->result, std::nullopt);
        engine_ms.push_back(outcome->result.stats.total_seconds * 1e3);
    }
    print_demo_spread(args, "engine time", engine_ms);
    return 0;
}

// Streams the scene over one StreamFrames call, in lockstep (send a frame, read its result) so
// that the round trip of each frame is measured alone. The scene is stream-owned: the first frame
// creates it from its additions and the daemon deletes it when the stream ends.
int run_demo_remote(const DemoArgs& args, scenes::ProceduralScene& scene,
                    const QueryRequest& request) {
    auto remote = connect(args.server, args.server_flags);
    if (!remote.ok()) {
        return fail(remote.status());
    }
    auto stream = remote.value()->open_stream("");
    if (!stream.ok()) {
        return fail(stream.status());
    }
    auto& frames = *stream.value();
    Scene mirror;
    cli::IdMap ids;
    print_demo_header(args, scene);
    std::vector<double> engine_ms;
    std::vector<double> rtt_ms;
    // A broken stream names the daemon and how far the frames got, not only gRPC's words
    // ("UNAVAILABLE: Socket closed").
    auto broken = [&](const Status& st, std::size_t frame) {
        const std::string answered = frame == 0
                                         ? "no frame answered yet"
                                         : "last frame answered: " + std::to_string(frame - 1);
        return fail(Status(st.code(), st.message() + " (stream to the daemon at " + args.server +
                                          " broke at frame " + std::to_string(frame) + "; " +
                                          answered + ")"));
    };
    for (std::size_t k = 0; k < scene.frame_count; ++k) {
        SceneUpdate local_update;
        if (k == 0) {
            local_update.additions = scene.initial;
        } else {
            local_update = scene.step(k, mirror);
        }
        client::FrameRequest frame;
        frame.frame = k;
        frame.queries = request;
        auto translated = ids.translate(local_update);
        if (!translated.ok()) {
            return fail(translated.status());
        }
        frame.update = std::move(translated).value();
        // The mirror keeps the whole update (ids, fragments) for the id bookkeeping below.
        auto applied = mirror.apply(local_update);
        if (!applied.ok()) {
            return fail(applied.status());
        }
        const auto start = std::chrono::steady_clock::now();
        if (auto sent = frames.send(frame); !sent.ok()) {
            return broken(sent, k);
        }
        auto response = frames.receive();
        if (!response.ok()) {
            return broken(response.status(), k);
        }
        const double round_trip_ms = milliseconds_since(start);
        if (auto st = ids.update(local_update, applied.value(), response.value()); !st.ok()) {
            return fail(st);
        }
        if (response->object_ids.size() != mirror.size()) {
            return fail({StatusCode::internal,
                         "the daemon's scene has " + std::to_string(response->object_ids.size()) +
                             " objects, the local mirror " + std::to_string(mirror.size())});
        }
        print_demo_frame(args, k, mirror.size(), mirror.triangle_count(), response->result,
                         round_trip_ms);
        engine_ms.push_back(response->result.stats.total_seconds * 1e3);
        rtt_ms.push_back(round_trip_ms);
    }
    if (auto st = frames.finish(); !st.ok()) {
        return broken(st, scene.frame_count);
    }
    print_demo_spread(args, "engine time", engine_ms);
    print_demo_spread(args, "round trip", rtt_ms);
    return 0;
}

int run_demo_to(const DemoArgs& args);

// --out FILE: the JSON lines into FILE, then a one-line summary on standard error.
int run_demo(const DemoArgs& given) {
    if (given.out.empty()) {
        return run_demo_to(given);
    }
    DemoArgs args = given;
    args.json = true;
    args.sink = std::fopen(args.out.c_str(), "wb");
    if (args.sink == nullptr) {
        std::fprintf(stderr, "proxima: error: cannot write '%s'\n", args.out.c_str());
        return 1;
    }
    const int code = run_demo_to(args);
    const bool written = std::ferror(args.sink) == 0;
    if (std::fclose(args.sink) != 0 || !written) {
        std::fprintf(stderr, "proxima: error: cannot write '%s'\n", args.out.c_str());
        return 1;
    }
    if (code == 0) {
        std::fprintf(stderr, "demo: %zu frames of %s; JSON in %s\n", args.frames,
                     args.scene.c_str(), args.out.c_str());
    }
    return code;
}

int run_demo_to(const DemoArgs& args) {
    auto culler = parse_culler(args.culler);
    if (!culler.ok()) {
        return fail(culler.status());
    }
    auto scene = scenes::by_name(args.scene, args.frames);
    if (scene.name.empty()) {
        return fail(invalid_argument("unknown scene '" + args.scene +
                                     "' (expected skirt, cloth-ball, bowl, ramps or breaking)"));
    }
    QueryRequest request;
    request.self = true;
    request.collisions = true;
    request.culler = culler.value();
    return args.server.empty() ? run_demo_local(args, scene, request)
                               : run_demo_remote(args, scene, request);
}

struct InfoArgs {
    std::string server;
    cli::ServerFlags server_flags;
    cli::JsonOutput output;
};

int run_info(const InfoArgs& args) {
    auto remote = connect(args.server, args.server_flags);
    if (!remote.ok()) {
        return fail(remote.status());
    }
    auto info = remote.value()->server_info();
    if (!info.ok()) {
        return fail(info.status());
    }
    const auto& i = info.value();
    if (args.output.wanted()) {
        nlohmann::json j = {{"address", args.server},
                            {"version", i.version},
                            {"api", i.api},
                            {"proximity_backend", i.proximity_backend},
                            {"gl_renderer", i.gl_renderer},
                            {"live_scenes", i.live_scenes},
                            {"live_streams", i.live_streams},
                            {"limits",
                             {{"max_scenes", i.max_scenes},
                              {"max_objects_per_scene", i.max_objects_per_scene},
                              {"max_triangles_per_scene", i.max_triangles_per_scene},
                              {"max_message_bytes", i.max_message_bytes},
                              {"max_frames_in_flight", i.max_frames_in_flight}}},
                            {"principal", i.principal},
                            {"quotas",
                             {{"max_scenes", i.quota_max_scenes},
                              {"max_objects", i.quota_max_objects},
                              {"max_triangles", i.quota_max_triangles},
                              {"max_bytes_held", i.quota_max_bytes_held},
                              {"max_bytes_in_flight", i.quota_max_bytes_in_flight},
                              {"max_frames_per_second", i.quota_max_frames_per_second},
                              {"max_streams", i.quota_max_streams}}}};
        return cli::emit_json(j, args.output, "info: proximad " + i.version + " at " + args.server);
    }
    std::printf("proximad %s at %s (api %s)\n", i.version.c_str(), args.server.c_str(),
                i.api.c_str());
    std::printf("proximity backend: %s\n", i.proximity_backend.c_str());
    std::printf("gl renderer:       %s\n",
                i.gl_renderer.empty() ? "(none)" : i.gl_renderer.c_str());
    std::printf("live:              %llu scenes, %llu streams\n",
                static_cast<unsigned long long>(i.live_scenes),
                static_cast<unsigned long long>(i.live_streams));
    std::printf(
        "limits:            %llu scenes, %llu objects and %llu triangles per scene, "
        "%llu-byte messages, %u frames in flight per stream\n",
        static_cast<unsigned long long>(i.max_scenes),
        static_cast<unsigned long long>(i.max_objects_per_scene),
        static_cast<unsigned long long>(i.max_triangles_per_scene),
        static_cast<unsigned long long>(i.max_message_bytes), i.max_frames_in_flight);
    if (!i.principal.empty()) {
        // Quotas of 0 are unlimited.
        std::printf(
            "token:             %s (quotas: %llu scenes, %llu objects, %llu triangles, %llu "
            "bytes held, %llu bytes in flight, %g frames/s, %llu streams; 0 = unlimited)\n",
            i.principal.c_str(), static_cast<unsigned long long>(i.quota_max_scenes),
            static_cast<unsigned long long>(i.quota_max_objects),
            static_cast<unsigned long long>(i.quota_max_triangles),
            static_cast<unsigned long long>(i.quota_max_bytes_held),
            static_cast<unsigned long long>(i.quota_max_bytes_in_flight),
            i.quota_max_frames_per_second, static_cast<unsigned long long>(i.quota_max_streams));
    }
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    try {
        CLI::App app{"proxima: exact proximity queries among deformable meshes", "proxima"};
        app.require_subcommand(1);
        app.set_version_flag("--version", "proxima " PROXIMA_VERSION);
        app.footer("Exit status: 0 success, 1 bad input or a failed operation, 2 a usage error.");
        auto* version = app.add_subcommand("version", "Print the version");

        DistanceArgs dist;
        auto* distance = app.add_subcommand(
            "distance", "Separation, self distance, collisions and tolerance on mesh files");
        auto* server_opt =
            cli::add_local_or_server(*distance, dist.local, dist.server, dist.server_flags,
                                     "Run the engine in this process (the default)",
                                     "Run on the proximad daemon at HOST:PORT instead");
        distance
            ->add_option("--inline-mesh-bytes", dist.inline_mesh_bytes,
                         "With --server: objects beyond this many bytes (in all) are uploaded "
                         "in chunks instead of inline")
            ->transform(cli::size_text(1024, true))
            ->capture_default_str()
            ->needs(server_opt);
        distance->add_flag("--split-components", dist.split_components,
                           "Make each connected component of a file an object");
        distance->add_flag("--weld", dist.weld,
                           "Merge vertices at identical positions in every file (by default "
                           "only in triangle soups, files whose triangles share no vertex)");
        distance->add_flag("--self", dist.self,
                           "Also: for every triangle, its closest non-adjacent triangle");
        distance->add_flag("--collisions", dist.collisions,
                           "Also: every intersecting triangle pair");
        distance
            ->add_option("--tolerance", dist.tolerance,
                         "Also: every triangle pair within this distance")
            ->check(cli::non_negative_number());
        distance->add_flag("--penetration", dist.penetration,
                           "Also: a local penetration vector per intersecting object pair "
                           "(implies --collisions)");
        distance->add_flag("--pns", dist.pns,
                           "Also: the culler's candidate pairs for the tolerance (or contact)");
        distance
            ->add_option("--culler", dist.culler,
                         "auto, brute, bvh, voronoi-cpu or voronoi-gpu (headless EGL)")
            ->check(CLI::IsMember({"auto", "brute", "bvh", "voronoi-cpu", "voronoi-gpu"}))
            ->capture_default_str();
        distance
            ->add_option("--voronoi-cell", dist.voronoi_cell,
                         "Voronoi cullers: grid cell size in scene units (default: the engine's "
                         "choice)")
            ->check(cli::positive_number());
        cli::add_json_output(*distance, dist.output);
        distance
            ->add_option("files", dist.files,
                         "Mesh files (PLY, OFF, OBJ, STL, glTF/GLB; each also .gz)")
            ->required();

        DemoArgs demo_args;
        auto* demo = app.add_subcommand(
            "demo", "Stream a built-in deforming scene through the engine, frame by frame");
        demo->add_option("--scene", demo_args.scene, "skirt, cloth-ball, bowl, ramps or breaking")
            ->capture_default_str();
        demo->add_option("--frames", demo_args.frames, "Number of frames")
            ->check(cli::whole_number(1, 100000))
            ->capture_default_str();
        demo->add_option("--culler", demo_args.culler,
                         "auto, brute, bvh, voronoi-cpu or voronoi-gpu (headless EGL)")
            ->check(CLI::IsMember({"auto", "brute", "bvh", "voronoi-cpu", "voronoi-gpu"}))
            ->capture_default_str();
        auto* demo_server = demo->add_option(
            "--server", demo_args.server, "Stream the frames to the proximad daemon at HOST:PORT");
        cli::add_server_flags(*demo, demo_args.server_flags, demo_server);
        demo->add_flag("--json", demo_args.json, "One JSON object per frame on standard output");
        demo->add_option("--out", demo_args.out,
                         "Write the JSON lines to FILE instead (a one-line summary on standard "
                         "error)")
            ->type_name("FILE");

        InfoArgs info_args;
        auto* info = app.add_subcommand("info", "Show a proximad daemon's version and limits");
        info->add_option("--server", info_args.server, "The daemon's HOST:PORT")->required();
        cli::add_server_flags(*info, info_args.server_flags);
        cli::add_json_output(*info, info_args.output);

        int command_exit = -1;
        cli::add_ccd_command(app, command_exit);
        cli::add_ccd_queries_command(app, command_exit);
        cli::add_import_command(app, command_exit);
        cli::add_generate_command(app, command_exit);
        cli::add_massive_commands(app, command_exit);
        cli::add_play_command(app, command_exit);
        cli::add_load_command(app, command_exit);
        cli::add_snapshot_command(app, command_exit);

        if (const int code = cli::parse_command_line(app, argc, argv); code >= 0) {
            return code;
        }
        if (command_exit >= 0) {
            return command_exit;
        }
        if (*version) {
            std::printf("proxima %s\n", PROXIMA_VERSION);
            return 0;
        }
        if (*distance) {
            return run_distance(dist);
        }
        if (*demo) {
            return run_demo(demo_args);
        }
        if (*info) {
            return run_info(info_args);
        }
        return 2;
    } catch (const std::bad_alloc&) {
        std::fprintf(stderr, "proxima: error: out of memory\n");
        return 1;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "proxima: error: %s\n", e.what());
        return 1;
    }
}
