#pragma once
// Culling strategies behind one interface. A culler only proposes candidate triangle pairs; the
// query code runs the exact test on each, so every culler gives the answer brute force gives as
// long as it never drops a pair that could matter (its bounds are conservative). The
// discrete-Voronoi culler plugs in here too.

#include <cstdint>
#include <memory>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "proxima/scene.hpp"

namespace proxima {

enum class CullerKind { automatic, brute, bvh };

const char* culler_name(CullerKind kind);
// Parses "auto", "brute" or "bvh"; unknown names give an invalid_argument status.
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
        FunctionRef(F&& f)  // NOLINT(google-explicit-constructor)
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
// The current squared distance bound of a triangle (for intra-object searches).
using BoundLookup = FunctionRef<double(std::uint32_t)>;

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
    // may be closer than sqrt(bound_sq). The visitor may lower bound_sq.
    virtual void nearest_between(const Scene& scene, std::size_t a, std::size_t b, double& bound_sq,
                                 PairVisitor visit) const = 0;

    // Calls visit(t, u), t < u, for every pair of object a's triangles that share no vertex and
    // may be closer than the larger of their two current bounds (`bound_sq(t)`, which the visitor
    // may lower as it goes). Bounds are read as the traversal proceeds; a stale (larger) bound
    // only costs speed. May call `visit` from several threads at once.
    virtual void self_pairs(const Scene& scene, std::size_t a, BoundLookup bound_sq,
                            PairVisitor visit) const = 0;

    // Appends every triangle pair that may be within `radius`: for a != b all pairs (ta, tb);
    // for a == b the non-adjacent pairs with ta < tb.
    virtual void pairs_within(const Scene& scene, std::size_t a, std::size_t b, double radius,
                              std::vector<TrianglePair>& out) const = 0;
};

std::unique_ptr<Culler> make_culler(CullerKind kind);

}  // namespace proxima
