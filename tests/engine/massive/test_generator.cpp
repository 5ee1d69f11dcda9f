// The procedural massive models: the plant is deterministic (bit for bit), hits its triangle
// target, scales its object count with it, and is made of valid objects that crowd each other
// (boxes within centimetres, beams touching the shoes and saddles that rest on them); the building
// writes a scene file whose every mesh exists, whose furniture stands exactly on the slabs, and
// whose summary is what an importer applying the same transforms gets.

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "proxima/distance/primitives.hpp"
#include "proxima/io/mesh_io.hpp"
#include "proxima/massive/generator.hpp"
#include "proxima/query/query.hpp"

namespace proxima::massive {
namespace {

namespace fs = std::filesystem;

std::vector<ModelObject> plant(std::uint64_t triangles, std::uint64_t seed,
                               GeneratedSummary* summary = nullptr) {
    std::vector<ModelObject> objects;
    PlantOptions options;
    options.triangles = triangles;
    options.seed = seed;
    auto result = generate_plant(options, [&](ModelObject&& o) {
        objects.push_back(std::move(o));
        return Status{};
    });
    EXPECT_TRUE(result.ok()) << result.status().to_string();
    if (summary != nullptr && result.ok()) {
        *summary = result.value();
    }
    return objects;
}

bool same_bits(const Vec3& a, const Vec3& b) {
    return std::bit_cast<std::uint64_t>(a.x) == std::bit_cast<std::uint64_t>(b.x) &&
           std::bit_cast<std::uint64_t>(a.y) == std::bit_cast<std::uint64_t>(b.y) &&
           std::bit_cast<std::uint64_t>(a.z) == std::bit_cast<std::uint64_t>(b.z);
}

bool identical(const ModelObject& a, const ModelObject& b) {
    if (a.name != b.name || a.mesh.triangles != b.mesh.triangles ||
        a.mesh.vertices.size() != b.mesh.vertices.size()) {
        return false;
    }
    for (std::size_t v = 0; v < a.mesh.vertices.size(); ++v) {
        if (!same_bits(a.mesh.vertices[v], b.mesh.vertices[v])) {
            return false;
        }
    }
    return true;
}

Aabb box_of(const TriangleMesh& mesh) {
    Aabb box;
    for (const auto& v : mesh.vertices) {
        box.extend(v);
    }
    return box;
}

// Unique per process: ctest runs test cases as parallel processes sharing TempDir().
fs::path temp_dir(const std::string& name) {
    fs::path dir = fs::path(::testing::TempDir()) /
                   ("proxima_generator_" + std::to_string(::getpid()) + "_" + name);
    fs::remove_all(dir);
    fs::create_directories(dir);
    return dir;
}

TEST(Plant, SameOptionsGiveBitIdenticalObjects) {
    const auto a = plant(100'000, 7);
    const auto b = plant(100'000, 7);
    ASSERT_EQ(a.size(), b.size());
    ASSERT_FALSE(a.empty());
    for (std::size_t i = 0; i < a.size(); ++i) {
        EXPECT_TRUE(identical(a[i], b[i])) << "object " << i << " '" << a[i].name << "'";
    }
    const auto c = plant(100'000, 8);
    bool differs = a.size() != c.size();
    for (std::size_t i = 0; !differs && i < a.size(); ++i) {
        differs = !identical(a[i], c[i]);
    }
    EXPECT_TRUE(differs) << "seeds 7 and 8 gave the same plant";
}

TEST(Plant, HitsTheTargetAndReportsWhatItStreamed) {
    for (std::uint64_t target : {10'000ull, 100'000ull, 1'000'000ull}) {
        GeneratedSummary summary;
        const auto objects = plant(target, 1, &summary);
        std::uint64_t triangles = 0;
        std::uint64_t vertices = 0;
        Aabb box;
        std::set<std::string> names;
        for (const auto& o : objects) {
            ASSERT_TRUE(validate_mesh(o.mesh, o.name).ok())
                << validate_mesh(o.mesh, o.name).to_string();
            triangles += o.mesh.triangles.size();
            vertices += o.mesh.vertices.size();
            box.extend(box_of(o.mesh));
            names.insert(o.name);
        }
        EXPECT_EQ(names.size(), objects.size()) << "object names must be unique";
        EXPECT_EQ(summary.objects, objects.size());
        EXPECT_EQ(summary.triangles, triangles);
        EXPECT_EQ(summary.vertices, vertices);
        EXPECT_EQ(summary.box.lo, box.lo);
        EXPECT_EQ(summary.box.hi, box.hi);
        const double ratio = static_cast<double>(triangles) / static_cast<double>(target);
        EXPECT_GT(ratio, 0.9) << target;
        EXPECT_LT(ratio, 1.1) << target;
    }
}

TEST(Plant, ObjectCountScalesWithTheTarget) {
    // About one object per 8,000 triangles (the paper's plant: 15M triangles, ~1,800 objects).
    for (std::uint64_t target : {100'000ull, 1'000'000ull}) {
        const auto objects = plant(target, 3);
        const double expected = static_cast<double>(target) / 8000.0;
        EXPECT_GT(static_cast<double>(objects.size()), 0.6 * expected) << target;
        EXPECT_LT(static_cast<double>(objects.size()), 1.6 * expected) << target;
        std::size_t smallest = SIZE_MAX;
        std::size_t largest = 0;
        for (const auto& o : objects) {
            smallest = std::min(smallest, o.mesh.triangles.size());
            largest = std::max(largest, o.mesh.triangles.size());
        }
        EXPECT_GT(largest, 10 * smallest) << "object sizes should vary";
    }
}

TEST(Plant, ObjectsCrowdEachOther) {
    const auto objects = plant(1'000'000, 1);
    std::vector<Aabb> boxes;
    for (const auto& o : objects) {
        boxes.push_back(box_of(o.mesh));
    }
    std::size_t crowded = 0;
    for (std::size_t i = 0; i < boxes.size(); ++i) {
        for (std::size_t j = 0; j < boxes.size(); ++j) {
            if (i != j && box_squared_distance(boxes[i], boxes[j]) <= 0.05 * 0.05) {
                ++crowded;
                break;
            }
        }
    }
    EXPECT_GT(static_cast<double>(crowded), 0.5 * static_cast<double>(boxes.size()))
        << crowded << " of " << boxes.size() << " objects have another within 5 cm";
}

// Every sub-mesh is a closed, consistently oriented surface: each directed edge u->v is matched by
// as many v->u (sub-meshes that share welded vertices keep this), and each connected component
// encloses a positive volume (outward normals).
TEST(Plant, ObjectsAreClosedOutwardSurfaces) {
    for (const auto& o : plant(100'000, 5)) {
        std::vector<std::pair<std::uint32_t, std::uint32_t>> edges;
        for (const auto& t : o.mesh.triangles) {
            for (int k = 0; k < 3; ++k) {
                edges.emplace_back(t[k], t[(k + 1) % 3]);
            }
        }
        std::vector<std::pair<std::uint32_t, std::uint32_t>> reversed;
        for (const auto& [u, v] : edges) {
            reversed.emplace_back(v, u);
        }
        std::sort(edges.begin(), edges.end());
        std::sort(reversed.begin(), reversed.end());
        EXPECT_EQ(edges, reversed) << o.name << " has open or inconsistently oriented edges";
        for (const auto& c : split_components(o.mesh).meshes) {
            double volume = 0.0;
            for (const auto& t : c.triangles) {
                volume += dot(c.vertices[t[0]], cross(c.vertices[t[1]], c.vertices[t[2]]));
            }
            EXPECT_GT(volume, 0.0) << o.name;
        }
    }
}

// Two objects that share a point: shoes stand on girders, saddles on deck beams, walkways on the
// frame. Only triangles near the other object's box are tried.
TEST(Plant, SomeObjectsTouchOrIntersect) {
    const auto objects = plant(100'000, 1);
    std::size_t touching_pairs = 0;
    for (std::size_t i = 0; i < objects.size(); ++i) {
        for (std::size_t j = i + 1; j < objects.size(); ++j) {
            const auto& a = objects[i].mesh;
            const auto& b = objects[j].mesh;
            const Aabb ab = box_of(a);
            const Aabb bb = box_of(b);
            if (box_squared_distance(ab, bb) > 0.0) {
                continue;
            }
            auto near = [](const TriangleMesh& m, const Aabb& other) {
                std::vector<Triangle> out;
                for (const auto& t : m.triangles) {
                    const Triangle tri{m.vertices[t[0]], m.vertices[t[1]], m.vertices[t[2]]};
                    if (box_squared_distance(triangle_box(tri[0], tri[1], tri[2]), other) == 0.0) {
                        out.push_back(tri);
                    }
                }
                return out;
            };
            const auto ta = near(a, bb);
            const auto tb = near(b, ab);
            bool touch = false;
            for (const auto& x : ta) {
                const Aabb xb = triangle_box(x[0], x[1], x[2]);
                for (const auto& y : tb) {
                    if (box_squared_distance(xb, triangle_box(y[0], y[1], y[2])) == 0.0 &&
                        triangle_triangle(x, y).squared_distance == 0.0) {
                        touch = true;
                        break;
                    }
                }
                if (touch) {
                    break;
                }
            }
            touching_pairs += touch ? 1 : 0;
        }
    }
    EXPECT_GE(touching_pairs, 1u);
}

// A generated object written to a file and read back (read_mesh welds identical positions) is the
// same object: no two vertices of an object share a position.
TEST(Plant, ObjectsRoundTripThroughFiles) {
    const auto objects = plant(30'000, 2);
    const fs::path dir = temp_dir("roundtrip");
    for (const auto& o : objects) {
        const std::string path = (dir / "object.off").string();
        ASSERT_TRUE(write_off(path, o.mesh).ok());
        auto read = read_mesh(path);
        ASSERT_TRUE(read.ok()) << read.status().to_string();
        ModelObject back{o.name, std::move(read).value()};
        EXPECT_TRUE(identical(o, back)) << o.name;
    }
    fs::remove_all(dir);
}

TEST(Plant, StopsOnCancelAndOnSinkErrors) {
    PlantOptions options;
    options.triangles = 100'000;
    CancelToken cancel;
    std::size_t received = 0;
    auto result = generate_plant(
        options,
        [&](ModelObject&&) {
            if (++received == 3) {
                cancel.cancel();
            }
            return Status{};
        },
        {}, &cancel);
    EXPECT_EQ(result.status().code(), StatusCode::cancelled);
    EXPECT_EQ(received, 3u);

    received = 0;
    result = generate_plant(options, [&](ModelObject&&) {
        return ++received == 2 ? Status(StatusCode::unavailable, "disk full") : Status{};
    });
    EXPECT_EQ(result.status().code(), StatusCode::unavailable);
    EXPECT_EQ(received, 2u);

    options.triangles = 0;
    EXPECT_EQ(generate_plant(options, [](ModelObject&&) { return Status{}; }).status().code(),
              StatusCode::invalid_argument);
}

TEST(Plant, ReportsProgress) {
    PlantOptions options;
    options.triangles = 1'000'000;
    std::vector<Progress> reports;
    auto result = generate_plant(
        options, [](ModelObject&&) { return Status{}; },
        [&](const Progress& p) { reports.push_back(p); });
    ASSERT_TRUE(result.ok());
    ASSERT_GE(reports.size(), 10u);
    EXPECT_LE(reports.size(), 200u);
    for (std::size_t i = 1; i < reports.size(); ++i) {
        EXPECT_GE(reports[i].done, reports[i - 1].done);
    }
    EXPECT_EQ(reports.back().step, "generating");
    EXPECT_EQ(reports.back().unit, "triangles");
    EXPECT_EQ(reports.back().done, result->triangles);
    EXPECT_EQ(reports.back().total, result->triangles);
}

// ---------------------------------------------------------------------------------------------
// The building.

fs::path furniture_dir() {
    return fs::path(PROXIMA_DATA_DIR) / "meshes" / "furniture-cc0";
}

std::string read_text(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

TEST(Building, WritesAConsistentSceneFile) {
    if (!fs::is_directory(furniture_dir())) {
        GTEST_SKIP() << "no furniture at " << furniture_dir();
    }
    const fs::path out = temp_dir("building");
    BuildingOptions options;
    options.furniture_dir = furniture_dir().string();
    options.triangles = 300'000;
    options.seed = 1;
    auto result = generate_building(options, out.string());
    ASSERT_TRUE(result.ok()) << result.status().to_string();
    const auto& summary = result->summary;
    EXPECT_EQ(fs::path(result->scene_file), out / "scene.json");

    const auto scene = nlohmann::json::parse(read_text(result->scene_file));
    EXPECT_EQ(scene.at("format"), "proxima-scene/1");
    std::map<std::string, TriangleMesh> meshes;
    for (const auto& [key, value] : scene.at("meshes").items()) {
        fs::path path(value.get<std::string>());
        if (path.is_relative()) {
            path = out / path;
        }
        ASSERT_TRUE(fs::is_regular_file(path)) << key << ": " << path;
        auto mesh = read_mesh(path.string());
        ASSERT_TRUE(mesh.ok()) << mesh.status().to_string();
        meshes[key] = std::move(mesh).value();
    }
    // Recompute the summary as an importer does; furniture must stand exactly on a slab top (a
    // multiple of the storey height) and be named floor-F/room-R/model-K.
    std::uint64_t triangles = 0;
    std::uint64_t vertices = 0;
    std::size_t furniture = 0;
    std::size_t on_slab = 0;
    std::set<std::string> names;
    std::set<double> slab_tops;
    Aabb box;
    for (const auto& object : scene.at("objects")) {
        const std::string name = object.at("name");
        names.insert(name);
        const bool is_furniture = name.find("/room-") != std::string::npos;
        for (const auto& part : object.at("parts")) {
            const TriangleMesh& mesh = meshes.at(part.at("mesh").get<std::string>());
            Affine transform;
            if (part.contains("transform")) {
                const auto m = part.at("transform").get<std::vector<double>>();
                ASSERT_EQ(m.size(), 12u);
                std::copy(m.begin(), m.end(), transform.m.begin());
            }
            double min_z = HUGE_VAL;
            for (const auto& v : mesh.vertices) {
                const Vec3 p = transform.apply(v);
                box.extend(p);
                min_z = std::min(min_z, p.z);
            }
            triangles += mesh.triangles.size();
            vertices += mesh.vertices.size();
            if (name.find("/slab") != std::string::npos) {
                slab_tops.insert(box_of(mesh).hi.z);
            }
            if (is_furniture) {
                ++furniture;
                on_slab += std::fmod(min_z, 3.5) == 0.0 ? 1 : 0;
            }
        }
    }
    EXPECT_EQ(names.size(), scene.at("objects").size()) << "object names must be unique";
    EXPECT_EQ(summary.objects, scene.at("objects").size());
    EXPECT_EQ(summary.triangles, triangles);
    EXPECT_EQ(summary.vertices, vertices);
    EXPECT_EQ(summary.box.lo, box.lo);
    EXPECT_EQ(summary.box.hi, box.hi);
    EXPECT_GT(furniture, 10u);
    EXPECT_EQ(on_slab, furniture) << "every instance's lowest point lies on a slab top";
    EXPECT_GE(slab_tops.size(), 2u);  // a ground slab and a roof at least
    const double ratio = static_cast<double>(summary.triangles) / 300'000.0;
    EXPECT_GT(ratio, 0.9);
    EXPECT_LT(ratio, 1.1);
    fs::remove_all(out);
}

TEST(Building, IsDeterministic) {
    if (!fs::is_directory(furniture_dir())) {
        GTEST_SKIP() << "no furniture at " << furniture_dir();
    }
    // A few of the models (every 20th file) keep this quick.
    const fs::path subset = temp_dir("furniture");
    std::vector<fs::path> files;
    for (const auto& e : fs::recursive_directory_iterator(furniture_dir())) {
        if (e.is_regular_file() && e.path().extension() == ".obj") {
            files.push_back(e.path());
        }
    }
    std::sort(files.begin(), files.end());
    ASSERT_GE(files.size(), 20u);
    for (std::size_t i = 0; i < files.size(); i += 20) {
        fs::create_symlink(files[i], subset / files[i].filename());
    }
    BuildingOptions options;
    options.furniture_dir = subset.string();
    options.triangles = 150'000;
    const fs::path a = temp_dir("building_a");
    const fs::path b = temp_dir("building_b");
    auto ra = generate_building(options, a.string());
    auto rb = generate_building(options, b.string());
    ASSERT_TRUE(ra.ok()) << ra.status().to_string();
    ASSERT_TRUE(rb.ok()) << rb.status().to_string();
    const std::string text = read_text(ra->scene_file);
    EXPECT_EQ(text, read_text(rb->scene_file));
    EXPECT_EQ(ra->summary.triangles, rb->summary.triangles);
    options.seed = 2;
    auto rc = generate_building(options, b.string());
    ASSERT_TRUE(rc.ok());
    EXPECT_NE(text, read_text(rc->scene_file));
    for (const auto& dir : {subset, a, b}) {
        fs::remove_all(dir);
    }
}

TEST(Building, MissingFurnitureIsNotFound) {
    BuildingOptions options;
    options.furniture_dir = "/nonexistent/furniture";
    const fs::path out = temp_dir("building_missing");
    EXPECT_EQ(generate_building(options, out.string()).status().code(), StatusCode::not_found);
    options.furniture_dir = out.string();  // exists, holds no mesh
    EXPECT_EQ(generate_building(options, out.string()).status().code(), StatusCode::not_found);
    fs::remove_all(out);
}

}  // namespace
}  // namespace proxima::massive
