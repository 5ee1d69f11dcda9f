// The region planner (proxima/massive/region.hpp) on a small store: which pieces, in which order,
// the max_triangles cut, the checks, and a room's view (masked, moved and added objects).
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <tuple>
#include <vector>

#include "proxima/massive/avatar.hpp"
#include "proxima/massive/region.hpp"
#include "proxima/massive/store.hpp"
#include "proxima/massive/verify.hpp"
#include "support/model_stores.hpp"

namespace proxima::massive {
namespace {

namespace fs = std::filesystem;

using test::box_mesh;

// A row of unit boxes along x, 2 apart (box i spans x 2i..2i+1), plus a long bar split into
// pieces (many thin boxes as one object) at y = 5.
class Region : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        s_dir = new fs::path(fs::temp_directory_path() /
                             ("proxima-region-" + std::to_string(::getpid())));
        fs::remove_all(*s_dir);
        StoreOptions options;
        options.max_piece_bytes = 4096;  // the bar (120 triangles) splits
        std::vector<ModelObject> objects;
        for (int i = 0; i < 5; ++i) {
            const Vec3 lo{2.0 * i, 0, 0};
            objects.push_back({"box-" + std::to_string(i), box_mesh(lo, lo + Vec3{1, 1, 1})});
        }
        TriangleMesh bar;
        for (int k = 0; k < 10; ++k) {
            auto b = box_mesh({1.0 * k, 5, 0}, {1.0 * k + 0.9, 5.5, 0.5});
            const auto base = static_cast<std::uint32_t>(bar.vertices.size());
            bar.vertices.insert(bar.vertices.end(), b.vertices.begin(), b.vertices.end());
            for (auto t : b.triangles) {
                bar.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
            }
        }
        objects.push_back({"bar", bar});
        test::write_model_store(s_dir->string(), objects, options);
        auto store = Store::open(s_dir->string());
        ASSERT_TRUE(store.ok());
        s_store = new std::shared_ptr<const Store>(store.value());
    }
    static void TearDownTestSuite() {
        delete s_store;
        std::error_code ec;
        fs::remove_all(*s_dir, ec);
        delete s_dir;
    }
    static const Store& store() { return **s_store; }
    static fs::path* s_dir;
    static std::shared_ptr<const Store>* s_store;
};
fs::path* Region::s_dir = nullptr;
std::shared_ptr<const Store>* Region::s_store = nullptr;

TEST_F(Region, BoxDistanceIsZeroInsideAndEuclideanOutside) {
    Aabb box;
    box.lo = {0, 0, 0};
    box.hi = {1, 1, 1};
    EXPECT_EQ(box_distance(box, {0.5, 0.5, 0.5}), 0.0);
    EXPECT_EQ(box_distance(box, {1, 1, 1}), 0.0);
    EXPECT_EQ(box_distance(box, {4, 0.5, 0.5}), 3.0);
    EXPECT_EQ(box_distance(box, {4, 5, 0.5}), 5.0);
    EXPECT_EQ(box_distance(box, {-3, -4, 0}), 5.0);
}

TEST_F(Region, NearestFirstWithinTheRadiusTiesByObjectThenPiece) {
    RegionRequest request;
    request.center = {4.5, 0.5, 0.5};  // inside box 2
    request.radius = 1.5;              // boxes 1 and 3 are exactly 1.5 away, 0 and 4 3.5
    const auto plan = plan_region(store(), nullptr, request);
    ASSERT_EQ(plan.pieces.size(), 3u);
    EXPECT_EQ(plan.pieces[0].object, 2u);
    EXPECT_EQ(plan.pieces[0].distance, 0.0);
    EXPECT_EQ(plan.pieces[1].object, 1u);  // tie at 1.5: the smaller object first
    EXPECT_EQ(plan.pieces[2].object, 3u);
    EXPECT_EQ(plan.pieces[1].distance, 1.5);
    EXPECT_EQ(plan.pieces[2].distance, 1.5);
    EXPECT_EQ(plan.triangles, 36u);
    EXPECT_FALSE(plan.truncated);

    // Radius 0: every piece, distances 0, by object then piece.
    request.radius = 0.0;
    const auto all = plan_region(store(), nullptr, request);
    ASSERT_EQ(all.pieces.size(), store().pieces().size());
    for (std::size_t k = 1; k < all.pieces.size(); ++k) {
        EXPECT_EQ(all.pieces[k].distance, 0.0);
        EXPECT_LT(std::tie(all.pieces[k - 1].object, all.pieces[k - 1].piece),
                  std::tie(all.pieces[k].object, all.pieces[k].piece));
    }
    EXPECT_EQ(all.triangles, store().summary().triangles);
}

TEST_F(Region, MaxTrianglesKeepsTheNearestPrefix) {
    RegionRequest request;
    request.center = {0.5, 0.5, 0.5};
    request.radius = 100.0;
    request.max_triangles = 30;  // box 0 (12), box 1 (12), then box 2 would pass 30
    auto plan = plan_region(store(), nullptr, request);
    ASSERT_EQ(plan.pieces.size(), 2u);
    EXPECT_EQ(plan.triangles, 24u);
    EXPECT_TRUE(plan.truncated);
    // Smaller than the nearest piece: nothing, truncated.
    request.max_triangles = 11;
    plan = plan_region(store(), nullptr, request);
    EXPECT_TRUE(plan.pieces.empty());
    EXPECT_TRUE(plan.truncated);
    // Exactly everything: not truncated.
    request.max_triangles = store().summary().triangles;
    plan = plan_region(store(), nullptr, request);
    EXPECT_EQ(plan.pieces.size(), store().pieces().size());
    EXPECT_FALSE(plan.truncated);
}

TEST_F(Region, ChecksNameTheField) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    RegionRequest request;
    EXPECT_TRUE(check_region_request(request, 6).ok());
    request.radius = -0.5;
    EXPECT_NE(check_region_request(request, 6).message().find("radius"), std::string::npos);
    request.radius = nan;
    EXPECT_EQ(check_region_request(request, 6).code(), StatusCode::invalid_argument);
    request.radius = 1.0;
    request.center.x = std::numeric_limits<double>::infinity();
    EXPECT_NE(check_region_request(request, 6).message().find("center"), std::string::npos);
    request.center.x = 0;
    request.objects = {5, 6};
    const auto s = check_region_request(request, 6);
    EXPECT_EQ(s.code(), StatusCode::invalid_argument);
    EXPECT_NE(s.message().find("objects[1]: object 6"), std::string::npos) << s.to_string();
}

TEST_F(Region, ARoomsViewMasksMovesAndAdds) {
    auto cache = std::make_shared<GeometryCache>(1 << 20);
    ModelView view(*s_store, cache);
    Affine up;
    up.m[11] = 10.0;  // box 1 lifted by 10
    ASSERT_TRUE(view.move_object(1, up).ok());
    ASSERT_TRUE(view.delete_object(3).ok());
    auto added = view.add_object({"crate", box_mesh({4, 0, 3}, {5, 1, 4})});
    ASSERT_TRUE(added.ok());
    const auto snapshot = view.snapshot();

    RegionRequest request;
    request.center = {2.5, 0.5, 0.5};
    request.radius = 1.5;  // box 1 is there in the store; in the room it has gone up
    const auto stored = plan_region(store(), nullptr, request);
    const auto room = plan_region(store(), snapshot.get(), request);
    ASSERT_EQ(stored.pieces.size(), 3u);  // boxes 1, 0, 2 (0 and 2 exactly 1.5 away)
    EXPECT_EQ(stored.pieces[0].object, 1u);
    ASSERT_EQ(room.pieces.size(), 2u);
    EXPECT_EQ(room.pieces[0].object, 0u);
    EXPECT_EQ(room.pieces[1].object, 2u);

    // The whole view: the moved box as one overlay piece (its transform applied, its own triangle
    // ids), the deleted box absent, the crate present.
    request.radius = 0.0;
    const auto whole = plan_region(store(), snapshot.get(), request);
    bool saw_moved = false;
    bool saw_added = false;
    for (const auto& ref : whole.pieces) {
        EXPECT_NE(ref.object, 3u);
        auto piece = read_region_piece(*s_store, *cache, snapshot.get(), ref);
        ASSERT_TRUE(piece.ok()) << piece.status().to_string();
        if (ref.object == 1u) {
            saw_moved = true;
            EXPECT_TRUE(ref.overlay);
            auto original = read_object(store(), 1);
            ASSERT_TRUE(original.ok());
            ASSERT_EQ(piece->triangles.size(), original->triangles.size());
            for (std::uint32_t t = 0; t < piece->triangles.size(); ++t) {
                EXPECT_EQ(piece->triangle_ids[t], t);
                for (int c = 0; c < 3; ++c) {
                    EXPECT_EQ(piece->vertices[piece->triangles[t][c]],
                              up.apply(original->vertices[original->triangles[t][c]]));
                }
            }
        }
        if (ref.object == added.value()) {
            saw_added = true;
            EXPECT_EQ(piece->object_name, "crate");
        }
    }
    EXPECT_TRUE(saw_moved);
    EXPECT_TRUE(saw_added);
    EXPECT_EQ(whole.triangles, store().summary().triangles - 12 + 12);  // box 3 out, crate in
}

}  // namespace
}  // namespace proxima::massive
