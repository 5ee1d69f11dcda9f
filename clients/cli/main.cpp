// proxima: the command-line tool. `distance --local` runs the engine in-process on mesh files;
// `demo` streams a built-in deforming scene through the engine and prints per-frame results.
#include <cstdio>
#include <exception>
#include <iostream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "common/json_output.hpp"
#include "common/local_scene.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scenes/procedural.hpp"

namespace {

using namespace proxima;

int fail(const Status& status) {
    std::fprintf(stderr, "proxima: error: %s\n", status.to_string().c_str());
    return 1;
}

struct DistanceArgs {
    bool local = false;
    bool split_components = false;
    bool self = false;
    bool collisions = false;
    bool pns = false;
    bool json = false;
    double tolerance = -1.0;
    std::string culler = "auto";
    std::vector<std::string> files;
};

void print_text(const std::vector<client::InputObject>& objects, const QueryResult& r,
                const DistanceArgs& args) {
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
    std::printf("culler %s, %llu exact tests (brute force: %llu), %.3f ms\n", r.stats.culler.c_str(),
                static_cast<unsigned long long>(r.stats.exact_tests),
                static_cast<unsigned long long>(r.stats.brute_force_tests),
                r.stats.total_seconds * 1e3);
}

int run_distance(const DistanceArgs& args) {
    auto culler = parse_culler(args.culler);
    if (!culler.ok()) {
        return fail(culler.status());
    }
    auto objects = client::load_objects(args.files, args.split_components);
    if (!objects.ok()) {
        return fail(objects.status());
    }
    ProximityEngine engine;
    SceneUpdate update;
    for (const auto& obj : objects.value()) {
        update.additions.push_back(obj.mesh);
    }
    if (auto applied = engine.scene().apply(std::move(update)); !applied.ok()) {
        return fail(applied.status());
    }
    QueryRequest request;
    request.self = args.self;
    request.collisions = args.collisions;
    request.pns = args.pns;
    request.culler = culler.value();
    if (args.tolerance >= 0.0) {
        request.tolerance = args.tolerance;
    }
    auto result = engine.query(request);
    if (!result.ok()) {
        return fail(result.status());
    }
    if (args.json) {
        client::OutputOptions opts{args.self, args.collisions, args.tolerance >= 0.0, args.pns};
        std::cout << client::distance_json(objects.value(), result.value(), opts).dump() << '\n';
    } else {
        print_text(objects.value(), result.value(), args);
    }
    return 0;
}

struct DemoArgs {
    std::string scene = "cloth-ball";
    std::size_t frames = 8;
    bool json = false;
    std::string culler = "auto";
};

int run_demo(const DemoArgs& args) {
    auto culler = parse_culler(args.culler);
    if (!culler.ok()) {
        return fail(culler.status());
    }
    auto scene = scenes::by_name(args.scene, args.frames);
    if (scene.name.empty()) {
        return fail(invalid_argument("unknown scene '" + args.scene +
                                     "' (expected skirt, cloth-ball, bowl, ramps or breaking)"));
    }
    ProximityEngine engine;
    SceneUpdate first;
    first.additions = scene.initial;
    if (auto r = engine.scene().apply(std::move(first)); !r.ok()) {
        return fail(r.status());
    }
    if (!args.json) {
        std::printf("scene %s: %s\n", scene.name.c_str(), scene.description.c_str());
        std::printf("%5s %7s %9s %12s %12s %10s %12s %9s\n", "frame", "objects", "triangles",
                    "min-separ.", "min-self", "collisions", "exact-tests", "ms");
    }
    QueryRequest request;
    request.self = true;
    request.collisions = true;
    request.culler = culler.value();
    for (std::size_t k = 0; k < scene.frame_count; ++k) {
        if (k > 0) {
            if (auto r = engine.scene().apply(scene.step(k, engine.scene())); !r.ok()) {
                return fail(r.status());
            }
        }
        auto result = engine.query(request);
        if (!result.ok()) {
            return fail(result.status());
        }
        double min_sep = std::numeric_limits<double>::infinity();
        for (const auto& s : result->separation) {
            min_sep = std::min(min_sep, s.distance);
        }
        double min_self = std::numeric_limits<double>::infinity();
        for (const auto& obj : result->self) {
            for (const auto& s : obj) {
                min_self = std::min(min_self, s.distance);
            }
        }
        const auto& st = result->stats;
        if (args.json) {
            nlohmann::json j = {{"frame", k},
                                {"objects", engine.scene().size()},
                                {"triangles", engine.scene().triangle_count()},
                                {"min_separation", std::isfinite(min_sep) ? nlohmann::json(min_sep)
                                                                          : nlohmann::json()},
                                {"min_self_distance", std::isfinite(min_self)
                                                          ? nlohmann::json(min_self)
                                                          : nlohmann::json()},
                                {"collisions", result->collisions.size()},
                                {"stats", client::stats_json(st)}};
            std::cout << j.dump() << '\n';
        } else {
            std::printf("%5zu %7zu %9zu %12.6g %12.6g %10zu %12llu %9.2f\n", k,
                        engine.scene().size(), engine.scene().triangle_count(), min_sep, min_self,
                        result->collisions.size(), static_cast<unsigned long long>(st.exact_tests),
                        st.total_seconds * 1e3);
        }
    }
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    try {
        CLI::App app{"proxima: exact proximity queries among deformable meshes"};
        app.require_subcommand(1);
        auto* version = app.add_subcommand("version", "Print the version");

        DistanceArgs dist;
        auto* distance = app.add_subcommand(
            "distance", "Separation, self distance, collisions and tolerance on mesh files");
        distance->add_flag("--local", dist.local, "Run the engine in this process (the default)");
        distance->add_flag("--split-components", dist.split_components,
                           "Make each connected component of a file an object");
        distance->add_flag("--self", dist.self,
                           "Also: for every triangle, its closest non-adjacent triangle");
        distance->add_flag("--collisions", dist.collisions,
                           "Also: every intersecting triangle pair");
        distance->add_option("--tolerance", dist.tolerance,
                             "Also: every triangle pair within this distance")
            ->check(CLI::NonNegativeNumber);
        distance->add_flag("--pns", dist.pns,
                           "Also: the culler's candidate pairs for the tolerance (or contact)");
        distance->add_option("--culler", dist.culler, "auto, brute or bvh")
            ->check(CLI::IsMember({"auto", "brute", "bvh"}));
        distance->add_flag("--json", dist.json, "Print one JSON object");
        distance->add_option("files", dist.files, "Mesh files (OBJ, PLY, STL, OFF, glTF, ...)")
            ->required();

        DemoArgs demo_args;
        auto* demo = app.add_subcommand(
            "demo", "Stream a built-in deforming scene through the engine, frame by frame");
        demo->add_option("--scene", demo_args.scene,
                         "skirt, cloth-ball, bowl, ramps or breaking");
        demo->add_option("--frames", demo_args.frames, "Number of frames")
            ->check(CLI::Range(1, 100000));
        demo->add_option("--culler", demo_args.culler, "auto, brute or bvh")
            ->check(CLI::IsMember({"auto", "brute", "bvh"}));
        demo->add_flag("--json", demo_args.json, "One JSON object per frame");

        CLI11_PARSE(app, argc, argv);
        if (*version) {
            std::printf("proxima 0.1.0\n");
            return 0;
        }
        if (*distance) {
            return run_distance(dist);
        }
        if (*demo) {
            return run_demo(demo_args);
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
