// proxima generate: the deterministic test models of the massive-model path as files.
//   proxima generate plant --triangles 15M --seed 1 --out DIR
//     every object of the procedural plant as DIR/meshes/<object name>.ply (binary PLY with
//     double coordinates: exact, and about 4x smaller and 20x faster to write than OFF text),
//     listed in DIR/scene.json (format proxima-scene/1, no transforms);
//   proxima generate building --furniture DIR --triangles 2M --seed 1 --out DIR
//     the furnished building (engine: generate_building);
//   proxima generate sequence --scene breaking --frames 16 --fps 30 --dir DIR
//     a procedural scene (engine: scenes::by_name) recorded for `proxima play`: one binary PLY per
//     frame, DIR/frame_0000.ply, ... (the frame's objects are the file's connected components,
//     in scene order), and DIR/sequence.json (the rate, and each frame's object names).
// Both print a one-line JSON summary on standard output, progress on standard error.

#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <system_error>

#include <nlohmann/json.hpp>

#include "cli/commands.hpp"
#include "common/json_output.hpp"
#include "common/progress.hpp"
#include "proxima/io/mesh_io.hpp"
#include "proxima/massive/generator.hpp"
#include "proxima/scenes/procedural.hpp"

namespace proxima::cli {

namespace {

namespace fs = std::filesystem;

// "15M" -> 15 * 2^20 (the one size rule: K, M, G, T are powers of 1024), at most 2^40.
StatusOr<std::uint64_t> parse_triangles(const std::string& text) {
    auto n = parse_size("--triangles", text, 1024);
    if (n.ok() && *n > (std::uint64_t{1} << 40)) {
        return invalid_argument("--triangles '" + text + "': at most 1T (2^40) triangles");
    }
    return n;
}

struct GenerateArgs {
    std::string scene;
    std::size_t frames = 16;
    double fps = 30.0;
    std::string triangles;
    std::uint64_t seed = 1;
    std::string out;
    std::string furniture;
    bool verify = false;
    bool quiet = false;
    JsonOutput output;
};

template <class T>
void append_le(std::string& out, T value) {
    auto bits = std::bit_cast<std::array<unsigned char, sizeof(T)>>(value);
    if constexpr (std::endian::native == std::endian::big) {
        std::reverse(bits.begin(), bits.end());
    }
    out.append(reinterpret_cast<const char*>(bits.data()), bits.size());
}

// Binary little-endian PLY: double x, y, z; faces as uchar-counted uint lists. proxima's own PLY
// reader takes it back bit for bit.
Status write_ply(const std::string& path, const TriangleMesh& mesh, std::string& buffer) {
    buffer.clear();
    buffer += "ply\nformat binary_little_endian 1.0\nelement vertex " +
              std::to_string(mesh.vertices.size()) +
              "\nproperty double x\nproperty double y\nproperty double z\nelement face " +
              std::to_string(mesh.triangles.size()) +
              "\nproperty list uchar uint vertex_indices\nend_header\n";
    buffer.reserve(buffer.size() + mesh.vertices.size() * 24 + mesh.triangles.size() * 13);
    for (const auto& v : mesh.vertices) {
        append_le(buffer, v.x);
        append_le(buffer, v.y);
        append_le(buffer, v.z);
    }
    for (const auto& t : mesh.triangles) {
        buffer.push_back(3);
        append_le(buffer, t[0]);
        append_le(buffer, t[1]);
        append_le(buffer, t[2]);
    }
    std::FILE* f = std::fopen(path.c_str(), "wb");
    if (f == nullptr) {
        return Status(StatusCode::unavailable, "cannot create '" + path + "'");
    }
    const bool written = std::fwrite(buffer.data(), 1, buffer.size(), f) == buffer.size();
    const bool closed = std::fclose(f) == 0;
    return written && closed ? Status{}
                             : Status(StatusCode::unavailable, "cannot write '" + path + "'");
}

bool same_mesh(const TriangleMesh& a, const TriangleMesh& b) {
    if (a.triangles != b.triangles || a.vertices.size() != b.vertices.size()) {
        return false;
    }
    for (std::size_t i = 0; i < a.vertices.size(); ++i) {
        for (int k = 0; k < 3; ++k) {
            if (std::bit_cast<std::uint64_t>(a.vertices[i][k]) !=
                std::bit_cast<std::uint64_t>(b.vertices[i][k])) {
                return false;
            }
        }
    }
    return true;
}

nlohmann::json summary_json(const std::string& model, const massive::GeneratedSummary& s,
                            const std::string& scene, double seconds) {
    return {{"model", model},
            {"object_count", s.objects},
            {"triangle_count", s.triangles},
            {"vertex_count", s.vertices},
            {"box", client::box_json(s.box)},
            {"scene", scene},
            {"seconds", seconds}};
}

// The one-line summary after --out FILE.
std::string generated_line(const std::string& model, std::uint64_t triangles,
                           const std::string& dir) {
    return "generate: " + model + " of " + std::to_string(triangles) + " triangles in " + dir;
}

double seconds_since(std::chrono::steady_clock::time_point start) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

int run_plant(const GenerateArgs& args) {
    auto triangles = parse_triangles(args.triangles);
    if (!triangles.ok()) {
        return fail(triangles.status());
    }
    const auto start = std::chrono::steady_clock::now();
    const fs::path out(args.out);
    std::error_code ec;
    fs::create_directories(out / "meshes", ec);
    if (ec) {
        return fail(Status(StatusCode::unavailable,
                           "cannot create '" + (out / "meshes").string() + "': " + ec.message()));
    }
    massive::PlantOptions options;
    options.triangles = triangles.value();
    options.seed = args.seed;
    nlohmann::ordered_json meshes = nlohmann::ordered_json::object();
    nlohmann::ordered_json objects = nlohmann::ordered_json::array();
    std::string buffer;
    fs::path made_dir;
    client::ProgressPrinter printer(args.quiet);
    auto generated = massive::generate_plant(
        options,
        [&](massive::ModelObject&& object) -> Status {
            // "bay-0012/pipe-3" -> meshes/bay-0012/pipe-3.ply
            const std::string file = "meshes/" + object.name + ".ply";
            const fs::path path = out / file;
            if (path.parent_path() != made_dir) {
                std::error_code dir_ec;
                fs::create_directories(path.parent_path(), dir_ec);
                if (dir_ec) {
                    return Status(
                        StatusCode::unavailable,
                        "cannot create '" + path.parent_path().string() + "': " + dir_ec.message());
                }
                made_dir = path.parent_path();
            }
            if (Status s = write_ply(path.string(), object.mesh, buffer); !s.ok()) {
                return s;
            }
            if (args.verify) {
                auto back = read_mesh(path.string());
                if (!back.ok()) {
                    return back.status();
                }
                if (!same_mesh(back.value(), object.mesh)) {
                    return Status(StatusCode::internal,
                                  "'" + path.string() + "' does not read back bit for bit");
                }
            }
            meshes[object.name] = file;
            nlohmann::ordered_json part = {{"mesh", object.name}};
            nlohmann::ordered_json entry = {{"name", object.name}};
            entry["parts"] = nlohmann::ordered_json::array();
            entry["parts"].push_back(std::move(part));
            objects.push_back(std::move(entry));
            return {};
        },
        printer.callback());
    printer.finish();
    if (!generated.ok()) {
        return fail(generated.status());
    }
    nlohmann::ordered_json scene;
    scene["format"] = "proxima-scene/1";
    scene["meshes"] = std::move(meshes);
    scene["objects"] = std::move(objects);
    const std::string scene_file = (out / "scene.json").string();
    {
        std::ofstream file(scene_file, std::ios::binary | std::ios::trunc);
        file << scene.dump(1) << '\n';
        if (!file.good()) {
            return fail(Status(StatusCode::unavailable, "cannot write '" + scene_file + "'"));
        }
    }
    return emit_json(summary_json("plant", generated.value(), scene_file, seconds_since(start)),
                     args.output, generated_line("plant", generated->triangles, args.out));
}

int run_building(const GenerateArgs& args) {
    auto triangles = parse_triangles(args.triangles);
    if (!triangles.ok()) {
        return fail(triangles.status());
    }
    const auto start = std::chrono::steady_clock::now();
    massive::BuildingOptions options;
    options.furniture_dir = args.furniture;
    options.triangles = triangles.value();
    options.seed = args.seed;
    client::ProgressPrinter printer(args.quiet);
    auto generated = massive::generate_building(options, args.out, printer.callback());
    printer.finish();
    if (!generated.ok()) {
        return fail(generated.status());
    }
    return emit_json(
        summary_json("building", generated->summary, generated->scene_file, seconds_since(start)),
        args.output, generated_line("building", generated->summary.triangles, args.out));
}

// A procedural scene recorded frame by frame: each frame's objects concatenated into one mesh (the
// objects are its connected components, in order), so `proxima play --split-components` streams
// it back with the same objects, and a break (replacement by fragments) is a topology change.
int run_sequence(const GenerateArgs& args) {
    const auto start = std::chrono::steady_clock::now();
    auto procedural = scenes::by_name(args.scene, args.frames);
    if (procedural.name.empty()) {
        return fail(invalid_argument("unknown scene '" + args.scene +
                                     "' (expected skirt, cloth-ball, bowl, ramps or breaking)"));
    }
    const fs::path out(args.out);
    std::error_code ec;
    fs::create_directories(out, ec);
    if (ec) {
        return fail(Status(StatusCode::unavailable,
                           "cannot create '" + out.string() + "': " + ec.message()));
    }
    client::ProgressPrinter printer(args.quiet);
    Scene scene;
    nlohmann::ordered_json frames = nlohmann::ordered_json::array();
    std::string buffer;
    Aabb box;
    std::size_t topology_changes = 0;
    TriangleMesh frame_mesh;
    for (std::size_t k = 0; k < procedural.frame_count; ++k) {
        SceneUpdate update;
        if (k == 0) {
            update.additions = procedural.initial;
        } else {
            update = procedural.step(k, scene);
        }
        const bool topology_change =
            k > 0 &&
            (!update.replacements.empty() || !update.additions.empty() || !update.removals.empty());
        topology_changes += topology_change ? 1 : 0;
        if (auto applied = scene.apply(std::move(update)); !applied.ok()) {
            return fail(applied.status());
        }
        frame_mesh.vertices.clear();
        frame_mesh.triangles.clear();
        nlohmann::ordered_json names = nlohmann::ordered_json::array();
        for (const auto& obj : scene.objects()) {
            const auto base = static_cast<std::uint32_t>(frame_mesh.vertices.size());
            frame_mesh.vertices.insert(frame_mesh.vertices.end(), obj.vertices.begin(),
                                       obj.vertices.end());
            for (const auto& t : obj.topology->triangles()) {
                frame_mesh.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
            }
            box.extend(obj.box);
            names.push_back(obj.name);
        }
        char name[32];
        std::snprintf(name, sizeof name, "frame_%04zu.ply", k);
        if (Status s = write_ply((out / name).string(), frame_mesh, buffer); !s.ok()) {
            return fail(s);
        }
        nlohmann::ordered_json entry;
        entry["file"] = name;
        entry["topology_change"] = topology_change;
        entry["object_count"] = scene.size();
        entry["triangle_count"] = frame_mesh.triangles.size();
        entry["objects"] = std::move(names);
        frames.push_back(std::move(entry));
        printer.update({"writing frames", k + 1, procedural.frame_count, "frames"});
    }
    printer.finish();
    nlohmann::ordered_json doc;
    doc["format"] = "proxima-sequence/1";
    doc["scene"] = procedural.name;
    doc["description"] = procedural.description;
    doc["fps"] = args.fps;
    doc["frame_count"] = procedural.frame_count;
    doc["frames"] = std::move(frames);
    const std::string sequence_file = (out / "sequence.json").string();
    {
        std::ofstream file(sequence_file, std::ios::binary | std::ios::trunc);
        file << doc.dump(1) << '\n';
        if (!file.good()) {
            return fail(Status(StatusCode::unavailable, "cannot write '" + sequence_file + "'"));
        }
    }
    const nlohmann::json summary = {{"model", "sequence"},
                                    {"object_count", scene.size()},
                                    {"triangle_count", frame_mesh.triangles.size()},
                                    {"vertex_count", frame_mesh.vertices.size()},
                                    {"box", client::box_json(box)},
                                    {"scene", sequence_file},
                                    {"frame_count", procedural.frame_count},
                                    {"topology_change_count", topology_changes},
                                    {"seconds", seconds_since(start)}};
    return emit_json(summary, args.output,
                     "generate: " + std::to_string(procedural.frame_count) + " frames of " +
                         procedural.name + " in " + args.out);
}

}  // namespace

void add_generate_command(CLI::App& app, int& exit_code) {
    auto* cmd = app.add_subcommand(
        "generate",
        "Write a deterministic test model (procedural plant or furnished building) or a "
        "procedural frame sequence");
    cmd->require_subcommand(1);

    auto plant = std::make_shared<GenerateArgs>();
    plant->triangles = "1M";
    auto* plant_cmd = cmd->add_subcommand(
        "plant",
        "A procedural process plant (frames, tanks, pipe runs, walkways, stairs): one binary PLY "
        "per object under OUT/meshes and OUT/scene.json");
    plant_cmd
        ->add_option("--triangles", plant->triangles,
                     "Approximate triangle count (within 10%); K, M, G: powers of 1024")
        ->check(size_text(1024))
        ->capture_default_str();
    plant_cmd->add_option("--seed", plant->seed, "Seed (same options, same model)")
        ->check(whole_number(0, UINT64_MAX))
        ->capture_default_str();
    plant_cmd->add_option("--dir", plant->out, "Output directory (created if absent)")->required();
    plant_cmd->add_flag("--verify", plant->verify,
                        "Read every written mesh back and check it is bit-identical");
    plant_cmd->add_flag("--quiet", plant->quiet, "No progress on standard error");
    add_json_output(*plant_cmd, plant->output, true);
    plant_cmd->callback([plant, &exit_code] { exit_code = run_plant(*plant); });

    auto building = std::make_shared<GenerateArgs>();
    building->triangles = "2M";
    auto* building_cmd = cmd->add_subcommand(
        "building",
        "A multi-storey building furnished with instances of real furniture meshes: shell meshes "
        "under OUT/shell and OUT/scene.json referencing the furniture files");
    building_cmd
        ->add_option("--furniture", building->furniture,
                     "Directory of furniture meshes (e.g. ../shared/data/meshes/furniture-cc0)")
        ->required();
    building_cmd
        ->add_option("--triangles", building->triangles,
                     "Approximate triangle count, furniture included; K, M, G: powers of 1024")
        ->check(size_text(1024))
        ->capture_default_str();
    building_cmd->add_option("--seed", building->seed, "Seed (same options, same model)")
        ->check(whole_number(0, UINT64_MAX))
        ->capture_default_str();
    building_cmd->add_option("--dir", building->out, "Output directory (created if absent)")
        ->required();
    building_cmd->add_flag("--quiet", building->quiet, "No progress on standard error");
    add_json_output(*building_cmd, building->output, true);
    building_cmd->callback([building, &exit_code] { exit_code = run_building(*building); });

    auto sequence = std::make_shared<GenerateArgs>();
    sequence->scene = "breaking";
    auto* sequence_cmd = cmd->add_subcommand(
        "sequence",
        "A procedural deforming scene recorded for proxima play: OUT/frame_0000.ply, ... (objects "
        "as connected components) and OUT/sequence.json");
    sequence_cmd
        ->add_option("--scene", sequence->scene,
                     "skirt, cloth-ball, bowl, ramps or breaking (objects break into pieces "
                     "halfway: a topology change)")
        ->capture_default_str();
    sequence_cmd->add_option("--frames", sequence->frames, "Number of frames")
        ->check(whole_number(1, 100000))
        ->capture_default_str();
    sequence_cmd->add_option("--fps", sequence->fps, "The recorded rate (sequence.json)")
        ->check(finite_number(0.0, true))
        ->capture_default_str();
    sequence_cmd->add_option("--dir", sequence->out, "Output directory (created if absent)")
        ->required();
    sequence_cmd->add_flag("--quiet", sequence->quiet, "No progress on standard error");
    add_json_output(*sequence_cmd, sequence->output, true);
    sequence_cmd->callback([sequence, &exit_code] { exit_code = run_sequence(*sequence); });
}

}  // namespace proxima::cli
