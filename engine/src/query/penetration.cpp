#include "proxima/query/penetration.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <optional>
#include <unordered_map>
#include <utility>

#include "proxima/distance/bounds.hpp"
#include "proxima/distance/primitives.hpp"
#include "proxima/geometry/predicates.hpp"

namespace proxima {

namespace {

Triangle corners(const SceneObject& obj, std::uint32_t t) {
    const auto& tri = obj.triangle(t);
    return {obj.vertices[tri[0]], obj.vertices[tri[1]], obj.vertices[tri[2]]};
}

// orient2d(a, b, p') for p' = p + (eps, eps^2) with eps an infinitesimal (Simulation of
// Simplicity). Expanding the determinant gives D0 + eps (a_v - b_v) + eps^2 (b_u - a_u), D0 the
// unperturbed determinant: its sign is decided exactly by the first nonzero term. It is 0 only when
// a and b coincide (in this projection), and antisymmetric in (a, b), so the two triangles sharing
// an edge always see the perturbed point on opposite sides of it.
int sos_orient2d(double au, double av, double bu, double bv, double pu, double pv) {
    const int s = orient2d(au, av, bu, bv, pu, pv);
    if (s != 0) {
        return s;
    }
    if (av != bv) {
        return av > bv ? 1 : -1;
    }
    if (bu != au) {
        return bu > au ? 1 : -1;
    }
    return 0;
}

// Contribution of one triangle to the signed crossing count of the (perturbed) ray from p along
// +axis: +1 / -1 (the sign of the normal's axis component) when the ray crosses it, else 0.
int ray_crossing(const Triangle& tri, const Vec3& p, int k) {
    const int u = (k + 1) % 3;
    const int v = (k + 2) % 3;
    const Vec3& a = tri[0];
    const Vec3& b = tri[1];
    const Vec3& c = tri[2];
    // Exact rejections: the triangle lies wholly behind p, or its projection misses p's (the
    // perturbation is infinitesimal, so strict comparisons stay valid for the perturbed point).
    if (std::max({a[k], b[k], c[k]}) < p[k] || std::max({a[u], b[u], c[u]}) < p[u] ||
        std::min({a[u], b[u], c[u]}) > p[u] || std::max({a[v], b[v], c[v]}) < p[v] ||
        std::min({a[v], b[v], c[v]}) > p[v]) {
        return 0;
    }
    const int s1 = sos_orient2d(a[u], a[v], b[u], b[v], p[u], p[v]);
    if (s1 == 0) {
        return 0;
    }
    if (sos_orient2d(b[u], b[v], c[u], c[v], p[u], p[v]) != s1 ||
        sos_orient2d(c[u], c[v], a[u], a[v], p[u], p[v]) != s1) {
        return 0;  // outside the projection (a degenerate projection is never strictly inside)
    }
    // Inside the projection: s1 is the sign of the normal's axis component n_k. The plane is met
    // beyond p iff n.(p - a) and n_k have opposite signs; orient3d(a, b, c, p) = -sign(n.(p - a))
    // (Shewchuk: positive when p is below the counter-clockwise plane). p on the plane (only
    // possible when p lies on the surface) counts as not crossed.
    const int h = orient3d(a, b, c, p);
    return h == s1 ? s1 : 0;
}

bool outside_box(const Aabb& box, const Vec3& p) {
    for (int k = 0; k < 3; ++k) {
        if (p[k] < box.lo[k] || p[k] > box.hi[k]) {
            return true;
        }
    }
    return false;
}

// Strictly inside a closed oriented surface (p off it): nonzero winding number. Either orientation
// of the surface works (winding -1 inside an inward-oriented one).
bool point_inside(const SceneObject& obj, const Vec3& p) {
    return !outside_box(obj.box, p) && detail::winding_number(obj, p) != 0;
}

// +1 when the surface is oriented outward (positive signed volume), -1 inward, 0 when the signed
// volume vanishes to rounding (no orientation can be trusted).
int orientation_sign(const SceneObject& obj) {
    const Vec3 o = obj.box.center();
    double vol = 0.0;
    double mag = 0.0;
    for (std::uint32_t t = 0; t < obj.triangle_count(); ++t) {
        const Triangle tri = corners(obj, t);
        const Vec3 a = tri[0] - o;
        const Vec3 b = tri[1] - o;
        const Vec3 c = tri[2] - o;
        const double d = dot(a, cross(b, c));
        vol += d;
        mag += std::abs(d);
    }
    if (!(std::abs(vol) > 1e-9 * mag)) {
        return 0;
    }
    return vol > 0 ? 1 : -1;
}

enum class State : std::uint8_t { intersecting, inside, outside };
using StateMap = std::unordered_map<std::uint32_t, State>;

// Stop check, cheap enough to call per work item.
struct Stopper {
    const CancelToken* cancel = nullptr;
    bool stopped = false;
    bool operator()() {
        if (!stopped && cancel != nullptr && cancel->should_stop()) {
            stopped = true;
        }
        return stopped;
    }
};

Status stopped_status(const CancelToken* cancel) {
    return stop_status(*cancel, "penetration depth");  // only called once `cancel` said stop
}

// Overlapping features of one surface: its intersecting triangles (already in `state`) plus the
// triangles reached from them over shared vertices that lie inside the other surface. A triangle
// that touches no triangle of the other surface lies wholly on one side of it, and two such
// triangles sharing a vertex lie on the same side, so `inside(t)` is asked once per connected piece
// of the band around the intersecting triangles: an inside piece is flooded (everything reachable
// without crossing an intersecting triangle is inside), an outside piece is only marked within the
// band (the walk stays local).
template <class Inside>
bool walk(const MeshTopology& topo, const std::vector<std::uint32_t>& intersecting, Inside&& inside,
          StateMap& state, Stopper& stop) {
    auto touches_intersecting = [&](std::uint32_t w) {
        for (const auto v : topo.triangle(w)) {
            for (const auto x : topo.vertex_triangles(v)) {
                const auto it = state.find(x);
                if (it != state.end() && it->second == State::intersecting) {
                    return true;
                }
            }
        }
        return false;
    };
    std::vector<std::uint32_t> stack;
    for (const auto t : intersecting) {
        if (stop()) {
            return false;
        }
        for (const auto u : topo.one_ring(t)) {
            if (state.count(u) != 0) {
                continue;
            }
            const bool in = inside(u);
            state[u] = in ? State::inside : State::outside;
            stack.assign(1, u);
            while (!stack.empty()) {
                const auto x = stack.back();
                stack.pop_back();
                for (const auto w : topo.one_ring(x)) {
                    if (state.count(w) != 0 || (!in && !touches_intersecting(w))) {
                        continue;
                    }
                    state[w] = in ? State::inside : State::outside;
                    stack.push_back(w);
                }
            }
        }
    }
    return true;
}

// Connected components (through shared vertices) of a set of triangles; returns the component of
// each entry of `list` and sets `count`.
std::vector<std::uint32_t> components(const MeshTopology& topo,
                                      const std::vector<std::uint32_t>& list,
                                      std::uint32_t& count) {
    std::unordered_map<std::uint32_t, std::uint32_t> index;
    for (std::uint32_t i = 0; i < list.size(); ++i) {
        index[list[i]] = i;
    }
    constexpr auto NONE = ~std::uint32_t{0};
    std::vector<std::uint32_t> comp(list.size(), NONE);
    count = 0;
    std::vector<std::uint32_t> stack;
    for (std::uint32_t i = 0; i < list.size(); ++i) {
        if (comp[i] != NONE) {
            continue;
        }
        comp[i] = count;
        stack.assign(1, i);
        while (!stack.empty()) {
            const auto j = stack.back();
            stack.pop_back();
            for (const auto w : topo.one_ring(list[j])) {
                const auto it = index.find(w);
                if (it != index.end() && comp[it->second] == NONE) {
                    comp[it->second] = count;
                    stack.push_back(it->second);
                }
            }
        }
        ++count;
    }
    return comp;
}

std::uint32_t component_count(const MeshTopology& topo, const std::vector<std::uint32_t>& list) {
    std::uint32_t count = 0;
    components(topo, list, count);
    return count;
}

// One side of a contact: an object, the classification of its triangles, and its overlapping
// features.
struct Side {
    const SceneObject* object = nullptr;
    const StateMap* state = nullptr;
    std::vector<std::uint32_t> features;  // ascending
    int orientation = 0;
    // For a vertex all of whose triangles intersect the other side: the closed surface to test it
    // against (none for a self-penetration or when the other surface is not closed).
    const SceneObject* test_against = nullptr;
};

// 1 when vertex v lies inside the other side, 0 outside, -1 unknown.
int vertex_inside(const Side& side, std::uint32_t v) {
    const auto& topo = *side.object->topology;
    for (const auto x : topo.vertex_triangles(v)) {
        const auto it = side.state->find(x);
        if (it == side.state->end() || it->second == State::intersecting) {
            continue;
        }
        return it->second == State::inside ? 1 : 0;
    }
    if (side.test_against != nullptr) {
        return point_inside(*side.test_against, side.object->vertices[v]) ? 1 : 0;
    }
    return -1;
}

// Points where the edges of `e` cross triangle `f` (floating-point, on the edges; the crossing
// itself is decided exactly). Edges lying in f's plane (coplanar contact) add nothing.
void edge_crossings(const Triangle& e, const Triangle& f, std::vector<Vec3>& out) {
    const Vec3 n = cross(f[1] - f[0], f[2] - f[0]);
    for (int i = 0; i < 3; ++i) {
        const Vec3& p = e[i];
        const Vec3& q = e[(i + 1) % 3];
        if (!segment_triangle_intersect(p, q, f[0], f[1], f[2])) {
            continue;
        }
        const double hp = dot(n, p - f[0]);
        const double hq = dot(n, q - f[0]);
        if (hp == hq) {
            continue;
        }
        const double t = std::clamp(hp / (hp - hq), 0.0, 1.0);
        out.push_back(p + t * (q - p));
    }
}

// A vertex of one side that lies inside the other side, with a feature triangle incident to it.
struct DeepPoint {
    Vec3 point;
    std::uint32_t triangle = 0;
};

std::vector<DeepPoint> deep_points(const Side& side) {
    std::vector<DeepPoint> out;
    std::unordered_map<std::uint32_t, bool> seen;
    for (const auto t : side.features) {
        for (const auto v : side.object->triangle(t)) {
            if (seen.try_emplace(v, true).second && vertex_inside(side, v) == 1) {
                out.push_back({side.object->vertices[v], t});
            }
        }
    }
    return out;
}

struct FarthestPair {
    bool found = false;
    double squared_distance = 0.0;
    std::uint32_t triangle = 0;        // of the deep point's side
    std::uint32_t other_triangle = 0;  // closest feature on the other side
    Vec3 point;                        // the deep point
    Vec3 other_point;                  // its closest point on the other side's features
};

// Seed §3.3, step 1, on vertex features: for each deep point of `from`, its closest feature among
// the other side's overlapping triangles (exact point-triangle distance); the deep point whose
// closest distance is largest (strictly larger replaces: ties keep the first). Pruning: a target
// whose box lies farther than the current minimum (widened by the rounding slack of
// distance/bounds.hpp) cannot be that minimum, and a deep point whose running minimum is already
// <= the best cannot replace it; neither changes the brute-force answer.
bool farthest_closest(const std::vector<DeepPoint>& from, const Side& to, double slack,
                      FarthestPair& best, Stopper& stop) {
    std::vector<Triangle> targets;
    std::vector<Aabb> boxes;
    targets.reserve(to.features.size());
    boxes.reserve(to.features.size());
    for (const auto g : to.features) {
        targets.push_back(corners(*to.object, g));
        boxes.push_back(triangle_box(targets.back()[0], targets.back()[1], targets.back()[2]));
    }
    for (std::size_t i = 0; i < from.size(); ++i) {
        if ((i & 63) == 0 && stop()) {
            return false;
        }
        const Vec3& p = from[i].point;
        const Aabb pbox{p, p};
        double min_sq = std::numeric_limits<double>::infinity();
        std::size_t arg = 0;
        CullThreshold threshold(min_sq, slack);
        for (std::size_t j = 0; j < targets.size(); ++j) {
            if (box_squared_distance(pbox, boxes[j]) > threshold.get()) {
                continue;
            }
            const double d =
                point_triangle(p, targets[j][0], targets[j][1], targets[j][2]).squared_distance;
            if (d < min_sq) {
                min_sq = d;
                arg = j;
                if (best.found && min_sq <= best.squared_distance) {
                    break;
                }
            }
        }
        if (std::isfinite(min_sq) && (!best.found || min_sq > best.squared_distance)) {
            best.found = true;
            best.squared_distance = min_sq;
            best.triangle = from[i].triangle;
            best.other_triangle = to.features[arg];
            best.point = p;
            best.other_point =
                point_triangle(p, targets[arg][0], targets[arg][1], targets[arg][2]).point_b;
        }
    }
    return true;
}

Vec3 area_normal_sum(const Side& side) {
    Vec3 n;
    for (const auto t : side.features) {
        const Triangle tri = corners(*side.object, t);
        n += cross(tri[1] - tri[0], tri[2] - tri[0]);
    }
    return (side.orientation < 0 ? -0.5 : 0.5) * n;
}

Vec3 vertex_mean(const Side& side) {
    Vec3 m;
    double k = 0.0;
    for (const auto t : side.features) {
        for (const auto v : side.object->triangle(t)) {
            m += side.object->vertices[v];
            k += 1.0;
        }
    }
    return k > 0.0 ? m / k : m;
}

// Width of a point set along a unit direction.
double width(const std::vector<Vec3>& points, const Vec3& dir) {
    double lo = std::numeric_limits<double>::infinity();
    double hi = -lo;
    for (const auto& p : points) {
        const double s = dot(dir, p);
        lo = std::min(lo, s);
        hi = std::max(hi, s);
    }
    return hi >= lo ? hi - lo : 0.0;
}

bool unit(Vec3& v) {
    const double len = norm(v);
    if (!(len > 0.0) || !std::isfinite(len)) {
        return false;
    }
    v = v / len;
    return true;
}

// Direction and depth for two sides whose features are known. `pairs` are the intersecting pairs,
// side a's triangle first.
bool estimate(const Side& a, const Side& b,
              const std::vector<std::pair<std::uint32_t, std::uint32_t>>& pairs, double slack,
              Penetration& out, Stopper& stop) {
    // The overlap region's vertices: vertices of either side inside the other (the deep points),
    // and the points where edges of one side cross triangles of the other.
    const auto deep_a = deep_points(a);
    const auto deep_b = deep_points(b);
    if (stop()) {
        return false;
    }
    std::vector<Vec3> region;
    for (const auto* deep : {&deep_a, &deep_b}) {
        for (const auto& d : *deep) {
            region.push_back(d.point);
        }
    }
    std::vector<Vec3> points;
    for (const auto& [ta, tb] : pairs) {
        const Triangle x = corners(*a.object, ta);
        const Triangle y = corners(*b.object, tb);
        points.clear();
        edge_crossings(x, y, points);
        edge_crossings(y, x, points);
        if (points.empty()) {
            Vec3 w;
            if (triangles_intersect(x, y, &w)) {
                points.push_back(w);
            }
        }
        region.insert(region.end(), points.begin(), points.end());
    }

    // Direction candidates: each side's farthest closest pair, pointing from side a to side b
    // (moving a along it takes a's deep point out through b's surface, and b's deep point is left
    // behind), and their bisector when both exist. The one along which the overlap region is
    // thinnest wins (ties: a's, then b's): the seed takes the single farthest pair; on curved,
    // tessellated surfaces the two sides' farthest pairs are nearly tied and each is tilted by a
    // facet normal, and the thinnest of the three is the better local translation.
    FarthestPair fa;
    FarthestPair fb;
    if (!farthest_closest(deep_a, b, slack, fa, stop) ||
        !farthest_closest(deep_b, a, slack, fb, stop)) {
        return false;
    }
    struct Candidate {
        Vec3 dir;
        std::uint32_t triangle, other_triangle;
    };
    std::vector<Candidate> candidates;
    if (fa.found && fa.squared_distance > 0.0) {
        Vec3 d = fa.other_point - fa.point;
        if (unit(d)) {
            candidates.push_back({d, fa.triangle, fa.other_triangle});
        }
    }
    if (fb.found && fb.squared_distance > 0.0) {
        Vec3 d = fb.point - fb.other_point;
        if (unit(d)) {
            candidates.push_back({d, fb.other_triangle, fb.triangle});
        }
    }
    if (candidates.size() == 2) {
        Vec3 d = candidates[0].dir + candidates[1].dir;
        const auto& deeper =
            fa.squared_distance >= fb.squared_distance ? candidates[0] : candidates[1];
        if (unit(d)) {
            candidates.push_back({d, deeper.triangle, deeper.other_triangle});
        }
    }
    Vec3 dir;
    if (candidates.empty()) {
        // No deep point is off the other side's features (every overlapping feature touches the
        // other side, or no inside is defined). Side a's outward normals point into side b where
        // a is inside b, so a leaves against them (and b along its own): the area-weighted sum
        // -N_a + N_b. Symmetric overlaps can cancel it; then the centroid difference of the
        // features, then +x as the last resort.
        out.normal_fallback = true;
        out.triangle = pairs.front().first;
        out.other_triangle = pairs.front().second;
        dir = area_normal_sum(b) - area_normal_sum(a);
        if (!unit(dir)) {
            dir = vertex_mean(b) - vertex_mean(a);
            if (!unit(dir)) {
                dir = {1.0, 0.0, 0.0};
            }
        }
    } else {
        double best = std::numeric_limits<double>::infinity();
        for (const auto& c : candidates) {
            const double w = width(region, c.dir);
            if (w < best) {
                best = w;
                dir = c.dir;
                out.triangle = c.triangle;
                out.other_triangle = c.other_triangle;
            }
        }
    }
    out.direction = dir;
    out.depth = width(region, dir);
    out.vector = out.depth * dir;
    return true;
}

// Self-penetration classifier: whether non-intersecting triangle t lies in a self-overlap, i.e.
// the winding numbers on its two sides are not those of the outer skin ({0, 1} for an outward
// surface, {-1, 0} for an inward one). The winding on the +axis side is the signed crossing count
// of a ray from t's centroid along +axis with every other triangle: the ray leaves through t's own
// place (t excluded), which holds when the centroid's projection is strictly inside t's
// projection on the axis where t's normal is largest (checked exactly; otherwise unknown).
std::optional<bool> in_self_overlap(const SceneObject& obj, int orientation, std::uint32_t t) {
    const Triangle tri = corners(obj, t);
    const Vec3 n = cross(tri[1] - tri[0], tri[2] - tri[0]);
    int k = 0;
    for (int i = 1; i < 3; ++i) {
        if (std::abs(n[i]) > std::abs(n[k])) {
            k = i;
        }
    }
    const int u = (k + 1) % 3;
    const int v = (k + 2) % 3;
    const int o = orient2d(tri[0][u], tri[0][v], tri[1][u], tri[1][v], tri[2][u], tri[2][v]);
    if (o == 0) {
        return std::nullopt;
    }
    const Vec3 c = (tri[0] + tri[1] + tri[2]) / 3.0;
    for (int e = 0; e < 3; ++e) {
        const Vec3& p = tri[e];
        const Vec3& q = tri[(e + 1) % 3];
        if (orient2d(p[u], p[v], q[u], q[v], c[u], c[v]) != o) {
            return std::nullopt;
        }
    }
    const int w_plus = detail::winding_number(obj, c, k, t);
    const int w_minus = w_plus + o;  // crossing t from its -axis side adds its contribution o
    const int lo = std::min(w_plus, w_minus);
    const int hi = std::max(w_plus, w_minus);
    return !(lo == std::min(0, orientation) && hi == std::max(0, orientation));
}

struct ObjectInfo {
    bool closed = false;
    int orientation = 0;
};

using PairList = std::vector<std::pair<std::uint32_t, std::uint32_t>>;

std::vector<std::uint32_t> sorted_unique(std::vector<std::uint32_t> v) {
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
    return v;
}

std::vector<std::uint32_t> features_of(const StateMap& state) {
    std::vector<std::uint32_t> out;
    for (const auto& [t, s] : state) {
        if (s != State::outside) {
            out.push_back(t);
        }
    }
    std::sort(out.begin(), out.end());
    return out;
}

bool two_objects(const SceneObject& oa, const ObjectInfo& ia, const SceneObject& ob,
                 const ObjectInfo& ib, const PairList& pairs, double slack, Penetration& out,
                 Stopper& stop) {
    std::vector<std::uint32_t> ia_tris;
    std::vector<std::uint32_t> ib_tris;
    for (const auto& [ta, tb] : pairs) {
        ia_tris.push_back(ta);
        ib_tris.push_back(tb);
    }
    ia_tris = sorted_unique(std::move(ia_tris));
    ib_tris = sorted_unique(std::move(ib_tris));
    StateMap sa;
    StateMap sb;
    for (const auto t : ia_tris) {
        sa[t] = State::intersecting;
    }
    for (const auto t : ib_tris) {
        sb[t] = State::intersecting;
    }
    // A's triangles can be classified against B only when B is closed, and vice versa.
    if (ib.closed) {
        auto inside_b = [&](std::uint32_t t) {
            return point_inside(ob, oa.vertices[oa.triangle(t)[0]]);
        };
        if (!walk(*oa.topology, ia_tris, inside_b, sa, stop)) {
            return false;
        }
    }
    if (ia.closed) {
        auto inside_a = [&](std::uint32_t t) {
            return point_inside(oa, ob.vertices[ob.triangle(t)[0]]);
        };
        if (!walk(*ob.topology, ib_tris, inside_a, sb, stop)) {
            return false;
        }
    }
    Side a{&oa, &sa, features_of(sa), ia.orientation, ib.closed ? &ob : nullptr};
    Side b{&ob, &sb, features_of(sb), ib.orientation, ia.closed ? &oa : nullptr};
    out.closed = ia.closed && ib.closed;
    out.isolated = component_count(*oa.topology, a.features) == 1 &&
                   component_count(*ob.topology, b.features) == 1;
    if (!estimate(a, b, pairs, slack, out, stop)) {
        return false;
    }
    out.triangles = std::move(a.features);
    out.other_triangles = std::move(b.features);
    return true;
}

bool self_object(const SceneObject& obj, const ObjectInfo& info, const PairList& pairs,
                 double slack, Penetration& out, Stopper& stop) {
    const auto& topo = *obj.topology;
    std::vector<std::uint32_t> hit;
    for (const auto& [t, u] : pairs) {
        hit.push_back(t);
        hit.push_back(u);
    }
    hit = sorted_unique(std::move(hit));
    StateMap state;
    for (const auto t : hit) {
        state[t] = State::intersecting;
    }
    const bool can_walk = info.closed && info.orientation != 0;
    if (can_walk) {
        auto overlap = [&](std::uint32_t t) {
            // Unknown (a sliver whose centroid cannot be placed) counts as outside: fewer
            // features, never a wrong inside region.
            return in_self_overlap(obj, info.orientation, t).value_or(false);
        };
        if (!walk(topo, hit, overlap, state, stop)) {
            return false;
        }
    }
    out.closed = can_walk;
    const auto features = features_of(state);

    // Two sides: connected pieces of the features, 2-coloured so that every intersecting pair
    // joins pieces of different colours (a piece pierced by another lies on the other side).
    std::uint32_t count = 0;
    const auto comp = components(topo, features, count);
    std::unordered_map<std::uint32_t, std::uint32_t> piece;
    for (std::size_t i = 0; i < features.size(); ++i) {
        piece[features[i]] = comp[i];
    }
    std::vector<std::vector<std::uint32_t>> links(count);
    bool bipartite = true;
    for (const auto& [t, u] : pairs) {
        const auto pt = piece.at(t);
        const auto pu = piece.at(u);
        if (pt == pu) {
            bipartite = false;
            break;
        }
        links[pt].push_back(pu);
        links[pu].push_back(pt);
    }
    std::vector<int> colour(count, -1);
    for (std::uint32_t start = 0; start < count && bipartite; ++start) {
        if (colour[start] >= 0) {
            continue;
        }
        colour[start] = 0;  // pieces are numbered by their smallest triangle: deterministic
        std::vector<std::uint32_t> stack{start};
        while (!stack.empty() && bipartite) {
            const auto p = stack.back();
            stack.pop_back();
            for (const auto q : links[p]) {
                if (colour[q] < 0) {
                    colour[q] = 1 - colour[p];
                    stack.push_back(q);
                } else if (colour[q] == colour[p]) {
                    bipartite = false;
                    break;
                }
            }
        }
    }
    if (!bipartite) {
        out.sides_split = false;
        out.isolated = count <= 1;
        out.triangles = features;
        out.other_triangles = features;
        out.triangle = pairs.front().first;
        out.other_triangle = pairs.front().second;
        return true;
    }
    Side a{&obj, &state, {}, info.orientation, nullptr};
    Side b{&obj, &state, {}, info.orientation, nullptr};
    for (std::size_t i = 0; i < features.size(); ++i) {
        (colour[comp[i]] == 0 ? a : b).features.push_back(features[i]);
    }
    PairList oriented;
    oriented.reserve(pairs.size());
    for (const auto& [t, u] : pairs) {
        if (colour[piece.at(t)] == 0) {
            oriented.emplace_back(t, u);
        } else {
            oriented.emplace_back(u, t);
        }
    }
    std::sort(oriented.begin(), oriented.end());
    out.isolated = component_count(topo, a.features) == 1 && component_count(topo, b.features) == 1;
    if (!estimate(a, b, oriented, slack, out, stop)) {
        return false;
    }
    out.triangles = std::move(a.features);
    out.other_triangles = std::move(b.features);
    return true;
}

}  // namespace

namespace detail {

int winding_number(const SceneObject& object, const Vec3& p, int axis, std::int64_t exclude) {
    int w = 0;
    for (std::uint32_t t = 0; t < object.triangle_count(); ++t) {
        if (static_cast<std::int64_t>(t) == exclude) {
            continue;
        }
        w += ray_crossing(corners(object, t), p, axis);
    }
    return w;
}

bool closed_oriented(const MeshTopology& topology) {
    // Net count of each undirected edge: +1 per use as (lo -> hi), -1 per use as (hi -> lo).
    std::unordered_map<std::uint64_t, int> net;
    net.reserve(topology.triangle_count() * 3);
    for (const auto& tri : topology.triangles()) {
        for (int e = 0; e < 3; ++e) {
            const auto i = tri[e];
            const auto j = tri[(e + 1) % 3];
            if (i == j) {
                continue;
            }
            const auto key = (static_cast<std::uint64_t>(std::min(i, j)) << 32) | std::max(i, j);
            net[key] += i < j ? 1 : -1;
        }
    }
    return std::all_of(net.begin(), net.end(), [](const auto& kv) { return kv.second == 0; });
}

}  // namespace detail

StatusOr<std::vector<Penetration>> penetration_depths(const Scene& scene,
                                                      const std::vector<FeaturePair>& collisions,
                                                      const CancelToken* cancel) {
    // Group by object pair (smaller object first), validating every index.
    std::map<std::pair<std::uint32_t, std::uint32_t>, PairList> groups;
    for (std::size_t i = 0; i < collisions.size(); ++i) {
        const auto& c = collisions[i];
        if (c.object >= scene.size() || c.other >= scene.size()) {
            return invalid_argument("collision pair " + std::to_string(i) + " names object " +
                                    std::to_string(std::max(c.object, c.other)) + " (scene has " +
                                    std::to_string(scene.size()) + " objects)");
        }
        if (c.triangle >= scene[c.object].triangle_count() ||
            c.other_triangle >= scene[c.other].triangle_count()) {
            return invalid_argument(
                "collision pair " + std::to_string(i) + " names a triangle out of range (object " +
                std::to_string(c.object) + " triangle " + std::to_string(c.triangle) + ", object " +
                std::to_string(c.other) + " triangle " + std::to_string(c.other_triangle) + ")");
        }
        if (c.object == c.other && c.triangle == c.other_triangle) {
            return invalid_argument("collision pair " + std::to_string(i) + " pairs triangle " +
                                    std::to_string(c.triangle) + " of object " +
                                    std::to_string(c.object) + " with itself");
        }
        if (c.object <= c.other) {
            groups[{c.object, c.other}].emplace_back(c.triangle, c.other_triangle);
        } else {
            groups[{c.other, c.object}].emplace_back(c.other_triangle, c.triangle);
        }
    }

    double scale = 0.0;
    for (const auto& o : scene.objects()) {
        scale = std::max(scale, coordinate_scale(o.box));
    }
    const double slack = rounding_slack(scale);

    std::unordered_map<std::uint32_t, ObjectInfo> infos;
    auto info = [&](std::uint32_t i) -> const ObjectInfo& {
        auto [it, fresh] = infos.try_emplace(i);
        if (fresh) {
            it->second.closed = detail::closed_oriented(*scene[i].topology);
            it->second.orientation = orientation_sign(scene[i]);
        }
        return it->second;
    };

    Stopper stop{cancel};
    std::vector<Penetration> out;
    out.reserve(groups.size());
    for (auto& [key, pairs] : groups) {
        if (stop()) {
            return stopped_status(cancel);
        }
        std::sort(pairs.begin(), pairs.end());
        pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
        Penetration p;
        p.object = key.first;
        p.other = key.second;
        const bool ok = key.first == key.second
                            ? self_object(scene[key.first], info(key.first), pairs, slack, p, stop)
                            : two_objects(scene[key.first], info(key.first), scene[key.second],
                                          info(key.second), pairs, slack, p, stop);
        if (!ok) {
            return stopped_status(cancel);
        }
        out.push_back(std::move(p));
    }
    return out;
}

}  // namespace proxima
