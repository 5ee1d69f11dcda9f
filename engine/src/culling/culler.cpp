#include "proxima/culling/culler.hpp"

#include "culling/cullers.hpp"
#include "proxima/culling/dvd.hpp"

namespace proxima {

const char* culler_name(CullerKind kind) {
    switch (kind) {
        case CullerKind::automatic:
            return "auto";
        case CullerKind::brute:
            return "brute";
        case CullerKind::bvh:
            return "bvh";
        case CullerKind::voronoi_cpu:
            return "voronoi-cpu";
        case CullerKind::voronoi_gpu:
            return "voronoi-gpu";
    }
    return "unknown";
}

StatusOr<CullerKind> parse_culler(std::string_view name) {
    if (name == "auto") {
        return CullerKind::automatic;
    }
    if (name == "brute") {
        return CullerKind::brute;
    }
    if (name == "bvh") {
        return CullerKind::bvh;
    }
    if (name == "voronoi-cpu") {
        return CullerKind::voronoi_cpu;
    }
    if (name == "voronoi-gpu") {
        return CullerKind::voronoi_gpu;
    }
    return invalid_argument("unknown culler '" + std::string(name) +
                            "' (expected auto, brute, bvh, voronoi-cpu or voronoi-gpu)");
}

std::unique_ptr<Culler> make_culler(CullerKind kind) {
    if (kind == CullerKind::brute) {
        return std::make_unique<detail::BruteCuller>();
    }
    if (kind == CullerKind::voronoi_cpu) {
        return make_voronoi_culler(kind, dvd::make_cpu_backend());
    }
    // `automatic` is resolved by ProximityEngine's cost model; alone it means the BVH culler.
    // voronoi_gpu needs a backend: make_voronoi_culler.
    return std::make_unique<detail::BvhCuller>();
}

std::unique_ptr<Culler> make_voronoi_culler(CullerKind kind,
                                            std::shared_ptr<dvd::Backend> backend) {
    return std::make_unique<detail::VoronoiCuller>(kind, std::move(backend));
}

}  // namespace proxima
