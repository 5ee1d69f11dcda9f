#pragma once
// Culling strategies behind one interface. A culler only proposes candidate triangle pairs; the
// query code runs the exact test on each, so every culler gives the answer brute force gives as
// long as it never drops a pair that could matter (its bounds are conservative). The
// discrete-Voronoi culler (seed 000 §4-5.2) plugs in here too: it adds Stage II hooks
// (refine_*) that the query calls before each stage; the other cullers ignore them.

#include <atomic>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "proxima/scene.hpp"

namespace proxima::dvd {
class Backend;
}

namespace proxima {

enum class CullerKind { automatic, brute, bvh, voronoi_cpu, voronoi_gpu };

// "auto", "brute", "bvh", "voronoi-cpu", "voronoi-gpu".
const char* culler_name(CullerKind kind);
// Parses the names above; unknown names give an invalid_argument status.
StatusOr<CullerKind> parse_culler(std::string_view name);

// Non-owning reference to a callable, for the per-candidate callback (no allocation, one
// indirect call).
template <class Fn>
class FunctionRef;
template <class R, class... Args>
class FunctionRef<R(Args...)> {
  public:
    template <class F>
    requires(!std::is_same_v<std::remove_cvref_t<F>, FunctionRef>)
        // Not a copy or move constructor in disguise: the constraint above excludes FunctionRef.
        // NOLINTNEXTLINE(google-explicit-constructor,bugprone-forwarding-reference-overload)
        FunctionRef(F&& f)
        : m_object(const_cast<void*>(static_cast<const void*>(&f))),
          m_call([](void* o, Args... args) -> R {
              return (*static_cast<std::remove_reference_t<F>*>(o))(std::forward<Args>(args)...);
          }) {}
    R operator()(Args... args) const { return m_call(m_object, std::forward<Args>(args)...); }

  private:
    void* m_object;
    R (*m_call)(void*, Args...);
};

// Called with (triangle of a, triangle of b). A nearest-search visitor may lower the bound it
// shares with the culler; the culler re-reads it after every call.
using PairVisitor = FunctionRef<void(std::uint32_t, std::uint32_t)>;
using TrianglePair = std::pair<std::uint32_t, std::uint32_t>;
// The current squared distance bound of each of one object's triangles, for intra-object
// searches: read straight from the searching query's array (a relaxed load per lookup; a stale,
// larger bound only costs speed). Once `stop` is set every lookup reads -1, which ends the
// traversal. Measured: the same lookup through a FunctionRef cost 2-3 % of a self query's
// instructions in its thunk alone.
class BoundLookup {
  public:
    BoundLookup(const std::atomic<double>* bounds, const std::atomic<bool>* stop)
        : m_bounds(bounds), m_stop(stop) {}
    double operator()(std::uint32_t t) const {
        return m_stop->load(std::memory_order_relaxed)
                   ? -1.0
                   : m_bounds[t].load(std::memory_order_relaxed);
    }
    // The array itself, for a culler that reads many bounds at once (leaf_thresholds), after
    // checking stopped() itself.
    const std::atomic<double>* bounds() const { return m_bounds; }
    bool stopped() const { return m_stop->load(std::memory_order_relaxed); }

  private:
    const std::atomic<double>* m_bounds;
    const std::atomic<bool>* m_stop;
};

// What the discrete-Voronoi stage of one query did (zero for the other cullers).
struct VoronoiStats {
    double seconds = 0;      // whole Stage II: sampling, buckets, kernel, bounds
    double dvd_seconds = 0;  // the kernel (Backend::run) alone
    std::uint64_t samples = 0;
    double cell = 0;  // grid cell size of the last kernel run
    // Triangle pairs a box test let through that a Voronoi lower bound removed.
    std::uint64_t culled = 0;
    // Largest error allowance (kernel_error_bound + triangle_error_term) used.
    double epsilon = 0;
    // Kernel runs skipped because their sampling would visit more grid points than allowed
    // (MAX_GRID_POINTS in voronoi_culler.cpp): those queries cull with the BVH alone, with the
    // same answers.
    std::uint64_t skipped = 0;
};

class Culler {
  public:
    virtual ~Culler() = default;
    virtual CullerKind kind() const = 0;
    // True when object-level Stage I culling (boxes, sweep and prune) may be used with this
    // culler; false for the brute-force reference, which considers every object pair.
    virtual bool object_culling() const = 0;

    // Brings per-object structures up to date with the scene: refit when only positions changed,
    // rebuild when an object is new or its topology changed, drop removed objects.
    virtual void prepare(const Scene& scene) = 0;

    // Calls visit(ta, tb) for every triangle pair (ta of object a, tb of object b, a != b) that
    // may be closer than sqrt(bound_sq). The visitor may lower bound_sq; a negative bound_sq asks
    // the traversal to stop (a cancelled query): every culler returns soon after, the brute-force
    // one after the current triangle of a.
    virtual void nearest_between(const Scene& scene, std::size_t a, std::size_t b, double& bound_sq,
                                 PairVisitor visit) const = 0;

    // Calls visit(t, u), t < u, for every pair of object a's triangles that share no vertex and
    // may be closer than the larger of their two current bounds (`bound_sq(t)`, which the visitor
    // may lower as it goes). Bounds are read as the traversal proceeds; a stale (larger) bound
    // only costs speed. May call `visit` from several threads at once. A negative bound asks the
    // traversal to stop (the brute-force culler checks it once per triangle t).
    virtual void self_pairs(const Scene& scene, std::size_t a, BoundLookup bound_sq,
                            PairVisitor visit) const = 0;

    // Appends every triangle pair that may be within `radius`: for a != b all pairs (ta, tb);
    // for a == b the non-adjacent pairs with ta < tb.
    virtual void pairs_within(const Scene& scene, std::size_t a, std::size_t b, double radius,
                              std::vector<TrianglePair>& out) const = 0;

    // ---- Stage II hooks (seed §5.2). Defaults do nothing, so a culler without Stage II is
    // unaffected. Each is called after prepare() for the scene it is given. ----

    // Grid cell size for the next refinements: a positive size, or nullopt for automatic.
    virtual void set_cell(std::optional<double> /*cell*/) {}
    // Separation: may lower object_upper[i] (a conservative upper bound on object i's separation
    // distance, one per scene object) and records per-triangle lower bounds that
    // nearest_between() uses for this scene state.
    virtual Status refine_separation(const Scene& /*scene*/,
                                     std::vector<double>& /*object_upper*/) {
        return {};
    }
    // Tolerance / collisions / PNS with `radius`: records per-triangle lower bounds that
    // pairs_within(..., radius, ...) uses.
    virtual Status refine_within(const Scene& /*scene*/, double /*radius*/) { return {}; }
    // Self query of object a: partner[t] = a non-adjacent triangle likely closest to t (or
    // UINT32_MAX), for the query to seed t's bound with one exact test. May be called for
    // several objects at once from different threads.
    virtual Status refine_self(const Scene& /*scene*/, std::size_t /*a*/,
                               std::vector<std::uint32_t>& partner) {
        partner.clear();
        return {};
    }
    // Statistics since the last call (and resets them).
    virtual VoronoiStats take_voronoi_stats() { return {}; }
};

std::unique_ptr<Culler> make_culler(CullerKind kind);
// The discrete-Voronoi culler on a kernel backend (kind voronoi_cpu or voronoi_gpu, as given).
std::unique_ptr<Culler> make_voronoi_culler(CullerKind kind, std::shared_ptr<dvd::Backend> backend);

}  // namespace proxima
