// proxima play: the recorded-sequence player. Streams a folder of numbered mesh files (one file
// per frame; the objects of a frame are the file, or with --split-components its connected
// components), or the keyframes of an MD2 model, through the engine in this process (--local,
// the default) or to a proximad daemon (--server), at the recorded rate (DIR/sequence.json
// {"fps": N}, or --fps N) or as fast as answered, with the chosen queries, and prints one line
// per frame (one JSON object per frame with --json) and a summary. A frame whose objects keep
// their topology moves vertices; any other is a topology change mid-stream (common/sequence.hpp:
// diff_frames). The player itself is common/player.hpp, shared with the load harness.

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli/commands.hpp"
#include "common/json_output.hpp"
#include "common/player.hpp"
#include "common/progress.hpp"
#include "proxima/culling/culler.hpp"
#include "proxima/gpu/egl_backend.hpp"
#include "proxima/query/query.hpp"

namespace proxima::cli {

namespace {

struct PlayArgs {
    std::string dir;
    bool local = false;
    std::string server;
    ServerFlags server_flags;
    double fps = 0.0;
    bool as_fast = false;
    std::size_t in_flight = 1;
    bool resilient = false;
    std::vector<std::string> queries{"separation"};
    double tolerance = -1.0;
    double ccd_min_distance = 0.0;
    std::string frames;
    std::string culler = "auto";
    bool split_components = false;
    bool weld = false;
    bool quiet = false;
    JsonOutput output;
    CLI::App* command = nullptr;
};

// "A:B", "A:", ":B" or "A" (frame A alone): frames [A, B) of the folder's natural order.
bool parse_frames(const std::string& text, client::SequenceOptions& options) {
    if (text.empty()) {
        return true;
    }
    auto number = [](const std::string& s, std::size_t& out) {
        if (s.empty() || s.size() > 12 || s.find_first_not_of("0123456789") != std::string::npos) {
            return false;
        }
        out = static_cast<std::size_t>(std::stoull(s));
        return true;
    };
    const auto colon = text.find(':');
    if (colon == std::string::npos) {
        if (!number(text, options.begin)) {
            return false;
        }
        options.end = options.begin + 1;
        return true;
    }
    const std::string a = text.substr(0, colon);
    const std::string b = text.substr(colon + 1);
    if ((!a.empty() && !number(a, options.begin)) || (!b.empty() && !number(b, options.end))) {
        return false;
    }
    return !(a.empty() && b.empty());
}

nlohmann::json nullable(double d) {
    return std::isfinite(d) ? nlohmann::json(d) : nlohmann::json(nullptr);
}

// The closest object pair of the frame (the vocabulary's closest pair; triangle ids in the
// frame file, object indices in the frame's object list).
nlohmann::json closest_json(const client::SequenceFrame& frame, const QueryResult& r) {
    std::size_t best = 0;
    for (std::size_t i = 1; i < r.separation.size(); ++i) {
        if (r.separation[i].distance < r.separation[best].distance) {
            best = i;
        }
    }
    const auto& objects = frame.objects;
    if (r.separation.empty() || r.separation[best].other == NO_OBJECT) {
        return {{"object", 0},        {"triangle", nullptr},       {"point", nullptr},
                {"other", nullptr},   {"other_triangle", nullptr}, {"other_point", nullptr},
                {"distance", nullptr}};
    }
    const auto& s = r.separation[best];
    const auto other = static_cast<std::size_t>(s.other);
    return {{"object", best},
            {"triangle", objects[best].file_triangle[s.triangle]},
            {"point", client::point_json(s.point)},
            {"other", other},
            {"other_triangle", objects[other].file_triangle[s.other_triangle]},
            {"other_point", client::point_json(s.other_point)},
            {"distance", s.distance}};
}

struct Asked {
    bool separation = false;
    bool self = false;
    bool collisions = false;
    bool tolerance = false;
    bool ccd = false;
};

nlohmann::json frame_json(const client::SequenceFrame& frame, const client::PlayedFrame& f,
                          const Asked& asked) {
    nlohmann::json j = {{"frame", frame.number},
                        {"file", frame.file},
                        {"topology_change", f.topology_change},
                        {"object_count", f.object_count},
                        {"triangle_count", f.triangle_count}};
    if (asked.separation) {
        j["closest"] = closest_json(frame, f.result);
    }
    if (asked.self) {
        j["min_self_distance"] = nullable(f.min_self_distance);
    }
    if (asked.collisions) {
        j["collision_count"] = f.collision_count;
    }
    if (asked.tolerance) {
        j["within_count"] = f.tolerance_count;
    }
    if (asked.ccd) {
        if (!f.ccd) {
            j["ccd"] = nullptr;  // the first frame, or a topology change
        } else {
            const auto& c = *f.ccd;
            nlohmann::json e = {{"toi", nullptr},
                                {"object", nullptr},
                                {"other", nullptr},
                                {"pair_count", c.pairs.size()}};
            if (c.earliest) {
                const auto& p = c.pairs[*c.earliest];
                e["toi"] = p.toi;
                e["object"] = p.object;
                e["other"] = p.other;
            }
            j["ccd"] = std::move(e);
        }
    }
    j["latency_ms"] = f.latency_ms;
    j["late_ms"] = f.late_ms;
    j["stats"] = client::stats_json(f.result.stats);
    return j;
}

std::string column(bool asked, const std::string& text) {
    return asked ? text : "-";
}

std::string number_text(double d) {
    if (!std::isfinite(d)) {
        return "inf";
    }
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.6g", d);
    return buf;
}

void print_header(const PlayArgs& args, const client::Sequence& seq, double fps) {
    std::printf("sequence %s: %zu frames, played %s%s", seq.dir.c_str(), seq.frames.size(),
                args.server.empty() ? "in this process" : "on proximad at ", args.server.c_str());
    if (fps > 0) {
        std::printf(" at %g frames/s\n", fps);
    } else {
        std::printf(" as fast as answered\n");
    }
    std::printf("%5s %4s %7s %9s %12s %12s %10s %8s %10s %9s %10s\n", "frame", "topo", "objects",
                "triangles", "min-separ.", "min-self", "collisions", "within", "toi", "engine-ms",
                "latency-ms");
}

void print_frame(const client::SequenceFrame& frame, const client::PlayedFrame& f,
                 const Asked& asked) {
    std::string toi = "-";
    if (asked.ccd && f.ccd) {
        toi = f.toi ? number_text(*f.toi) : "none";
    }
    std::printf("%5zu %4s %7zu %9zu %12s %12s %10s %8s %10s %9.2f %10.2f\n", frame.number,
                f.topology_change ? "T" : "", f.object_count, f.triangle_count,
                column(asked.separation, number_text(f.min_separation)).c_str(),
                column(asked.self, number_text(f.min_self_distance)).c_str(),
                column(asked.collisions, std::to_string(f.collision_count)).c_str(),
                column(asked.tolerance, std::to_string(f.tolerance_count)).c_str(), toi.c_str(),
                f.engine_ms, f.latency_ms);
    std::fflush(stdout);
}

std::string summary_text(const client::PlayReport& r, bool resilient) {
    std::vector<double> latency;
    std::size_t late = 0;
    for (const auto& f : r.frames) {
        latency.push_back(f.latency_ms);
        late += f.late_ms > 0 ? 1 : 0;
    }
    const auto s = client::spread(latency);
    char buf[320];
    std::snprintf(buf, sizeof buf,
                  "play: %zu frames (%zu topology changes) in %.1f ms; latency median %.2f ms, "
                  "p99 %.2f ms, max %.2f ms; scene set up in %.1f ms; %zu frames sent late",
                  r.frames.size(), r.topology_changes, r.wall_ms, s.median, s.p99, s.max,
                  r.setup_ms, late);
    std::string text = buf;
    if (resilient) {
        text += "; scene re-created " + std::to_string(r.recreations) + " times";
        for (const auto& cause : r.recreation_causes) {
            text += " (after " + cause + ")";
        }
    }
    return text;
}

int run_play(const PlayArgs& args) {
    client::SequenceOptions seq_options;
    seq_options.split_components = args.split_components;
    seq_options.weld = args.weld;
    if (!parse_frames(args.frames, seq_options)) {
        return usage_error(*args.command, "--frames '" + args.frames +
                                              "': expected A:B, A:, :B or A (frame numbers)");
    }
    Asked asked;
    for (const auto& q : args.queries) {
        asked.separation |= q == "separation";
        asked.self |= q == "self";
        asked.collisions |= q == "collisions";
        asked.tolerance |= q == "tolerance";
        asked.ccd |= q == "ccd";
    }
    asked.tolerance |= args.tolerance >= 0.0;
    if (asked.tolerance && args.tolerance < 0.0) {
        return usage_error(*args.command, "--query tolerance needs --tolerance X");
    }
    auto culler = parse_culler(args.culler);
    if (!culler.ok()) {
        return fail(culler.status());
    }
    auto sequence = client::load_sequence(args.dir, seq_options);
    if (!sequence.ok()) {
        return fail(sequence.status());
    }
    const auto& seq = sequence.value();

    client::PlayOptions options;
    options.queries.separation = asked.separation;
    options.queries.self = asked.self;
    options.queries.collisions = asked.collisions;
    if (asked.tolerance) {
        options.queries.tolerance = args.tolerance;
    }
    options.queries.culler = culler.value();
    options.ccd = asked.ccd;
    options.ccd_min_distance = args.ccd_min_distance;
    options.fps = args.as_fast ? 0.0 : args.fps > 0.0 ? args.fps : seq.fps;
    options.keep_results = false;
    options.in_flight = args.in_flight;
    options.resilient = args.resilient;
    // With --culler voronoi-gpu a local engine starts its own headless EGL context (as the daemon
    // does once at start-up); without one the frames fail with EGL's reason.
    options.prepare_engine = [&](ProximityEngine& engine) {
        if (options.queries.culler != CullerKind::voronoi_gpu) {
            return;
        }
        auto backend = gpu::make_egl_backend();
        if (backend.ok()) {
            engine.set_gpu_backend(std::move(backend).value());
        } else {
            engine.set_gpu_unavailable_reason("EGL unavailable: " + backend.status().message());
        }
    };

    std::FILE* sink = nullptr;
    if (!args.output.out.empty()) {
        sink = std::fopen(args.output.out.c_str(), "wb");
        if (sink == nullptr) {
            std::fprintf(stderr, "proxima: error: cannot write '%s'\n", args.output.out.c_str());
            return 1;
        }
    }
    const bool json = args.output.wanted();
    // Progress on standard error for long runs whose lines do not go to a terminal.
    const bool progress_wanted =
        !args.quiet && seq.frames.size() >= 50 && (sink != nullptr || isatty(STDOUT_FILENO) == 0);
    client::ProgressPrinter progress(!progress_wanted);
    options.on_frame = [&](const client::PlayedFrame& f) -> Status {
        const auto& frame = seq.frames[f.index];
        if (json) {
            const std::string line = frame_json(frame, f, asked).dump() + "\n";
            std::FILE* to = sink != nullptr ? sink : stdout;
            if (std::fwrite(line.data(), 1, line.size(), to) != line.size()) {
                return {StatusCode::internal, "cannot write the frame lines"};
            }
            std::fflush(to);
        } else {
            print_frame(frame, f, asked);
        }
        progress.update({"playing", f.index + 1, seq.frames.size(), "frames"});
        return {};
    };
    if (!json) {
        print_header(args, seq, options.fps);
    }
    StatusOr<client::PlayReport> report = Status{};
    if (args.server.empty()) {
        report = client::play_local(seq, options);
    } else {
        auto remote = connect_server(args.server, args.server_flags);
        if (!remote.ok()) {
            report = remote.status();
        } else {
            report = client::play_remote(*remote.value(), seq, options);
        }
    }
    progress.finish();
    if (sink != nullptr) {
        const bool written = std::ferror(sink) == 0;
        if (std::fclose(sink) != 0 || !written) {
            std::fprintf(stderr, "proxima: error: cannot write '%s'\n", args.output.out.c_str());
            return 1;
        }
    }
    if (!report.ok()) {
        return fail(report.status());
    }
    if (sink != nullptr) {
        std::fprintf(stderr, "%s; JSON in %s\n",
                     summary_text(report.value(), args.resilient).c_str(), args.output.out.c_str());
    } else if (!json) {
        std::printf("%s\n", summary_text(report.value(), args.resilient).c_str());
    }
    return 0;
}

}  // namespace

void add_play_command(CLI::App& app, int& exit_code) {
    auto args = std::make_shared<PlayArgs>();
    auto* cmd = app.add_subcommand(
        "play",
        "Play a recorded sequence (a folder of numbered mesh files, one per frame) through the "
        "engine or a daemon, with per-frame results and latency");
    args->command = cmd;
    cmd->add_option("dir", args->dir,
                    "The sequence: a folder of numbered mesh files (frame_000.obj, "
                    "frame_001.obj, ...) or a Quake II MD2 model (its keyframes)")
        ->required();
    auto* server_opt = add_local_or_server(*cmd, args->local, args->server, args->server_flags,
                                           "Run the engine in this process (the default)",
                                           "Stream the frames to the proximad daemon at HOST:PORT");
    auto* fps = cmd->add_option("--fps", args->fps,
                                "Send frames at this rate (default: the folder's sequence.json "
                                "fps, else as fast as answered)")
                    ->check(finite_number(0.0, true));
    cmd->add_flag("--as-fast-as-answered", args->as_fast,
                  "Send each frame as soon as the previous one is answered")
        ->excludes(fps);
    cmd->add_option("--in-flight", args->in_flight,
                    "With --server: frames sent ahead of their answers (pipelining; at most the "
                    "daemon's max_frames_in_flight); 1 is lockstep")
        ->check(whole_number(1, 1024))
        ->capture_default_str()
        ->needs(server_opt);
    cmd->add_flag("--resilient", args->resilient,
                  "With --server: re-create the scene (and re-send the frames in flight) when "
                  "the daemon goes away, e.g. on another daemon behind HAProxy")
        ->needs(server_opt);
    cmd->add_option("--query", args->queries,
                    "Comma-separated: separation, self, collisions, tolerance, ccd")
        ->delimiter(',')
        ->check(CLI::IsMember({"separation", "self", "collisions", "tolerance", "ccd"}))
        ->capture_default_str();
    cmd->add_option("--tolerance", args->tolerance,
                    "The tolerance query's distance (implies --query tolerance)")
        ->check(non_negative_number());
    cmd->add_option("--ccd-min-distance", args->ccd_min_distance,
                    "CCD: report contact when primitives come within this distance")
        ->check(non_negative_number())
        ->capture_default_str();
    cmd->add_option("--frames", args->frames,
                    "A:B plays frames A to B-1 of the folder's order (A:, :B, A also work)")
        ->type_name("A:B");
    cmd->add_option("--culler", args->culler,
                    "auto, brute, bvh, voronoi-cpu or voronoi-gpu (headless EGL)")
        ->check(CLI::IsMember({"auto", "brute", "bvh", "voronoi-cpu", "voronoi-gpu"}))
        ->capture_default_str();
    cmd->add_flag("--split-components", args->split_components,
                  "Make each connected component of a frame file an object");
    cmd->add_flag("--weld", args->weld,
                  "Merge vertices at identical positions in every file (by default only in "
                  "triangle soups; vertices meeting in one frame would make it a topology "
                  "change)");
    cmd->add_flag("--quiet", args->quiet, "No progress on standard error");
    cmd->add_flag("--json", args->output.json, "One JSON object per frame on standard output");
    cmd->add_option("--out", args->output.out,
                    "Write the JSON lines to FILE instead (a one-line summary on standard error)")
        ->type_name("FILE");
    cmd->callback([args, &exit_code] { exit_code = run_play(*args); });
}

}  // namespace proxima::cli
