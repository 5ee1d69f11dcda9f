// Procedural massive models: a process plant (steel frames, tanks, pipe runs, walkways, stairs) and
// a furnished multi-storey building. Both are pure functions of their options: every random number
// comes from std::mt19937_64 (whose sequence the standard fixes) turned into doubles from raw bits,
// never from std::uniform_*_distribution (whose mapping differs between standard libraries).
//
// The plant is planned first (bay by bay, each bay from its own generator so that the plan of bay b
// does not depend on how many bays there are), then one tessellation density is chosen by bisection
// on the exact triangle count of the plan, then the objects are meshed and streamed one at a time.

#include "proxima/massive/generator.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <numbers>
#include <random>
#include <string>
#include <system_error>
#include <utility>
#include <variant>
#include <vector>

#include <nlohmann/json.hpp>

#include "proxima/io/mesh_io.hpp"

namespace proxima::massive {

namespace {

constexpr double PI = std::numbers::pi;

// ---------------------------------------------------------------------------------------------
// Random numbers.

std::uint64_t mix64(std::uint64_t x) {
    // splitmix64's finaliser: decorrelates nearby seeds (seed 1 and 2, bay 7 and 8).
    x += 0x9e3779b97f4a7c15ull;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
    return x ^ (x >> 31);
}

class Rng {
  public:
    explicit Rng(std::uint64_t seed) : m_gen(seed) {}
    // [0, 1) with 53 random bits.
    double uniform() { return static_cast<double>(m_gen() >> 11) * 0x1.0p-53; }
    double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
    // 0 .. n - 1 (multiply-shift: no modulo bias worth mentioning, no platform dependence).
    std::uint32_t index(std::uint32_t n) {
        return static_cast<std::uint32_t>(((m_gen() >> 32) * n) >> 32);
    }
    bool chance(double p) { return uniform() < p; }
    // lo + k step for a random k with lo + k step <= hi: "round" dimensions as a designer picks
    // them, and exactly representable when lo and step are.
    double grid(double lo, double hi, double step) {
        const auto steps = static_cast<std::uint32_t>(std::floor((hi - lo) / step + 1e-9));
        return lo + step * index(steps + 1);
    }
    template <class T, std::size_t N>
    const T& pick(const std::array<T, N>& values) {
        return values[index(static_cast<std::uint32_t>(N))];
    }

  private:
    std::mt19937_64 m_gen;
};

// ---------------------------------------------------------------------------------------------
// Primitives. Every one is a closed, outward-oriented triangle mesh; an object is a list of them.

constexpr Vec3 X_AXIS{1, 0, 0};
constexpr Vec3 Y_AXIS{0, 1, 0};
constexpr Vec3 Z_AXIS{0, 0, 1};

// Axis-aligned box: its faces lie exactly on lo and hi, so boxes placed on a beam top touch it.
struct Box {
    Vec3 lo;
    Vec3 hi;
};

// origin + i a + j b + k c (i, j, k in {0, 1}); (a, b, c) right-handed.
struct Parallelepiped {
    Vec3 origin;
    Vec3 a;
    Vec3 b;
    Vec3 c;
};

// An I profile extruded along coordinate `axis` from s0 to s1. In the profile plane, `v` is the
// depth direction (flanges at v = top - depth and v = top) and `u` the flange-width direction,
// centred on uc. `top` is exact: a girder's top face is at z = top.
struct Beam {
    int axis = 0;
    int u = 1;
    int v = 2;
    double s0 = 0.0;
    double s1 = 0.0;
    double uc = 0.0;
    double top = 0.0;
    double width = 0.2;
    double depth = 0.3;
    double flange = 0.015;
    double web = 0.01;
};

// A straight cylinder with flat ends from `from` to `to` (an axis-aligned direction). Angle 0 of
// every ring points along `e1`, so a horizontal pipe with e1 = -z has vertices exactly at its
// nominal bottom line (its clearance above a beam is the planned one). `phase` turns the rings by
// that fraction of an angular step, so that two spools meeting at a joint share no vertex.
struct Tube {
    Vec3 from;
    Vec3 to;
    Vec3 e1;
    double radius = 0.1;
    double segment = 0.5;  // nominal length of an axial segment at density 1; 0: one segment
    double phase = 0.0;
    int min_around = 6;
};

// A 90-degree pipe bend starting at `start` heading along `a`, ending heading along `b` (a and b
// orthogonal unit axis vectors), bend radius `bend` about the centre start + bend b.
struct Elbow {
    Vec3 start;
    Vec3 a;
    Vec3 b;
    double bend = 0.3;
    double radius = 0.1;
};

// A vessel of revolution about `axis` (unit, axis-aligned) from `base`: a cylindrical shell of
// `length`, each end flat or a 2:1 ellipsoidal head. Angle 0 points along e1.
struct Vessel {
    Vec3 base;
    Vec3 axis;
    Vec3 e1;
    double radius = 1.0;
    double length = 1.0;
    bool dome0 = false;
    bool dome1 = true;
};

using Primitive = std::variant<Box, Parallelepiped, Beam, Tube, Elbow, Vessel>;

struct ObjectPlan {
    std::string name;
    std::vector<Primitive> parts;
};

struct MeshSize {
    std::uint64_t vertices = 0;
    std::uint64_t triangles = 0;
    MeshSize& operator+=(const MeshSize& o) {
        vertices += o.vertices;
        triangles += o.triangles;
        return *this;
    }
};

// Tessellation as a function of the density d (1 = the nominal plant). Segments around grow with
// the square root of the radius (big pipes and tanks get more), so that the segment counts of
// different radii step at different densities and the total count is a fine-grained function of d.
int around_pipe(double r, double d, int min_around) {
    return std::max(min_around, static_cast<int>(std::lround(d * (8.0 + 50.0 * std::sqrt(r)))));
}
int around_vessel(double r, double d) {
    return std::max(8, static_cast<int>(std::lround(d * (8.0 + 80.0 * std::sqrt(r)))));
}
int along(double length, double d, double segment) {
    if (segment <= 0.0) {
        return 1;
    }
    return std::max(1, static_cast<int>(std::lround(d * length / segment)));
}
int elbow_rings(int around) {
    return std::max(2, (around + 2) / 4);
}
double length_of(const Vec3& a, const Vec3& b) {
    return norm(b - a);
}

struct VesselTess {
    int around = 8;
    int shell = 1;  // axial segments of the shell
    int head = 2;   // a domed head has head - 1 rings and a pole
};
VesselTess vessel_tess(const Vessel& p, double d) {
    VesselTess t;
    t.around = around_vessel(p.radius, d);
    const double step = 2.0 * PI * p.radius / t.around;  // square quads on the shell
    t.shell = std::max(1, static_cast<int>(std::lround(p.length / step)));
    t.head = std::max(2, static_cast<int>(std::lround(t.around / 4.0)));
    return t;
}

MeshSize size_of(const Primitive& prim, double d) {
    struct Visitor {
        double d;
        MeshSize operator()(const Box&) const { return {8, 12}; }
        MeshSize operator()(const Parallelepiped&) const { return {8, 12}; }
        MeshSize operator()(const Beam& b) const {
            const std::uint64_t k = along(b.s1 - b.s0, d, 0.5);
            return {12 * (k + 1), 24 * k + 20};
        }
        MeshSize operator()(const Tube& t) const {
            const std::uint64_t n = around_pipe(t.radius, d, t.min_around);
            const std::uint64_t k = along(length_of(t.from, t.to), d, t.segment);
            return {n * (k + 1), 2 * n * k + 2 * (n - 2)};
        }
        MeshSize operator()(const Elbow& e) const {
            const std::uint64_t n = around_pipe(e.radius, d, 6);
            const std::uint64_t m = elbow_rings(static_cast<int>(n));
            return {n * (m + 1), 2 * n * m + 2 * (n - 2)};
        }
        MeshSize operator()(const Vessel& v) const {
            const VesselTess t = vessel_tess(v, d);
            const std::uint64_t n = t.around;
            const std::uint64_t rings =
                (t.shell + 1) + (v.dome0 ? t.head - 1 : 0) + (v.dome1 ? t.head - 1 : 0);
            const std::uint64_t poles = (v.dome0 ? 1 : 0) + (v.dome1 ? 1 : 0);
            return {n * rings + poles,
                    2 * n * (rings - 1) + (v.dome0 ? n : n - 2) + (v.dome1 ? n : n - 2)};
        }
    };
    return std::visit(Visitor{d}, prim);
}

MeshSize size_of(const ObjectPlan& plan, double d) {
    MeshSize s;
    for (const auto& p : plan.parts) {
        s += size_of(p, d);
    }
    return s;
}

// ---------------------------------------------------------------------------------------------
// Meshing.

// cos and sin of 2 pi (i + phase) / n, computed once per (n, phase) and generation. Angle 0 is
// exactly (1, 0).
class CircleCache {
  public:
    const std::vector<std::pair<double, double>>& get(int n, double phase) {
        const auto key = std::make_pair(n, phase);
        auto it = m_tables.find(key);
        if (it == m_tables.end()) {
            std::vector<std::pair<double, double>> table(static_cast<std::size_t>(n));
            for (int i = 0; i < n; ++i) {
                const double angle = 2.0 * PI * (static_cast<double>(i) + phase) / n;
                table[static_cast<std::size_t>(i)] = {std::cos(angle), std::sin(angle)};
            }
            it = m_tables.emplace(key, std::move(table)).first;
        }
        return it->second;
    }

  private:
    std::map<std::pair<int, double>, std::vector<std::pair<double, double>>> m_tables;
};

struct Ring {
    Vec3 centre;
    Vec3 e1;
    Vec3 e2;
    double radius = 0.0;
};

class Mesher {
  public:
    Mesher(TriangleMesh& mesh, CircleCache& circles, double density)
        : m_mesh(mesh), m_circles(circles), m_d(density) {}

    void operator()(const Box& b) {
        const std::uint32_t base = next();
        for (int k = 0; k < 8; ++k) {
            m_mesh.vertices.push_back(
                {(k & 1) ? b.hi.x : b.lo.x, (k & 2) ? b.hi.y : b.lo.y, (k & 4) ? b.hi.z : b.lo.z});
        }
        hexahedron(base);
    }

    void operator()(const Parallelepiped& p) {
        const std::uint32_t base = next();
        for (int k = 0; k < 8; ++k) {
            Vec3 q = p.origin;
            if (k & 1) {
                q += p.a;
            }
            if (k & 2) {
                q += p.b;
            }
            if (k & 4) {
                q += p.c;
            }
            m_mesh.vertices.push_back(q);
        }
        hexahedron(base);
    }

    void operator()(const Beam& b) {
        const int k = along(b.s1 - b.s0, m_d, 0.5);
        // The I profile, counter-clockwise in (u, v).
        const double ul = b.uc - 0.5 * b.width;
        const double ur = b.uc + 0.5 * b.width;
        const double wl = b.uc - 0.5 * b.web;
        const double wr = b.uc + 0.5 * b.web;
        const double vt = b.top;
        const double vb = b.top - b.depth;
        const double vt2 = vt - b.flange;
        const double vb2 = vb + b.flange;
        const std::array<std::pair<double, double>, 12> profile = {{{ul, vb},
                                                                    {ur, vb},
                                                                    {ur, vb2},
                                                                    {wr, vb2},
                                                                    {wr, vt2},
                                                                    {ur, vt2},
                                                                    {ur, vt},
                                                                    {ul, vt},
                                                                    {ul, vt2},
                                                                    {wl, vt2},
                                                                    {wl, vb2},
                                                                    {ul, vb2}}};
        const std::uint32_t base = next();
        for (int j = 0; j <= k; ++j) {
            const double s = j == k ? b.s1 : b.s0 + (b.s1 - b.s0) * (static_cast<double>(j) / k);
            for (const auto& [pu, pv] : profile) {
                Vec3 p;
                p[b.axis] = s;
                p[b.u] = pu;
                p[b.v] = pv;
                m_mesh.vertices.push_back(p);
            }
        }
        // (u, v, axis) cyclic: e_u x e_v = e_axis, the profile's counter-clockwise side faces +s.
        const bool flip = !((b.u + 1) % 3 == b.v && (b.v + 1) % 3 == b.axis);
        for (int j = 0; j < k; ++j) {
            const std::uint32_t r0 = base + static_cast<std::uint32_t>(12 * j);
            const std::uint32_t r1 = r0 + 12;
            for (std::uint32_t i = 0; i < 12; ++i) {
                const std::uint32_t i1 = (i + 1) % 12;
                tri(r0 + i, r0 + i1, r1 + i1, flip);
                tri(r0 + i, r1 + i1, r1 + i, flip);
            }
        }
        // Ten triangles (twelve vertices, no diagonal crossing the web's re-entrant corners).
        static constexpr std::array<std::array<std::uint32_t, 3>, 10> CAP = {{{0, 1, 2},
                                                                              {0, 2, 3},
                                                                              {0, 3, 10},
                                                                              {0, 10, 11},
                                                                              {10, 3, 4},
                                                                              {10, 4, 9},
                                                                              {7, 8, 9},
                                                                              {7, 9, 4},
                                                                              {7, 4, 5},
                                                                              {7, 5, 6}}};
        const std::uint32_t last = base + static_cast<std::uint32_t>(12 * k);
        for (const auto& c : CAP) {
            tri(base + c[0], base + c[2], base + c[1], flip);  // faces -s
            tri(last + c[0], last + c[1], last + c[2], flip);  // faces +s
        }
    }

    void operator()(const Tube& t) {
        const int n = around_pipe(t.radius, m_d, t.min_around);
        const int k = along(length_of(t.from, t.to), m_d, t.segment);
        const Vec3 axis = (t.to - t.from) / length_of(t.from, t.to);
        const Vec3 e2 = cross(axis, t.e1);
        m_rings.clear();
        for (int j = 0; j <= k; ++j) {
            const Vec3 c = j == k ? t.to : t.from + (t.to - t.from) * (static_cast<double>(j) / k);
            m_rings.push_back({c, t.e1, e2, t.radius});
        }
        rings(n, t.phase, nullptr, nullptr);
    }

    void operator()(const Elbow& e) {
        const int n = around_pipe(e.radius, m_d, 6);
        const int m = elbow_rings(n);
        const Vec3 centre = e.start + e.bend * e.b;
        const Vec3 e2 = -cross(e.a, e.b);
        m_rings.clear();
        for (int j = 0; j <= m; ++j) {
            const double phi = 0.5 * PI * static_cast<double>(j) / m;
            const Vec3 w = std::sin(phi) * e.a - std::cos(phi) * e.b;
            m_rings.push_back({j == 0 ? e.start : centre + e.bend * w, w, e2, e.radius});
        }
        // A quarter step off the straight spools' vertices (phase 0 or 1/2): no shared vertex.
        rings(n, 0.25, nullptr, nullptr);
    }

    void operator()(const Vessel& v) {
        const VesselTess t = vessel_tess(v, m_d);
        const Vec3 e2 = cross(v.axis, v.e1);
        const double half = 0.5 * v.radius;  // 2:1 ellipsoidal heads
        m_rings.clear();
        auto ring = [&](double s, double r) {
            m_rings.push_back({v.base + v.axis * s, v.e1, e2, r});
        };
        if (v.dome0) {
            for (int i = t.head - 1; i >= 1; --i) {
                const double alpha = 0.5 * PI * i / t.head;
                ring(-half * std::sin(alpha), v.radius * std::cos(alpha));
            }
        }
        for (int j = 0; j <= t.shell; ++j) {
            ring(j == t.shell ? v.length : v.length * (static_cast<double>(j) / t.shell), v.radius);
        }
        if (v.dome1) {
            for (int i = 1; i < t.head; ++i) {
                const double alpha = 0.5 * PI * i / t.head;
                ring(v.length + half * std::sin(alpha), v.radius * std::cos(alpha));
            }
        }
        const Vec3 pole0 = v.base - v.axis * half;
        const Vec3 pole1 = v.base + v.axis * (v.length + half);
        rings(t.around, 0.0, v.dome0 ? &pole0 : nullptr, v.dome1 ? &pole1 : nullptr);
    }

  private:
    std::uint32_t next() const { return static_cast<std::uint32_t>(m_mesh.vertices.size()); }

    void tri(std::uint32_t a, std::uint32_t b, std::uint32_t c, bool flip = false) {
        if (flip) {
            m_mesh.triangles.push_back({a, c, b});
        } else {
            m_mesh.triangles.push_back({a, b, c});
        }
    }

    // Vertex k of a hexahedron is corner (k & 1, k & 2, k & 4) of a right-handed cell.
    void hexahedron(std::uint32_t b) {
        static constexpr std::array<std::array<std::uint32_t, 4>, 6> FACES = {{
            {0, 2, 3, 1},  // -c
            {4, 5, 7, 6},  // +c
            {0, 1, 5, 4},  // -b
            {2, 6, 7, 3},  // +b
            {0, 4, 6, 2},  // -a
            {1, 3, 7, 5},  // +a
        }};
        for (const auto& f : FACES) {
            tri(b + f[0], b + f[1], b + f[2]);
            tri(b + f[0], b + f[2], b + f[3]);
        }
    }

    // A closed surface through the rings in m_rings (n vertices each, along the rings' common
    // direction e1 x e2): quads between consecutive rings, and at each end a fan to the pole when
    // given, else a flat cap fanned from the ring's first vertex (no extra vertex).
    void rings(int n, double phase, const Vec3* pole0, const Vec3* pole1) {
        const auto& table = m_circles.get(n, phase);
        const std::uint32_t base = next();
        for (const Ring& r : m_rings) {
            for (const auto& [c, s] : table) {
                m_mesh.vertices.push_back(r.centre + (r.radius * c) * r.e1 + (r.radius * s) * r.e2);
            }
        }
        const auto un = static_cast<std::uint32_t>(n);
        const auto count = static_cast<std::uint32_t>(m_rings.size());
        for (std::uint32_t j = 0; j + 1 < count; ++j) {
            const std::uint32_t r0 = base + j * un;
            const std::uint32_t r1 = r0 + un;
            for (std::uint32_t i = 0; i < un; ++i) {
                const std::uint32_t i1 = i + 1 == un ? 0 : i + 1;
                tri(r0 + i, r0 + i1, r1 + i1);
                tri(r0 + i, r1 + i1, r1 + i);
            }
        }
        const std::uint32_t first = base;
        const std::uint32_t last = base + (count - 1) * un;
        if (pole0 != nullptr) {
            const std::uint32_t p = next();
            m_mesh.vertices.push_back(*pole0);
            for (std::uint32_t i = 0; i < un; ++i) {
                tri(p, first + (i + 1) % un, first + i);
            }
        } else {
            for (std::uint32_t i = 1; i + 1 < un; ++i) {
                tri(first, first + i + 1, first + i);
            }
        }
        if (pole1 != nullptr) {
            const std::uint32_t p = next();
            m_mesh.vertices.push_back(*pole1);
            for (std::uint32_t i = 0; i < un; ++i) {
                tri(p, last + i, last + (i + 1) % un);
            }
        } else {
            for (std::uint32_t i = 1; i + 1 < un; ++i) {
                tri(last, last + i, last + i + 1);
            }
        }
    }

    TriangleMesh& m_mesh;
    CircleCache& m_circles;
    double m_d;
    std::vector<Ring> m_rings;
};

// Merges vertices with bit-identical positions (+0 and -0 alike) onto their first occurrence, as
// read_mesh does on import: a generated object written to a file and read back is then the same
// object, vertex for vertex. Sub-meshes that meet (a girder end on a column face) can share a
// position; within one primitive none does.
class Welder {
  public:
    void weld(TriangleMesh& mesh) {
        const std::size_t n = mesh.vertices.size();
        std::size_t size = 16;
        while (size < 2 * n) {
            size *= 2;
        }
        m_table.assign(size, 0);
        const std::size_t mask = size - 1;
        bool duplicates = false;
        m_remap.resize(n);
        for (std::size_t v = 0; v < n; ++v) {
            const Vec3 p = key(mesh.vertices[v]);
            std::size_t h = hash(p) & mask;
            for (;;) {
                const std::uint32_t slot = m_table[h];
                if (slot == 0) {
                    m_table[h] = static_cast<std::uint32_t>(v + 1);
                    m_remap[v] = static_cast<std::uint32_t>(v);
                    break;
                }
                if (key(mesh.vertices[slot - 1]) == p) {
                    m_remap[v] = slot - 1;
                    duplicates = true;
                    break;
                }
                h = (h + 1) & mask;
            }
        }
        if (!duplicates) {
            return;
        }
        // Kept vertices in order of first occurrence.
        std::uint32_t kept = 0;
        for (std::size_t v = 0; v < n; ++v) {
            if (m_remap[v] == v) {
                mesh.vertices[kept] = mesh.vertices[v];
                m_remap[v] = kept++;
            } else {
                m_remap[v] = m_remap[m_remap[v]];
            }
        }
        mesh.vertices.resize(kept);
        for (auto& t : mesh.triangles) {
            for (auto& i : t) {
                i = m_remap[i];
            }
        }
    }

  private:
    static Vec3 key(const Vec3& p) { return {p.x + 0.0, p.y + 0.0, p.z + 0.0}; }
    static std::size_t hash(const Vec3& p) {
        std::uint64_t h = mix64(std::bit_cast<std::uint64_t>(p.x));
        h = mix64(h ^ std::bit_cast<std::uint64_t>(p.y));
        h = mix64(h ^ std::bit_cast<std::uint64_t>(p.z));
        return static_cast<std::size_t>(h);
    }

    std::vector<std::uint32_t> m_table;  // vertex index + 1, 0 = empty
    std::vector<std::uint32_t> m_remap;
};

// ---------------------------------------------------------------------------------------------
// The plant plan.

// Bays sit on a grid of cells: the frame (up to 15 x 10 m), stairs on its +x side, a vertical
// tank on its +y side and pipe ends reaching 1.5 m beyond its -y side all fit in a cell.
constexpr double CELL_X = 19.0;
constexpr double CELL_Y = 20.0;
// Triangles of an average bay at density 1 (about ten objects: one per ~8,000 triangles). The
// bay count follows the target, the density absorbs the rest.
constexpr double BAY_TRIANGLES = 80'000.0;

// Pipe outer radii (2" to 16" nominal).
constexpr std::array<double, 8> PIPE_RADII = {0.0302, 0.0445, 0.0572, 0.0842,
                                              0.1095, 0.1365, 0.1619, 0.2032};

struct Frame {
    double x0 = 0.0;
    double y0 = 0.0;
    double w = 12.0;
    double d = 10.0;
    std::vector<double> levels;  // girder tops, bottom to top
    double column_depth = 0.3;
    double girder_width = 0.2;
    // Per level, the x (absolute) of every beam running along y: pipes rest on them.
    std::vector<std::vector<double>> supports;
};

double sq(double x) {
    return x * x;
}

// A pipe run through `points` (successive legs axis-aligned, orthogonal at each corner) with
// long-radius elbows at the corners, flanges at every elbow end, spool joint and free end, and
// shoes wherever a horizontal leg crosses a beam of its level: a shoe stands on the beam's top
// (touching it) and reaches the pipe's axis. `open_end`: the run ends inside a vessel wall, with
// a nozzle flange `nozzle` before its end.
struct PipeRun {
    std::vector<Vec3> points;
    double radius = 0.1;
    std::size_t level = 0;  // the level whose beams carry the horizontal legs
    bool open_end = false;
    double nozzle = 0.0;
};

void plan_pipe(const PipeRun& run, const Frame& frame, ObjectPlan& out) {
    const double r = run.radius;
    const double bend = 3.0 * r;  // long radius: 1.5 D
    const double flange_r = 1.35 * r + 0.012;
    const double flange_half = 0.018 + 0.1 * r;
    const double level_z = frame.levels[run.level];
    const auto& supports = frame.supports[run.level];
    const std::size_t legs = run.points.size() - 1;
    int spool = 0;
    auto flange = [&](const Vec3& at, const Vec3& dir) {
        const Vec3 e1 = dir.z != 0.0 ? X_AXIS : -Z_AXIS;
        out.parts.push_back(
            Tube{at - flange_half * dir, at + flange_half * dir, e1, flange_r, 0.0, 0.0, 6});
    };
    for (std::size_t i = 0; i < legs; ++i) {
        const Vec3 p = run.points[i];
        const Vec3 q = run.points[i + 1];
        const Vec3 dir = (q - p) / length_of(p, q);
        const bool vertical = dir.z != 0.0;
        const bool last = i + 1 == legs;
        const Vec3 e1 = vertical ? X_AXIS : -Z_AXIS;
        // The straight part between the elbows.
        const Vec3 a = i > 0 ? p + bend * dir : p;
        const Vec3 b = last ? q : q - bend * dir;
        const double straight = length_of(a, b);
        // Spools of at most ~6 m; joints kept clear of the supports (a flange there would sit in
        // the beam).
        const int spools = std::max(1, static_cast<int>(std::ceil(straight / 6.0)));
        Vec3 from = a;
        for (int s = 1; s <= spools; ++s) {
            Vec3 to = b;
            if (s < spools) {
                double t = straight * s / spools;
                if (dir.x != 0.0) {
                    for (double x : supports) {
                        const double off = (a.x + t * dir.x) - x;
                        if (std::abs(off) < 0.4) {
                            t += (off > 0) == (dir.x > 0) ? 0.4 : -0.4;
                        }
                    }
                }
                to = a + t * dir;
            }
            out.parts.push_back(Tube{from, to, e1, r, 0.5, (spool++ % 2) ? 0.5 : 0.0, 6});
            if (s < spools) {
                flange(to, dir);
            }
            from = to;
        }
        flange(a, dir);
        if (!(last && run.open_end)) {
            flange(b, dir);
        }
        if (last && run.open_end && run.nozzle > 0.0) {
            flange(q - run.nozzle * dir, dir);
        }
        if (!last) {
            const Vec3 n = run.points[i + 2];
            out.parts.push_back(Elbow{b, dir, (n - q) / length_of(q, n), bend, r});
        }
        if (vertical) {
            continue;
        }
        const double zc = p.z;
        const double half = 0.6 * r;
        if (dir.x != 0.0) {
            const double lo = std::min(a.x, b.x);
            const double hi = std::max(a.x, b.x);
            for (double x : supports) {
                if (x > lo + 0.15 && x < hi - 0.15) {
                    out.parts.push_back(
                        Box{{x - 0.05, p.y - half, level_z}, {x + 0.05, p.y + half, zc}});
                }
            }
        } else {
            const double lo = std::min(a.y, b.y);
            const double hi = std::max(a.y, b.y);
            for (double y : {frame.y0, frame.y0 + frame.d}) {
                if (y > lo + 0.15 && y < hi - 0.15) {
                    out.parts.push_back(
                        Box{{p.x - half, y - 0.05, level_z}, {p.x + half, y + 0.05, zc}});
                }
            }
        }
    }
}

std::string object_name(std::uint32_t bay, const std::string& what) {
    std::array<char, 32> buf{};
    std::snprintf(buf.data(), buf.size(), "bay-%04u/", bay);
    return buf.data() + what;
}

// The planning of one bay, step by step; the steps draw from one generator, in this order: the
// layout, the tanks, the pipe runs, the walkways, the stairs.
struct BayPlanner {
    BayPlanner(std::uint64_t seed, std::uint32_t bay_index, double x, double y)
        : rng(mix64(seed ^ mix64(bay_index))), bay(bay_index), x0(x), y0(y) {}

    Rng rng;
    std::uint32_t bay;
    double x0;
    double y0;
    Frame f;
    int levels = 0;
    double top = 0.0;
    double gd = 0.0;  // girder depth
    std::vector<double> columns;
    std::vector<double> secondary;
    std::vector<double> deck;
    // The vertical tank (the first level's last pipe may end in it).
    bool vertical_tank = false;
    double tank_x = 0.0;
    double tank_y = 0.0;
    double tank_r = 0.0;
    std::vector<ObjectPlan> objects;

    // The frame's size, levels and sections, the x of its columns and beams, and the beams
    // under the pipes of every level.
    void plan_layout() {
        f.x0 = x0;
        f.y0 = y0;
        f.w = rng.pick(std::array{9.0, 12.0, 15.0});
        f.d = rng.pick(std::array{8.0, 9.0, 10.0});
        levels = 2 + static_cast<int>(rng.index(2));
        const double level_height = rng.grid(4.0, 5.0, 0.25);
        for (int l = 0; l < levels; ++l) {
            f.levels.push_back(level_height * (l + 1));
        }
        top = f.levels.back();
        const double w = f.w;
        // Columns are wider than girders (so their faces never share a vertex position with a
        // girder end).
        f.column_depth = rng.pick(std::array{0.3, 0.35, 0.4});
        f.girder_width = rng.pick(std::array{0.2, 0.24, 0.28});
        gd = rng.pick(std::array{0.3, 0.36, 0.45});

        columns = {0.0, w};
        if (w >= 12.0) {
            columns.insert(columns.begin() + 1, 0.5 * w);
        }
        if (w == 9.0) {
            secondary = {0.5 * w};
        } else if (w == 15.0) {
            secondary = {0.25 * w, 0.75 * w};
        }
        // The top level also carries deck beams at w/4 and 3w/4 (the horizontal tank's saddles).
        deck = secondary;
        for (double x : {0.25 * w, 0.75 * w}) {
            if (std::find(deck.begin(), deck.end(), x) == deck.end()) {
                deck.push_back(x);
            }
        }
        std::sort(deck.begin(), deck.end());
        for (int l = 0; l < levels; ++l) {
            std::vector<double> s;
            s.reserve(columns.size() + std::max(deck.size(), secondary.size()));
            for (double x : columns) {
                s.push_back(x0 + x);
            }
            for (double x : (l + 1 == levels ? deck : secondary)) {
                s.push_back(x0 + x);
            }
            std::sort(s.begin(), s.end());
            f.supports.push_back(std::move(s));
        }
    }

    // The frame: columns, girders along x and y on every level, secondary (or deck) beams.
    void plan_frame() {
        const double d = f.d;
        const double cd = f.column_depth;
        const double gw = f.girder_width;
        ObjectPlan frame{object_name(bay, "frame"), {}};
        for (double c : columns) {
            for (double y : {0.0, d}) {
                frame.parts.push_back(
                    Beam{2, 1, 0, 0.0, top, y0 + y, x0 + c + 0.5 * cd, cd, cd, 0.02, 0.012});
            }
        }
        for (int l = 0; l < levels; ++l) {
            const double z = f.levels[static_cast<std::size_t>(l)];
            for (double y : {0.0, d}) {
                for (std::size_t c = 0; c + 1 < columns.size(); ++c) {
                    frame.parts.push_back(Beam{0, 1, 2, x0 + columns[c] + 0.5 * cd,
                                               x0 + columns[c + 1] - 0.5 * cd, y0 + y, z, gw, gd,
                                               0.016, 0.01});
                }
            }
            for (double c : columns) {
                frame.parts.push_back(Beam{1, 0, 2, y0 + 0.5 * cd, y0 + d - 0.5 * cd, x0 + c, z, gw,
                                           gd, 0.016, 0.01});
            }
            for (double x : (l + 1 == levels ? deck : secondary)) {
                frame.parts.push_back(Beam{1, 0, 2, y0 + 0.5 * gw, y0 + d - 0.5 * gw, x0 + x, z, gw,
                                           gd - 0.06, 0.014, 0.009});
            }
        }
        objects.push_back(std::move(frame));
    }

    // Tanks: a vertical one beside the frame (+y) on a pad, a horizontal one on saddles on the
    // top deck beams.
    void plan_tanks() {
        const double w = f.w;
        const double d = f.d;
        vertical_tank = rng.chance(0.75);
        const bool horizontal_tank = rng.chance(0.6) || !vertical_tank;
        int tanks = 0;
        if (vertical_tank) {
            tank_r = rng.grid(1.0, 3.0, 0.25);
            tank_x = x0 + rng.grid(0.35 * w, 0.65 * w, 0.25);
            tank_y = y0 + d + 1.0 + tank_r;
            const double height = rng.grid(6.0, 13.0, 0.5);
            ObjectPlan tank{object_name(bay, "tank-" + std::to_string(++tanks)), {}};
            const double pad = tank_r + 0.3;
            tank.parts.push_back(
                Box{{tank_x - pad, tank_y - pad, 0.0}, {tank_x + pad, tank_y + pad, 0.3}});
            tank.parts.push_back(
                Vessel{{tank_x, tank_y, 0.3}, Z_AXIS, X_AXIS, tank_r, height, false, true});
            objects.push_back(std::move(tank));
        }
        if (horizontal_tank) {
            const double r = rng.grid(0.8, std::min(2.0, 0.5 * d - 1.6), 0.1);
            const double length = rng.grid(0.55 * w, 0.85 * w - r, 0.25);
            const double saddle = rng.grid(0.25, 0.5, 0.05);
            const double yc = y0 + 0.5 * d;
            const double zc = top + saddle + r;
            ObjectPlan tank{object_name(bay, "tank-" + std::to_string(++tanks)), {}};
            tank.parts.push_back(Vessel{
                {x0 + 0.5 * w - 0.5 * length, yc, zc}, X_AXIS, -Z_AXIS, r, length, true, true});
            for (double x : {0.25 * w, 0.75 * w}) {
                tank.parts.push_back(Box{{x0 + x - 0.08, yc - 0.7 * r, top},
                                         {x0 + x + 0.08, yc + 0.7 * r, zc - 0.5 * r}});
            }
            objects.push_back(std::move(tank));
        }
    }

    // Lanes side by side from the -y side, a few millimetres to a few centimetres apart:
    // (radius, y).
    std::vector<std::pair<double, double>> plan_lanes() {
        const int wanted = 2 + static_cast<int>(rng.index(4));
        std::vector<std::pair<double, double>> lanes;
        for (int i = 0; i < wanted; ++i) {
            const double r = rng.pick(PIPE_RADII);
            const double gap = 0.004 + 0.056 * sq(rng.uniform());
            const double yl =
                lanes.empty() ? y0 + 0.8 + r : lanes.back().second + lanes.back().first + gap + r;
            if (yl + r > y0 + f.d - 1.0) {
                break;
            }
            lanes.emplace_back(r, yl);
        }
        return lanes;
    }

    // The run of lane i of level l: from grade or over the -y girder, along the lane, then into
    // the vertical tank, over the -y girder or down to grade (or ending in the air).
    PipeRun plan_run(int l, std::size_t i, const std::vector<std::pair<double, double>>& lanes,
                     double margin) {
        const double level_z = f.levels[static_cast<std::size_t>(l)];
        const auto [r, yl] = lanes[i];
        const double clearance = 0.003 + 0.047 * sq(rng.uniform());
        const double zc = level_z + clearance + r;
        const double xs = x0 + margin + rng.uniform(0.0, 0.9);
        const double xe = x0 + f.w - margin - rng.uniform(0.0, 0.9);
        PipeRun run;
        run.radius = r;
        run.level = static_cast<std::size_t>(l);
        if (i == 0 && rng.chance(0.4)) {
            run.points.push_back({xs, y0 - 1.5, zc});  // enters over the -y girder
        } else {
            run.points.push_back({xs, yl, rng.grid(0.3, 1.2, 0.1)});  // riser from grade
        }
        run.points.push_back({xs, yl, zc});
        const bool last_lane = i + 1 == lanes.size();
        const double tank_reach = tank_x - 0.5 * tank_r;
        const double pipe_x = std::max(tank_reach, xs + 6.0 * r + 0.6);
        if (vertical_tank && l == 0 && last_lane && pipe_x < tank_x + 0.6 * tank_r) {
            // Into the vertical tank's shell, with a nozzle flange outside it.
            const double dx = pipe_x - tank_x;
            const double wall = tank_y - std::sqrt(tank_r * tank_r - dx * dx);
            run.points.push_back({pipe_x, yl, zc});
            run.points.push_back({pipe_x, wall + 0.1, zc});
            run.open_end = true;
            run.nozzle = 0.3;
        } else {
            run.points.push_back({xe, yl, zc});
            if (i == 0 && rng.chance(0.4)) {
                run.points.push_back({xe, y0 - 1.5, zc});  // leaves over the -y girder
                if (rng.chance(0.5)) {
                    run.points.push_back({xe, y0 - 1.5, rng.grid(0.3, 1.2, 0.1)});
                }
            } else if (rng.chance(0.65)) {
                run.points.push_back({xe, yl, rng.grid(0.3, 1.2, 0.1)});
            }
        }
        return run;
    }

    // Pipe runs: on each level below the top, lanes a few millimetres to centimetres above the
    // beams they cross. Risers of higher levels stand outside the horizontal extent of lower
    // levels.
    void plan_pipes() {
        int pipes = 0;
        for (int l = 0; l + 1 < levels; ++l) {
            const double margin = 0.5 + 1.2 * (levels - 2 - l);
            const auto lanes = plan_lanes();
            for (std::size_t i = 0; i < lanes.size(); ++i) {
                const PipeRun run = plan_run(l, i, lanes, margin);
                ObjectPlan pipe{object_name(bay, "pipe-" + std::to_string(++pipes)), {}};
                plan_pipe(run, f, pipe);
                objects.push_back(std::move(pipe));
            }
        }
    }

    // Walkways on the top level along one or both long sides: a grating resting on the girders
    // and column tops, a toe board, posts and two rails on the outer edge.
    void plan_walkways() {
        const double w = f.w;
        const double d = f.d;
        const double gw = f.girder_width;
        const std::uint32_t sides = 1 + rng.index(3);  // bit 0: -y side, bit 1: +y side
        int walkways = 0;
        for (int side = 0; side < 2; ++side) {
            if ((sides & (1u << side)) == 0) {
                continue;
            }
            const double edge = side == 0 ? y0 - 0.5 * gw : y0 + d + 0.5 * gw;
            const double inner = side == 0 ? y0 + 1.0 : y0 + d - 1.0;
            const double inward = side == 0 ? 1.0 : -1.0;
            const double deck_top = top + 0.03;
            ObjectPlan walkway{object_name(bay, "walkway-" + std::to_string(++walkways)), {}};
            walkway.parts.push_back(Box{{x0 - 0.1, std::min(edge, inner), top},
                                        {x0 + w + 0.1, std::max(edge, inner), deck_top}});
            const double board = edge + inward * 0.01;
            walkway.parts.push_back(Box{{x0 - 0.1, std::min(edge, board), deck_top},
                                        {x0 + w + 0.1, std::max(edge, board), deck_top + 0.1}});
            const double post_y = edge + inward * 0.04;
            const int posts = static_cast<int>(std::ceil((w + 0.1) / 1.8)) + 1;
            for (int k = 0; k < posts; ++k) {
                const double x = x0 - 0.05 + (w + 0.1) * k / (posts - 1);
                walkway.parts.push_back(Tube{{x, post_y, deck_top},
                                             {x, post_y, deck_top + 1.1},
                                             X_AXIS,
                                             0.024,
                                             0.5,
                                             0.0,
                                             4});
            }
            for (double z : {deck_top + 0.5, deck_top + 1.07}) {
                walkway.parts.push_back(Tube{
                    {x0 - 0.1, post_y, z}, {x0 + w + 0.1, post_y, z}, -Z_AXIS, 0.021, 0.5, 0.0, 4});
            }
            objects.push_back(std::move(walkway));
        }
    }

    // Stairs up to the first level beside the +x side, their landing a few millimetres to
    // centimetres from the frame.
    void plan_stairs() {
        if (!rng.chance(0.6)) {
            return;
        }
        const double w = f.w;
        const double d = f.d;
        const double gw = f.girder_width;
        const double z1 = f.levels[0];
        const int steps = static_cast<int>(std::ceil(z1 / 0.19));
        const double rise = z1 / steps;
        const double going = std::min(0.26, (d - 2.4) / steps);
        const double xa = x0 + w + 0.5 * gw + 0.005 + 0.025 * rng.uniform();
        const double xb = xa + 0.9;
        const double y_top = y0 + d - 1.4;
        const double y_bottom = y_top - steps * going;
        ObjectPlan stairs{object_name(bay, "stairs"), {}};
        stairs.parts.push_back(Box{{xa, y_top, z1 - 0.04}, {xb, y0 + d - 0.5, z1}});
        for (int i = 1; i < steps; ++i) {
            const double zt = rise * i;
            stairs.parts.push_back(Box{{xa, y_top - (steps - i) * going, zt - 0.04},
                                       {xb, y_top - (steps - i - 1) * going, zt}});
        }
        for (double x : {xa - 0.012, xb}) {
            stairs.parts.push_back(Parallelepiped{
                {x, y_bottom, -0.2}, {0.012, 0, 0}, {0, y_top - y_bottom, z1}, {0, 0, 0.25}});
        }
        objects.push_back(std::move(stairs));
    }
};

// One bay: a frame, one or two tanks, pipe runs on every level but the top, walkways on the top
// level and, often, stairs to the first level. Absolute coordinates (the bay's cell at x0, y0);
// every contact that should be exact is between values computed by the same expression.
std::vector<ObjectPlan> plan_bay(std::uint64_t seed, std::uint32_t bay, double x0, double y0) {
    BayPlanner planner(seed, bay, x0, y0);
    planner.plan_layout();
    planner.plan_frame();
    planner.plan_tanks();
    planner.plan_pipes();
    planner.plan_walkways();
    planner.plan_stairs();
    return std::move(planner.objects);
}

}  // namespace

StatusOr<GeneratedSummary> generate_plant(const PlantOptions& options, const ObjectSink& sink,
                                          const ProgressFn& progress, const CancelToken* cancel) {
    constexpr std::uint64_t MAX_TRIANGLES = 10'000'000'000ull;
    if (options.triangles == 0 || options.triangles > MAX_TRIANGLES) {
        return invalid_argument("plant: the triangle target must be between 1 and " +
                                std::to_string(MAX_TRIANGLES) + " (got " +
                                std::to_string(options.triangles) + ")");
    }
    const double target = static_cast<double>(options.triangles);
    const auto bays =
        static_cast<std::uint32_t>(std::max<long long>(1, std::llround(target / BAY_TRIANGLES)));
    const auto columns =
        static_cast<std::uint32_t>(std::ceil(std::sqrt(static_cast<double>(bays))));
    std::vector<std::vector<ObjectPlan>> plan;
    plan.reserve(bays);
    for (std::uint32_t b = 0; b < bays; ++b) {
        const std::uint32_t column = b % columns;
        const std::uint32_t row = b / columns;
        plan.push_back(plan_bay(options.seed, b, CELL_X * column, CELL_Y * row));
    }

    // The density whose exact triangle count is closest to the target (the count is a
    // non-decreasing step function of the density).
    auto count = [&](double d) {
        std::uint64_t total = 0;
        for (const auto& bay : plan) {
            for (const auto& object : bay) {
                total += size_of(object, d).triangles;
            }
        }
        return total;
    };
    double lo = 1.0 / 64.0;
    double hi = 16.0;
    std::uint64_t count_lo = count(lo);
    std::uint64_t count_hi = count(hi);
    double density = 1.0;
    if (count_lo >= options.triangles) {
        density = lo;
    } else if (count_hi <= options.triangles) {
        density = hi;
    } else {
        for (int it = 0; it < 48 && hi / lo > 1.0 + 1e-9; ++it) {
            const double mid = std::sqrt(lo * hi);
            const std::uint64_t c = count(mid);
            if (c < options.triangles) {
                lo = mid;
                count_lo = c;
            } else {
                hi = mid;
                count_hi = c;
            }
        }
        density = options.triangles - count_lo <= count_hi - options.triangles ? lo : hi;
    }
    const std::uint64_t total = count(density);

    GeneratedSummary summary;
    CircleCache circles;
    Welder welder;
    const std::uint64_t report_step = std::max<std::uint64_t>(1, total / 100);
    std::uint64_t next_report = report_step;
    std::uint64_t reported = 0;
    if (progress) {
        progress({"generating", 0, total, "triangles"});
    }
    for (const auto& bay : plan) {
        for (const auto& object : bay) {
            if (cancel != nullptr && cancel->should_stop()) {
                return stop_status(*cancel, "plant generation");
            }
            const MeshSize size = size_of(object, density);
            ModelObject out;
            out.name = object.name;
            out.mesh.vertices.reserve(size.vertices);
            out.mesh.triangles.reserve(size.triangles);
            Mesher mesher(out.mesh, circles, density);
            for (const auto& part : object.parts) {
                std::visit(mesher, part);
            }
            welder.weld(out.mesh);
            for (const auto& v : out.mesh.vertices) {
                summary.box.extend(v);
            }
            summary.objects += 1;
            summary.triangles += out.mesh.triangles.size();
            summary.vertices += out.mesh.vertices.size();
            if (Status s = sink(std::move(out)); !s.ok()) {
                return s;
            }
            if (progress && summary.triangles >= next_report) {
                progress({"generating", summary.triangles, total, "triangles"});
                reported = summary.triangles;
                next_report = (summary.triangles / report_step + 1) * report_step;
            }
        }
    }
    if (progress && reported != summary.triangles) {
        progress({"generating", summary.triangles, total, "triangles"});
    }
    return summary;
}

// ---------------------------------------------------------------------------------------------
// The building.

namespace {

// Room grid pitch, storey height, slab, wall and column sizes (metres). Storey levels are
// multiples of an exactly representable height, so a slab's top, a wall's foot and a piece of
// furniture's base are the same double.
constexpr double ROOM_X = 6.0;
constexpr double ROOM_Y = 5.0;
constexpr double STOREY = 3.5;
constexpr double SLAB = 0.25;
constexpr double WALL = 0.2;
constexpr double COLUMN = 0.4;
constexpr double DOOR_WIDTH = 0.9;
constexpr double DOOR_HEIGHT = 2.1;
// Largest extent of a normalised furniture model: below the clear storey height, and small enough
// for every model to fit a room.
constexpr double MAX_FURNITURE = 2.4;
constexpr double MIN_FURNITURE = 0.1;

bool is_mesh_file(const std::filesystem::path& path) {
    std::string ext = path.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    // The formats read_mesh accepts (ACCEPTED_MESH_FORMATS); any other file would be refused.
    static const std::array<const char*, 6> EXTENSIONS = {".ply", ".off",  ".obj",
                                                          ".stl", ".gltf", ".glb"};
    return std::any_of(EXTENSIONS.begin(), EXTENSIONS.end(),
                       [&](const char* e) { return ext == e; });
}

// Formats whose convention is y up (Blender's OBJ export, glTF); PLY, OFF and STL are taken as
// z up.
bool is_y_up(const std::filesystem::path& path) {
    std::string ext = path.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return ext == ".obj" || ext == ".gltf" || ext == ".glb";
}

using IntMatrix = std::array<std::array<int, 3>, 3>;

IntMatrix multiply(const IntMatrix& a, const IntMatrix& b) {
    IntMatrix c{};
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            for (int k = 0; k < 3; ++k) {
                c[i][j] += a[i][k] * b[k][j];
            }
        }
    }
    return c;
}

struct FurnitureModel {
    std::string key;   // path under the furniture directory, '/'-separated
    std::string path;  // absolute
    std::string stem;
    TriangleMesh mesh;
    // Linear part of the instance transform for each quarter turn about z: the up-axis swap, the
    // unit scale, the rotation. Entries are 0 or +-scale, so they are exact.
    std::array<Affine, 4> linear;
    std::array<Aabb, 4> box;  // of the mesh under `linear` (translation 0), as Affine::apply rounds
};

Status load_model(const std::filesystem::path& root, const std::filesystem::path& file,
                  FurnitureModel& model) {
    auto read = read_mesh(file.string());
    if (!read.ok()) {
        return read.status();
    }
    model.mesh = std::move(read).value();
    model.path = std::filesystem::absolute(file).lexically_normal().string();
    model.key = file.lexically_relative(root).generic_string();
    model.stem = file.stem().string();
    Aabb raw;
    for (const auto& v : model.mesh.vertices) {
        raw.extend(v);
    }
    const Vec3 e = raw.extent();
    const double largest = std::max({e.x, e.y, e.z});
    // Units: metres, centimetres or millimetres, whichever makes the model closest to a metre;
    // then clamped to a plausible furniture size.
    double scale = 1.0;
    if (largest > 0.0) {
        double best = std::abs(std::log(largest));
        for (double unit : {0.01, 0.001}) {
            const double score = std::abs(std::log(largest * unit));
            if (score < best) {
                best = score;
                scale = unit;
            }
        }
        const double size = largest * scale;
        if (size > MAX_FURNITURE) {
            scale *= MAX_FURNITURE / size;
        } else if (size < MIN_FURNITURE) {
            scale *= MIN_FURNITURE / size;
        }
    }
    const IntMatrix up = is_y_up(file) ? IntMatrix{{{1, 0, 0}, {0, 0, -1}, {0, 1, 0}}}
                                       : IntMatrix{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
    IntMatrix turn{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
    const IntMatrix quarter{{{0, -1, 0}, {1, 0, 0}, {0, 0, 1}}};
    for (int q = 0; q < 4; ++q) {
        const IntMatrix m = multiply(turn, up);
        Affine a;
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) {
                a.m[4 * static_cast<std::size_t>(i) + static_cast<std::size_t>(j)] =
                    m[i][j] == 0 ? 0.0 : m[i][j] * scale;
            }
            a.m[4 * static_cast<std::size_t>(i) + 3] = 0.0;
        }
        model.linear[static_cast<std::size_t>(q)] = a;
        Aabb box;
        for (const auto& v : model.mesh.vertices) {
            box.extend(a.apply(v));
        }
        model.box[static_cast<std::size_t>(q)] = box;
        turn = multiply(quarter, turn);
    }
    return {};
}

// The translation t with fl(value + t) == target, so that an instance's extreme vertex lands
// exactly on a slab top or a wall face (Affine::apply adds the translation last, and rounding is
// monotonic: the extreme vertex stays the extreme). The nearest t when no t hits it exactly.
double offset_onto(double value, double target) {
    double t = target - value;
    for (int i = 0; i < 64 && value + t != target; ++i) {
        t = value + t < target ? std::nextafter(t, HUGE_VAL) : std::nextafter(t, -HUGE_VAL);
    }
    return t;
}

struct Instance {
    std::uint32_t model = 0;
    Affine transform;
    std::string name;
};

struct ShellObject {
    std::string name;
    std::vector<Box> boxes;
};

// {"name": name, "parts": [{"mesh": mesh, "transform": [12 numbers]}]}
nlohmann::ordered_json scene_object(const std::string& name, const std::string& mesh,
                                    const Affine& transform) {
    nlohmann::ordered_json part;
    part["mesh"] = mesh;
    part["transform"] = transform.m;
    nlohmann::ordered_json object;
    object["name"] = name;
    object["parts"] = nlohmann::ordered_json::array();
    object["parts"].push_back(std::move(part));
    return object;
}

std::string shell_file_name(const std::string& object) {
    std::string name = object;
    std::replace(name.begin(), name.end(), '/', '-');
    return "shell/" + name + ".off";
}

// The mesh files under the furniture directory, sorted by their '/'-separated path.
StatusOr<std::vector<std::filesystem::path>> list_furniture(const BuildingOptions& options) {
    namespace fs = std::filesystem;
    std::error_code ec;
    const fs::path root(options.furniture_dir);
    if (options.furniture_dir.empty() || !fs::is_directory(root, ec)) {
        return not_found("building: furniture directory '" + options.furniture_dir +
                         "' does not exist");
    }
    if (options.triangles == 0) {
        return invalid_argument("building: the triangle target must be positive");
    }
    std::vector<fs::path> files;
    for (fs::recursive_directory_iterator it(root, ec), end; !ec && it != end; it.increment(ec)) {
        if (it->is_regular_file(ec) && is_mesh_file(it->path())) {
            files.push_back(it->path());
        }
    }
    if (ec) {
        return Status(StatusCode::unavailable, "building: cannot list furniture directory '" +
                                                   options.furniture_dir + "': " + ec.message());
    }
    std::sort(files.begin(), files.end(), [](const fs::path& a, const fs::path& b) {
        return a.generic_string() < b.generic_string();
    });
    if (files.empty()) {
        return not_found("building: no mesh files under '" + options.furniture_dir + "'");
    }
    return files;
}

StatusOr<std::vector<FurnitureModel>> load_models(const std::filesystem::path& root,
                                                  const std::vector<std::filesystem::path>& files,
                                                  const ProgressFn& progress) {
    std::vector<FurnitureModel> models(files.size());
    for (std::size_t i = 0; i < files.size(); ++i) {
        if (progress) {
            progress({"reading", i, files.size(), "files"});
        }
        if (Status s = load_model(root, files[i], models[i]); !s.ok()) {
            return s;
        }
    }
    if (progress) {
        progress({"reading", files.size(), files.size(), "files"});
    }
    return models;
}

// Which instances: random models until the target is reached, never overshooting it by more
// than 2% (a smaller model is taken instead near the end).
std::vector<std::uint32_t> pick_models(const std::vector<FurnitureModel>& models,
                                       std::uint64_t target, Rng& rng) {
    const std::uint64_t slack = target / 50;
    std::vector<std::uint32_t> picks;
    std::uint64_t planned = 0;
    while (planned < target) {
        const std::uint64_t room = target - planned + slack;
        std::int64_t chosen = -1;
        for (int attempt = 0; attempt < 32 && chosen < 0; ++attempt) {
            const std::uint32_t i = rng.index(static_cast<std::uint32_t>(models.size()));
            if (models[i].mesh.triangles.size() <= room) {
                chosen = i;
            }
        }
        if (chosen < 0) {
            // The largest model that still fits (lowest index among equals).
            for (std::size_t i = 0; i < models.size(); ++i) {
                const auto n = models[i].mesh.triangles.size();
                if (n <= room &&
                    (chosen < 0 ||
                     n > models[static_cast<std::size_t>(chosen)].mesh.triangles.size())) {
                    chosen = static_cast<std::int64_t>(i);
                }
            }
        }
        if (chosen < 0) {
            break;
        }
        picks.push_back(static_cast<std::uint32_t>(chosen));
        planned += models[static_cast<std::size_t>(chosen)].mesh.triangles.size();
    }
    return picks;
}

double level(int storey) {
    return STOREY * storey;
}

// The room grid of every storey: nx by ny rooms.
struct RoomGrid {
    int nx = 1;
    int ny = 1;
    int rooms_per_storey = 1;
};

// About seven instances a room, about as many storeys as rooms along a side.
RoomGrid room_grid(std::size_t instances) {
    const double rooms_estimate = std::max(1.0, std::ceil(instances / 7.0));
    const int storeys_estimate =
        std::max(1, static_cast<int>(std::lround(std::cbrt(rooms_estimate))));
    const int per_storey = static_cast<int>(std::ceil(rooms_estimate / storeys_estimate));
    RoomGrid grid;
    grid.nx = static_cast<int>(std::ceil(std::sqrt(static_cast<double>(per_storey))));
    grid.ny = (per_storey + grid.nx - 1) / grid.nx;
    grid.rooms_per_storey = grid.nx * grid.ny;
    return grid;
}

// Placement: rooms in order (storey by storey), instances in rows along x from the room's -y
// wall. The first row stands against the wall (touching its face), the first instance of a row
// against the column face; neighbours touch or stand millimetres to decimetres apart; every
// instance stands on the slab (touching it).
class Placer {
  public:
    Placer(const RoomGrid& grid, Rng& rng)
        : m_grid(grid),
          m_rng(rng),
          m_room_capacity(4 + static_cast<int>(rng.index(6))),
          m_current(room_box(0)) {
        start_room(0);
    }

    Status place(std::uint32_t pick, const FurnitureModel& model) {
        static constexpr std::array<double, 6> GAPS = {0.0, 0.002, 0.01, 0.03, 0.1, 0.4};
        static constexpr std::array<double, 4> AISLES = {0.005, 0.02, 0.05, 0.8};
        auto q = static_cast<std::size_t>(m_rng.index(4));
        const double gap = m_rng.pick(GAPS);
        const double aisle = m_rng.pick(AISLES);
        // Find a place: this row, a new row, a new room (a model always fits an empty room).
        for (int tries = 0;; ++tries) {
            if (try_place(pick, model, q, gap)) {
                return {};
            }
            if (tries > 8) {
                q = (q + 1) % 4;  // a room too narrow for this orientation
            }
            if (!m_row_empty && m_room_items < m_room_capacity) {
                m_row_y = m_row_y + m_row_depth + aisle;
                m_row_depth = 0.0;
                m_row_empty = true;
                m_cursor = m_current.lo.x;
            } else {
                start_room(m_room + 1);
            }
            if (tries > 64) {
                return Status(StatusCode::internal, "building: cannot place '" + model.key + "'");
            }
        }
    }

    int storeys() const { return m_room / m_grid.rooms_per_storey + 1; }
    std::vector<Instance>& instances() { return m_instances; }

  private:
    Aabb room_box(int k) const {
        const int storey = k / m_grid.rooms_per_storey;
        const int r = k % m_grid.rooms_per_storey;
        const int i = r % m_grid.nx;
        const int j = r / m_grid.nx;
        Aabb b;
        b.lo = {ROOM_X * i + 0.5 * COLUMN, ROOM_Y * j + 0.5 * WALL, level(storey)};
        b.hi = {ROOM_X * (i + 1) - 0.5 * COLUMN, ROOM_Y * (j + 1) - 0.5 * COLUMN,
                level(storey + 1) - SLAB};
        return b;
    }

    void start_room(int k) {
        m_room = k;
        m_current = room_box(k);
        m_room_items = 0;
        m_room_capacity = 4 + static_cast<int>(m_rng.index(6));
        m_row_y = m_current.lo.y;
        m_row_depth = 0.0;
        m_cursor = m_current.lo.x;
        m_row_empty = true;
    }

    // Places the model in orientation q at the end of the current row when it fits there.
    bool try_place(std::uint32_t pick, const FurnitureModel& model, std::size_t q, double gap) {
        const Aabb& b = model.box[q];
        const Vec3 e = b.extent();
        const double x = m_row_empty ? m_current.lo.x : m_cursor + gap;
        const double y = m_row_y;
        if (!(m_room_items < m_room_capacity && x + e.x <= m_current.hi.x &&
              y + e.y <= m_current.hi.y)) {
            return false;
        }
        Affine a = model.linear[q];
        a.m[3] = offset_onto(b.lo.x, x);
        a.m[7] = offset_onto(b.lo.y, y);
        a.m[11] = offset_onto(b.lo.z, m_current.lo.z);
        const int storey = m_room / m_grid.rooms_per_storey;
        m_instances.push_back({pick, a,
                               "floor-" + std::to_string(storey) + "/room-" +
                                   std::to_string(m_room % m_grid.rooms_per_storey) + "/" +
                                   model.stem + "-" + std::to_string(m_room_items + 1)});
        m_cursor = b.hi.x + a.m[3];
        m_row_depth = std::max(m_row_depth, (b.hi.y + a.m[7]) - m_row_y);
        m_row_empty = false;
        ++m_room_items;
        return true;
    }

    const RoomGrid& m_grid;
    Rng& m_rng;
    std::vector<Instance> m_instances;
    int m_room = 0;
    int m_room_items = 0;
    int m_room_capacity;
    double m_row_y = 0.0;
    double m_row_depth = 0.0;
    double m_cursor = 0.0;
    bool m_row_empty = true;
    Aabb m_current;
};

// The walls of storey s (z0 to z1): along x (axis 0) at y = ROOM_Y j, then along y (axis 1) at
// x = ROOM_X i, touching the columns; each span with a door except on the outside (the ground
// floor has one entrance).
void plan_walls(const RoomGrid& grid, int s, const std::string& prefix, Rng& rng,
                std::vector<ShellObject>& shell) {
    const double z0 = level(s);
    const double z1 = level(s + 1) - SLAB;
    for (int axis = 0; axis < 2; ++axis) {
        const int lines = axis == 0 ? grid.ny : grid.nx;
        const int spans = axis == 0 ? grid.nx : grid.ny;
        const double pitch = axis == 0 ? ROOM_X : ROOM_Y;
        const double across = axis == 0 ? ROOM_Y : ROOM_X;
        for (int line = 0; line <= lines; ++line) {
            ShellObject wall{prefix + (axis == 0 ? "/wall-x-" : "/wall-y-") + std::to_string(line),
                             {}};
            const double c = across * line;
            auto add = [&](double a0, double a1, double za, double zb) {
                Box b;
                b.lo[axis] = a0;
                b.hi[axis] = a1;
                b.lo[1 - axis] = c - 0.5 * WALL;
                b.hi[1 - axis] = c + 0.5 * WALL;
                b.lo.z = za;
                b.hi.z = zb;
                wall.boxes.push_back(b);
            };
            for (int span = 0; span < spans; ++span) {
                const double a0 = pitch * span + 0.5 * COLUMN;
                const double a1 = pitch * (span + 1) - 0.5 * COLUMN;
                const bool outside = line == 0 || line == lines;
                const bool door = !outside || (s == 0 && axis == 0 && line == 0 && span == 0);
                if (!door) {
                    add(a0, a1, z0, z1);
                    continue;
                }
                const double d0 = rng.grid(a0 + 0.3, a1 - 0.3 - DOOR_WIDTH, 0.1);
                const double d1 = d0 + DOOR_WIDTH;
                add(a0, d0, z0, z1);
                add(d0, d1, z0 + DOOR_HEIGHT, z1);
                add(d1, a1, z0, z1);
            }
            shell.push_back(std::move(wall));
        }
    }
}

// The shell: a slab under every storey and a roof slab; per storey the columns at the grid
// points, and the walls.
std::vector<ShellObject> plan_shell(const RoomGrid& grid, int storeys, Rng& rng) {
    std::vector<ShellObject> shell;
    const double x_max = ROOM_X * grid.nx;
    const double y_max = ROOM_Y * grid.ny;
    for (int s = 0; s <= storeys; ++s) {
        const std::string prefix =
            s == storeys ? std::string("roof") : "floor-" + std::to_string(s);
        shell.push_back(
            {prefix + "/slab",
             {Box{{-0.5, -0.5, level(s) - SLAB}, {x_max + 0.5, y_max + 0.5, level(s)}}}});
        if (s == storeys) {
            break;
        }
        const double z0 = level(s);
        const double z1 = level(s + 1) - SLAB;
        ShellObject columns{prefix + "/columns", {}};
        for (int i = 0; i <= grid.nx; ++i) {
            for (int j = 0; j <= grid.ny; ++j) {
                const double x = ROOM_X * i;
                const double y = ROOM_Y * j;
                columns.boxes.push_back(Box{{x - 0.5 * COLUMN, y - 0.5 * COLUMN, z0},
                                            {x + 0.5 * COLUMN, y + 0.5 * COLUMN, z1}});
            }
        }
        shell.push_back(std::move(columns));
        plan_walls(grid, s, prefix, rng, shell);
    }
    return shell;
}

// The scene file's contents as they are written, and the summary.
class SceneWriter {
  public:
    SceneWriter(const std::filesystem::path& out, std::size_t total_objects,
                const ProgressFn& progress, GeneratedSummary& summary)
        : m_out(out), m_total(total_objects), m_progress(progress), m_summary(summary) {}

    // Meshes and writes one shell object (an OFF file under shell/).
    Status add_shell(const ShellObject& object) {
        const Affine identity;
        ModelObject mesh_object;
        Mesher mesher(mesh_object.mesh, m_circles, 1.0);
        for (const Box& b : object.boxes) {
            mesher(b);
        }
        m_welder.weld(mesh_object.mesh);
        const std::string file = shell_file_name(object.name);
        if (Status s = write_off((m_out / file).string(), mesh_object.mesh); !s.ok()) {
            return Status(StatusCode::unavailable, "building: " + s.message());
        }
        for (const auto& v : mesh_object.mesh.vertices) {
            m_summary.box.extend(identity.apply(v));
        }
        m_summary.objects += 1;
        m_summary.triangles += mesh_object.mesh.triangles.size();
        m_summary.vertices += mesh_object.mesh.vertices.size();
        m_meshes[object.name] = file;
        m_objects.push_back(scene_object(object.name, object.name, identity));
        report();
        return {};
    }

    // One furniture instance; its model's file is listed on first use.
    void add_instance(const Instance& instance, const FurnitureModel& model, bool first_use) {
        if (first_use) {
            m_meshes[model.key] = model.path;
        }
        for (const auto& v : model.mesh.vertices) {
            m_summary.box.extend(instance.transform.apply(v));
        }
        m_summary.objects += 1;
        m_summary.triangles += model.mesh.triangles.size();
        m_summary.vertices += model.mesh.vertices.size();
        m_objects.push_back(scene_object(instance.name, model.key, instance.transform));
        report();
    }

    Status write_scene(const std::string& scene_file) {
        nlohmann::ordered_json scene;
        scene["format"] = "proxima-scene/1";
        scene["meshes"] = std::move(m_meshes);
        scene["objects"] = std::move(m_objects);
        std::ofstream file(scene_file, std::ios::binary | std::ios::trunc);
        file << scene.dump(1) << '\n';
        if (!file.good()) {
            return Status(StatusCode::unavailable, "building: cannot write '" + scene_file + "'");
        }
        return {};
    }

  private:
    void report() {
        if (m_progress) {
            m_progress({"writing", ++m_written, m_total, "objects"});
        }
    }

    std::filesystem::path m_out;
    std::size_t m_total;
    const ProgressFn& m_progress;
    GeneratedSummary& m_summary;
    std::size_t m_written = 0;
    nlohmann::ordered_json m_meshes = nlohmann::ordered_json::object();
    nlohmann::ordered_json m_objects = nlohmann::ordered_json::array();
    CircleCache m_circles;
    Welder m_welder;
};

}  // namespace

StatusOr<GeneratedScene> generate_building(const BuildingOptions& options,
                                           const std::string& out_dir, const ProgressFn& progress) {
    namespace fs = std::filesystem;
    auto files = list_furniture(options);
    if (!files.ok()) {
        return files.status();
    }
    auto models = load_models(fs::path(options.furniture_dir), *files, progress);
    if (!models.ok()) {
        return models.status();
    }

    Rng rng(mix64(options.seed ^ 0x6275696c64696e67ull));
    const std::vector<std::uint32_t> picks = pick_models(*models, options.triangles, rng);
    const RoomGrid grid = room_grid(picks.size());
    Placer placer(grid, rng);
    for (std::uint32_t pick : picks) {
        if (Status s = placer.place(pick, (*models)[pick]); !s.ok()) {
            return s;
        }
    }
    const std::vector<Instance>& instances = placer.instances();
    const std::vector<ShellObject> shell = plan_shell(grid, placer.storeys(), rng);

    // Write the shell meshes and the scene file.
    std::error_code ec;
    const fs::path out(out_dir);
    fs::create_directories(out / "shell", ec);
    if (ec) {
        return Status(StatusCode::unavailable, "building: cannot create '" +
                                                   (out / "shell").string() + "': " + ec.message());
    }
    GeneratedScene result;
    SceneWriter writer(out, shell.size() + instances.size(), progress, result.summary);
    for (const ShellObject& object : shell) {
        if (Status s = writer.add_shell(object); !s.ok()) {
            return s;
        }
    }
    std::vector<bool> used(models->size(), false);
    for (const Instance& instance : instances) {
        const bool first_use = !used[instance.model];
        used[instance.model] = true;
        writer.add_instance(instance, (*models)[instance.model], first_use);
    }
    result.scene_file = (out / "scene.json").string();
    if (Status s = writer.write_scene(result.scene_file); !s.ok()) {
        return s;
    }
    return result;
}

}  // namespace proxima::massive
