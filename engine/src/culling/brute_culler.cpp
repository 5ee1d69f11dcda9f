// The brute-force reference: every pair, no bounds consulted. Queries through it are the
// definition of the right answer that every other culler is tested against.
#include <tbb/parallel_for.h>

#include "culling/cullers.hpp"

namespace proxima::detail {

void BruteCuller::nearest_between(const Scene& scene, std::size_t a, std::size_t b,
                                  double& bound_sq, PairVisitor visit) const {
    const auto na = static_cast<std::uint32_t>(scene[a].triangle_count());
    const auto nb = static_cast<std::uint32_t>(scene[b].triangle_count());
    for (std::uint32_t ta = 0; ta < na && bound_sq >= 0.0; ++ta) {  // negative: stop
        for (std::uint32_t tb = 0; tb < nb; ++tb) {
            visit(ta, tb);
        }
    }
}

void BruteCuller::self_pairs(const Scene& scene, std::size_t a, BoundLookup bound_sq,
                             PairVisitor visit) const {
    const auto& topo = *scene[a].topology;
    const auto n = static_cast<std::uint32_t>(topo.triangle_count());
    // Every non-adjacent pair, whatever the bounds; parallel over the first triangle only to keep
    // the reference affordable in tests.
    tbb::parallel_for(std::uint32_t{0}, n, [&](std::uint32_t t) {
        if (bound_sq(t) < 0.0) {
            return;  // the query was stopped
        }
        for (std::uint32_t u = t + 1; u < n; ++u) {
            if (!topo.adjacent(t, u)) {
                visit(t, u);
            }
        }
    });
}

void BruteCuller::pairs_within(const Scene& scene, std::size_t a, std::size_t b, double radius,
                               std::vector<TrianglePair>& out) const {
    const auto na = static_cast<std::uint32_t>(scene[a].triangle_count());
    const auto nb = static_cast<std::uint32_t>(scene[b].triangle_count());
    if (a != b) {
        for (std::uint32_t ta = 0; ta < na; ++ta) {
            for (std::uint32_t tb = 0; tb < nb; ++tb) {
                out.emplace_back(ta, tb);
            }
        }
        return;
    }
    const auto& topo = *scene[a].topology;
    for (std::uint32_t ta = 0; ta < na; ++ta) {
        for (std::uint32_t tb = ta + 1; tb < na; ++tb) {
            if (!topo.adjacent(ta, tb)) {
                out.emplace_back(ta, tb);
            }
        }
    }
}

}  // namespace proxima::detail
