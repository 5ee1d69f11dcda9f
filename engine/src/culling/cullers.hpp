#pragma once
// Internal: the concrete cullers. Only make_culler() is public.
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "proxima/culling/bvh.hpp"
#include "proxima/culling/culler.hpp"
#include "proxima/culling/dvd.hpp"

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
    // No partners; rebuilds object a's hierarchy when its refit has left it degraded.
    Status refine_self(const Scene& scene, std::size_t a,
                       std::vector<std::uint32_t>& partner) override;

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

// Seed 000 §4-5.2 on top of the BVH culler: the BVH proposes pairs, and per-triangle lower bounds
// from the discrete-Voronoi kernel (Lemma 2) remove those that cannot matter; per-object upper
// bounds tighten Stage I, and Voronoi partners seed the self query. voronoi_culler.cpp explains.
class VoronoiCuller final : public Culler {
  public:
    VoronoiCuller(CullerKind kind, std::shared_ptr<dvd::Backend> backend);
    ~VoronoiCuller() override;
    CullerKind kind() const override { return m_kind; }
    bool object_culling() const override { return true; }
    void prepare(const Scene& scene) override;
    void nearest_between(const Scene& scene, std::size_t a, std::size_t b, double& bound_sq,
                         PairVisitor visit) const override;
    void self_pairs(const Scene& scene, std::size_t a, BoundLookup bound_sq,
                    PairVisitor visit) const override;
    void pairs_within(const Scene& scene, std::size_t a, std::size_t b, double radius,
                      std::vector<TrianglePair>& out) const override;

    void set_cell(std::optional<double> cell) override { m_cell = cell; }
    Status refine_separation(const Scene& scene, std::vector<double>& object_upper) override;
    Status refine_within(const Scene& scene, double radius) override;
    Status refine_self(const Scene& scene, std::size_t a,
                       std::vector<std::uint32_t>& partner) override;
    VoronoiStats take_voronoi_stats() override;

    // Per-triangle lower bounds of one refinement, indexed by scene triangle offset + triangle.
    struct Bounds {
        bool valid = false;
        double radius = 0;  // refine_within's radius
        std::vector<double> lower;
    };

  private:
    double cell_for(const Scene& scene, double factor) const;
    void add_stats(const VoronoiStats& s);

    CullerKind m_kind;
    std::shared_ptr<dvd::Backend> m_backend;
    BvhCuller m_bvh;
    std::optional<double> m_cell;
    const Scene* m_scene = nullptr;
    std::uint64_t m_generation = ~0ull;
    std::vector<std::size_t> m_offsets;  // first global triangle of each scene object
    double m_edge_scale = 0;             // median edge length of the scene (the grid's scale)
    Bounds m_separation;                 // inter-object, for nearest_between
    Bounds m_within;  // every non-adjacent triangle of any object, for pairs_within
    mutable std::atomic<std::uint64_t> m_culled{0};
    std::mutex m_stats_lock;
    VoronoiStats m_stats;
};

}  // namespace proxima::detail
