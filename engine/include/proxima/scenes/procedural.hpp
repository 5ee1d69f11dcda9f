#pragma once
// Deterministic procedural scenes modelled on the five benchmarks of seed 000 Table 1, each a
// sequence of frames. Used by the demo, the benchmarks and the tests: the same inputs everywhere,
// no files needed. Deterministic across runs and machines (integer-seeded, no wall-clock input).

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "proxima/scene.hpp"

namespace proxima::scenes {

struct ProceduralScene {
    std::string name;
    std::string description;
    std::size_t frame_count = 0;
    // Objects of frame 0, in order.
    std::vector<NamedMesh> initial;
    // The update that turns frame k-1 into frame k (1 <= k < frame_count), given the scene as it
    // is after frame k-1 (object ids are read from it). Vertex updates keep topology; a topology
    // change replaces objects by fragments.
    std::function<SceneUpdate(std::size_t k, const Scene& scene)> step;
};

// ~12K triangles: a skirt-like cylindrical cloth swaying and folding around a body (seed: skirt).
ProceduralScene skirt(std::size_t frames = 16);
// ~15K triangles: a cloth sheet falling onto and draping over a rotating ball (seed: cloth on
// ball).
ProceduralScene cloth_ball(std::size_t frames = 16);
// ~4.5K triangles: ten deforming objects settling in a bowl (seed: bowl, 'siggraph 06' letters).
ProceduralScene bowl(std::size_t frames = 16);
// ~38K triangles: 200 deforming objects sliding down ramps (seed: letters in a funnel and ramps).
ProceduralScene ramps(std::size_t frames = 16);
// ~5.5K triangles: objects that break into pieces mid-sequence, 25 pieces after the break (seed:
// breaking objects); the break is a topology change.
ProceduralScene breaking(std::size_t frames = 16);

// All five, in the order above.
std::vector<ProceduralScene> all(std::size_t frames = 16);
// By name ("skirt", "cloth-ball", "bowl", "ramps", "breaking"); empty name() when unknown.
ProceduralScene by_name(const std::string& name, std::size_t frames = 16);

}  // namespace proxima::scenes
