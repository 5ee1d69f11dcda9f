#pragma once
// Massive models (seed 001, IMMPACT): the types shared by the generator, the importer and store,
// the overlap graph and the runtime cache. A massive model is a list of *objects* (CAD function
// groups: a pipe run, a tank, a floor's furniture piece); objects larger than a fraction of the
// cache are split into *pieces* by a k-d tree over triangle centres (§4.2.1). Pieces are the unit
// of disk reads, of cache residency and of overlap-graph nodes; results are reported per object.

#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "proxima/mesh/mesh.hpp"
#include "proxima/status.hpp"

namespace proxima::massive {

// One object as the generator and the importer produce it (vertices in model coordinates).
struct ModelObject {
    std::string name;
    TriangleMesh mesh;
};

// Receives objects one at a time (a generator streams 100M triangles without holding them).
using ObjectSink = std::function<Status(ModelObject&&)>;

// Progress of a long step: `done` of `total` `unit`s (total 0 when unknown).
struct Progress {
    std::string step;  // "reading", "splitting", "writing chunks", "verifying", "partitioning"...
    std::uint64_t done = 0;
    std::uint64_t total = 0;
    std::string unit;  // "objects", "triangles", "bytes", "edges"
};
using ProgressFn = std::function<void(const Progress&)>;

// Bytes a piece occupies in the runtime cache with its hierarchy fully built: the node weight of
// the overlap graph (§4.1: linear in the triangle count) and the cache's charge. Vertices as
// doubles (24 B), triangles (12 B), the source-triangle map (4 B), per-triangle boxes (48 B) and
// at most 2 n / 4 hierarchy nodes (~64 B each).
inline std::uint64_t piece_weight(std::uint64_t vertex_count, std::uint64_t triangle_count) {
    return 256 + vertex_count * 24 + triangle_count * (12 + 4 + 48 + 32);
}

// An affine map x' = A x + t, row-major 3x4: {a00, a01, a02, tx, a10, a11, a12, ty, a20, ...}.
// Scene-file transforms, instances and avatar poses all go through `apply`, so every path (the
// importer, the in-memory reference, the avatar query) produces bit-identical coordinates.
struct Affine {
    std::array<double, 12> m{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    Vec3 apply(const Vec3& p) const {
        return {((m[0] * p.x + m[1] * p.y) + m[2] * p.z) + m[3],
                ((m[4] * p.x + m[5] * p.y) + m[6] * p.z) + m[7],
                ((m[8] * p.x + m[9] * p.y) + m[10] * p.z) + m[11]};
    }
    bool finite() const {
        for (double v : m) {
            if (!std::isfinite(v)) {
                return false;
            }
        }
        return true;
    }
};

// Default cache budget M (the seed's 160 MB) and split fraction (a piece at most M / 10, §6.3).
inline constexpr std::uint64_t DEFAULT_CACHE_BYTES = 160ull << 20;
inline constexpr std::uint64_t SPLIT_FRACTION = 10;

}  // namespace proxima::massive
