// proxima snapshot: an offscreen PNG image of mesh files, results coloured as on the review page
// (colliding triangles red, pairs within --tolerance amber, closest pairs as blue segments).
// Local mode renders in this process with the engine's own headless EGL context (llvmpipe where
// there is no GPU); --server creates a scene with the files on the daemon, calls Snapshot (the
// daemon renders with its context) and deletes the scene. Both run render::take_snapshot on the
// same scene, so on the same renderer they write the same PNG bytes. --server ADDR --model NAME
// (with --center, --radius, --room, --max-triangles as for `proxima region`) renders a served
// massive model's region on the daemon instead of files.

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "cli/commands.hpp"
#include "client/proxima_client.hpp"
#include "common/local_scene.hpp"
#include "proxima/query/query.hpp"
#include "proxima/render/snapshot.hpp"

namespace proxima::cli {

namespace {

struct SnapshotArgs {
    bool local = false;
    std::string server;
    ServerFlags server_flags;
    bool split_components = false;
    bool weld = false;
    std::string camera;  // "ex,ey,ez,tx,ty,tz[,ux,uy,uz]"
    double fov = 45.0;
    int width = 800;
    int height = 600;
    double tolerance = -1.0;  // < 0: no tolerance query
    bool no_collisions = false;
    bool no_segments = false;
    std::string out;
    std::vector<std::string> files;
    // A served massive model's region instead of files (--server only).
    std::string model;
    RegionFlags region;
};

// 6 or 9 comma-separated finite numbers: eye, target and optionally up.
StatusOr<render::Camera> parse_camera(const std::string& text, double fov) {
    std::vector<double> v;
    std::stringstream in(text);
    std::string item;
    while (std::getline(in, item, ',')) {
        try {
            std::size_t used = 0;
            const double x = std::stod(item, &used);
            if (used != item.size() || !std::isfinite(x)) {
                throw std::invalid_argument(item);
            }
            v.push_back(x);
        } catch (const std::exception&) {
            return invalid_argument("--camera: '" + item + "' is not a finite number");
        }
    }
    if (v.size() != 6 && v.size() != 9) {
        return invalid_argument(
            "--camera: expected 6 numbers (eye x,y,z, target x,y,z) or 9 (then up x,y,z), got " +
            std::to_string(v.size()));
    }
    render::Camera c;
    c.eye = {v[0], v[1], v[2]};
    c.target = {v[3], v[4], v[5]};
    if (v.size() == 9) {
        c.up = {v[6], v[7], v[8]};
    }
    c.fov_degrees = fov;
    if (Status s = render::validate_camera(c); !s.ok()) {
        return Status(s.code(), "--" + s.message());
    }
    return c;
}

StatusOr<render::Snapshot> snapshot_local(const std::vector<client::InputObject>& objects,
                                          const render::SnapshotRequest& request) {
    ProximityEngine engine;
    SceneUpdate update;
    for (const auto& obj : objects) {
        update.additions.push_back(obj.mesh);
    }
    if (auto applied = engine.scene().apply(std::move(update)); !applied.ok()) {
        return applied.status();
    }
    return render::take_snapshot(engine, request);
}

StatusOr<render::Snapshot> snapshot_remote(const SnapshotArgs& args,
                                           const std::vector<client::InputObject>& objects,
                                           const render::SnapshotRequest& request) {
    client::ConnectOptions options;
    options.inline_mesh_bytes = 1u << 20;  // float64 vertices: the scene is the local one
    auto c = connect_server(args.server, args.server_flags, options);
    if (!c.ok()) {
        return c.status();
    }
    std::vector<NamedMesh> meshes;
    meshes.reserve(objects.size());
    for (const auto& obj : objects) {
        meshes.push_back(obj.mesh);
    }
    auto scene = (*c)->create_scene("proxima snapshot", meshes);
    if (!scene.ok()) {
        return scene.status();
    }
    auto snapshot = (*c)->snapshot(scene->scene_id, request);
    if (Status deleted = (*c)->delete_scene(scene->scene_id); !deleted.ok()) {
        std::fprintf(stderr, "proxima: warning: could not delete scene %s: %s\n",
                     scene->scene_id.c_str(), deleted.to_string().c_str());
    }
    return snapshot;
}

StatusOr<render::Snapshot> snapshot_model(const SnapshotArgs& args,
                                          const client::RegionRequest& region,
                                          const render::SnapshotRequest& request) {
    auto c = connect_server(args.server, args.server_flags, client::ConnectOptions{});
    if (!c.ok()) {
        return c.status();
    }
    return (*c)->snapshot_region(region, request);
}

std::string point_text(const Vec3& p) {
    char buffer[96];
    std::snprintf(buffer, sizeof buffer, "%.6g,%.6g,%.6g", p.x, p.y, p.z);
    return buffer;
}

int run_snapshot(const SnapshotArgs& args) {
    render::SnapshotRequest request;
    request.render.width = args.width;
    request.render.height = args.height;
    if (!args.camera.empty()) {
        auto camera = parse_camera(args.camera, args.fov);
        if (!camera.ok()) {
            return fail(camera.status());
        }
        request.render.camera = *camera;
    }
    request.collisions = !args.no_collisions;
    request.segments = !args.no_segments;
    if (args.tolerance >= 0) {
        request.tolerance = args.tolerance;
    }
    if (Status s = render::validate_snapshot_request(request); !s.ok()) {
        return fail(s);
    }
    StatusOr<client::RegionRequest> region = client::RegionRequest{};
    if (!args.model.empty()) {
        if (args.server.empty()) {
            return fail(invalid_argument("--model: a model region needs --server ADDR"));
        }
        if (!args.files.empty()) {
            return fail(invalid_argument("--model: give either mesh files or --model, not both"));
        }
        region = region_request(args.model, args.region);
        if (!region.ok()) {
            return fail(region.status());
        }
    } else if (args.files.empty()) {
        return fail(invalid_argument("files: give mesh files (or --server ADDR --model NAME)"));
    }
    StatusOr<std::vector<client::InputObject>> objects = std::vector<client::InputObject>{};
    if (args.model.empty()) {
        objects = client::load_objects(args.files, args.split_components, weld_mode(args.weld));
        if (!objects.ok()) {
            return fail(objects.status());
        }
    }
    auto snapshot = !args.model.empty()   ? snapshot_model(args, *region, request)
                    : args.server.empty() ? snapshot_local(*objects, request)
                                          : snapshot_remote(args, *objects, request);
    if (!snapshot.ok()) {
        return fail(snapshot.status());
    }
    std::ofstream file(args.out, std::ios::binary | std::ios::trunc);
    file.write(snapshot->png.data(), static_cast<std::streamsize>(snapshot->png.size()));
    file.close();
    if (!file) {
        return fail(Status(StatusCode::unavailable, "--out: cannot write '" + args.out + "'"));
    }
    std::string counts = std::to_string(snapshot->collision_count) + " colliding pairs";
    if (request.tolerance) {
        char tol[64];
        std::snprintf(tol, sizeof tol, "%.9g", *request.tolerance);
        counts += ", " + std::to_string(snapshot->tolerance_count) + " within " + tol;
    }
    counts += ", " + std::to_string(snapshot->segment_count) + " closest-pair segments";
    std::string what = std::to_string(objects->size()) + " objects";
    if (snapshot->region) {
        what = "model " + args.model + " (" + std::to_string(snapshot->region->objects) +
               " objects, " + std::to_string(snapshot->region->pieces) + " pieces, " +
               std::to_string(snapshot->region->triangles) + " triangles" +
               (snapshot->region->truncated ? ", cut at --max-triangles" : "") + ")";
    }
    std::fprintf(stderr, "snapshot: %dx%d PNG of %s in %s (%s; camera %s -> %s, fov %.6g; %s)\n",
                 snapshot->width, snapshot->height, what.c_str(), args.out.c_str(), counts.c_str(),
                 point_text(snapshot->camera.eye).c_str(),
                 point_text(snapshot->camera.target).c_str(), snapshot->camera.fov_degrees,
                 snapshot->renderer.c_str());
    return 0;
}

}  // namespace

void add_snapshot_command(CLI::App& app, int& exit_code) {
    auto args = std::make_shared<SnapshotArgs>();
    auto* cmd = app.add_subcommand(
        "snapshot",
        "An offscreen PNG of mesh files: colliding triangles red, pairs within --tolerance amber, "
        "closest pairs as segments");
    auto* server_opt = add_local_or_server(*cmd, args->local, args->server, args->server_flags,
                                           "Render in this process (the default)",
                                           "Render on the proximad daemon at HOST:PORT instead");
    cmd->add_flag("--split-components", args->split_components,
                  "Make each connected component of a file an object");
    cmd->add_flag("--weld", args->weld,
                  "Merge vertices at identical positions in every file (by default only in "
                  "triangle soups)");
    cmd->add_option("--camera", args->camera,
                    "eye_x,eye_y,eye_z,target_x,target_y,target_z[,up_x,up_y,up_z] (default: a "
                    "three-quarter view that fits the scene; up +z)");
    cmd->add_option("--fov", args->fov, "Vertical field of view in degrees, in (0, 180)")
        ->check(CLI::Range(0.0, 180.0))
        ->capture_default_str();
    cmd->add_option("--width", args->width, "Image width in pixels")
        ->check(CLI::Range(1, render::MAX_SNAPSHOT_SIDE))
        ->capture_default_str();
    cmd->add_option("--height", args->height, "Image height in pixels")
        ->check(CLI::Range(1, render::MAX_SNAPSHOT_SIDE))
        ->capture_default_str();
    cmd->add_option("--tolerance", args->tolerance,
                    "Colour the triangles of pairs within this distance amber")
        ->check(non_negative_number());
    cmd->add_flag("--no-collisions", args->no_collisions, "Do not colour collisions");
    cmd->add_flag("--no-segments", args->no_segments, "Do not draw closest-pair segments");
    cmd->add_option("--out", args->out, "The PNG file to write")->required();
    cmd->add_option("files", args->files, "Mesh files (any format proxima reads)");
    auto* model_opt = cmd->add_option("--model", args->model,
                                      "Instead of files: a region of this massive model served "
                                      "by --server (as `proxima region` selects it)");
    model_opt->needs(server_opt);
    add_region_flags(*cmd, args->region, model_opt);
    cmd->callback([args, &exit_code] { exit_code = run_snapshot(*args); });
}

}  // namespace proxima::cli
