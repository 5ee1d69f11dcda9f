#pragma once
// Random test geometry: deformed closed meshes (spheres, boxes), open sheets, and degenerate
// triangles, arranged to touch, cross, nest or stay apart. Seeded, so a failure names its seed.

#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include "proxima/mesh/mesh.hpp"
#include "proxima/scene.hpp"

namespace proxima::test {

using Rng = std::mt19937_64;

inline double uniform(Rng& rng, double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng);
}

// UV sphere with `rings` x `segments` quads (closed, poles shared), radius r, noise in [0, noise).
inline TriangleMesh sphere(Rng& rng, int rings, int segments, double r, double noise) {
    TriangleMesh m;
    m.vertices.push_back({0, 0, r});
    for (int i = 1; i < rings; ++i) {
        const double th = std::numbers::pi * i / rings;
        for (int j = 0; j < segments; ++j) {
            const double ph = 2 * std::numbers::pi * j / segments;
            const double rr = r * (1.0 + uniform(rng, -noise, noise));
            m.vertices.push_back({rr * std::sin(th) * std::cos(ph),
                                  rr * std::sin(th) * std::sin(ph), rr * std::cos(th)});
        }
    }
    m.vertices.push_back({0, 0, -r});
    const auto south = static_cast<std::uint32_t>(m.vertices.size() - 1);
    auto at = [&](int i, int j) {
        return static_cast<std::uint32_t>(1 + (i - 1) * segments + (j % segments));
    };
    for (int j = 0; j < segments; ++j) {
        m.triangles.push_back({0, at(1, j), at(1, j + 1)});
    }
    for (int i = 1; i + 1 < rings; ++i) {
        for (int j = 0; j < segments; ++j) {
            m.triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
            m.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
        }
    }
    for (int j = 0; j < segments; ++j) {
        m.triangles.push_back({at(rings - 1, j), south, at(rings - 1, j + 1)});
    }
    return m;
}

// Open sheet of nx x ny quads over [0,1]^2, bent by a random wave so distant parts fold close.
inline TriangleMesh sheet(Rng& rng, int nx, int ny, double fold) {
    TriangleMesh m;
    const double a = uniform(rng, 0.5, 3.0);
    const double b = uniform(rng, 0.5, 3.0);
    for (int j = 0; j <= ny; ++j) {
        for (int i = 0; i <= nx; ++i) {
            const double u = static_cast<double>(i) / nx;
            const double v = static_cast<double>(j) / ny;
            // Fold the sheet over itself along u: a half turn of radius `fold`.
            const double ang = std::numbers::pi * u;
            m.vertices.push_back({fold * std::sin(ang) + 0.02 * std::sin(a * 7 * v), v,
                                  fold * (1 - std::cos(ang)) + 0.02 * std::cos(b * 5 * u)});
        }
    }
    auto id = [&](int i, int j) { return static_cast<std::uint32_t>(j * (nx + 1) + i); };
    for (int j = 0; j < ny; ++j) {
        for (int i = 0; i < nx; ++i) {
            m.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
            m.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
        }
    }
    return m;
}

// Axis-aligned box [lo, hi] as 12 triangles.
inline TriangleMesh box(const Vec3& lo, const Vec3& hi) {
    TriangleMesh m;
    for (int k = 0; k < 8; ++k) {
        m.vertices.push_back({(k & 1) ? hi.x : lo.x, (k & 2) ? hi.y : lo.y, (k & 4) ? hi.z : lo.z});
    }
    m.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                   {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
    return m;
}

// A soup of small random triangles with deliberate degeneracies: zero-area (collinear), repeated
// vertex indices, coincident vertices under distinct indices.
inline TriangleMesh degenerate_soup(Rng& rng, int count, double spread) {
    TriangleMesh m;
    for (int t = 0; t < count; ++t) {
        const Vec3 c{uniform(rng, 0, spread), uniform(rng, 0, spread), uniform(rng, 0, spread)};
        const Vec3 d{uniform(rng, -0.2, 0.2), uniform(rng, -0.2, 0.2), uniform(rng, -0.2, 0.2)};
        const Vec3 e{uniform(rng, -0.2, 0.2), uniform(rng, -0.2, 0.2), uniform(rng, -0.2, 0.2)};
        const auto base = static_cast<std::uint32_t>(m.vertices.size());
        switch (t % 4) {
            case 0:  // collinear
                m.vertices.insert(m.vertices.end(), {c, c + d, c + 2.5 * d});
                break;
            case 1:  // two coincident positions under distinct indices
                m.vertices.insert(m.vertices.end(), {c, c, c + e});
                break;
            default:
                m.vertices.insert(m.vertices.end(), {c, c + d, c + e});
        }
        if (t % 7 == 3) {
            m.triangles.push_back({base, base, base + 2});  // repeated index
        } else {
            m.triangles.push_back({base, base + 1, base + 2});
        }
    }
    return m;
}

inline void transform(TriangleMesh& m, double scale, const Vec3& offset, double angle) {
    const double c = std::cos(angle);
    const double s = std::sin(angle);
    for (auto& v : m.vertices) {
        const Vec3 p = scale * v;
        v = Vec3{c * p.x - s * p.y, s * p.x + c * p.y, p.z} + offset;
    }
}

// A random scene of 1..6 objects in a box of side ~2: objects overlap, nest, touch and separate.
inline std::vector<NamedMesh> random_scene(Rng& rng) {
    std::vector<NamedMesh> out;
    const int n = std::uniform_int_distribution<int>(1, 6)(rng);
    for (int k = 0; k < n; ++k) {
        TriangleMesh m;
        const int kind = std::uniform_int_distribution<int>(0, 9)(rng);
        if (kind <= 3) {
            m = sphere(rng, std::uniform_int_distribution<int>(3, 7)(rng),
                       std::uniform_int_distribution<int>(3, 9)(rng), 1.0, 0.15);
            transform(m, uniform(rng, 0.2, 0.8),
                      {uniform(rng, 0, 2), uniform(rng, 0, 2), uniform(rng, 0, 2)},
                      uniform(rng, 0, 6));
        } else if (kind <= 6) {
            m = sheet(rng, std::uniform_int_distribution<int>(2, 8)(rng),
                      std::uniform_int_distribution<int>(2, 6)(rng), uniform(rng, 0.01, 0.3));
            transform(m, uniform(rng, 0.5, 1.5),
                      {uniform(rng, 0, 2), uniform(rng, 0, 2), uniform(rng, 0, 2)},
                      uniform(rng, 0, 6));
        } else if (kind == 7) {
            // Nested: a small sphere inside a larger one.
            TriangleMesh outer = sphere(rng, 5, 6, 1.0, 0.05);
            TriangleMesh inner = sphere(rng, 4, 5, 0.3, 0.05);
            const Vec3 o{uniform(rng, 0, 2), uniform(rng, 0, 2), uniform(rng, 0, 2)};
            transform(outer, 0.6, o, 0);
            transform(inner, 0.6, o, 0);
            out.push_back({"outer", outer});
            m = inner;
        } else if (kind == 8) {
            // Exactly touching boxes: a shared face plane at x = 1 (with dyadic coordinates).
            out.push_back({"box-a", box({0.0, 0.0, 0.0}, {1.0, 1.0, 1.0})});
            m = box({1.0, 0.25, 0.25}, {1.5, 0.75, 0.75});
        } else {
            m = degenerate_soup(rng, std::uniform_int_distribution<int>(2, 25)(rng), 2.0);
        }
        out.push_back({"obj" + std::to_string(k), std::move(m)});
    }
    return out;
}

// Moves every vertex by a small random displacement (same topology).
inline std::vector<Vec3> jitter(Rng& rng, const std::vector<Vec3>& v, double amount) {
    std::vector<Vec3> out = v;
    for (auto& p : out) {
        p += Vec3{uniform(rng, -amount, amount), uniform(rng, -amount, amount),
                  uniform(rng, -amount, amount)};
    }
    return out;
}

}  // namespace proxima::test
