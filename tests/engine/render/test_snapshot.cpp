// Offscreen snapshots (proxima/render/snapshot.hpp): a known scene (two intersecting boxes, one
// far away) rendered with a fixed camera on the machine's EGL context (llvmpipe in CI); pixels at
// projected positions must have the colour the results give them. In CI (environment variable CI
// set) the context must start; elsewhere the rendering tests skip when it cannot.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <string>

#include "proxima/query/query.hpp"
#include "proxima/render/snapshot.hpp"

namespace proxima::render {
namespace {

bool in_ci() {
    const char* ci = std::getenv("CI");
    return ci != nullptr && *ci != '\0';
}

NamedMesh box(const std::string& name, Vec3 lo, Vec3 hi) {
    NamedMesh m;
    m.name = name;
    for (int i = 0; i < 8; ++i) {
        m.mesh.vertices.push_back(
            {(i & 1) != 0 ? hi.x : lo.x, (i & 2) != 0 ? hi.y : lo.y, (i & 4) != 0 ? hi.z : lo.z});
    }
    m.mesh.triangles = {{0, 1, 3}, {0, 3, 2}, {4, 7, 5}, {4, 6, 7}, {0, 5, 1}, {0, 4, 5},
                        {2, 3, 7}, {2, 7, 6}, {0, 2, 6}, {0, 6, 4}, {1, 5, 7}, {1, 7, 3}};
    return m;
}

constexpr int W = 240;
constexpr int H = 120;

Camera front_camera() {
    Camera c;
    c.eye = {2.5, -10, 0.5};
    c.target = {2.5, 0, 0.5};
    c.up = {0, 0, 1};
    c.fov_degrees = 30;
    return c;
}

// Pixel of world point p seen by front_camera() (looking along +y, x to the right, z up).
std::pair<int, int> project(const Vec3& p) {
    const double t = 1.0 / std::tan(30.0 * 3.14159265358979323846 / 360.0);
    const double depth = p.y + 10.0;
    const double aspect = static_cast<double>(W) / H;
    const double nx = (p.x - 2.5) / depth * t / aspect;
    const double ny = (p.z - 0.5) / depth * t;
    return {static_cast<int>((nx + 1) / 2 * W), static_cast<int>((1 - ny) / 2 * H)};
}

bool is_red(Rgb c) {
    return c.r > 120 && c.g < 60 && c.b < 60;
}
bool is_grey(Rgb c) {
    return std::abs(c.r - c.g) < 6 && std::abs(c.g - c.b) < 6 && c.r > 50 && c.r < 200;
}
bool is_blue(Rgb c) {
    return c.b > 200 && c.r < 60;
}

struct Rendered {
    StatusOr<RenderResult> result = Status(StatusCode::internal, "not rendered");
    Colouring colouring;
};

// A: [0,1]^3; B: [0.5,1.5]x[0.2,0.8]x[0.2,0.8] crosses A's face x = 1 (its front face y = 0.2
// is cut by it; A's front face y = 0 touches nothing); C: [4,5]x[0,1]x[0,1], far.
Rendered render_known_scene(ProximityEngine& engine) {
    Rendered r;
    EXPECT_TRUE(engine.scene().add_object(box("A", {0, 0, 0}, {1, 1, 1})).ok());
    EXPECT_TRUE(engine.scene().add_object(box("B", {0.5, 0.2, 0.2}, {1.5, 0.8, 0.8})).ok());
    EXPECT_TRUE(engine.scene().add_object(box("C", {4, 0, 0}, {5, 1, 1})).ok());
    QueryRequest request;
    request.separation = true;
    request.collisions = true;
    request.tolerance = 0.01;
    auto answer = engine.query(request);
    EXPECT_TRUE(answer.ok()) << answer.status().to_string();
    if (!answer.ok()) {
        return r;
    }
    r.colouring = colour_results(engine.scene(), *answer);
    RenderOptions options;
    options.width = W;
    options.height = H;
    options.camera = front_camera();
    r.result = render(engine.scene(), r.colouring, options);
    return r;
}

void skip_without_egl(const Status& s) {
    if (s.code() == StatusCode::unavailable && !in_ci()) {
        GTEST_SKIP() << "no EGL context on this machine: " << s.message();
    }
}

TEST(Snapshot, ColoursFollowTheResults) {
    setenv("MESA_SHADER_CACHE_DISABLE", "true", 0);
    ProximityEngine engine;
    Rendered r = render_known_scene(engine);
    skip_without_egl(r.result.status());
    ASSERT_TRUE(r.result.ok()) << r.result.status().to_string();
    const Image& image = r.result->image;
    ASSERT_EQ(image.width, W);
    ASSERT_EQ(image.height, H);
    // The colouring: B's front face red (it crosses A), A's front face and C grey.
    ASSERT_EQ(r.colouring.triangles.size(), 3u);
    EXPECT_FALSE(r.colouring.triangles[1].empty());
    EXPECT_TRUE(r.colouring.triangles[2].empty());  // C touches nothing: all base grey
    ASSERT_FALSE(r.colouring.segments.empty());     // C's closest pair

    auto [bx, by] = project({1.3, 0.2, 0.5});  // B's front face, right of A
    EXPECT_TRUE(is_red(image.at(bx, by))) << "B at " << bx << "," << by;
    auto [ax, ay] = project({0.25, 0, 0.5});  // A's front face
    EXPECT_TRUE(is_grey(image.at(ax, ay))) << "A at " << ax << "," << ay;
    auto [cx, cy] = project({4.5, 0, 0.2});  // C's front face, below any segment
    EXPECT_TRUE(is_grey(image.at(cx, cy))) << "C at " << cx << "," << cy;
    EXPECT_EQ(image.at(1, 1), DEFAULT_BACKGROUND);
    EXPECT_EQ(image.at(W - 2, H - 2), DEFAULT_BACKGROUND);
    // The closest pair B-C is a segment across the gap between x = 1.5 and x = 4.
    auto [gx, gy] = project({2.75, 0, 0.5});
    (void)gy;
    bool blue = false;
    for (int y = 0; y < H; ++y) {
        blue = blue || is_blue(image.at(gx, y));
    }
    EXPECT_TRUE(blue) << "no segment pixel in column " << gx;

    // PNG round trip at the asked size, same pixels.
    auto png = encode_png(image);
    ASSERT_TRUE(png.ok()) << png.status().to_string();
    EXPECT_EQ(png->substr(1, 3), "PNG");
    auto decoded = decode_png(*png);
    ASSERT_TRUE(decoded.ok()) << decoded.status().to_string();
    EXPECT_EQ(decoded->width, W);
    EXPECT_EQ(decoded->height, H);
    EXPECT_EQ(decoded->rgb, image.rgb);

    // Deterministic: a second render gives the same pixels.
    ProximityEngine again;
    Rendered r2 = render_known_scene(again);
    ASSERT_TRUE(r2.result.ok());
    EXPECT_EQ(r2.result->image.rgb, image.rgb);
}

TEST(Snapshot, DefaultCameraShowsTheWholeScene) {
    setenv("MESA_SHADER_CACHE_DISABLE", "true", 0);
    Scene scene;
    ASSERT_TRUE(scene.add_object(box("A", {0, 0, 0}, {1, 1, 1})).ok());
    ASSERT_TRUE(scene.add_object(box("C", {4, 0, 0}, {5, 1, 1})).ok());
    RenderOptions options;
    options.width = 64;
    options.height = 48;
    auto r = render(scene, {}, options);
    skip_without_egl(r.status());
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    // Every border pixel is background (the fitted view leaves a margin), and some are not.
    int covered = 0;
    for (int y = 0; y < 48; ++y) {
        for (int x = 0; x < 64; ++x) {
            const bool border = x == 0 || y == 0 || x == 63 || y == 47;
            if (border) {
                EXPECT_EQ(r->image.at(x, y), DEFAULT_BACKGROUND) << x << "," << y;
            } else if (r->image.at(x, y) != DEFAULT_BACKGROUND) {
                ++covered;
                EXPECT_TRUE(is_grey(r->image.at(x, y)));
            }
        }
    }
    EXPECT_GT(covered, 64 * 48 / 20);
    EXPECT_EQ(r->camera.target, (Vec3{2.5, 0.5, 0.5}));
}

TEST(Snapshot, BadInputIsInvalidArgument) {
    Scene scene;
    ASSERT_TRUE(scene.add_object(box("A", {0, 0, 0}, {1, 1, 1})).ok());
    RenderOptions options;
    options.width = 0;
    EXPECT_EQ(render(scene, {}, options).status().code(), StatusCode::invalid_argument);
    options.width = MAX_SNAPSHOT_SIDE + 1;
    options.height = 10;
    EXPECT_EQ(render(scene, {}, options).status().code(), StatusCode::invalid_argument);
    options.width = 10;
    Camera c = front_camera();
    c.eye = c.target;
    options.camera = c;
    EXPECT_EQ(render(scene, {}, options).status().code(), StatusCode::invalid_argument);
    c = front_camera();
    c.up = {0, 1, 0};  // parallel to the view direction
    options.camera = c;
    EXPECT_EQ(render(scene, {}, options).status().code(), StatusCode::invalid_argument);
    options.camera.reset();
    Colouring wrong;
    wrong.triangles = {std::vector<Rgb>(3, BASE_GREY)};  // 3 colours, 12 triangles
    EXPECT_EQ(render(scene, wrong, options).status().code(), StatusCode::invalid_argument);
    EXPECT_EQ(decode_png("not a png").status().code(), StatusCode::invalid_argument);
}

TEST(Snapshot, ToleranceIsAmberCollisionsRed) {
    Scene scene;
    ASSERT_TRUE(scene.add_object(box("A", {0, 0, 0}, {1, 1, 1})).ok());
    QueryResult result;
    result.tolerance = {{0, 0, 0, 5, 0.1}, {0, 1, 0, 7, 0.1}};
    result.collisions = {{0, 1, 0, 9, 0}};
    Colouring c = colour_results(scene, result);
    ASSERT_EQ(c.triangles.size(), 1u);
    ASSERT_EQ(c.triangles[0].size(), 12u);
    EXPECT_EQ(c.triangles[0][0], TOLERANCE_AMBER);
    EXPECT_EQ(c.triangles[0][1], COLLISION_RED);  // both: red wins
    EXPECT_EQ(c.triangles[0][5], TOLERANCE_AMBER);
    EXPECT_EQ(c.triangles[0][9], COLLISION_RED);
    EXPECT_EQ(c.triangles[0][2], BASE_GREY);
    Colouring none = colour_results(scene, result, {false, false, false});
    EXPECT_TRUE(none.triangles[0].empty());
}

}  // namespace
}  // namespace proxima::render
