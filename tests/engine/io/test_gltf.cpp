// The native glTF 2.0 reader (engine/src/io/gltf.cpp), through read_mesh_from_memory and
// read_mesh: .gltf with base64 and external buffers, .glb, index types, strips and fans, node
// transforms and instancing, strides, sparse and quantized accessors, and errors naming the
// problem instead of crashes or huge allocations.

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "proxima/io/mesh_io.hpp"
#include "support/mesh_files.hpp"

namespace proxima {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;

using test::no_weld;
using test::temp_path;
using test::write_bytes;

std::string base64(const std::string& bytes) {
    static const char* const ALPHABET =
        "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string out;
    std::size_t i = 0;
    for (; i + 2 < bytes.size(); i += 3) {
        const std::uint32_t v =
            static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[i])) << 16 |
            static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[i + 1])) << 8 |
            static_cast<unsigned char>(bytes[i + 2]);
        for (int k = 18; k >= 0; k -= 6) {
            out += ALPHABET[(v >> k) & 63];
        }
    }
    if (i + 1 == bytes.size()) {
        const std::uint32_t v = static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[i]))
                                << 16;
        out += ALPHABET[(v >> 18) & 63];
        out += ALPHABET[(v >> 12) & 63];
        out += "==";
    } else if (i + 2 == bytes.size()) {
        const std::uint32_t v =
            static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[i])) << 16 |
            static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[i + 1])) << 8;
        out += ALPHABET[(v >> 18) & 63];
        out += ALPHABET[(v >> 12) & 63];
        out += ALPHABET[(v >> 6) & 63];
        out += '=';
    }
    return out;
}

template <class T>
std::string bytes_of(const std::vector<T>& values) {
    std::string out(values.size() * sizeof(T), '\0');
    std::memcpy(out.data(), values.data(), out.size());
    return out;
}

std::string u32(std::uint32_t v) {
    return std::string{static_cast<char>(v & 0xff), static_cast<char>((v >> 8) & 0xff),
                       static_cast<char>((v >> 16) & 0xff), static_cast<char>(v >> 24)};
}

// A glTF document and its one binary buffer, written as .gltf (base64 data URI) or .glb.
struct Builder {
    Json doc = {{"asset", {{"version", "2.0"}}}};
    std::string bin;

    std::size_t view(const std::string& bytes, std::optional<int> stride = std::nullopt) {
        while (bin.size() % 4 != 0) {
            bin += '\0';
        }
        Json v = {{"buffer", 0}, {"byteOffset", bin.size()}, {"byteLength", bytes.size()}};
        if (stride) {
            v["byteStride"] = *stride;
        }
        bin += bytes;
        doc["bufferViews"].push_back(v);
        return doc["bufferViews"].size() - 1;
    }
    std::size_t accessor(Json accessor) {
        doc["accessors"].push_back(std::move(accessor));
        return doc["accessors"].size() - 1;
    }
    std::size_t positions(const std::vector<float>& xyz) {
        const std::size_t v = view(bytes_of(xyz));
        return accessor({{"bufferView", v},
                         {"componentType", 5126},
                         {"count", xyz.size() / 3},
                         {"type", "VEC3"}});
    }
    template <class T>
    std::size_t indices(const std::vector<T>& values) {
        const int type = sizeof(T) == 1 ? 5121 : sizeof(T) == 2 ? 5123 : 5125;
        const std::size_t v = view(bytes_of(values));
        return accessor({{"bufferView", v},
                         {"componentType", type},
                         {"count", values.size()},
                         {"type", "SCALAR"}});
    }
    std::size_t mesh(const std::vector<Json>& primitives) {
        doc["meshes"].push_back({{"primitives", primitives}});
        return doc["meshes"].size() - 1;
    }
    std::size_t node(Json node) {
        doc["nodes"].push_back(std::move(node));
        return doc["nodes"].size() - 1;
    }
    void scene(const std::vector<std::size_t>& roots) {
        doc["scenes"].push_back({{"nodes", roots}});
        doc["scene"] = doc["scenes"].size() - 1;
    }

    std::string gltf() const {
        Json out = doc;
        if (!bin.empty()) {
            out["buffers"] =
                Json::array({{{"byteLength", bin.size()},
                              {"uri", "data:application/octet-stream;base64," + base64(bin)}}});
        }
        return out.dump();
    }
    std::string glb() const {
        Json out = doc;
        if (!bin.empty()) {
            out["buffers"] = Json::array({{{"byteLength", bin.size()}}});
        }
        std::string json = out.dump();
        while (json.size() % 4 != 0) {
            json += ' ';
        }
        std::string padded = bin;
        while (padded.size() % 4 != 0) {
            padded += '\0';
        }
        std::string file =
            "glTF" + u32(2) + u32(0) + u32(static_cast<std::uint32_t>(json.size())) + "JSON" + json;
        if (!padded.empty()) {
            file +=
                u32(static_cast<std::uint32_t>(padded.size())) + std::string("BIN\0", 4) + padded;
        }
        const std::string length = u32(static_cast<std::uint32_t>(file.size()));
        file.replace(8, 4, length);
        return file;
    }
};

// One triangle (0,0,0) (1,0,0) (0,1,0), indexed with u16, in one node.
Builder triangle() {
    Builder b;
    const std::size_t p = b.positions({0, 0, 0, 1, 0, 0, 0, 1, 0});
    const std::size_t i = b.indices(std::vector<std::uint16_t>{0, 1, 2});
    const std::size_t m = b.mesh({{{"attributes", {{"POSITION", p}}}, {"indices", i}}});
    b.scene({b.node({{"mesh", m}})});
    return b;
}

StatusOr<TriangleMesh> read_text(const std::string& gltf) {
    return read_mesh_from_memory(gltf, "gltf", "test.gltf", no_weld());
}
StatusOr<TriangleMesh> read_doc(const Json& doc) {
    return read_text(doc.dump());
}

// The read fails with a message that names the file and holds every fragment.
void expect_refused(const StatusOr<TriangleMesh>& read, const std::vector<std::string>& fragments,
                    const std::string& name = "test.gltf") {
    ASSERT_FALSE(read.ok()) << "read " << read->triangles.size() << " triangles";
    const std::string& message = read.status().message();
    EXPECT_NE(message.find("mesh file '" + name + "'"), std::string::npos) << message;
    for (const auto& fragment : fragments) {
        EXPECT_NE(message.find(fragment), std::string::npos)
            << "'" << fragment << "' not in: " << message;
    }
}

void expect_triangles(const TriangleMesh& mesh, const std::vector<TriangleIndices>& expected) {
    ASSERT_EQ(mesh.triangles.size(), expected.size());
    for (std::size_t t = 0; t < expected.size(); ++t) {
        EXPECT_EQ(mesh.triangles[t], expected[t]) << "triangle " << t;
    }
}

const std::vector<Vec3> TRIANGLE = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};

// ---------------------------------------------------------------------------------------------
// What is read

TEST(Gltf, SingleTriangleFromBase64DataUri) {
    const auto read = read_text(triangle().gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->vertices, TRIANGLE);
    expect_triangles(*read, {{0, 1, 2}});
    // The other media type the spec names, and the file extension with a dot, any case.
    Builder b = triangle();
    Json doc = Json::parse(b.gltf());
    std::string uri = doc["buffers"][0]["uri"];
    uri.replace(0, uri.find(';'), "data:application/gltf-buffer");
    doc["buffers"][0]["uri"] = uri;
    const auto other = read_mesh_from_memory(doc.dump(), ".GLTF", "test.gltf", no_weld());
    ASSERT_TRUE(other.ok()) << other.status().to_string();
    EXPECT_EQ(other->vertices, TRIANGLE);
}

TEST(Gltf, SingleTriangleFromGlb) {
    const auto read = read_mesh_from_memory(triangle().glb(), "glb", "test.glb", no_weld());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->vertices, TRIANGLE);
    expect_triangles(*read, {{0, 1, 2}});
}

TEST(Gltf, GlbFromAFile) {
    const std::string path = temp_path("triangle.glb");
    write_bytes(path, triangle().glb());
    const auto read = read_mesh(path, no_weld());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->vertices, TRIANGLE);
    fs::remove(path);
}

// An external buffer beside the .gltf, its name percent-encoded in the URI.
TEST(Gltf, ExternalBufferBesideTheFile) {
    Builder b = triangle();
    const std::string bin_name = "proxima_gltf_" + std::to_string(::getpid()) + " buffer.bin";
    write_bytes(::testing::TempDir() + bin_name, b.bin);
    Json doc = b.doc;
    std::string uri = bin_name;
    uri.replace(uri.find(' '), 1, "%20");
    doc["buffers"] = Json::array({{{"byteLength", b.bin.size()}, {"uri", uri}}});
    const std::string path = temp_path("external.gltf");
    write_bytes(path, doc.dump());
    const auto read = read_mesh(path, no_weld());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->vertices, TRIANGLE);
    // From memory, nothing else is read.
    const auto memory = read_doc(doc);
    ASSERT_FALSE(memory.ok());
    EXPECT_EQ(memory.status().code(), StatusCode::not_found);
    EXPECT_NE(memory.status().message().find("buffer 0"), std::string::npos);
    fs::remove(path);
    fs::remove(::testing::TempDir() + bin_name);
}

TEST(Gltf, IndicesOfEveryComponentType) {
    const std::vector<float> quad = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
    const std::vector<TriangleIndices> expected = {{0, 1, 2}, {0, 2, 3}};
    for (int type : {5121, 5123, 5125}) {
        Builder b;
        const std::size_t p = b.positions(quad);
        std::size_t i = 0;
        if (type == 5121) {
            i = b.indices(std::vector<std::uint8_t>{0, 1, 2, 0, 2, 3});
        } else if (type == 5123) {
            i = b.indices(std::vector<std::uint16_t>{0, 1, 2, 0, 2, 3});
        } else {
            i = b.indices(std::vector<std::uint32_t>{0, 1, 2, 0, 2, 3});
        }
        b.scene(
            {b.node({{"mesh", b.mesh({{{"attributes", {{"POSITION", p}}}, {"indices", i}}})}})});
        for (const bool binary : {false, true}) {
            const auto read = binary ? read_mesh_from_memory(b.glb(), "glb", "t.glb", no_weld())
                                     : read_text(b.gltf());
            ASSERT_TRUE(read.ok()) << type << ": " << read.status().to_string();
            EXPECT_EQ(read->vertices.size(), 4u);
            expect_triangles(*read, expected);
        }
    }
}

TEST(Gltf, PrimitiveWithoutIndicesUsesItsVerticesInOrder) {
    Builder b;
    const std::size_t p = b.positions({0, 0, 0, 1, 0, 0, 0, 1, 0, 5, 5, 5, 6, 5, 5, 5, 6, 5});
    b.scene({b.node({{"mesh", b.mesh({{{"attributes", {{"POSITION", p}}}}})}})});
    const auto read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    expect_triangles(*read, {{0, 1, 2}, {3, 4, 5}});
}

TEST(Gltf, StripsAndFansAreTriangulatedAsTheSpecSays) {
    Builder b;
    const std::size_t p = b.positions({0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0, 2, 1, 0});
    const std::size_t five = b.indices(std::vector<std::uint16_t>{0, 1, 2, 3, 4});
    const std::size_t two = b.indices(std::vector<std::uint16_t>{0, 1});
    const std::size_t m = b.mesh({
        {{"attributes", {{"POSITION", p}}}, {"indices", five}, {"mode", 5}},  // strip
        {{"attributes", {{"POSITION", p}}}, {"indices", five}, {"mode", 6}},  // fan
        {{"attributes", {{"POSITION", p}}}, {"indices", two}, {"mode", 5}},   // too short: nothing
        {{"attributes", {{"POSITION", p}}}, {"indices", five}, {"mode", 0}},  // points: dropped
        {{"attributes", {{"POSITION", p}}}, {"indices", two}, {"mode", 1}},   // lines: dropped
        {{"attributes", {{"POSITION", p}}}, {"indices", five}, {"mode", 3}},  // line strip
    });
    b.scene({b.node({{"mesh", m}})});
    const auto read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    // Primitives sharing a POSITION accessor share its vertices.
    EXPECT_EQ(read->vertices.size(), 5u);
    expect_triangles(*read, {{0, 1, 2}, {1, 3, 2}, {2, 3, 4}, {1, 2, 0}, {2, 3, 0}, {3, 4, 0}});
}

// parent: matrix = translate (10, 20, 30) * scale 2; child: T (1, 0, 0) * R (180 degrees about
// z, written unnormalised) * S (1, 2, 3). Every product is exact in double.
TEST(Gltf, NodeHierarchyComposesMatrixAndTrs) {
    Builder b;
    const std::size_t p = b.positions({1, 0, 0, 0, 1, 0, 0, 0, 1});
    const std::size_t m = b.mesh({{{"attributes", {{"POSITION", p}}}}});
    const std::size_t child = b.node({{"mesh", m},
                                      {"translation", {1, 0, 0}},
                                      {"rotation", {0, 0, 2, 0}},
                                      {"scale", {1, 2, 3}}});
    const std::size_t parent =
        b.node({{"children", Json::array({child})},
                {"matrix", {2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0, 10, 20, 30, 1}}});
    b.scene({parent});
    const auto read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    // child: (1,0,0) -> S (1,0,0) -> R (-1,0,0) -> T (0,0,0); parent -> (10,20,30)
    //        (0,1,0) -> (0,2,0) -> (0,-2,0) -> (1,-2,0) -> (12,16,30)
    //        (0,0,1) -> (0,0,3) -> (0,0,3) -> (1,0,3) -> (12,20,36)
    const std::vector<Vec3> expected = {{10, 20, 30}, {12, 16, 30}, {12, 20, 36}};
    EXPECT_EQ(read->vertices, expected);
    expect_triangles(*read, {{0, 1, 2}});
}

TEST(Gltf, RotationQuaternionAboutZ) {
    Builder b;
    const std::size_t p = b.positions({1, 0, 0, 0, 1, 0, 0, 0, 1});
    const double h = std::sqrt(0.5);
    const std::size_t m = b.mesh({{{"attributes", {{"POSITION", p}}}}});
    b.scene({b.node({{"mesh", m}, {"rotation", {0, 0, h, h}}})});  // 90 degrees about z
    const auto read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    const std::vector<Vec3> expected = {{0, 1, 0}, {-1, 0, 0}, {0, 0, 1}};
    for (std::size_t v = 0; v < 3; ++v) {
        for (int k = 0; k < 3; ++k) {
            EXPECT_NEAR(read->vertices[v][k], expected[v][k], 1e-15) << v << " " << k;
        }
    }
}

TEST(Gltf, OneMeshInstancedByTwoNodes) {
    Builder b = triangle();
    b.doc["nodes"][0]["translation"] = {0, 0, 5};
    b.node({{"mesh", 0}, {"translation", {100, 0, 0}}});
    b.doc["scenes"][0]["nodes"] = {0, 1};
    const auto read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    const std::vector<Vec3> expected = {{0, 0, 5},   {1, 0, 5},   {0, 1, 5},
                                        {100, 0, 0}, {101, 0, 0}, {100, 1, 0}};
    EXPECT_EQ(read->vertices, expected);
    expect_triangles(*read, {{0, 1, 2}, {3, 4, 5}});
}

TEST(Gltf, SceneSelection) {
    Builder b = triangle();
    b.node({{"mesh", 0}, {"translation", {7, 0, 0}}});
    b.scene({1});  // "scene": 1 picks the second scene
    auto read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    ASSERT_EQ(read->vertices.size(), 3u);
    EXPECT_EQ(read->vertices[0], (Vec3{7, 0, 0}));
    // Without "scene": the first scene.
    b.doc.erase("scene");
    read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->vertices, TRIANGLE);
    // Without scenes: every root node.
    b.doc.erase("scenes");
    read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->vertices.size(), 6u);
}

// Positions interleaved with normals (stride 24); the normals are never read or validated.
TEST(Gltf, ByteStrideAndUnusedAttributes) {
    Builder b;
    const std::vector<float> interleaved = {0, 0, 0, 9, 9, 9, 1, 0, 0, 9, 9, 9, 0, 1, 0, 9, 9, 9};
    const std::size_t v = b.view(bytes_of(interleaved), 24);
    const std::size_t p =
        b.accessor({{"bufferView", v}, {"componentType", 5126}, {"count", 3}, {"type", "VEC3"}});
    const std::size_t m =
        b.mesh({{{"attributes", {{"POSITION", p}, {"NORMAL", 99}, {"TEXCOORD_0", "junk"}}}}});
    b.scene({b.node({{"mesh", m}})});
    const auto read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->vertices, TRIANGLE);
}

TEST(Gltf, SparseAccessors) {
    Builder b;
    const std::size_t base = b.view(bytes_of(std::vector<float>{0, 0, 0, 5, 5, 5, 0, 1, 0}));
    const std::size_t sparse_indices = b.view(bytes_of(std::vector<std::uint16_t>{1}));
    const std::size_t sparse_values = b.view(bytes_of(std::vector<float>{1, 0, 0}));
    const Json sparse = {{"count", 1},
                         {"indices", {{"bufferView", sparse_indices}, {"componentType", 5123}}},
                         {"values", {{"bufferView", sparse_values}}}};
    const std::size_t p = b.accessor({{"bufferView", base},
                                      {"componentType", 5126},
                                      {"count", 3},
                                      {"type", "VEC3"},
                                      {"sparse", sparse}});
    // Without a bufferView: zeros, then the sparse values.
    const std::size_t q =
        b.accessor({{"componentType", 5126}, {"count", 3}, {"type", "VEC3"}, {"sparse", sparse}});
    b.scene({b.node({{"mesh", b.mesh({{{"attributes", {{"POSITION", p}}}},
                                      {{"attributes", {{"POSITION", q}}}}})}})});
    const auto read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    const std::vector<Vec3> expected = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0},
                                        {0, 0, 0}, {1, 0, 0}, {0, 0, 0}};
    EXPECT_EQ(read->vertices, expected);
    // A sparse index beyond the accessor is refused.
    Builder bad = b;
    bad.bin.replace(bad.doc["bufferViews"][sparse_indices]["byteOffset"].get<std::size_t>(), 2,
                    bytes_of(std::vector<std::uint16_t>{3}));
    expect_refused(read_text(bad.gltf()), {"sparse", "is 3, out of range (3 elements)"});
}

TEST(Gltf, QuantizedPositionsWithKhrMeshQuantization) {
    Builder b;
    const std::size_t v =
        b.view(bytes_of(std::vector<std::int16_t>{0, 0, 0, 0, 32767, 0, 0, 0, -32768, 0, 0, 0}), 8);
    const std::size_t p = b.accessor({{"bufferView", v},
                                      {"componentType", 5122},
                                      {"normalized", true},
                                      {"count", 3},
                                      {"type", "VEC3"}});
    b.scene({b.node({{"mesh", b.mesh({{{"attributes", {{"POSITION", p}}}}})}})});
    // Without the extension, POSITION must be FLOAT.
    expect_refused(read_text(b.gltf()),
                   {"accessor 0", "SHORT (5122)", "must be FLOAT", "KHR_mesh_quantization"});
    b.doc["extensionsUsed"] = Json::array({"KHR_mesh_quantization"});
    b.doc["extensionsRequired"] = Json::array({"KHR_mesh_quantization"});
    const auto read = read_text(b.gltf());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    const std::vector<Vec3> expected = {{0, 0, 0}, {1, 0, 0}, {-1, 0, 0}};
    EXPECT_EQ(read->vertices, expected);
}

TEST(Gltf, RealSampleTwoCylinderEngine) {
    const std::string path = std::string(PROXIMA_DATA_DIR) + "/meshes/gltf/2CylinderEngine.glb";
    if (!fs::exists(path)) {
        GTEST_SKIP() << "sample not found: " << path;
    }
    const auto read = read_mesh(path, no_weld());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    // assimp read the same number of triangles (75,730 in its meshes, instanced to 121,496).
    EXPECT_EQ(read->triangles.size(), 121496u);
    // Every instance's vertices (primitives of a mesh share POSITION accessors here).
    EXPECT_EQ(read->vertices.size(), 84657u);
    for (const auto& t : read->triangles) {
        for (const auto i : t) {
            ASSERT_LT(i, read->vertices.size());
        }
    }
    Vec3 lo{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
            std::numeric_limits<double>::infinity()};
    Vec3 hi = -lo;
    for (const auto& v : read->vertices) {
        for (int k = 0; k < 3; ++k) {
            ASSERT_TRUE(std::isfinite(v[k]));
            lo[k] = std::min(lo[k], v[k]);
            hi[k] = std::max(hi[k], v[k]);
        }
    }
    // The box of every transformed position, computed independently (Python, in double).
    const Vec3 expected_lo{-371.6922629127621, -180.9715576171875, -139.9999929500657};
    const Vec3 expected_hi{371.69216918961064, 92.04156168904416, 127.99999618810878};
    for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(lo[k], expected_lo[k], 1e-9) << k;
        EXPECT_NEAR(hi[k], expected_hi[k], 1e-9) << k;
    }
    // Welded (the default), the triangles stay.
    const auto welded = read_mesh(path);
    ASSERT_TRUE(welded.ok()) << welded.status().to_string();
    EXPECT_EQ(welded->triangles.size(), 121496u);
}

// ---------------------------------------------------------------------------------------------
// What is refused, each with a message naming the file and the problem

TEST(Gltf, IndexOutOfRangeIsRefused) {
    Builder b = triangle();
    b.bin.replace(36 + 2, 2, bytes_of(std::vector<std::uint16_t>{7}));
    expect_refused(read_text(b.gltf()),
                   {"mesh 0, primitive 0", "index 1 is 7, out of range (3 vertices)"});
}

TEST(Gltf, AccessorPastItsBufferViewIsRefused) {
    Builder b = triangle();
    b.doc["accessors"][0]["count"] = 4;
    expect_refused(read_text(b.gltf()),
                   {"accessor 0 (POSITION of mesh 0, primitive 0)", "4 elements of 12 bytes",
                    "run past the end of bufferView 0 (36 bytes)"});
    b = triangle();
    b.doc["accessors"][1]["byteOffset"] = 2;
    expect_refused(read_text(b.gltf()), {"accessor 1 (indices of mesh 0, primitive 0)",
                                         "from byte 2, run past the end of bufferView 1"});
}

TEST(Gltf, BufferViewPastItsBufferIsRefused) {
    Builder b = triangle();
    b.doc["bufferViews"][1]["byteLength"] = 8;
    expect_refused(read_text(b.gltf()),
                   {"bufferView 1", "bytes 36 + 8 run past the end of buffer 0 (42 bytes)"});
    // A buffer whose data is shorter than its byteLength.
    Json doc = Json::parse(triangle().gltf());
    doc["buffers"][0]["byteLength"] = 100;
    expect_refused(read_doc(doc), {"buffer 0 declares byteLength 100", "holds 42 bytes"});
}

TEST(Gltf, BadByteStrideIsRefused) {
    Builder b = triangle();
    b.doc["bufferViews"][0]["byteStride"] = 6;
    expect_refused(read_text(b.gltf()), {"bufferView 0: byteStride 6"});
    b.doc["bufferViews"][0]["byteStride"] = 8;
    expect_refused(read_text(b.gltf()), {"byteStride 8 is shorter than the elements"});
}

TEST(Gltf, BadBase64IsRefused) {
    Json doc = Json::parse(triangle().gltf());
    std::string uri = doc["buffers"][0]["uri"];
    uri[uri.find(',') + 5] = '*';
    doc["buffers"][0]["uri"] = uri;
    expect_refused(read_doc(doc), {"buffer 0: invalid base64", "'*'"});
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64,AAAAA";
    expect_refused(read_doc(doc), {"buffer 0: invalid base64"});
    doc["buffers"][0]["uri"] = "data:application/octet-stream,AAAA";
    expect_refused(read_doc(doc), {"buffer 0: a data URI that is not base64"});
}

TEST(Gltf, MissingBufferIsRefused) {
    Json doc = triangle().doc;
    // A .gltf buffer without a uri.
    doc["buffers"] = Json::array({{{"byteLength", 44}}});
    expect_refused(read_doc(doc), {"buffer 0 has no uri"});
    // An external file, from memory.
    doc["buffers"][0]["uri"] = "missing.bin";
    expect_refused(read_doc(doc), {"buffer 0 ('missing.bin') cannot be loaded"});
    // From a file: not beside it.
    const std::string path = temp_path("missing_buffer.gltf");
    write_bytes(path, doc.dump());
    expect_refused(read_mesh(path), {"buffer 0 ('missing.bin') cannot be loaded"}, path);
    // No buffers at all.
    doc.erase("buffers");
    expect_refused(read_doc(doc), {"bufferView 0 refers to buffer 0, out of range"});
    // A .glb without a BIN chunk.
    Builder b = triangle();
    std::string glb = b.glb();
    const std::uint32_t json_length =
        static_cast<unsigned char>(glb[12]) | static_cast<unsigned char>(glb[13]) << 8;
    glb.resize(20 + json_length);
    glb.replace(8, 4, u32(static_cast<std::uint32_t>(glb.size())));
    expect_refused(read_mesh_from_memory(glb, "glb", "test.glb"),
                   {"buffer 0 has no uri and the file has no BIN chunk"}, "test.glb");
    fs::remove(path);
}

TEST(Gltf, NodeCyclesAreRefused) {
    Builder b = triangle();
    b.node({{"children", Json::array({2})}});
    b.node({{"children", Json::array({1})}});
    expect_refused(read_text(b.gltf()), {"nodes form a cycle through node"});
    b.doc["nodes"][1]["children"] = Json::array({1});
    expect_refused(read_text(b.gltf()), {"nodes form a cycle: node 1 is its own child"});
}

TEST(Gltf, NodeWithTwoParentsIsRefused) {
    Builder b = triangle();
    b.node({{"children", Json::array({0})}});
    b.node({{"children", Json::array({0})}});
    b.doc["scenes"][0]["nodes"] = {1, 2};
    expect_refused(read_text(b.gltf()), {"node 0 has two parents, node 1 and node 2"});
    // A scene listing a node twice, or a node that is not a root.
    b = triangle();
    b.doc["scenes"][0]["nodes"] = {0, 0};
    expect_refused(read_text(b.gltf()), {"scene 0 lists node 0 twice"});
    b = triangle();
    b.node({{"children", Json::array({0})}});
    b.doc["scenes"][0]["nodes"] = {1, 0};
    expect_refused(read_text(b.gltf()), {"scene 0 lists node 0, which is a child of node 1"});
    b.doc["nodes"][1]["children"] = {0, 0};
    b.doc["scenes"][0]["nodes"] = Json::array({1});
    expect_refused(read_text(b.gltf()), {"node 1 lists child 0 twice"});
}

TEST(Gltf, GltfOneIsRefused) {
    Json doc = triangle().doc;
    doc["asset"]["version"] = "1.0";
    expect_refused(read_doc(doc), {"glTF 1.0 is not supported, convert it to glTF 2.0"});
    // glTF 1.0 without asset.version: its top-level dictionaries give it away.
    expect_refused(read_text(std::string(R"({"meshes":{"m":{"primitives":[]}}})")), {"glTF 1.0"});
    // Binary glTF 1.0 (KHR_binary_glTF).
    std::string glb = triangle().glb();
    glb.replace(4, 4, u32(1));
    expect_refused(read_mesh_from_memory(glb, "glb", "test.glb"), {"glTF 1.0"}, "test.glb");
    doc["asset"]["version"] = "3.0";
    expect_refused(read_doc(doc), {"glTF version '3.0' is not supported"});
    doc.erase("asset");
    expect_refused(read_doc(doc), {"no asset.version"});
}

TEST(Gltf, RequiredUnknownExtensionIsRefused) {
    Json doc = triangle().doc;
    doc["extensionsUsed"] = Json::array({"KHR_draco_mesh_compression"});
    doc["extensionsRequired"] = Json::array({"KHR_draco_mesh_compression"});
    expect_refused(read_doc(doc), {"requires glTF extension 'KHR_draco_mesh_compression'"});
    // Extensions that only used (with the plain data as fallback), or that change no geometry,
    // are fine.
    Builder b = triangle();
    b.doc["extensionsUsed"] = {"KHR_draco_mesh_compression", "KHR_texture_transform"};
    b.doc["extensionsRequired"] = Json::array({"KHR_texture_transform"});
    const auto read = read_text(b.gltf());
    EXPECT_TRUE(read.ok()) << read.status().to_string();
}

TEST(Gltf, WrongPositionTypeIsRefused) {
    Builder b = triangle();
    b.doc["accessors"][0]["type"] = "VEC2";
    expect_refused(read_text(b.gltf()), {"accessor 0 (POSITION of mesh 0, primitive 0): type VEC2, "
                                         "VEC3 expected"});
    b = triangle();
    b.doc["accessors"][0]["componentType"] = 5125;
    expect_refused(read_text(b.gltf()), {"UNSIGNED_INT (5125), POSITION must be FLOAT (5126)"});
    b = triangle();
    b.doc["accessors"][1]["componentType"] = 5126;
    b.doc["accessors"][1]["count"] = 1;
    expect_refused(read_text(b.gltf()), {"indices of mesh 0, primitive 0", "FLOAT (5126)"});
    b = triangle();
    b.doc["accessors"][0]["componentType"] = 5000;
    expect_refused(read_text(b.gltf()), {"componentType 5000 is not a glTF component type"});
    b = triangle();
    b.doc["accessors"][0]["type"] = "VEC7";
    expect_refused(read_text(b.gltf()), {"'type' must be SCALAR, VEC2"});
}

TEST(Gltf, HugeCountsWithTinyDataAreRefused) {
    Builder b = triangle();
    b.doc["accessors"][0]["count"] = 4000000000u;
    expect_refused(read_text(b.gltf()), {"4000000000 elements", "run past the end"});
    b.doc["accessors"][0]["count"] = std::numeric_limits<std::uint64_t>::max();
    expect_refused(read_text(b.gltf()), {"run past the end"});
    // Without a bufferView an accessor is zeros: its count is bounded by the output limit.
    b = triangle();
    b.doc["accessors"][0].erase("bufferView");
    b.doc["accessors"][0]["count"] = 300000000;
    b.doc["meshes"][0]["primitives"][0].erase("indices");
    expect_refused(read_text(b.gltf()), {"would produce more than 1048576 vertices"});
}

// A few hundred bytes instancing a 300,000-triangle mesh (an index accessor of zeros) 4 times:
// refused before anything is allocated.
TEST(Gltf, InstancingBeyondTheOutputLimitIsRefused) {
    Builder b = triangle();
    b.doc["accessors"][1].erase("bufferView");
    b.doc["accessors"][1]["count"] = 900000;
    const auto one = read_text(b.gltf());
    ASSERT_TRUE(one.ok()) << one.status().to_string();
    EXPECT_EQ(one->triangles.size(), 300000u);
    for (int i = 0; i < 3; ++i) {
        b.node({{"mesh", 0}});
    }
    b.doc["scenes"][0]["nodes"] = {0, 1, 2, 3};
    expect_refused(read_text(b.gltf()),
                   {"would produce more than 1048576 triangles", "at mesh 0 of node 3"});
}

TEST(Gltf, WrongJsonTypesAreRefused) {
    struct Case {
        std::string pointer;  // JSON pointer of the field to replace
        Json value;
        std::string fragment;
    };
    const std::vector<Case> cases = {
        {"/accessors/0/count", "3",
         "accessor 0 (POSITION of mesh 0, primitive 0): 'count' must be a non-negative integer, "
         "found \"3\""},
        {"/accessors/0/count", -3, "'count' must be a non-negative integer, found -3"},
        {"/accessors/0/count", 1.5, "found 1.5"},
        {"/accessors/0/count", 0, "count is 0"},
        {"/accessors/0/byteOffset", -4, "'byteOffset' must be a non-negative integer"},
        {"/accessors/0/normalized", 1, "'normalized' must be true or false"},
        {"/accessors/0/bufferView", Json::array(),
         "'bufferView' must be a non-negative integer, found an array"},
        {"/bufferViews/0/byteLength", "36",
         "bufferView 0: 'byteLength' must be a non-negative integer"},
        {"/bufferViews/0/buffer", nullptr,
         "bufferView 0: 'buffer' must be a non-negative integer, found null"},
        {"/buffers/0/uri", 7, "buffer 0: 'uri' must be a string, found 7"},
        {"/nodes/0/mesh", "0", "node 0: 'mesh' must be a non-negative integer"},
        {"/nodes/0/mesh", 5, "node 0 refers to mesh 5, out of range (the file has 1 meshes)"},
        {"/nodes/0/children", 1, "node 0: 'children' must be an array, found 1"},
        {"/nodes/0/children", Json::array({9}), "node 0 has child 9, out of range"},
        {"/nodes/0/matrix", Json::array({1, 2, 3}),
         "'matrix' must be an array of 16 numbers, found an array of 3"},
        {"/nodes/0/translation", Json::array({1, "2", 3}),
         "node 0: 'translation'[1] must be a number"},
        {"/nodes/0/rotation", Json::array({0, 0, 0, 0}),
         "node 0: 'rotation' is not a usable quaternion"},
        {"/nodes/0", 3, "node 0 must be an object, found 3"},
        {"/scenes/0/nodes", Json::array({-1}), "scene 0: 'nodes' holds -1, not a node index"},
        {"/scenes/0/nodes", Json::array({4}), "scene 0 lists node 4, out of range"},
        {"/scene", 2, "'scene' is 2, out of range (the file has 1 scenes)"},
        {"/meshes/0/primitives", Json::object(), "mesh 0: 'primitives' must be an array"},
        {"/meshes/0/primitives/0/mode", 7,
         "mesh 0, primitive 0: mode 7 is not a glTF primitive mode"},
        {"/meshes/0/primitives/0/mode", "4", "'mode' must be a non-negative integer"},
        {"/meshes/0/primitives/0/attributes", Json::array(), "'attributes' must be an object"},
        {"/meshes/0/primitives/0/attributes/POSITION", 3, "refers to accessor 3, out of range"},
        {"/meshes/0/primitives/0/indices", true,
         "'indices' must be a non-negative integer, found true"},
        {"/accessors", Json::object(), "'accessors' must be an array, found an object"},
        {"/extensionsRequired", "KHR_draco_mesh_compression",
         "'extensionsRequired' must be an array"},
        {"/asset", "2.0", "no asset.version"},
    };
    for (const auto& c : cases) {
        Json doc = Json::parse(triangle().gltf());
        doc[Json::json_pointer(c.pointer)] = c.value;
        SCOPED_TRACE(c.pointer + " = " + c.value.dump());
        expect_refused(read_doc(doc), {c.fragment});
    }
}

TEST(Gltf, TriangleCountsNotAMultipleOfThreeAreRefused) {
    Builder b = triangle();
    b.doc["accessors"][1]["count"] = 2;
    expect_refused(read_text(b.gltf()),
                   {"mesh 0, primitive 0: TRIANGLES with 2 indices, not a multiple of 3"});
}

TEST(Gltf, MalformedJsonIsRefused) {
    expect_refused(read_text(std::string("{\"asset\":")), {"the glTF JSON is not valid JSON"});
    expect_refused(read_text(std::string("[1, 2]")),
                   {"the glTF JSON is an array, not a JSON object"});
    expect_refused(read_text(std::string()), {"not valid JSON"});
    const std::string latin1 = "{\"asset\":{\"version\":\"2.0\"},\"nodes\":[{\"name\":\"W\xfc\"}]}";
    expect_refused(read_text(latin1), {"not valid UTF-8 (byte 46"});
}

TEST(Gltf, MalformedGlbContainersAreRefused) {
    const std::string good = triangle().glb();
    const auto read_glb = [](const std::string& data) {
        return read_mesh_from_memory(data, "glb", "test.glb");
    };
    expect_refused(read_glb(good.substr(0, 10)), {"binary glTF: the file is 10 bytes"}, "test.glb");
    std::string bad = good;
    bad[0] = 'x';
    expect_refused(read_glb(bad), {"does not start with 'glTF'"}, "test.glb");
    bad = good;
    bad.replace(8, 4, u32(static_cast<std::uint32_t>(good.size() + 1)));
    expect_refused(read_glb(bad),
                   {"the header declares " + std::to_string(good.size() + 1) +
                    " bytes, the file holds " + std::to_string(good.size())},
                   "test.glb");
    bad = good;
    bad.replace(12, 4, u32(0x29000000));
    expect_refused(read_glb(bad), {"the chunk at byte 12 declares 687865856 bytes"}, "test.glb");
    bad = good;
    bad.replace(16, 4, std::string("BIN\0", 4));
    expect_refused(read_glb(bad), {"the first chunk has type", "not JSON"}, "test.glb");
    // A BIN chunk shorter than the buffer's byteLength.
    bad = good;
    bad.replace(bad.size() - 44 - 8, 4, u32(40));
    bad.resize(bad.size() - 4);
    bad.replace(8, 4, u32(static_cast<std::uint32_t>(bad.size())));
    expect_refused(read_glb(bad), {"buffer 0 declares byteLength 42, the BIN chunk holds 40 bytes"},
                   "test.glb");
    // Bytes beyond the header's length are ignored.
    const auto padded = read_mesh_from_memory(good + "trailing", "glb", "test.glb", no_weld());
    ASSERT_TRUE(padded.ok()) << padded.status().to_string();
    EXPECT_EQ(padded->vertices, TRIANGLE);
}

}  // namespace
}  // namespace proxima
