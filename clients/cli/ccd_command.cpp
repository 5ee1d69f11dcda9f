// proxima ccd: continuous collision detection between two frames of a scene given as two mesh
// files with the same topology (each vertex moves linearly from its position in T0_FILE to its
// position in T1_FILE). Every vertex-triangle and edge-edge pair that touches in [0, 1], within
// and between objects, with its time of impact; per object pair and for the scene the earliest.
// Local mode runs the engine in this process; --server creates a scene on the daemon with the
// T0 objects and sends one CCD frame with the T1 positions (the result is a ccd::CcdResult either
// way and is printed by the same function, so the two modes print the same answer).

#include <cstdio>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli/commands.hpp"
#include "client/proxima_client.hpp"
#include "common/local_scene.hpp"
#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/scene.hpp"

namespace proxima::cli {

namespace {

struct CcdArgs {
    bool local = false;
    std::string server;
    ServerFlags server_flags;
    bool split_components = false;
    bool weld = false;
    double min_distance = 0.0;
    double toi_tolerance = ccd::ElementaryOptions{}.toi_tolerance;
    JsonOutput output;
    std::vector<std::string> files;
};

// `p` already in the files' numbering (client::in_file_numbering).
nlohmann::json pair_json(const ccd::CcdPair& p) {
    return {
        {"kind", ccd::ccd_kind_name(p.kind)},
        {"object", p.object},
        {"primitive", p.primitive},
        {"other", p.other},
        {"other_primitive", p.other_primitive},
        {"vertices", std::vector<std::uint32_t>(
                         p.vertices.begin(), p.vertices.begin() + static_cast<std::ptrdiff_t>(
                                                                      ccd::vertex_count(p.kind)))},
        {"other_vertices", std::vector<std::uint32_t>(
                               p.other_vertices.begin(),
                               p.other_vertices.begin() +
                                   static_cast<std::ptrdiff_t>(ccd::other_vertex_count(p.kind)))},
        {"toi", p.toi},
        {"capped", p.capped}};
}

}  // namespace

StatusOr<FramePair> load_frame_pair(const std::string& t0_file, const std::string& t1_file,
                                    bool split_components, WeldMode weld) {
    auto t0 = client::load_objects({t0_file}, split_components, weld);
    if (!t0.ok()) {
        return t0.status();
    }
    auto t1 = client::load_objects({t1_file}, split_components, weld);
    if (!t1.ok()) {
        return t1.status();
    }
    const auto& a = t0.value();
    const auto& b = t1.value();
    const std::string both = "'" + t0_file + "' and '" + t1_file + "'";
    if (a.size() != b.size()) {
        return invalid_argument(both +
                                " do not have the same topology: " + std::to_string(a.size()) +
                                " objects at t0, " + std::to_string(b.size()) + " at t1");
    }
    FramePair frames;
    for (std::size_t i = 0; i < a.size(); ++i) {
        const auto& ma = a[i].mesh.mesh;
        const auto& mb = b[i].mesh.mesh;
        if (ma.vertices.size() != mb.vertices.size()) {
            return invalid_argument(both + " do not have the same topology: object " +
                                    std::to_string(i) + " has " +
                                    std::to_string(ma.vertices.size()) + " vertices at t0, " +
                                    std::to_string(mb.vertices.size()) + " at t1");
        }
        if (ma.triangles != mb.triangles) {
            return invalid_argument(
                both + " do not have the same topology: the triangles of object " +
                std::to_string(i) + " differ (" + std::to_string(ma.triangles.size()) + " at t0, " +
                std::to_string(mb.triangles.size()) + " at t1)");
        }
        frames.positions_t1.push_back(mb.vertices);
    }
    frames.objects = std::move(t0).value();
    return frames;
}

namespace {

// Prints a CCD result, local or from a daemon. Objects are indices of the objects as loaded
// (files in order, or their connected components with --split-components); every other id is the
// file's own: a vf primitive is a file vertex id and other_primitive a file triangle id; ee
// primitives are file edge indices (positions in the sorted list of the file's unique edges, as
// vertex id pairs); `vertices` / `other_vertices` are file vertex ids.
int print_ccd_result(const std::vector<client::InputObject>& objects, const ccd::CcdResult& result,
                     const JsonOutput& output) {
    // The same result with every id in the files' numbering.
    ccd::CcdResult r = result;
    const auto file_edges = client::file_edge_ids(objects);
    for (auto& p : r.pairs) {
        p = client::in_file_numbering(objects, file_edges, p);
    }
    const auto& st = r.stats;
    if (output.wanted()) {
        nlohmann::json doc;
        doc["objects"] = nlohmann::json::array();
        for (const auto& o : objects) {
            doc["objects"].push_back({{"name", o.mesh.name},
                                      {"file", o.file},
                                      {"component", o.component},
                                      {"vertex_count", o.mesh.mesh.vertices.size()},
                                      {"triangle_count", o.mesh.mesh.triangles.size()}});
        }
        doc["pairs"] = nlohmann::json::array();
        for (const auto& p : r.pairs) {
            doc["pairs"].push_back(pair_json(p));
        }
        doc["object_pairs"] = nlohmann::json::array();
        for (const auto& op : r.object_pairs) {
            // The proto's ObjectPairToi: the object pair (object <= other), its earliest toi and
            // the index in `pairs` of that contact, whose own `object` owns its `primitive`.
            doc["object_pairs"].push_back(
                {{"object", op.object}, {"other", op.other}, {"toi", op.toi}, {"pair", op.pair}});
        }
        doc["earliest"] = r.earliest ? pair_json(r.pairs[*r.earliest]) : nlohmann::json(nullptr);
        doc["stats"] = {{"candidate_pairs", st.candidate_pairs},
                        {"elementary_tests", st.elementary_tests},
                        {"brute_force_tests", st.brute_force_tests},
                        {"capped_tests", st.capped_tests},
                        {"object_pairs_tested", st.object_pairs_tested},
                        {"broad_phase_seconds", st.broad_phase_seconds},
                        {"narrow_phase_seconds", st.narrow_phase_seconds},
                        {"total_seconds", st.total_seconds}};
        return emit_json(doc, output,
                         "ccd: " + std::to_string(r.pairs.size()) + " colliding pairs among " +
                             std::to_string(objects.size()) + " objects");
    }
    auto name = [&](std::uint32_t i) {
        return i < objects.size() ? objects[i].mesh.name : "object " + std::to_string(i);
    };
    std::size_t vf = 0;
    for (const auto& p : r.pairs) {
        vf += p.kind == ccd::CcdKind::vertex_face ? 1 : 0;
    }
    std::printf("%zu contacts (%zu vertex-face, %zu edge-edge) in %zu object pairs\n",
                r.pairs.size(), vf, r.pairs.size() - vf, r.object_pairs.size());
    if (r.earliest) {
        const auto& p = r.pairs[*r.earliest];
        std::printf("earliest: toi %.9g, %s %s %u of %s - %s %u of %s%s\n", p.toi,
                    ccd::ccd_kind_name(p.kind),
                    p.kind == ccd::CcdKind::vertex_face ? "vertex" : "edge", p.primitive,
                    name(p.object).c_str(),
                    p.kind == ccd::CcdKind::vertex_face ? "triangle" : "edge", p.other_primitive,
                    name(p.other).c_str(), p.capped ? " (capped)" : "");
    } else {
        std::printf("no contact in [0, 1]\n");
    }
    for (const auto& op : r.object_pairs) {
        const auto& p = r.pairs[op.pair];
        std::printf("%-30s %-30s  toi %.9g (%s %u - %u)\n", name(op.object).c_str(),
                    name(op.other).c_str(), op.toi, ccd::ccd_kind_name(p.kind), p.primitive,
                    p.other_primitive);
    }
    std::printf(
        "%llu candidate triangle pairs, %llu elementary tests (brute force: %llu), %llu "
        "capped; broad %.3f ms, narrow %.3f ms, total %.3f ms\n",
        static_cast<unsigned long long>(st.candidate_pairs),
        static_cast<unsigned long long>(st.elementary_tests),
        static_cast<unsigned long long>(st.brute_force_tests),
        static_cast<unsigned long long>(st.capped_tests), st.broad_phase_seconds * 1e3,
        st.narrow_phase_seconds * 1e3, st.total_seconds * 1e3);
    return 0;
}

StatusOr<ccd::CcdResult> ccd_local(const FramePair& frames, const ccd::CcdRequest& request) {
    Scene scene;
    for (const auto& obj : frames.objects) {
        auto id = scene.add_object(obj.mesh);
        if (!id.ok()) {
            return id.status();
        }
    }
    return ccd::continuous_collisions(scene, frames.positions_t1, request);
}

// On the daemon: a scene with the T0 objects (in input order, so indices mean the same as
// locally), one CCD frame moving every object to its T1 positions, then the scene is deleted.
StatusOr<ccd::CcdResult> ccd_remote(const CcdArgs& args, const FramePair& frames,
                                    const ccd::CcdRequest& request) {
    auto c = connect_server(args.server, args.server_flags);
    if (!c.ok()) {
        return c.status();
    }
    auto response = query_in_temporary_scene(
        *c.value(), "proxima ccd", frames.objects,
        [&](client::FrameRequest& frame, const client::RemoteScene& scene) {
            frame.ccd = true;
            frame.ccd_request = request;
            frame.queries.separation = false;
            for (std::size_t i = 0; i < frames.objects.size(); ++i) {
                frame.update.positions.push_back({scene.objects[i].id, frames.positions_t1[i]});
            }
        });
    if (!response.ok()) {
        return response.status();
    }
    if (!response->ccd) {
        return Status(StatusCode::internal, "the daemon's answer has no CCD result");
    }
    // Object and pair indices were checked when the answer was decoded.
    return std::move(*response->ccd);
}

int run_ccd(const CcdArgs& args) {
    auto frames =
        load_frame_pair(args.files[0], args.files[1], args.split_components, weld_mode(args.weld));
    if (!frames.ok()) {
        return fail(frames.status());
    }
    ccd::CcdRequest request;
    request.elementary.min_distance = args.min_distance;
    request.elementary.toi_tolerance = args.toi_tolerance;
    auto result = args.server.empty() ? ccd_local(frames.value(), request)
                                      : ccd_remote(args, frames.value(), request);
    if (!result.ok()) {
        return fail(result.status());
    }
    return print_ccd_result(frames->objects, result.value(), args.output);
}

}  // namespace

void add_ccd_command(CLI::App& app, int& exit_code) {
    auto args = std::make_shared<CcdArgs>();
    auto* cmd = app.add_subcommand(
        "ccd",
        "Continuous collisions between two frames: every vertex moves linearly from T0_FILE to "
        "T1_FILE (same topology)");
    add_local_or_server(*cmd, args->local, args->server, args->server_flags,
                        "Run the engine in this process (the default)",
                        "Run on the proximad daemon at HOST:PORT instead");
    cmd->add_flag("--split-components", args->split_components,
                  "Make each connected component of a file an object");
    cmd->add_flag("--weld", args->weld,
                  "Merge vertices at identical positions in every file (by default only in "
                  "triangle soups, files whose triangles share no vertex)");
    cmd->add_option("--min-distance", args->min_distance,
                    "Report contact when primitives come within this distance")
        ->check(non_negative_number())
        ->capture_default_str();
    cmd->add_option("--toi-tolerance", args->toi_tolerance,
                    "Precision of each time of impact, a fraction of the step in [0, 1]")
        ->check(CLI::Range(0.0, 1.0))
        ->capture_default_str();
    add_json_output(*cmd, args->output);
    cmd->add_option("files", args->files, "T0_FILE T1_FILE: the two frames (any mesh format)")
        ->required()
        ->expected(2);
    cmd->callback([args, &exit_code] { exit_code = run_ccd(*args); });
}

}  // namespace proxima::cli
