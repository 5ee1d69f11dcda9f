#pragma once
// Deterministic test models for the massive-model path (seed 001 §6 used a 15M-triangle coal-fired
// power plant with ~1,800 objects). The same options always produce bit-identical objects in the
// same order, on every machine, so a benchmark or a test can name a model by its options.

#include <cstdint>
#include <string>

#include "proxima/massive/model.hpp"
#include "proxima/query/query.hpp"

namespace proxima::massive {

struct PlantOptions {
    // Approximate size: the result is within 10% of it (>= 10,000).
    std::uint64_t triangles = 1'000'000;
    std::uint64_t seed = 1;
};

struct GeneratedSummary {
    std::uint64_t objects = 0;
    std::uint64_t triangles = 0;
    std::uint64_t vertices = 0;
    Aabb box;
};

// A procedural plant: bays on a grid, each with steel frames (I-beam columns and girders), tanks
// (cylinders with domed heads), pipe runs (straight segments, elbows, flanges) routed along the
// frames at small clearances, walkways with handrails and stairs. About one object per 8,000
// triangles (15M triangles: ~1,800 objects), many of them touching or within centimetres of
// others. Objects are streamed to `sink` one at a time; a non-ok status from the sink, or a
// cancelled token, stops generation and is returned.
StatusOr<GeneratedSummary> generate_plant(const PlantOptions& options, const ObjectSink& sink,
                                          const ProgressFn& progress = {},
                                          const CancelToken* cancel = nullptr);

struct BuildingOptions {
    // Directory of real furniture meshes (../shared/data/meshes/furniture-cc0 or a copy); every
    // mesh file found under it (sorted by path) is an instance source.
    std::string furniture_dir;
    // Approximate triangle count of the whole building, furniture instances included.
    std::uint64_t triangles = 2'000'000;
    std::uint64_t seed = 1;
};

// A multi-storey building (floor slabs, walls with door openings, columns) filled with instances
// of the furniture meshes (rotated about z, placed on the floors, some against walls, some
// touching each other). Writes `out_dir`/scene.json in the scene-file format of the importer
// (io: proxima-scene/1), the building shell as mesh files beside it, and references the furniture
// files by absolute path. Returns the summary and the scene file's path.
struct GeneratedScene {
    GeneratedSummary summary;
    std::string scene_file;
};
StatusOr<GeneratedScene> generate_building(const BuildingOptions& options,
                                           const std::string& out_dir,
                                           const ProgressFn& progress = {});

}  // namespace proxima::massive
