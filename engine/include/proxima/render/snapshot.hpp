#pragma once
// Offscreen snapshots: a scene rendered into a PNG image with a headless EGL/OpenGL context
// (Mesa llvmpipe where there is no GPU), results coloured as on the review page: base grey,
// triangles of colliding pairs red, triangles of pairs within the tolerance amber, closest pairs
// (separation) as segments. Flat shading with a headlight (light from the eye).
//
// Threading: render() runs its GL work on a thread of its own that creates the context, renders,
// reads the pixels back and destroys the context; calls are serialized by a process-wide mutex,
// so any thread may call it and no two snapshots touch GL at once. The context is separate from
// the discrete-Voronoi backend's (its own thread), so a snapshot never disturbs culling.

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "proxima/query/query.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"

namespace proxima::render {

// Largest image side and pixel count a snapshot may ask for.
inline constexpr int MAX_SNAPSHOT_SIDE = 4096;
inline constexpr std::int64_t MAX_SNAPSHOT_PIXELS = 4096LL * 4096LL;
// Largest scene a snapshot draws (its vertex buffer takes 108 bytes a triangle).
inline constexpr std::size_t MAX_SNAPSHOT_TRIANGLES = 10'000'000;

struct Rgb {
    std::uint8_t r = 0;
    std::uint8_t g = 0;
    std::uint8_t b = 0;
    friend bool operator==(const Rgb&, const Rgb&) = default;
};

inline constexpr Rgb BASE_GREY{170, 170, 170};
inline constexpr Rgb COLLISION_RED{220, 30, 30};
inline constexpr Rgb TOLERANCE_AMBER{255, 176, 0};
inline constexpr Rgb SEGMENT_BLUE{20, 90, 255};
inline constexpr Rgb DEFAULT_BACKGROUND{255, 255, 255};

struct Camera {
    Vec3 eye;
    Vec3 target;
    Vec3 up{0, 0, 1};
    double fov_degrees = 45.0;  // vertical field of view, in (0, 180)
};

// `invalid_argument` for a non-finite value, eye == target, an up vector parallel to the view
// direction, or a field of view outside (0, 180).
Status validate_camera(const Camera& camera);

// A camera that shows the whole box: looking at its centre from the direction (1, -1.5, 1) (a
// three-quarter view, z up), far enough that the box's bounding sphere fits the vertical and
// horizontal fields of view of a width x height image.
Camera fit_camera(const Aabb& box, int width, int height, double fov_degrees = 45.0);

struct Segment {
    Vec3 a;
    Vec3 b;
};

struct Colouring {
    // Per object (scene order), per triangle; an object whose vector is empty is all BASE_GREY.
    std::vector<std::vector<Rgb>> triangles;
    std::vector<Segment> segments;  // drawn in SEGMENT_BLUE, over the triangles
};

struct ColourOptions {
    bool collisions = true;  // triangles of colliding pairs red
    bool tolerance = true;   // triangles of pairs within the tolerance amber (red wins)
    bool segments = true;    // separation's closest pairs as segments
};

// Colours from a query's result on `scene` (the result's collisions, tolerance and separation,
// each when present and asked).
Colouring colour_results(const Scene& scene, const QueryResult& result,
                         const ColourOptions& options = {});

struct Image {
    int width = 0;
    int height = 0;
    std::vector<std::uint8_t> rgb;  // row-major, top row first, 3 bytes per pixel

    Rgb at(int x, int y) const {
        const auto i = (static_cast<std::size_t>(y) * static_cast<std::size_t>(width) +
                        static_cast<std::size_t>(x)) *
                       3;
        return {rgb[i], rgb[i + 1], rgb[i + 2]};
    }
};

struct RenderOptions {
    int width = 800;
    int height = 600;
    std::optional<Camera> camera;  // unset: fit_camera(scene box)
    Rgb background = DEFAULT_BACKGROUND;
};

// `invalid_argument` for a side outside [1, MAX_SNAPSHOT_SIDE] or more than MAX_SNAPSHOT_PIXELS.
Status validate_size(int width, int height);

struct RenderResult {
    Image image;
    Camera camera;         // the camera used
    std::string renderer;  // GL_RENDERER, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)"
};

// Renders `scene` offscreen. `invalid_argument` for a bad size or camera or a colouring that does
// not match the scene; `resource_exhausted` for more than MAX_SNAPSHOT_TRIANGLES; `unavailable`
// when no EGL context can be created (or PROXIMA_DISABLE_EGL is set); `internal` for a GL error.
StatusOr<RenderResult> render(const Scene& scene, const Colouring& colouring,
                              const RenderOptions& options);

// What a snapshot shows and how: the queries whose results colour it, and the image.
struct SnapshotRequest {
    RenderOptions render;
    bool collisions = true;           // colliding triangles red
    std::optional<double> tolerance;  // triangles of pairs within it amber (>= 0)
    bool segments = true;             // separation's closest pairs as segments
};

// A model region's snapshot: what was drawn (render/region_snapshot.hpp).
struct SnapshotRegion {
    std::uint64_t pieces = 0;
    std::uint64_t triangles = 0;
    std::uint64_t objects = 0;        // model objects with at least one piece drawn
    bool truncated = false;           // max_triangles left selected pieces out
    std::uint64_t model_version = 0;  // the room's version seen (0 without a room)
    std::string generation;
};

struct Snapshot {
    std::string png;
    Camera camera;  // the camera used
    int width = 0;
    int height = 0;
    std::string renderer;
    std::size_t collision_count = 0;  // triangle pairs coloured red
    std::size_t tolerance_count = 0;  // triangle pairs within the tolerance
    std::size_t segment_count = 0;
    std::optional<SnapshotRegion> region;  // set for a model region's snapshot
};

// Checks the size, the camera (when set) and the tolerance without touching the scene or GL.
Status validate_snapshot_request(const SnapshotRequest& request);

// Runs the queries the colours need on `engine` (its culler state is reused), colours, renders
// and encodes: the daemon's Snapshot call and `proxima snapshot` both come here, so the same
// scene gives the same PNG bytes on the same renderer.
StatusOr<Snapshot> take_snapshot(ProximityEngine& engine, const SnapshotRequest& request,
                                 const CancelToken* cancel = nullptr);

// PNG (8-bit RGB, no interlace) through libpng.
StatusOr<std::string> encode_png(const Image& image);
// For tests and tools: any 8-bit PNG libpng reads, converted to RGB.
StatusOr<Image> decode_png(std::string_view bytes);

}  // namespace proxima::render
