// The procedural benchmark scenes: sizes as documented, deterministic, every frame's update
// applies to a Scene, the breaking scene's topology change, closed meshes where promised.

#include <gtest/gtest.h>

#include <cstring>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "proxima/scene.hpp"
#include "proxima/scenes/procedural.hpp"

namespace proxima {
namespace {

constexpr std::size_t FRAMES = 6;

std::size_t triangles(const std::vector<NamedMesh>& meshes) {
    std::size_t n = 0;
    for (const auto& m : meshes) {
        n += m.mesh.triangles.size();
    }
    return n;
}

Scene load(const scenes::ProceduralScene& ps) {
    Scene scene;
    for (const auto& m : ps.initial) {
        auto id = scene.add_object(m);
        EXPECT_TRUE(id.ok()) << ps.name << " '" << m.name << "': " << id.status().to_string();
    }
    return scene;
}

// Runs frames 1..last; every update must apply.
void advance(const scenes::ProceduralScene& ps, Scene& scene, std::size_t last) {
    for (std::size_t k = 1; k <= last; ++k) {
        auto r = scene.apply(ps.step(k, scene));
        ASSERT_TRUE(r.ok()) << ps.name << " frame " << k << ": " << r.status().to_string();
    }
}

bool bit_identical(const Scene& a, const Scene& b) {
    if (a.size() != b.size()) {
        return false;
    }
    for (std::size_t i = 0; i < a.size(); ++i) {
        const auto& va = a[i].vertices;
        const auto& vb = b[i].vertices;
        if (a[i].name != b[i].name || va.size() != vb.size() ||
            std::memcmp(va.data(), vb.data(), va.size() * sizeof(Vec3)) != 0 ||
            a[i].topology->triangles() != b[i].topology->triangles()) {
            return false;
        }
    }
    return true;
}

// Watertight and consistently oriented: every directed edge appears once, its reverse once.
bool closed_and_oriented(const std::vector<TriangleIndices>& tris) {
    std::map<std::pair<std::uint32_t, std::uint32_t>, int> directed;
    for (const auto& t : tris) {
        for (int e = 0; e < 3; ++e) {
            if (++directed[{t[e], t[(e + 1) % 3]}] > 1) {
                return false;
            }
        }
    }
    for (const auto& [edge, count] : directed) {
        if (directed.count({edge.second, edge.first}) == 0) {
            return false;
        }
    }
    return true;
}

bool is_cloth(const std::string& name) {
    return name == "skirt" || name == "cloth";
}

TEST(Procedural, TriangleCountsAsDocumented) {
    const std::map<std::string, std::size_t> expected{{"skirt", 12000},
                                                      {"cloth-ball", 15000},
                                                      {"bowl", 4500},
                                                      {"ramps", 38000},
                                                      {"breaking", 5500}};
    const auto scenes = scenes::all(FRAMES);
    ASSERT_EQ(scenes.size(), 5u);
    for (const auto& ps : scenes) {
        ASSERT_EQ(expected.count(ps.name), 1u) << ps.name;
        const double target = static_cast<double>(expected.at(ps.name));
        const double n = static_cast<double>(triangles(ps.initial));
        EXPECT_GE(n, 0.9 * target) << ps.name;
        EXPECT_LE(n, 1.1 * target) << ps.name;
        EXPECT_EQ(ps.frame_count, FRAMES);
        EXPECT_FALSE(ps.description.empty());
    }
}

TEST(Procedural, RampsObjectsAreSmall) {
    const auto ps = scenes::ramps(FRAMES);
    std::size_t moving = 0;
    for (const auto& m : ps.initial) {
        if (m.name.rfind("ramp", 0) == 0) {
            continue;
        }
        ++moving;
        EXPECT_GE(m.mesh.triangles.size(), 175u) << m.name;
        EXPECT_LE(m.mesh.triangles.size(), 190u) << m.name;
    }
    EXPECT_EQ(moving, 200u);
}

TEST(Procedural, Deterministic) {
    for (const auto& name : {"skirt", "cloth-ball", "bowl", "ramps", "breaking"}) {
        const auto a = scenes::by_name(name, FRAMES);
        const auto b = scenes::by_name(name, FRAMES);
        Scene sa = load(a);
        Scene sb = load(b);
        EXPECT_TRUE(bit_identical(sa, sb)) << name << " frame 0";
        advance(a, sa, 3);
        advance(b, sb, 3);
        EXPECT_TRUE(bit_identical(sa, sb)) << name << " frame 3";
    }
}

TEST(Procedural, EveryFrameApplies) {
    for (const auto& ps : scenes::all(FRAMES)) {
        Scene scene = load(ps);
        const auto before = scene.triangle_count();
        std::vector<std::vector<Vec3>> frame0;
        for (const auto& o : scene.objects()) {
            frame0.push_back(o.vertices);
        }
        advance(ps, scene, ps.frame_count - 1);
        EXPECT_GT(scene.triangle_count(), 0u);
        if (ps.name != "breaking") {
            EXPECT_EQ(scene.triangle_count(), before) << ps.name;
            // Deforming: the cloth or the objects moved; static parts (bowl, ramps) did not.
            std::size_t moved = 0;
            for (std::size_t i = 0; i < scene.size(); ++i) {
                moved += scene[i].vertices != frame0[i] ? 1 : 0;
            }
            EXPECT_GT(moved, 0u) << ps.name;
        }
    }
}

TEST(Procedural, ClosedObjectsAreWatertight) {
    for (const auto& ps : scenes::all(FRAMES)) {
        Scene scene = load(ps);
        auto check = [&](const char* when) {
            for (const auto& o : scene.objects()) {
                if (!is_cloth(o.name)) {
                    EXPECT_TRUE(closed_and_oriented(o.topology->triangles()))
                        << ps.name << " '" << o.name << "' " << when;
                }
            }
        };
        check("at frame 0");
        advance(ps, scene, ps.frame_count - 1);
        check("at the last frame");
    }
}

TEST(Procedural, BreakingReplacesFiveBallsByTwentyFivePieces) {
    const auto ps = scenes::breaking(FRAMES);
    Scene scene = load(ps);
    EXPECT_EQ(scene.size(), 5u);
    const std::size_t break_frame = FRAMES / 2;
    for (std::size_t k = 1; k < FRAMES; ++k) {
        const auto update = ps.step(k, scene);
        EXPECT_EQ(update.replacements.size(), k == break_frame ? 5u : 0u) << "frame " << k;
        for (const auto& r : update.replacements) {
            EXPECT_EQ(r.fragments.size(), 5u);
        }
        auto applied = scene.apply(update);
        ASSERT_TRUE(applied.ok()) << applied.status().to_string();
        EXPECT_EQ(scene.size(), k < break_frame ? 5u : 25u) << "frame " << k;
    }
    const double n = static_cast<double>(scene.triangle_count());
    EXPECT_GE(n, 0.9 * 5500);
    EXPECT_LE(n, 1.1 * 5500);
}

TEST(Procedural, StepReadsIdsFromTheScene) {
    // Objects the generator does not know are left alone; ids need not start at 1.
    const auto ps = scenes::bowl(FRAMES);
    Scene scene;
    TriangleMesh extra{{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, {{0, 1, 2}}};
    ASSERT_TRUE(scene.add_object({"caller's own", extra}).ok());
    for (const auto& m : ps.initial) {
        ASSERT_TRUE(scene.add_object(m).ok());
    }
    const auto update = ps.step(1, scene);
    for (const auto& p : update.positions) {
        EXPECT_NE(p.object, scene[0].id);
    }
    EXPECT_TRUE(scene.apply(update).ok());
}

TEST(Procedural, ByNameRoundTrip) {
    for (const auto& ps : scenes::all(4)) {
        const auto again = scenes::by_name(ps.name, 4);
        EXPECT_EQ(again.name, ps.name);
        EXPECT_EQ(again.initial.size(), ps.initial.size());
        EXPECT_EQ(again.frame_count, 4u);
    }
    EXPECT_TRUE(scenes::by_name("no-such-scene").name.empty());
}

}  // namespace
}  // namespace proxima
