#include "proxima/culling/culler.hpp"

#include "culling/cullers.hpp"

namespace proxima {

const char* culler_name(CullerKind kind) {
    switch (kind) {
        case CullerKind::automatic:
            return "auto";
        case CullerKind::brute:
            return "brute";
        case CullerKind::bvh:
            return "bvh";
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
    return invalid_argument("unknown culler '" + std::string(name) +
                            "' (expected auto, brute or bvh)");
}

std::unique_ptr<Culler> make_culler(CullerKind kind) {
    if (kind == CullerKind::brute) {
        return std::make_unique<detail::BruteCuller>();
    }
    // `automatic` picks the BVH culler until the discrete-Voronoi culler lands with its cost model.
    return std::make_unique<detail::BvhCuller>();
}

}  // namespace proxima
