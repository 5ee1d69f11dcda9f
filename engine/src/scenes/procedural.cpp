#include "proxima/scenes/procedural.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <numbers>
#include <random>
#include <tuple>
#include <unordered_map>
#include <utility>

namespace proxima::scenes {

namespace {

constexpr double PI = std::numbers::pi;
// Frame k is at time k / FPS seconds. Motion is a closed-form function of that time (never of
// frame_count, except where a scene's event is placed relative to it), so frame k is the same
// geometry whatever the sequence length and whatever the thread count.
constexpr double FPS = 30.0;

double frame_time(std::size_t k) {
    return static_cast<double>(k) / FPS;
}

double smoothstep(double e0, double e1, double x) {
    const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
    return t * t * (3.0 - 2.0 * t);
}

// Uniform doubles from mt19937_64's raw output: the engine's sequence is fixed by the standard,
// std::uniform_real_distribution's mapping is not (it differs between standard libraries).
class Rng {
  public:
    explicit Rng(std::uint64_t seed) : m_gen(seed) {}
    double uniform(double lo, double hi) {
        return lo + (hi - lo) * static_cast<double>(m_gen() >> 11) * 0x1.0p-53;
    }
    Vec3 unit_vector() {
        // Rejection keeps the distribution uniform and the sequence platform-independent.
        for (;;) {
            const Vec3 v{uniform(-1, 1), uniform(-1, 1), uniform(-1, 1)};
            const double n2 = squared_norm(v);
            if (n2 > 1e-4 && n2 <= 1.0) {
                return v / std::sqrt(n2);
            }
        }
    }

  private:
    std::mt19937_64 m_gen;
};

// ---------------------------------------------------------------------------------------------
// Rotations.

struct Mat3 {
    Vec3 r0{1, 0, 0};
    Vec3 r1{0, 1, 0};
    Vec3 r2{0, 0, 1};

    Vec3 operator*(const Vec3& v) const { return {dot(r0, v), dot(r1, v), dot(r2, v)}; }
    Mat3 operator*(const Mat3& b) const {
        const Vec3 c0{b.r0.x, b.r1.x, b.r2.x};
        const Vec3 c1{b.r0.y, b.r1.y, b.r2.y};
        const Vec3 c2{b.r0.z, b.r1.z, b.r2.z};
        return {{dot(r0, c0), dot(r0, c1), dot(r0, c2)},
                {dot(r1, c0), dot(r1, c1), dot(r1, c2)},
                {dot(r2, c0), dot(r2, c1), dot(r2, c2)}};
    }
};

// Rodrigues' formula; `axis` need not be normalised.
Mat3 rotation(Vec3 axis, double angle) {
    axis = axis / norm(axis);
    const double c = std::cos(angle);
    const double s = std::sin(angle);
    const double t = 1.0 - c;
    const double x = axis.x;
    const double y = axis.y;
    const double z = axis.z;
    return {{t * x * x + c, t * x * y - s * z, t * x * z + s * y},
            {t * x * y + s * z, t * y * y + c, t * y * z - s * x},
            {t * x * z - s * y, t * y * z + s * x, t * z * z + c}};
}

// ---------------------------------------------------------------------------------------------
// Shapes. Closed shapes are consistently oriented (outward normals) and watertight: every edge is
// shared by exactly two triangles, which the tests check.

using Row = std::vector<std::uint32_t>;

// Triangulates the band between two rows of vertex indices. A row of one index is a pole (a fan).
// `periodic` closes the band around; `flip` reverses the orientation. With rows running along +u
// and `b` displaced from `a` along +v, the normals point along u x v.
void stitch(const Row& a, const Row& b, bool periodic, bool flip,
            std::vector<TriangleIndices>& out) {
    auto emit = [&](std::uint32_t p, std::uint32_t q, std::uint32_t r) {
        out.push_back(flip ? TriangleIndices{p, r, q} : TriangleIndices{p, q, r});
    };
    if (a.size() == 1) {
        const std::size_t n = periodic ? b.size() : b.size() - 1;
        for (std::size_t j = 0; j < n; ++j) {
            emit(a[0], b[(j + 1) % b.size()], b[j]);
        }
        return;
    }
    if (b.size() == 1) {
        const std::size_t n = periodic ? a.size() : a.size() - 1;
        for (std::size_t j = 0; j < n; ++j) {
            emit(a[j], a[(j + 1) % a.size()], b[0]);
        }
        return;
    }
    const std::size_t n = periodic ? a.size() : a.size() - 1;
    for (std::size_t j = 0; j < n; ++j) {
        const std::size_t j1 = (j + 1) % a.size();
        emit(a[j], a[j1], b[j1]);
        emit(a[j], b[j1], b[j]);
    }
}

std::uint32_t add_vertex(TriangleMesh& mesh, const Vec3& p) {
    mesh.vertices.push_back(p);
    return static_cast<std::uint32_t>(mesh.vertices.size() - 1);
}

// Closed surface of revolution about +y: `profile` holds (radius, y) from the first pole to the
// last (radius 0 at both ends), `m` segments around. 2 m (profile.size() - 2) triangles.
TriangleMesh revolution(const std::vector<std::pair<double, double>>& profile, int m) {
    TriangleMesh mesh;
    std::vector<Row> rows;
    for (std::size_t i = 0; i < profile.size(); ++i) {
        const auto [radius, y] = profile[i];
        if (i == 0 || i + 1 == profile.size()) {
            rows.push_back({add_vertex(mesh, {0.0, y, 0.0})});
            continue;
        }
        Row row;
        for (int j = 0; j < m; ++j) {
            const double phi = 2.0 * PI * j / m;
            row.push_back(add_vertex(mesh, {radius * std::cos(phi), y, radius * std::sin(phi)}));
        }
        rows.push_back(std::move(row));
    }
    for (std::size_t i = 0; i + 1 < rows.size(); ++i) {
        stitch(rows[i], rows[i + 1], true, false, mesh.triangles);
    }
    return mesh;
}

// Unit sphere, `m` segments around, `n` from pole to pole: 2 m (n - 1) triangles.
TriangleMesh uv_sphere(int m, int n) {
    std::vector<std::pair<double, double>> profile;
    for (int i = 0; i <= n; ++i) {
        const double theta = PI * i / n;
        profile.emplace_back(std::sin(theta), std::cos(theta));
    }
    return revolution(profile, m);
}

// Torus about +y: `m` segments around the axis, `n` around the tube: 2 m n triangles.
TriangleMesh torus(int m, int n, double major, double minor) {
    TriangleMesh mesh;
    std::vector<Row> rows;
    for (int i = 0; i < n; ++i) {
        const double v = 2.0 * PI * i / n;
        Row row;
        for (int j = 0; j < m; ++j) {
            const double u = 2.0 * PI * j / m;
            const double rho = major + minor * std::cos(v);
            row.push_back(
                add_vertex(mesh, {rho * std::cos(u), minor * std::sin(v), rho * std::sin(u)}));
        }
        rows.push_back(std::move(row));
    }
    for (int i = 0; i < n; ++i) {
        // Rows advance along +v, which with +u gives inward normals: flip.
        stitch(rows[i], rows[(i + 1) % n], true, true, mesh.triangles);
    }
    return mesh;
}

// Box of half extents `half`, each face an (n_b x n_c) grid, vertices shared along edges:
// 4 (nx ny + ny nz + nz nx) triangles.
TriangleMesh tessellated_box(const Vec3& half, std::array<int, 3> n) {
    TriangleMesh mesh;
    std::map<std::tuple<int, int, int>, std::uint32_t> lattice;
    auto vertex = [&](std::array<int, 3> ijk) {
        auto [it, inserted] = lattice.emplace(std::make_tuple(ijk[0], ijk[1], ijk[2]), 0u);
        if (inserted) {
            Vec3 p;
            for (int a = 0; a < 3; ++a) {
                p[a] = half[a] * (2.0 * ijk[a] / n[a] - 1.0);
            }
            it->second = add_vertex(mesh, p);
        }
        return it->second;
    };
    for (int a = 0; a < 3; ++a) {
        const int b = (a + 1) % 3;
        const int c = (a + 2) % 3;
        for (int side = 0; side < 2; ++side) {
            for (int i = 0; i < n[b]; ++i) {
                for (int j = 0; j < n[c]; ++j) {
                    auto at = [&](int di, int dj) {
                        std::array<int, 3> ijk{};
                        ijk[a] = side * n[a];
                        ijk[b] = i + di;
                        ijk[c] = j + dj;
                        return vertex(ijk);
                    };
                    const auto p00 = at(0, 0);
                    const auto p10 = at(1, 0);
                    const auto p11 = at(1, 1);
                    const auto p01 = at(0, 1);
                    // e_b x e_c = e_a: counter-clockwise seen from +a; reversed on the -a side.
                    if (side == 1) {
                        mesh.triangles.push_back({p00, p10, p11});
                        mesh.triangles.push_back({p00, p11, p01});
                    } else {
                        mesh.triangles.push_back({p00, p11, p10});
                        mesh.triangles.push_back({p00, p01, p11});
                    }
                }
            }
        }
    }
    return mesh;
}

// A sheet of (nu x nv) vertices; `wrap` joins the first and last columns into a tube (nu columns
// around). Vertex (i, j) is at index j * nu + i; positions are set by the caller.
TriangleMesh sheet(int nu, int nv, bool wrap) {
    TriangleMesh mesh;
    mesh.vertices.resize(static_cast<std::size_t>(nu) * nv);
    for (int j = 0; j + 1 < nv; ++j) {
        Row a;
        Row b;
        for (int i = 0; i < nu; ++i) {
            a.push_back(static_cast<std::uint32_t>(j * nu + i));
            b.push_back(static_cast<std::uint32_t>((j + 1) * nu + i));
        }
        stitch(a, b, wrap, false, mesh.triangles);
    }
    return mesh;
}

// One fragment of a broken unit sphere: the wedge between longitudes phi0 and phi1 (about +y),
// closed by two half-disks through the axis. `n` segments pole to pole, `k` across the outer
// patch, `j` from the axis to the rim on each flat face: 2 (n - 1) (k + 2 j) triangles.
TriangleMesh sphere_wedge(int n, int k, int j, double phi0, double phi1) {
    TriangleMesh mesh;
    const auto north = add_vertex(mesh, {0, 1, 0});
    const auto south = add_vertex(mesh, {0, -1, 0});
    std::vector<Row> outer(1, Row{north});
    std::vector<Row> face0(1, Row{north});
    std::vector<Row> face1(1, Row{north});
    auto dir = [](double phi) { return Vec3{std::cos(phi), 0.0, std::sin(phi)}; };
    for (int i = 1; i < n; ++i) {
        const double theta = PI * i / n;
        const double s = std::sin(theta);
        const double y = std::cos(theta);
        Row out_row;
        for (int q = 0; q <= k; ++q) {
            const double phi = phi0 + (phi1 - phi0) * q / k;
            out_row.push_back(add_vertex(mesh, s * dir(phi) + Vec3{0, y, 0}));
        }
        const auto axis = add_vertex(mesh, {0, y, 0});
        Row f0{axis};
        Row f1{axis};
        for (int r = 1; r < j; ++r) {
            f0.push_back(add_vertex(mesh, (s * r / j) * dir(phi0) + Vec3{0, y, 0}));
            f1.push_back(add_vertex(mesh, (s * r / j) * dir(phi1) + Vec3{0, y, 0}));
        }
        f0.push_back(out_row.front());
        f1.push_back(out_row.back());
        outer.push_back(std::move(out_row));
        face0.push_back(std::move(f0));
        face1.push_back(std::move(f1));
    }
    outer.push_back(Row{south});
    face0.push_back(Row{south});
    face1.push_back(Row{south});
    for (std::size_t i = 0; i + 1 < outer.size(); ++i) {
        // Outer rows run along +phi, descending: normals outward. The face rows run from the
        // axis outward, descending: normal -e_phi, outward for the face at phi0, inward at phi1.
        stitch(outer[i], outer[i + 1], false, false, mesh.triangles);
        stitch(face0[i], face0[i + 1], false, false, mesh.triangles);
        stitch(face1[i], face1[i + 1], false, true, mesh.triangles);
    }
    return mesh;
}

// Radial projection of the unit sphere onto the superellipsoid |x|^q + |y|^q + |z|^q = 1: a
// rounded box for q around 6 (still watertight, same topology as the sphere).
std::vector<Vec3> rounded_box(const std::vector<Vec3>& sphere, double q) {
    std::vector<Vec3> out;
    out.reserve(sphere.size());
    for (const auto& d : sphere) {
        const double s = std::pow(
            std::pow(std::abs(d.x), q) + std::pow(std::abs(d.y), q) + std::pow(std::abs(d.z), q),
            -1.0 / q);
        out.push_back(s * d);
    }
    return out;
}

// Pleat profile shared by the skirt and the draped cloth. For an angle `phi` along a band of
// pleats (one pleat per 2 pi), returns the radial bulge in [-1, 1] and the remapped angle. The
// remapping makes the cloth dwell at nearly constant angle on the flanks and pairs neighbouring
// flanks unevenly, so opposite sides of a fold come close: self-proximity that the 1-ring does
// not explain. Monotone in phi for strength <= 1 (derivative >= 0.15), so the sheet never folds
// through itself.
std::pair<double, double> pleat(double phi, double strength) {
    const double b = 0.7 * strength;
    const double c = 0.9 * strength;
    const double remapped = phi - 0.5 * b * std::sin(2.0 * phi) + c * (1.0 - std::cos(phi));
    return {std::sin(phi), remapped};
}

// Smooth, volume-roughly-preserving squash along local y plus a travelling ripple: the shape
// changes every frame, the topology never. `size` scales the ripple's wavelength.
Vec3 wobble(const Vec3& p, double squash, double ripple, double phase, double size) {
    const double lateral = 1.0 / std::sqrt(squash);
    const double k = 2.5 / size;
    const double f =
        1.0 + ripple * std::sin(k * p.x + phase) * std::cos(k * p.z - 0.7 * phase + 0.3 * k * p.y);
    return {f * lateral * p.x, f * squash * p.y, f * lateral * p.z};
}

// ---------------------------------------------------------------------------------------------
// A scene as phases of parts. Phase 0 holds the objects from frame 0; a scene with a topology
// event switches to phase 1 at `break_frame`, where each part of phase 1 names the phase-0 part it
// replaces (its parent) or carries over by name.

struct Part {
    std::string name;
    std::vector<TriangleIndices> triangles;
    std::size_t vertex_count = 0;
    std::ptrdiff_t parent = -1;  // index in the previous phase of the object this one replaces
    bool moves = true;           // static parts get no position updates
    // World positions of every vertex at frame k (out is resized by the callee).
    std::function<void(std::size_t k, std::vector<Vec3>& out)> place;
};

struct Sequence {
    std::size_t break_frame = std::numeric_limits<std::size_t>::max();
    std::vector<std::vector<Part>> phases;
    std::vector<std::unordered_map<std::string, std::size_t>> index;
    std::vector<std::vector<std::vector<std::size_t>>> children;  // [phase][parent] -> parts

    std::size_t phase_of(std::size_t k) const {
        return phases.size() > 1 && k >= break_frame ? 1 : 0;
    }

    void finish() {
        index.assign(phases.size(), {});
        children.assign(phases.size(), {});
        for (std::size_t ph = 0; ph < phases.size(); ++ph) {
            for (std::size_t p = 0; p < phases[ph].size(); ++p) {
                index[ph].emplace(phases[ph][p].name, p);
            }
            if (ph > 0) {
                children[ph].resize(phases[ph - 1].size());
                for (std::size_t p = 0; p < phases[ph].size(); ++p) {
                    if (phases[ph][p].parent >= 0) {
                        children[ph][static_cast<std::size_t>(phases[ph][p].parent)].push_back(p);
                    }
                }
            }
        }
    }

    std::vector<Vec3> positions(std::size_t phase, std::size_t part, std::size_t k) const {
        std::vector<Vec3> out;
        phases[phase][part].place(k, out);
        return out;
    }

    NamedMesh mesh(std::size_t phase, std::size_t part, std::size_t k) const {
        const Part& p = phases[phase][part];
        return {p.name, {positions(phase, part, k), p.triangles}};
    }

    // Objects are matched by name, so ids are whatever the scene gave them, and objects a caller
    // added or changed on its own are left alone.
    SceneUpdate step(std::size_t k, const Scene& scene) const {
        SceneUpdate update;
        if (k == 0) {
            return update;
        }
        const std::size_t prev = phase_of(k - 1);
        const std::size_t cur = phase_of(k);
        for (const auto& obj : scene.objects()) {
            if (prev != cur) {
                auto it = index[prev].find(obj.name);
                if (it != index[prev].end() && !children[cur][it->second].empty()) {
                    SceneUpdate::Replacement r;
                    r.object = obj.id;
                    for (auto q : children[cur][it->second]) {
                        r.fragments.push_back(mesh(cur, q, k));
                    }
                    update.replacements.push_back(std::move(r));
                    continue;
                }
            }
            auto it = index[cur].find(obj.name);
            if (it == index[cur].end()) {
                continue;
            }
            const Part& part = phases[cur][it->second];
            if (!part.moves || obj.vertices.size() != part.vertex_count) {
                continue;
            }
            update.positions.push_back({obj.id, positions(cur, it->second, k)});
        }
        return update;
    }
};

ProceduralScene make_scene(std::string name, std::string description, std::size_t frames,
                           const std::shared_ptr<Sequence>& seq) {
    seq->finish();
    ProceduralScene scene;
    scene.name = std::move(name);
    scene.description = std::move(description);
    scene.frame_count = frames;
    const std::size_t ph = seq->phase_of(0);
    for (std::size_t p = 0; p < seq->phases[ph].size(); ++p) {
        scene.initial.push_back(seq->mesh(ph, p, 0));
    }
    scene.step = [seq](std::size_t k, const Scene& s) { return seq->step(k, s); };
    return scene;
}

// A part whose vertices are a fixed local shape mapped by `map(k, local) -> world`.
template <class Map>
Part shaped_part(std::string name, TriangleMesh local, Map map, bool moves = true) {
    Part part;
    part.name = std::move(name);
    part.triangles = std::move(local.triangles);
    part.vertex_count = local.vertices.size();
    part.moves = moves;
    auto rest = std::make_shared<const std::vector<Vec3>>(std::move(local.vertices));
    part.place = [rest, map](std::size_t k, std::vector<Vec3>& out) { map(k, *rest, out); };
    return part;
}

// A small deforming closed object for the bowl and the ramps: a sphere, a rounded box or a torus
// of about `radius`, tessellated m around and n pole to pole: 2 m (n - 1) triangles.
TriangleMesh small_object(int kind, double radius, int m, int n) {
    switch (kind % 3) {
        case 0: {
            auto mesh = uv_sphere(m, n);
            for (auto& v : mesh.vertices) {
                v = radius * v;
            }
            return mesh;
        }
        case 1: {
            auto mesh = uv_sphere(m, n);
            mesh.vertices = rounded_box(mesh.vertices, 6.0);
            // Half extent 0.72 r: the corners (at 1.44 times the half extent) reach 1.04 r.
            for (auto& v : mesh.vertices) {
                v = (0.72 * radius) * v;
            }
            return mesh;
        }
        default:
            // m around the axis, n - 1 around the tube: the same 2 m (n - 1) triangles.
            return torus(m, n - 1, 0.68 * radius, 0.32 * radius);
    }
}

// ---------------------------------------------------------------------------------------------
// Skirt: a pleated cylindrical cloth tube (open at both ends) hanging from the waist and swaying,
// its pleats deepening and twisting so that the flanks of neighbouring folds come close, with two
// walking legs inside it (elongated ellipsoids bending at the knee).

constexpr int SKIRT_AROUND = 96;
constexpr int SKIRT_ROWS = 57;

void place_skirt(std::size_t k, std::vector<Vec3>& out) {
    const double t = frame_time(k);
    out.resize(static_cast<std::size_t>(SKIRT_AROUND) * SKIRT_ROWS);
    constexpr int PLEATS = 12;
    const double fold = 0.75 + 0.25 * std::sin(2.1 * t);
    const double sway_x = 0.07 * std::sin(2.3 * t + 0.3);
    const double sway_z = 0.05 * std::sin(1.9 * t + 1.1);
    const double twist = 0.25 * std::sin(1.7 * t);
    for (int j = 0; j < SKIRT_ROWS; ++j) {
        const double s = static_cast<double>(j) / (SKIRT_ROWS - 1);  // 0 at the waist
        const double radius = 0.15 + 0.22 * s;
        const double depth = 0.18 * (0.25 + 0.75 * s) * fold;
        const double strength = (0.3 + 0.7 * s) * fold;
        for (int i = 0; i < SKIRT_AROUND; ++i) {
            const double theta = 2.0 * PI * i / SKIRT_AROUND;
            const auto [bulge, remapped] = pleat(PLEATS * theta, strength);
            const double angle = remapped / PLEATS + twist * s * s;
            const double r = radius * (1.0 + depth * bulge);
            const double hem_lift = 0.05 * s * s * (1.0 - std::cos(angle - 2.3 * t));
            out[static_cast<std::size_t>(j) * SKIRT_AROUND + i] = {
                sway_x * s * s + r * std::cos(angle), 1.0 - 0.62 * s + hem_lift,
                sway_z * s * s + r * std::sin(angle)};
        }
    }
}

Part skirt_leg(int side) {
    auto mesh = uv_sphere(24, 12);
    for (auto& v : mesh.vertices) {
        v = Vec3{0.062 * v.x, 0.43 * v.y, 0.062 * v.z};
    }
    const double sign = side == 0 ? -1.0 : 1.0;
    auto map = [sign](std::size_t k, const std::vector<Vec3>& rest, std::vector<Vec3>& out) {
        const double t = frame_time(k);
        const double gait = std::sin(3.0 * t + (sign > 0 ? PI : 0.0));
        const Mat3 hip = rotation({1, 0, 0}, 0.16 * gait);
        const Mat3 knee = rotation({1, 0, 0}, -0.35 * std::max(0.0, -gait));
        const Vec3 hip_at{sign * 0.085, 0.97, 0.0};
        out.resize(rest.size());
        for (std::size_t v = 0; v < rest.size(); ++v) {
            const Vec3& p = rest[v];
            // The shin (below the ellipsoid's centre) bends about the knee, blended over a short
            // band so the surface stays smooth.
            const double w = smoothstep(0.0, -0.08, p.y);
            const Vec3 bent = knee * p;
            const Vec3 q = (1.0 - w) * p + w * bent + Vec3{0.0, -0.43, 0.0};
            out[v] = hip_at + hip * q;
        }
    };
    return shaped_part(side == 0 ? "leg.left" : "leg.right", std::move(mesh), map);
}

// ---------------------------------------------------------------------------------------------
// Cloth on a ball: a square sheet drops onto a rotating ball, wraps over its cap and hangs down
// in folds. The draped shape is closed form: a point at planar distance rho from the sheet's
// centre lies on the sphere while rho is within the contact radius, then leaves it along the
// tangent and bends toward the vertical (bend radius never below the ball's, so the sheet stays
// outside the ball); the hanging part bulges outward in pleats.

constexpr int CLOTH_N = 85;
constexpr double BALL_RADIUS = 0.5;

void place_cloth(std::size_t k, std::vector<Vec3>& out) {
    const double t = frame_time(k);
    out.resize(static_cast<std::size_t>(CLOTH_N) * CLOTH_N);
    const double rc = BALL_RADIUS + 0.004;  // the cloth rests just off the ball
    const double lift = t < 0.12 ? 0.3 * (1.0 - t / 0.12) * (1.0 - t / 0.12) : 0.0;
    const double progress = smoothstep(0.05, 0.45, t);
    const double contact = progress * 0.5 * PI * rc;  // arc length wrapped on the ball
    const double psi_c = contact / rc;
    const double bend = rc + 2.5 * (1.0 - progress) * (1.0 - progress);
    const double spin = 0.15 * t * progress;
    const double sway = 0.3 * std::sin(1.3 * t);
    for (int j = 0; j < CLOTH_N; ++j) {
        for (int i = 0; i < CLOTH_N; ++i) {
            const double u = 2.0 * i / (CLOTH_N - 1) - 1.0;
            const double w = 2.0 * j / (CLOTH_N - 1) - 1.0;
            const double rho = std::hypot(u, w);
            double az = std::atan2(w, u) + spin;
            double horizontal = 0.0;
            double y = 0.0;
            if (rho <= contact) {
                const double psi = rho / rc;
                horizontal = rc * std::sin(psi);
                y = rc * std::cos(psi);
            } else {
                const double e = rho - contact;
                const double arc = bend * (0.5 * PI - psi_c);
                const double h0 = rc * std::sin(psi_c);
                const double y0 = rc * std::cos(psi_c);
                if (e <= arc) {
                    const double beta = psi_c + e / bend;
                    horizontal = h0 + bend * (std::sin(beta) - std::sin(psi_c));
                    y = y0 + bend * (std::cos(beta) - std::cos(psi_c));
                } else {
                    horizontal = h0 + bend * (1.0 - std::sin(psi_c));
                    y = y0 - bend * std::cos(psi_c) - (e - arc);
                }
                // Outward-only pleats, growing from nothing at the contact circle.
                const double grow = std::min(1.0, e / 0.25) * progress;
                const double amplitude = 0.07 * grow;
                const auto [bulge, remapped] = pleat(9.0 * az + sway, grow);
                az = (remapped - sway) / 9.0;
                horizontal += amplitude * (1.0 + bulge);
            }
            out[static_cast<std::size_t>(j) * CLOTH_N + i] = {horizontal * std::cos(az), y + lift,
                                                              horizontal * std::sin(az)};
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Bowl: a thick bowl (closed surface of revolution) and ten deforming objects dropping into it
// with damped bounces, settling in two rings and one at the bottom.

constexpr double BOWL_INNER = 0.6;  // inner sphere radius; the sphere's centre is at y = 0.6

TriangleMesh bowl_mesh() {
    constexpr int SEGMENTS = 8;  // per wall, bottom to rim
    constexpr double RIM = 1.4;  // polar angle of the rim from the bottom (radians)
    constexpr double OUTER = BOWL_INNER + 0.03;
    std::vector<std::pair<double, double>> profile;
    for (int i = 0; i <= SEGMENTS; ++i) {
        const double a = RIM * i / SEGMENTS;
        profile.emplace_back(BOWL_INNER * std::sin(a), BOWL_INNER - BOWL_INNER * std::cos(a));
    }
    for (int i = SEGMENTS; i >= 0; --i) {
        const double a = RIM * i / SEGMENTS;
        profile.emplace_back(OUTER * std::sin(a), BOWL_INNER - OUTER * std::cos(a));
    }
    return revolution(profile, 50);
}

// ---------------------------------------------------------------------------------------------
// Ramps: four inclined slabs in a zig-zag; 200 small deforming objects in four lanes slide down
// them at constant speed, tumble and squash, fall off each ramp's low end onto the next one, and
// re-enter at the top after the last (as if fed by a funnel).

struct RampPath {
    std::vector<Vec3> points;   // centre-line of an object of radius RAMP_OBJECT_MAX (z = 0)
    std::vector<double> along;  // arc length at each point
    double length = 0.0;

    Vec3 at(double s) const {
        s = std::fmod(s, length);
        if (s < 0) {
            s += length;
        }
        const auto it = std::upper_bound(along.begin(), along.end(), s);
        const std::size_t i =
            std::min<std::size_t>(static_cast<std::size_t>(it - along.begin()), along.size() - 1);
        const std::size_t i0 = i - 1;
        const double seg = along[i] - along[i0];
        const double f = seg > 0 ? (s - along[i0]) / seg : 0.0;
        return points[i0] + f * (points[i] - points[i0]);
    }
};

constexpr int RAMP_COUNT = 4;
constexpr double RAMP_SLOPE = 0.25;       // drop per unit of x
constexpr double RAMP_THICK = 0.05;       // slab thickness
constexpr double RAMP_HALF_WIDTH = 0.32;  // along z
constexpr double RAMP_OBJECT_MAX = 0.062;

double ramp_half_length(int j) {
    return 1.0 + 0.15 * j;
}
double ramp_direction(int j) {
    return j % 2 == 0 ? 1.0 : -1.0;
}  // +1: descends toward +x
double ramp_centre_y(int j) {
    double y = 3.0;
    for (int i = 0; i < j; ++i) {
        y -= 0.5 * ramp_half_length(i) + 0.45;
    }
    return y;
}
// Height of an object centre resting on ramp j at x: the slab's top surface plus the largest
// object's reach (radius times the squash and ripple allowance), measured across the incline.
double ramp_rest_y(int j, double x) {
    const double cos_g = 1.0 / std::sqrt(1.0 + RAMP_SLOPE * RAMP_SLOPE);
    return ramp_centre_y(j) - RAMP_SLOPE * ramp_direction(j) * x +
           (0.5 * RAMP_THICK + 1.2 * RAMP_OBJECT_MAX) / cos_g;
}

RampPath ramp_path() {
    RampPath path;
    const double clear = RAMP_OBJECT_MAX + 0.02;
    double x = -ramp_half_length(0) + RAMP_OBJECT_MAX;
    path.points.push_back({x, ramp_rest_y(0, x), 0});
    for (int j = 0; j < RAMP_COUNT; ++j) {
        const double d = ramp_direction(j);
        const double edge = d * ramp_half_length(j);
        const double y_edge = ramp_rest_y(j, edge);
        path.points.push_back({edge, y_edge, 0});
        x = edge + d * clear;
        path.points.push_back({x, y_edge, 0});
        const double y_next = j + 1 < RAMP_COUNT ? ramp_rest_y(j + 1, x) : y_edge - 0.6;
        path.points.push_back({x, y_next, 0});
    }
    path.along.push_back(0.0);
    for (std::size_t i = 1; i < path.points.size(); ++i) {
        path.along.push_back(path.along.back() + norm(path.points[i] - path.points[i - 1]));
    }
    path.length = path.along.back();
    return path;
}

Part ramp_slab(int j) {
    const double hl = ramp_half_length(j) * std::sqrt(1.0 + RAMP_SLOPE * RAMP_SLOPE);
    auto mesh = tessellated_box({hl, 0.5 * RAMP_THICK, RAMP_HALF_WIDTH}, {20, 1, 6});
    const Mat3 tilt = rotation({0, 0, 1}, -ramp_direction(j) * std::atan(RAMP_SLOPE));
    const Vec3 centre{0.0, ramp_centre_y(j), 0.0};
    for (auto& v : mesh.vertices) {
        v = centre + tilt * v;
    }
    auto map = [](std::size_t, const std::vector<Vec3>& rest, std::vector<Vec3>& out) {
        out = rest;
    };
    return shaped_part("ramp" + std::to_string(j), std::move(mesh), map, false);
}

// ---------------------------------------------------------------------------------------------
// Breaking: five wobbling balls converge; at the break frame each shatters into five wedge
// fragments (closed meshes), which fly apart and tumble.

constexpr int BREAK_BALLS = 5;
constexpr int BREAK_PIECES = 5;
constexpr double BREAK_RADIUS = 0.25;
constexpr double CRACK = 0.002;

double breaking_ring(std::size_t k) {
    // Centres on a circle shrinking until neighbours nearly touch (chord 2 r sin(pi/5) > 0.5).
    return std::max(0.44, 0.6 - 0.022 * static_cast<double>(k));
}

Vec3 breaking_centre(int ball, std::size_t k) {
    const double a = 2.0 * PI * ball / BREAK_BALLS;
    const double r = breaking_ring(k);
    return {r * std::cos(a), 1.0 + 0.05 * std::sin(1.3 * ball + 2.0 * frame_time(k)),
            r * std::sin(a)};
}

}  // namespace

// ---------------------------------------------------------------------------------------------

ProceduralScene skirt(std::size_t frames) {
    auto seq = std::make_shared<Sequence>();
    seq->phases.resize(1);
    Part cloth;
    cloth.name = "skirt";
    cloth.triangles = sheet(SKIRT_AROUND, SKIRT_ROWS, true).triangles;
    cloth.vertex_count = static_cast<std::size_t>(SKIRT_AROUND) * SKIRT_ROWS;
    cloth.place = place_skirt;
    seq->phases[0].push_back(std::move(cloth));
    seq->phases[0].push_back(skirt_leg(0));
    seq->phases[0].push_back(skirt_leg(1));
    return make_scene("skirt",
                      "pleated cloth tube (96 x 57 vertices, open) swaying around two walking legs",
                      frames, seq);
}

ProceduralScene cloth_ball(std::size_t frames) {
    auto seq = std::make_shared<Sequence>();
    seq->phases.resize(1);
    Part cloth;
    cloth.name = "cloth";
    cloth.triangles = sheet(CLOTH_N, CLOTH_N, false).triangles;
    cloth.vertex_count = static_cast<std::size_t>(CLOTH_N) * CLOTH_N;
    cloth.place = place_cloth;
    seq->phases[0].push_back(std::move(cloth));
    auto ball = uv_sphere(32, 17);
    for (auto& v : ball.vertices) {
        v = BALL_RADIUS * v;
    }
    seq->phases[0].push_back(
        shaped_part("ball", std::move(ball),
                    [](std::size_t k, const std::vector<Vec3>& rest, std::vector<Vec3>& out) {
                        const Mat3 r = rotation({0.3, 1.0, 0.2}, 1.5 * frame_time(k));
                        out.resize(rest.size());
                        for (std::size_t v = 0; v < rest.size(); ++v) {
                            out[v] = r * rest[v];
                        }
                    }));
    return make_scene("cloth-ball",
                      "square cloth (85 x 85 vertices) dropping and draping in folds over a "
                      "rotating ball",
                      frames, seq);
}

ProceduralScene bowl(std::size_t frames) {
    auto seq = std::make_shared<Sequence>();
    seq->phases.resize(1);
    auto bowl_local = bowl_mesh();
    seq->phases[0].push_back(shaped_part(
        "bowl", std::move(bowl_local),
        [](std::size_t, const std::vector<Vec3>& rest, std::vector<Vec3>& out) { out = rest; },
        false));
    Rng rng(0xB0E1);
    constexpr double RADIUS = 0.1;
    for (int i = 0; i < 10; ++i) {
        // Resting place on the inner wall: one at the bottom, a ring of six, a ring of three.
        double alpha = 0.0;
        double beta = 0.0;
        if (i >= 1 && i <= 6) {
            alpha = 0.5;
            beta = 2.0 * PI * (i - 1) / 6.0;
        } else if (i >= 7) {
            alpha = 0.95;
            beta = 2.0 * PI * (i - 7) / 3.0 + PI / 6.0;
        }
        // The centre stays this far inside the bowl's inner sphere: the radius plus what the
        // impact squash and the ripple add to it.
        const double reach = BOWL_INNER - 1.17 * RADIUS;
        const Vec3 rest{reach * std::sin(alpha) * std::cos(beta),
                        BOWL_INNER - reach * std::cos(alpha),
                        reach * std::sin(alpha) * std::sin(beta)};
        const double height = 0.15 + 0.05 * i;  // drop height above the resting place
        const Vec3 axis = rng.unit_vector();
        const double turn = rng.uniform(1.0, 3.0);
        const double phase = rng.uniform(0.0, 2.0 * PI);
        auto mesh = small_object(i, RADIUS, 16, 10);
        auto map = [=](std::size_t k, const std::vector<Vec3>& local, std::vector<Vec3>& out) {
            const double t = frame_time(k);
            constexpr double G = 9.81;
            const double t_hit = std::sqrt(2.0 * height / G);
            double y = 0.0;
            double squash = 1.0;
            if (t < t_hit) {
                y = height - 0.5 * G * t * t;
            } else {
                const double dt = t - t_hit;
                y = 0.06 * std::exp(-3.0 * dt) * std::abs(std::sin(9.0 * dt));
                squash = 1.0 - 0.15 * std::exp(-4.0 * dt) * std::abs(std::cos(9.0 * dt));
            }
            // Straight down onto the resting place: the resting places are apart, so objects
            // falling at different heights never pass through each other.
            const Vec3 centre = rest + Vec3{0.0, y, 0.0};
            const Mat3 spin = rotation(axis, turn * (1.0 - std::exp(-2.0 * t)));
            out.resize(local.size());
            for (std::size_t v = 0; v < local.size(); ++v) {
                out[v] = centre + spin * wobble(local[v], squash, 0.04, 6.0 * t + phase, RADIUS);
            }
        };
        seq->phases[0].push_back(shaped_part("object" + std::to_string(i), std::move(mesh), map));
    }
    return make_scene("bowl", "ten deforming spheres, rounded boxes and tori settling in a bowl",
                      frames, seq);
}

ProceduralScene ramps(std::size_t frames) {
    auto seq = std::make_shared<Sequence>();
    seq->phases.resize(1);
    for (int j = 0; j < RAMP_COUNT; ++j) {
        seq->phases[0].push_back(ramp_slab(j));
    }
    auto path = std::make_shared<const RampPath>(ramp_path());
    constexpr int OBJECTS = 200;
    constexpr int LANES = 4;
    constexpr double SPEED = 0.9;
    Rng rng(0x5A3B);
    for (int i = 0; i < OBJECTS; ++i) {
        const int lane = i % LANES;
        const int slot = i / LANES;
        constexpr int PER_LANE = OBJECTS / LANES;
        const double spacing = path->length / PER_LANE;
        const double start = (slot + 0.25 * lane + rng.uniform(-0.1, 0.1)) * spacing;
        const double z = (lane - 1.5) * 0.155 + rng.uniform(-0.005, 0.005);
        const double radius = rng.uniform(0.05, RAMP_OBJECT_MAX);
        const double phase = rng.uniform(0.0, 2.0 * PI);
        const double surge = rng.uniform(0.5, 1.0);
        const Vec3 tumble_axis = Vec3{0, 0, 1} + 0.3 * rng.unit_vector();
        // 176-180 triangles: spheres 10 x 10, rounded boxes and tori 11 x 9.
        const int kind = i % 3;
        auto mesh =
            kind == 0 ? small_object(kind, radius, 10, 10) : small_object(kind, radius, 11, 9);
        auto map = [=](std::size_t k, const std::vector<Vec3>& local, std::vector<Vec3>& out) {
            const double t = frame_time(k);
            // Speed surges make neighbours in a lane close in and separate again.
            const double s = start + SPEED * t + 0.03 * surge * std::sin(2.0 * t + phase);
            Vec3 centre = path->at(s);
            // Centre-line is for the largest radius: smaller objects float slightly above.
            centre.z = z + 0.012 * std::sin(1.7 * t + 2.0 * phase);
            const Mat3 roll = rotation(tumble_axis, -s / radius);
            const double squash = 1.0 + 0.06 * std::sin(5.0 * t + phase);
            out.resize(local.size());
            for (std::size_t v = 0; v < local.size(); ++v) {
                out[v] = centre + roll * wobble(local[v], squash, 0.03, 4.0 * t + phase, radius);
            }
        };
        seq->phases[0].push_back(shaped_part("object" + std::to_string(i), std::move(mesh), map));
    }
    return make_scene("ramps",
                      "200 deforming objects (176-180 triangles each) sliding down four ramps",
                      frames, seq);
}

ProceduralScene breaking(std::size_t frames) {
    auto seq = std::make_shared<Sequence>();
    seq->phases.resize(2);
    // The break comes halfway through (frame 1 for sequences shorter than 3 frames).
    const std::size_t break_frame = std::max<std::size_t>(1, frames / 2);
    seq->break_frame = break_frame;
    Rng rng(0xF4AC);
    for (int b = 0; b < BREAK_BALLS; ++b) {
        const Vec3 axis = rng.unit_vector();
        const double angle = rng.uniform(0.0, 2.0 * PI);
        const Mat3 orient = rotation(axis, angle);
        const double phase = rng.uniform(0.0, 2.0 * PI);
        const std::string name = "ball" + std::to_string(b);
        auto ball_shape = [=](std::size_t k, const Vec3& p) {
            const double t = frame_time(k);
            const double squash = 1.0 + 0.06 * std::sin(7.0 * t + phase);
            return breaking_centre(b, k) +
                   orient * wobble(p, squash, 0.03, 5.0 * t + phase, BREAK_RADIUS);
        };
        auto mesh = uv_sphere(30, 19);
        for (auto& v : mesh.vertices) {
            v = BREAK_RADIUS * v;
        }
        seq->phases[0].push_back(
            shaped_part(name, std::move(mesh),
                        [=](std::size_t k, const std::vector<Vec3>& local, std::vector<Vec3>& out) {
                            out.resize(local.size());
                            for (std::size_t v = 0; v < local.size(); ++v) {
                                out[v] = ball_shape(k, local[v]);
                            }
                        }));

        // Cut longitudes, jittered so no two balls break alike.
        std::vector<double> cuts;
        cuts.reserve(BREAK_PIECES + 1);
        const double offset = rng.uniform(0.0, 2.0 * PI);
        for (int q = 0; q < BREAK_PIECES; ++q) {
            cuts.push_back(offset + 2.0 * PI * (q + rng.uniform(-0.2, 0.2)) / BREAK_PIECES);
        }
        cuts.push_back(cuts.front() + 2.0 * PI);
        for (int q = 0; q < BREAK_PIECES; ++q) {
            auto piece = sphere_wedge(12, 6, 2, cuts[q], cuts[q + 1]);
            Vec3 centroid;
            for (auto& v : piece.vertices) {
                v = BREAK_RADIUS * v;
                centroid += v;
            }
            centroid = centroid / static_cast<double>(piece.vertices.size());
            const double mid = 0.5 * (cuts[q] + cuts[q + 1]);
            const Vec3 out_dir{std::cos(mid), 0.0, std::sin(mid)};
            const Vec3 spin_axis = rng.unit_vector();
            const double spin_rate = rng.uniform(0.3, 1.0);
            const double speed = rng.uniform(0.3, 0.5);
            // Fragments start where the ball's surface was at the break (no wobble, which the flat
            // faces could not follow), each pushed CRACK outward so that neighbouring cut faces
            // are close but not coplanar-overlapping, then separate: along the ball's outward
            // direction (which dominates, so fragments of neighbouring balls do not fly through
            // each other) plus their own, with a slow spin about their centroid.
            auto map = [=](std::size_t k, const std::vector<Vec3>& local, std::vector<Vec3>& out) {
                const double dt = frame_time(k) - frame_time(break_frame);
                const Vec3 base = breaking_centre(b, break_frame);
                const Vec3 ball_out = Vec3{base.x, 0.0, base.z} / std::hypot(base.x, base.z);
                const Mat3 spin = rotation(spin_axis, spin_rate * dt);
                const Vec3 drift = CRACK * (orient * out_dir) +
                                   dt * (speed * (orient * out_dir) + ball_out) +
                                   Vec3{0.0, -dt * dt, 0.0};
                out.resize(local.size());
                for (std::size_t v = 0; v < local.size(); ++v) {
                    out[v] = base + drift + orient * (centroid + spin * (local[v] - centroid));
                }
            };
            Part part = shaped_part(name + ".piece" + std::to_string(q), std::move(piece), map);
            part.parent = b;
            seq->phases[1].push_back(std::move(part));
        }
    }
    return make_scene("breaking",
                      "five wobbling balls converging; at frame frame_count/2 each breaks into "
                      "five closed wedge fragments (25 objects after the break) that fly apart",
                      frames, seq);
}

std::vector<ProceduralScene> all(std::size_t frames) {
    std::vector<ProceduralScene> out;
    out.push_back(skirt(frames));
    out.push_back(cloth_ball(frames));
    out.push_back(bowl(frames));
    out.push_back(ramps(frames));
    out.push_back(breaking(frames));
    return out;
}

ProceduralScene by_name(const std::string& name, std::size_t frames) {
    if (name == "skirt") {
        return skirt(frames);
    }
    if (name == "cloth-ball") {
        return cloth_ball(frames);
    }
    if (name == "bowl") {
        return bowl(frames);
    }
    if (name == "ramps") {
        return ramps(frames);
    }
    if (name == "breaking") {
        return breaking(frames);
    }
    return {};
}

}  // namespace proxima::scenes
