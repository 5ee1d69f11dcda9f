#pragma once
// Internal: the concrete cullers. Only make_culler() is public.
#include <cstdint>
#include <vector>

#include "proxima/culling/bvh.hpp"
#include "proxima/culling/culler.hpp"

namespace proxima::detail {

class BruteCuller final : public Culler {
  public:
    CullerKind kind() const override { return CullerKind::brute; }
    bool object_culling() const override { return false; }
    void prepare(const Scene&) override {}
    void nearest_between(const Scene& scene, std::size_t a, std::size_t b, double& bound_sq,
                         PairVisitor visit) const override;
    void self_pairs(const Scene& scene, std::size_t a, BoundLookup bound_sq,
                    PairVisitor visit) const override;
    void pairs_within(const Scene& scene, std::size_t a, std::size_t b, double radius,
                      std::vector<TrianglePair>& out) const override;
};

class BvhCuller final : public Culler {
  public:
    CullerKind kind() const override { return CullerKind::bvh; }
    bool object_culling() const override { return true; }
    void prepare(const Scene& scene) override;
    void nearest_between(const Scene& scene, std::size_t a, std::size_t b, double& bound_sq,
                         PairVisitor visit) const override;
    void self_pairs(const Scene& scene, std::size_t a, BoundLookup bound_sq,
                    PairVisitor visit) const override;
    void pairs_within(const Scene& scene, std::size_t a, std::size_t b, double radius,
                      std::vector<TrianglePair>& out) const override;

    struct Entry {
        ObjectId id = 0;
        std::uint64_t topology_version = 0;
        Bvh bvh;
    };

  private:
    // One entry per scene object, in scene order, valid for m_generation.
    std::vector<Entry> m_entries;
    const Scene* m_scene = nullptr;
    std::uint64_t m_generation = ~0ull;
};

}  // namespace proxima::detail
