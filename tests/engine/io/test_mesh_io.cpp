// read_mesh: native double-precision PLY and OFF (bit-exact coordinates, fan triangulation in
// file order, any PLY layout), the native OBJ reader (double precision, triangulation of
// non-convex polygons), assimp for STL, the format allowlist, the in-memory entry point, and
// errors instead of crashes on bad input. The native glTF reader has its own file: test_gltf.cpp.

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numbers>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "proxima/io/mesh_io.hpp"
#include "support/mesh_files.hpp"

namespace proxima {
namespace {

namespace fs = std::filesystem;

using test::no_weld;
using test::read_bytes;
using test::temp_path;
using test::write_bytes;

std::string g17(double v) {
    std::array<char, 40> buf{};
    std::snprintf(buf.data(), buf.size(), "%.17g", v);
    return buf.data();
}

bool same_bits(double a, double b) {
    return std::bit_cast<std::uint64_t>(a) == std::bit_cast<std::uint64_t>(b);
}

// Coordinates that a float reader, or a sloppy text parser, would change.
const std::vector<Vec3>& sample_vertices() {
    static const std::vector<Vec3> vertices = {
        {0.1, 1.0 / 3.0, 1e-300},
        {-2.5, 1e300, 4.9406564584124654e-324},  // the smallest subnormal
        {std::numbers::pi, -0.0, 123456789.123456789},
        {0.30000000000000004, -1.0 / 7.0, 2.0 / 3.0},
        {1.0e-5, 6.02214076e23, -0.1},
        {std::nextafter(1.0, 2.0), -std::numbers::e, 16777217.0},
    };
    return vertices;
}

// A quad, a triangle and a pentagon.
const std::vector<std::vector<std::uint32_t>>& sample_faces() {
    static const std::vector<std::vector<std::uint32_t>> faces = {
        {0, 1, 2, 3}, {3, 4, 5}, {5, 4, 3, 2, 1}};
    return faces;
}

// Fans (v0, vi, vi+1) in file order.
const std::vector<TriangleIndices>& sample_triangles() {
    static const std::vector<TriangleIndices> triangles = {{0, 1, 2}, {0, 2, 3}, {3, 4, 5},
                                                           {5, 4, 3}, {5, 3, 2}, {5, 2, 1}};
    return triangles;
}

void expect_sample_mesh(const StatusOr<TriangleMesh>& read) {
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    const auto& expected = sample_vertices();
    ASSERT_EQ(read->vertices.size(), expected.size());
    for (std::size_t v = 0; v < expected.size(); ++v) {
        for (int k = 0; k < 3; ++k) {
            EXPECT_TRUE(same_bits(read->vertices[v][k], expected[v][k]))
                << "vertex " << v << " axis " << k << ": read " << g17(read->vertices[v][k])
                << ", expected " << g17(expected[v][k]);
        }
    }
    EXPECT_EQ(read->triangles, sample_triangles());
}

// Writes scalars in a chosen byte order.
class BinaryWriter {
  public:
    explicit BinaryWriter(bool big_endian) : m_big_endian(big_endian) {}

    template <class T>
    void put(T value) {
        auto bytes = std::bit_cast<std::array<char, sizeof(T)>>(value);
        if (m_big_endian != (std::endian::native == std::endian::big)) {
            std::reverse(bytes.begin(), bytes.end());
        }
        m_bytes.append(bytes.data(), bytes.size());
    }

    const std::string& bytes() const { return m_bytes; }

  private:
    bool m_big_endian;
    std::string m_bytes;
};

// The sample mesh with elements and properties the reader must skip: an element before the
// vertices, properties (scalar and list) around x, y and z, properties around the index list and
// an element after the faces.
constexpr const char* SAMPLE_PLY_LAYOUT =
    "comment written by test_mesh_io\n"
    "obj_info nothing to see\n"
    "element camera 1\n"
    "property float focal\n"
    "property list uchar int junk\n"
    "element vertex 6\n"
    "property uchar red\n"
    "property double x\n"
    "property list ushort float normals\n"
    "property double y\n"
    "property short flags\n"
    "property float64 z\n"
    "element face 3\n"
    "property uchar flag_before\n"
    "property list uint8 uint32 vertex_indices\n"
    "property float quality\n"
    "element edge 2\n"
    "property int vertex1\n"
    "property int32 vertex2\n"
    "end_header\n";

std::string sample_binary_ply(bool big_endian) {
    std::string header = "ply\nformat ";
    header += big_endian ? "binary_big_endian" : "binary_little_endian";
    header += " 1.0\n";
    header += SAMPLE_PLY_LAYOUT;
    BinaryWriter w(big_endian);
    w.put(35.0f);  // camera
    w.put(std::uint8_t{2});
    w.put(std::int32_t{-7});
    w.put(std::int32_t{9});
    for (const Vec3& p : sample_vertices()) {
        w.put(std::uint8_t{200});
        w.put(p.x);
        w.put(std::uint16_t{3});
        w.put(0.0f);
        w.put(1.0f);
        w.put(std::numeric_limits<float>::quiet_NaN());  // skipped: never validated
        w.put(p.y);
        w.put(std::int16_t{-3});
        w.put(p.z);
    }
    for (const auto& face : sample_faces()) {
        w.put(std::uint8_t{1});
        w.put(static_cast<std::uint8_t>(face.size()));
        for (auto i : face) {
            w.put(i);
        }
        w.put(0.5f);
    }
    for (int e = 0; e < 2; ++e) {
        w.put(std::int32_t{e});
        w.put(std::int32_t{e + 1});
    }
    return header + w.bytes();
}

std::string sample_ascii_ply(const std::string& newline = "\n") {
    std::string text = "ply\nformat ascii 1.0\n";
    text += SAMPLE_PLY_LAYOUT;
    if (newline != "\n") {
        std::string converted;
        for (char c : text) {
            converted += c == '\n' ? newline : std::string(1, c);
        }
        text = converted;
    }
    text += "35 2 -7 9" + newline;
    for (const Vec3& p : sample_vertices()) {
        // Coordinates spelt in different ways that all parse to the same double.
        text += "200 " + g17(p.x) + " 3 0 1 nan " + g17(p.y) + " -3 " + g17(p.z) + newline;
    }
    for (const auto& face : sample_faces()) {
        // One += per piece: gcc 12 warns falsely (-Wrestrict) on "literal" + temporary.
        text += "1 ";
        text += std::to_string(face.size());
        for (auto i : face) {
            text += ' ';
            text += std::to_string(i);
        }
        text += " 0.5" + newline;
    }
    text += "0 1" + newline + "1 2" + newline;
    return text;
}

void expect_error_naming(const StatusOr<TriangleMesh>& read, const std::string& path,
                         const std::string& fragment = {}) {
    ASSERT_FALSE(read.ok()) << path << " was read without error";
    EXPECT_EQ(read.status().code(), StatusCode::invalid_argument) << read.status().to_string();
    EXPECT_NE(read.status().message().find("'" + path + "'"), std::string::npos)
        << read.status().to_string();
    if (!fragment.empty()) {
        EXPECT_NE(read.status().message().find(fragment), std::string::npos)
            << "expected '" << fragment << "' in: " << read.status().to_string();
    }
}

// The shared data folder, or empty: the real-file tests then skip with NO_DATA.
std::string data_dir() {
    std::string dir = PROXIMA_DATA_DIR;
    std::error_code ec;
    if (dir.empty() || !fs::is_directory(dir, ec)) {
        return {};
    }
    return dir;
}

constexpr const char* NO_DATA = "shared data folder not found (PROXIMA_DATA_DIR='" PROXIMA_DATA_DIR
                                "'): the real-file tests need ../shared/data";

// ---------------------------------------------------------------------------------------------
// Native PLY

TEST(MeshIo, AsciiPlyIsBitExact) {
    const std::string path = temp_path("ascii.ply");
    write_bytes(path, sample_ascii_ply());
    expect_sample_mesh(read_mesh(path, no_weld()));
}

TEST(MeshIo, AsciiPlyWithCrLfLines) {
    const std::string path = temp_path("crlf.ply");
    write_bytes(path, sample_ascii_ply("\r\n"));
    expect_sample_mesh(read_mesh(path, no_weld()));
}

TEST(MeshIo, BinaryLittleEndianPlyIsBitExact) {
    const std::string path = temp_path("le.ply");
    write_bytes(path, sample_binary_ply(false));
    expect_sample_mesh(read_mesh(path, no_weld()));
}

TEST(MeshIo, BinaryBigEndianPlyIsBitExact) {
    const std::string path = temp_path("be.ply");
    write_bytes(path, sample_binary_ply(true));
    expect_sample_mesh(read_mesh(path, no_weld()));
}

// Faces before vertices, coordinates of integer and float types, "vertex_index" with other
// count and index types: everything converts exactly to double.
TEST(MeshIo, PlyScalarTypesAndElementOrder) {
    for (bool big_endian : {false, true}) {
        std::string header = "ply\nformat ";
        header += big_endian ? "binary_big_endian" : "binary_little_endian";
        header +=
            " 1.0\n"
            "element face 2\n"
            "property list ushort int16 vertex_index\n"
            "element vertex 4\n"
            "property int8 z\n"
            "property float y\n"
            "property uint x\n"
            "property char pad\n"
            "end_header\n";
        BinaryWriter w(big_endian);
        w.put(std::uint16_t{3});
        for (std::int16_t i : {0, 1, 2}) {
            w.put(i);
        }
        w.put(std::uint16_t{4});
        for (std::int16_t i : {3, 2, 1, 0}) {
            w.put(i);
        }
        const std::array<std::int8_t, 4> zs = {-128, 0, 127, -1};
        const std::array<float, 4> ys = {0.1f, -1e-30f, 3.4e38f, 1.0f / 3.0f};
        const std::array<std::uint32_t, 4> xs = {0, 4294967295u, 16777217u, 7};
        for (int v = 0; v < 4; ++v) {
            w.put(zs[v]);
            w.put(ys[v]);
            w.put(xs[v]);
            w.put(std::int8_t{-1});
        }
        const std::string path = temp_path(big_endian ? "types_be.ply" : "types_le.ply");
        write_bytes(path, header + w.bytes());
        const auto read = read_mesh(path, no_weld());
        ASSERT_TRUE(read.ok()) << read.status().to_string();
        ASSERT_EQ(read->vertices.size(), 4u);
        for (int v = 0; v < 4; ++v) {
            EXPECT_EQ(read->vertices[v].x, static_cast<double>(xs[v]));
            EXPECT_EQ(read->vertices[v].y, static_cast<double>(ys[v]));
            EXPECT_EQ(read->vertices[v].z, static_cast<double>(zs[v]));
        }
        const std::vector<TriangleIndices> expected = {{0, 1, 2}, {3, 2, 1}, {3, 1, 0}};
        EXPECT_EQ(read->triangles, expected);
    }
}

TEST(MeshIo, PlyAndOffRecognisedByContentAndUppercaseExtension) {
    const std::string upper = temp_path("upper.PLY");
    write_bytes(upper, sample_binary_ply(false));
    expect_sample_mesh(read_mesh(upper, no_weld()));

    const std::string no_extension = temp_path("ply_without_extension");
    write_bytes(no_extension, sample_binary_ply(true));
    expect_sample_mesh(read_mesh(no_extension, no_weld()));

    TriangleMesh mesh{sample_vertices(), sample_triangles()};
    const std::string off = temp_path("off.txt");
    ASSERT_TRUE(write_off(off, mesh).ok());
    expect_sample_mesh(read_mesh(off, no_weld()));
}

TEST(MeshIo, WeldingMergesBitIdenticalPositions) {
    // Two triangles stored STL-style, one vertex per corner, sharing an edge.
    const std::string path = temp_path("weld.ply");
    write_bytes(path,
                "ply\nformat ascii 1.0\nelement vertex 6\nproperty double x\nproperty double y\n"
                "property double z\nelement face 2\nproperty list uchar int vertex_indices\n"
                "end_header\n"
                "0 0 0\n1 0 0\n0 1 0\n1 0 0\n0 1 0\n-0 -0 1e-300\n"
                "3 0 1 2\n3 3 4 5\n");
    const auto raw = read_mesh(path, no_weld());
    ASSERT_TRUE(raw.ok()) << raw.status().to_string();
    EXPECT_EQ(raw->vertices.size(), 6u);
    const auto welded = read_mesh(path);
    ASSERT_TRUE(welded.ok()) << welded.status().to_string();
    EXPECT_EQ(welded->vertices.size(), 4u);
    const std::vector<TriangleIndices> expected = {{0, 1, 2}, {1, 2, 3}};
    EXPECT_EQ(welded->triangles, expected);
}

// ---------------------------------------------------------------------------------------------
// Native OFF

TEST(MeshIo, OffRoundTripIsBitExact) {
    const std::string path = temp_path("round_trip.off");
    TriangleMesh mesh{sample_vertices(), sample_triangles()};
    ASSERT_TRUE(write_off(path, mesh).ok());
    expect_sample_mesh(read_mesh(path, no_weld()));
}

TEST(MeshIo, OffPolygonsCommentsAndColours) {
    std::string text =
        "# leading comment\n"
        "\n"
        "OFF # keyword comment\n"
        "6 3 0\n";
    for (const Vec3& p : sample_vertices()) {
        text += g17(p.x) + " " + g17(p.y) + "\t" + g17(p.z) + "  # a vertex\n";
    }
    text += "4 0 1 2 3 255 0 0\n";  // a face colour after the indices
    text += "3 3 4 5\n";
    text += "5 5 4 3\n  2 1\n";  // a polygon that goes on on the next line
    const std::string path = temp_path("commented.off");
    write_bytes(path, text);
    expect_sample_mesh(read_mesh(path, no_weld()));
}

TEST(MeshIo, OffVariants) {
    // Counts on the keyword line, no trailing newline.
    const std::string inline_counts = temp_path("inline.off");
    write_bytes(inline_counts, "OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2");
    auto read = read_mesh(inline_counts);
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->triangles.size(), 1u);

    // COFF: colour columns after xyz.
    const std::string coff = temp_path("colour.off");
    write_bytes(coff,
                "COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0\n0.5 1 0 0 0 255 255\n"
                "3 0 1 2\n");
    read = read_mesh(coff, no_weld());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    ASSERT_EQ(read->vertices.size(), 3u);
    EXPECT_EQ(read->vertices[2], (Vec3{0.5, 1.0, 0.0}));

    // The keyword is optional in OFF.
    const std::string bare = temp_path("bare.off");
    write_bytes(bare, "3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
    read = read_mesh(bare);
    ASSERT_TRUE(read.ok()) << read.status().to_string();

    const std::string binary = temp_path("binary.off");
    write_bytes(binary, "OFF BINARY\n");
    expect_error_naming(read_mesh(binary), binary, "binary OFF");

    const std::string four = temp_path("four.off");
    write_bytes(four, "4OFF\n3 1 0\n0 0 0 1\n1 0 0 1\n0 1 0 1\n3 0 1 2\n");
    expect_error_naming(read_mesh(four), four, "not supported");
}

// ---------------------------------------------------------------------------------------------
// Real files

TEST(MeshIo, RodTwistFrameIsReadInDoublePrecision) {
    const std::string dir = data_dir();
    if (dir.empty()) {
        GTEST_SKIP() << NO_DATA;
    }
    const std::string path = dir + "/frames/rod-twist/3036.ply";
    const auto raw = read_mesh(path, no_weld());
    ASSERT_TRUE(raw.ok()) << raw.status().to_string();
    EXPECT_EQ(raw->vertices.size(), 39940u);
    EXPECT_EQ(raw->triangles.size(), 79864u);
    std::size_t not_float = 0;
    for (const Vec3& p : raw->vertices) {
        for (int k = 0; k < 3; ++k) {
            if (static_cast<double>(static_cast<float>(p[k])) != p[k]) {
                ++not_float;
            }
        }
    }
    EXPECT_GT(not_float, 0u) << "every coordinate is a float: the file was read at float precision";
    std::printf("rod-twist 3036: %zu of %zu coordinates need double precision\n", not_float,
                raw->vertices.size() * 3);

    const auto welded = read_mesh(path);
    ASSERT_TRUE(welded.ok()) << welded.status().to_string();
    EXPECT_LE(welded->vertices.size(), 39940u);
    EXPECT_EQ(welded->triangles.size(), 79864u);
}

TEST(MeshIo, NBodyFrameIsBigEndianFloatWithColours) {
    const std::string dir = data_dir();
    if (dir.empty()) {
        GTEST_SKIP() << NO_DATA;
    }
    const auto read = read_mesh(dir + "/frames/n-body-simulation/balls16_18.ply", no_weld());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->vertices.size(), 73960u);
    EXPECT_EQ(read->triangles.size(), 146480u);
}

TEST(MeshIo, AllFramesRead) {
    const std::string dir = data_dir();
    if (dir.empty()) {
        GTEST_SKIP() << NO_DATA;
    }
    std::size_t files = 0;
    for (const auto& entry : fs::recursive_directory_iterator(dir + "/frames")) {
        if (entry.path().extension() != ".ply") {
            continue;
        }
        const auto read = read_mesh(entry.path().string());
        EXPECT_TRUE(read.ok()) << read.status().to_string();
        ++files;
    }
    EXPECT_GE(files, 10u);
}

TEST(MeshIo, OffScansAndCadParts) {
    const std::string dir = data_dir();
    if (dir.empty()) {
        GTEST_SKIP() << NO_DATA;
    }
    const std::vector<std::pair<std::string, std::size_t>> files = {
        {"meshes/scans/armadillo.off", 52000},
        {"meshes/scans/bunny00.off", 75408},
        {"meshes/scans/ChineseDragon-10kv.off", 19994},
        {"meshes/cad/sphere966.off", 1848},  // comment lines before the keyword
        {"meshes/cad/boeing.off", 2564},     // trailing blanks
        {"meshes/cad/pinion.off", 1300},     // a non-zero edge count
        {"meshes/cad/fandisk.off", 12946},
    };
    for (const auto& [name, triangles] : files) {
        const auto read = read_mesh((fs::path(dir) / name).string());
        ASSERT_TRUE(read.ok()) << read.status().to_string();
        EXPECT_EQ(read->triangles.size(), triangles) << name;
    }
}

TEST(MeshIo, StlThroughAssimpAndGlb) {
    const std::string dir = data_dir();
    if (dir.empty()) {
        GTEST_SKIP() << NO_DATA;
    }
    const auto stl = read_mesh(dir + "/meshes/cad/CrankArm.brepmesh_coarse.stl");
    ASSERT_TRUE(stl.ok()) << stl.status().to_string();
    EXPECT_GT(stl->triangles.size(), 0u);
    // STL stores every corner separately: welding restores the shared vertices.
    EXPECT_LT(stl->vertices.size(), 3 * stl->triangles.size());
    std::printf("CrankArm.brepmesh_coarse.stl: %zu triangles, %zu vertices after welding\n",
                stl->triangles.size(), stl->vertices.size());

    // The file's 29 meshes hold 75,730 triangles; its 67 mesh nodes instance them, and read_mesh
    // places every instance (node transforms applied): 121,496 triangles, as with Debian's assimp.
    const auto glb = read_mesh(dir + "/meshes/gltf/2CylinderEngine.glb");
    ASSERT_TRUE(glb.ok()) << glb.status().to_string();
    EXPECT_EQ(glb->triangles.size(), 121496u);
    std::printf("2CylinderEngine.glb: %zu triangles (75,730 in its meshes, before instancing)\n",
                glb->triangles.size());
}

// ---------------------------------------------------------------------------------------------
// The format allowlist and the in-memory entry point (the fuzz target's)

const std::string TETRA_OBJ = "o tetra\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\n";

TEST(MeshIo, ObjAndAsciiStl) {
    const std::string obj = temp_path("tetra.obj");
    write_bytes(obj, TETRA_OBJ);
    const auto read = read_mesh(obj);
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->vertices.size(), 4u);
    EXPECT_EQ(read->triangles.size(), 2u);

    const std::string stl = temp_path("tri.STL");  // extensions in any case
    write_bytes(stl,
                "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                "vertex 0 1 0\nendloop\nendfacet\nendsolid t\n");
    const auto tri = read_mesh(stl);
    ASSERT_TRUE(tri.ok()) << tri.status().to_string();
    EXPECT_EQ(tri->triangles.size(), 1u);
}

// Material libraries are never read (Debian's assimp crashed on some, and on an OBJ naming itself
// as its material library): the OBJ reader opens no other file and ignores mtllib/usemtl.
TEST(MeshIo, ObjMaterialLibrariesAreNeverRead) {
    const std::string named_mtl = temp_path("bad_named.mtl");
    write_bytes(named_mtl, "map_emissive a\nmap_Kd b\n");
    const std::string named = temp_path("named.obj");
    write_bytes(named, "mtllib " + fs::path(named_mtl).filename().string() + "\n" + TETRA_OBJ);
    const auto read = read_mesh(named);
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->triangles.size(), 2u);

    // An OBJ whose mtllib names itself (SIGSEGV in assimp; tests/fuzz/regressions/mesh/).
    const std::string self = temp_path("self.obj");
    write_bytes(self, "mtllib self.obj\nusemtl x\n" + TETRA_OBJ);
    const auto read_self = read_mesh(self);
    ASSERT_TRUE(read_self.ok()) << read_self.status().to_string();
    EXPECT_EQ(read_self->triangles.size(), 2u);

    const auto memory = read_mesh_from_memory("mtllib l\nmap_emissive\n" + TETRA_OBJ, "obj", "m");
    ASSERT_TRUE(memory.ok()) << memory.status().to_string();
    EXPECT_EQ(memory->triangles.size(), 2u);
}

// ---------------------------------------------------------------------------------------------
// Native OBJ

TEST(MeshIo, ObjCoordinatesAreReadInDouble) {
    // 0.1 and 1/3 are not floats: assimp (ai_real = float) rounded them.
    const auto read = read_mesh_from_memory(
        "v 0.1 0.3333333333333333 1e-300\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "obj", "d.obj");
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    ASSERT_EQ(read->vertices.size(), 3u);
    EXPECT_EQ(read->vertices[0].x, 0.1);
    EXPECT_EQ(read->vertices[0].y, 0.3333333333333333);
    EXPECT_EQ(read->vertices[0].z, 1e-300);
}

TEST(MeshIo, ObjSyntax) {
    // Corners with texture and normal indices, negative (relative) and forward references, a
    // continuation line, comments, CRLF line ends, w and colour values, points and lines dropped,
    // statements that carry no geometry ignored.
    const std::string obj =
        "# comment\r\n"
        "o thing\r\ng part\r\ns 1\r\nusemtl m\r\n"
        "v 0 0 0 1\r\n"
        "v 1 0 0 0.5 0.5 0.5\r\n"
        "v 0 1 0\r\n"
        "vt 0 0\r\nvn 0 0 1\r\n"
        "f 1/1/1 2/1/1 3/1/1 # a comment after a face\r\n"
        "f -3//1 -2//1 \\\r\n   -1//1\r\n"
        "f 1 5 4\r\n"  // forward references: vertices 4 and 5 come below
        "l 1 2\r\np 3\r\nf 1 2\r\n"
        "v 0 0 1\r\nv +1e0 -0 1\r\n";
    const auto read = read_mesh_from_memory(obj, "obj", "syntax.obj", no_weld());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    ASSERT_EQ(read->triangles.size(), 3u);
    // Vertices in order of first use; unused ones are not kept.
    ASSERT_EQ(read->vertices.size(), 5u);
    EXPECT_EQ(read->triangles[0], (TriangleIndices{0, 1, 2}));
    EXPECT_EQ(read->triangles[1], (TriangleIndices{0, 1, 2}));
    EXPECT_EQ(read->triangles[2], (TriangleIndices{0, 3, 4}));
    EXPECT_EQ(read->vertices[3].x, 1.0);
    EXPECT_EQ(read->vertices[4].z, 1.0);
}

namespace {

double triangle_area(const TriangleMesh& mesh, const TriangleIndices& t) {
    const Vec3& a = mesh.vertices[t[0]];
    const Vec3& b = mesh.vertices[t[1]];
    const Vec3& c = mesh.vertices[t[2]];
    const double ux = b.x - a.x, uy = b.y - a.y, uz = b.z - a.z;
    const double vx = c.x - a.x, vy = c.y - a.y, vz = c.z - a.z;
    const double x = uy * vz - uz * vy, y = uz * vx - ux * vz, z = ux * vy - uy * vx;
    return 0.5 * std::sqrt(x * x + y * y + z * z);
}

double total_area(const TriangleMesh& mesh) {
    double sum = 0;
    for (const auto& t : mesh.triangles) {
        sum += triangle_area(mesh, t);
    }
    return sum;
}

}  // namespace

TEST(MeshIo, ObjPolygonsAreTriangulatedInsideThemselves) {
    // A convex pentagon: the fan from its first corner, in order.
    const auto convex = read_mesh_from_memory(
        "v 0 0 0\nv 2 0 0\nv 3 1 0\nv 1 2 0\nv -1 1 0\nf 1 2 3 4 5\n", "obj", "c.obj");
    ASSERT_TRUE(convex.ok()) << convex.status().to_string();
    ASSERT_EQ(convex->triangles.size(), 3u);
    EXPECT_EQ(convex->triangles[0], (TriangleIndices{0, 1, 2}));
    EXPECT_EQ(convex->triangles[1], (TriangleIndices{0, 2, 3}));
    EXPECT_EQ(convex->triangles[2], (TriangleIndices{0, 3, 4}));

    // A U (a 3 x 2 rectangle less a 1 x 1 notch) in the plane x = 5, starting at a corner that
    // does not see the whole polygon: the fan from it would cover the notch too (area 7, not 5).
    const auto u_shape = read_mesh_from_memory(
        "v 5 2 2\nv 5 2 1\nv 5 1 1\nv 5 1 2\nv 5 0 2\nv 5 0 0\nv 5 3 0\nv 5 3 2\n"
        "f 1 2 3 4 5 6 7 8\n",
        "obj", "u.obj");
    ASSERT_TRUE(u_shape.ok()) << u_shape.status().to_string();
    ASSERT_EQ(u_shape->triangles.size(), 6u);
    EXPECT_DOUBLE_EQ(total_area(*u_shape), 5.0);

    // A concave quad (an arrowhead, reflex at corner 4) with the opposite orientation.
    const auto arrow =
        read_mesh_from_memory("v 0 0 0\nv 0 4 0\nv 4 2 0\nv 1 2 0\nf 1 4 3 2\n", "obj", "a.obj");
    ASSERT_TRUE(arrow.ok()) << arrow.status().to_string();
    ASSERT_EQ(arrow->triangles.size(), 2u);
    EXPECT_DOUBLE_EQ(total_area(*arrow), 5.0);  // 8 for the hull, less the notch's 3
}

TEST(MeshIo, ObjErrorsNameTheLine) {
    const auto expect = [](const std::string& text, const std::string& fragment) {
        const auto read = read_mesh_from_memory(text, "obj", "bad.obj");
        ASSERT_FALSE(read.ok()) << text;
        EXPECT_EQ(read.status().code(), StatusCode::invalid_argument);
        EXPECT_NE(read.status().message().find(fragment), std::string::npos)
            << read.status().to_string();
        EXPECT_NE(read.status().message().find("'bad.obj'"), std::string::npos);
    };
    expect("v 0 0\n", "line 1: a vertex needs three coordinates");
    expect("v 0 0 0\nv 1 x 0\n", "line 2: 'x' is not a number");
    expect("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "line 4: vertex 4 of 3");
    expect("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", "line 4: vertex -4 of 3 read so far");
    expect("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", "'0' is not a face corner");
    expect("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3x\n", "'3x' is not a face corner");
    expect("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 +-3\n", "'+-3' is not a face corner");
    expect("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nv 0 \x01 0\n", "'\\x01' is not a number");
    expect("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", "is not a face corner");
    // No triangles at all, or not finite: validate_mesh's errors.
    expect("v 0 0 0\nv 1 0 0\nf 1 2\n", "bad.obj");
    expect("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "bad.obj");
}

// Every OBJ file of the shared data reads, with one triangle less than corners per polygon
// (faces with fewer than three corners dropped), and welded.
TEST(MeshIo, EverySharedObjFileReads) {
    const std::string dir = data_dir();
    if (dir.empty()) {
        GTEST_SKIP() << NO_DATA;
    }
    std::size_t files = 0;
    for (const auto& entry : fs::recursive_directory_iterator(dir + "/meshes")) {
        if (entry.path().extension() != ".obj") {
            continue;
        }
        ++files;
        const std::string text = read_bytes(entry.path().string());
        std::size_t expected = 0;
        std::istringstream lines(text);
        for (std::string line; std::getline(lines, line);) {
            std::istringstream words(line);
            std::string keyword;
            words >> keyword;
            if (keyword != "f") {
                continue;
            }
            std::size_t corners = 0;
            for (std::string corner; words >> corner && corner[0] != '#';) {
                ++corners;
            }
            expected += corners >= 3 ? corners - 2 : 0;
        }
        const auto read = read_mesh(entry.path().string());
        ASSERT_TRUE(read.ok()) << read.status().to_string();
        EXPECT_EQ(read->triangles.size(), expected) << entry.path();
    }
    EXPECT_GE(files, 500u);
}

// Assimp would read these (by content, or by its ~40 other importers); the allowlist refuses
// them, naming the accepted formats.
TEST(MeshIo, FormatsOutsideTheAllowlistAreRefused) {
    for (const char* name : {"tetra.txt", "tetra.dae", "tetra.3ds", "tetra"}) {
        const std::string path = temp_path(name);
        write_bytes(path, TETRA_OBJ);
        expect_error_naming(read_mesh(path), path, "accepted: .ply, .off, .obj, .stl");
    }
    const auto memory = read_mesh_from_memory(TETRA_OBJ, "dae", "in-memory");
    ASSERT_FALSE(memory.ok());
    EXPECT_NE(memory.status().message().find("unsupported format 'dae'"), std::string::npos)
        << memory.status().to_string();
}

TEST(MeshIo, FromMemoryReadsLikeFromAFile) {
    expect_sample_mesh(read_mesh_from_memory(sample_ascii_ply(), "ply", "a.ply", no_weld()));
    expect_sample_mesh(read_mesh_from_memory(sample_binary_ply(true), ".PLY", "b.ply", no_weld()));
    const std::string off_path = temp_path("memory.off");
    ASSERT_TRUE(write_off(off_path, TriangleMesh{sample_vertices(), sample_triangles()}).ok());
    expect_sample_mesh(read_mesh_from_memory(read_bytes(off_path), "off", "c.off", no_weld()));

    const auto obj = read_mesh_from_memory(TETRA_OBJ, "obj", "d.obj");
    ASSERT_TRUE(obj.ok()) << obj.status().to_string();
    EXPECT_EQ(obj->triangles.size(), 2u);
    // Errors name the given name.
    const auto bad = read_mesh_from_memory("ply\ngarbage\n", "ply", "named.ply");
    ASSERT_FALSE(bad.ok());
    EXPECT_NE(bad.status().message().find("'named.ply'"), std::string::npos)
        << bad.status().to_string();
}

// Debian's assimp sizes a binary glTF's buffers from its header before comparing them with the
// file (a 49-byte .glb took 5 s and 800 MB): every declared length must fit in the file.
TEST(MeshIo, GlbLengthsBeyondTheFileAreRefused) {
    std::string glb("glTF\x02\x00\x00\x00", 8);
    const auto u32 = [](std::uint32_t v) {
        return std::string{static_cast<char>(v & 0xff), static_cast<char>((v >> 8) & 0xff),
                           static_cast<char>((v >> 16) & 0xff), static_cast<char>(v >> 24)};
    };
    const std::string json = R"({"asset":{"version":"2.0"}})";
    const std::string huge_chunk = glb + u32(40) + u32(0x29000000) + "JSON" + json.substr(0, 20);
    const std::string path = temp_path("huge_chunk.glb");
    write_bytes(path, huge_chunk);
    expect_error_naming(read_mesh(path), path, "declares 687865856 bytes");
    const auto memory = read_mesh_from_memory(huge_chunk, "glb", "memory.glb");
    ASSERT_FALSE(memory.ok());
    EXPECT_NE(memory.status().message().find("binary glTF"), std::string::npos);

    const std::string long_header = glb + u32(1000) + u32(json.size()) + "JSON" + json;
    const std::string long_path = temp_path("long_header.glb");
    write_bytes(long_path, long_header);
    expect_error_naming(read_mesh(long_path), long_path, "the header declares 1000 bytes");
}

// Debian's assimp asked for 2^32 faces (64 GiB) for a strip or loop with too few vertices. The
// native reader adds nothing for such a primitive (the file then has no triangles), and refuses
// JSON that is not UTF-8 (assimp did not check) naming the byte.
TEST(MeshIo, GltfStripsWithTooFewVerticesAddNothing) {
    const std::string gltf =
        R"({"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],)"
        R"("meshes":[{"primitives":[{"attributes":{"NORMAL":0},"mode":5}]}]})";
    const std::string path = temp_path("strip.gltf");
    write_bytes(path, gltf);
    expect_error_naming(read_mesh(path), path, "mesh has no triangles");
    const auto memory = read_mesh_from_memory(gltf, "gltf", "strip.gltf");
    ASSERT_FALSE(memory.ok());
    EXPECT_NE(memory.status().message().find("mesh has no triangles"), std::string::npos)
        << memory.status().to_string();

    std::string not_utf8 = gltf;
    not_utf8.insert(not_utf8.find("NORMAL") + 6, "\xff");
    write_bytes(path, not_utf8);
    expect_error_naming(read_mesh(path), path, "not valid UTF-8");
}

// In memory, nothing but the buffer is read: a .gltf's external buffer is not found.
TEST(MeshIo, FromMemoryReadsNoOtherFile) {
    const std::string bin = temp_path("external.bin");
    std::string buffer(3 * 12 + 3 * 2, '\0');
    const float corners[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    std::memcpy(buffer.data(), corners, sizeof corners);
    const std::uint16_t indices[3] = {0, 1, 2};
    std::memcpy(buffer.data() + 36, indices, sizeof indices);
    write_bytes(bin, buffer);
    const std::string gltf =
        R"({"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],)"
        R"("meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1}]}],)"
        R"("accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",)"
        R"("min":[0,0,0],"max":[1,1,0]},{"bufferView":1,"componentType":5123,"count":3,)"
        R"("type":"SCALAR"}],"bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":36},)"
        R"({"buffer":0,"byteOffset":36,"byteLength":6}],"buffers":[{"byteLength":42,"uri":")" +
        fs::path(bin).filename().string() + R"("}]})";
    const std::string gltf_path = temp_path("external.gltf");
    write_bytes(gltf_path, gltf);
    // From the file system the buffer beside it loads ...
    const auto from_file = read_mesh(gltf_path);
    ASSERT_TRUE(from_file.ok()) << from_file.status().to_string();
    EXPECT_EQ(from_file->triangles.size(), 1u);
    // ... from memory it does not exist.
    const auto from_memory = read_mesh_from_memory(gltf, "gltf", "external.gltf");
    EXPECT_FALSE(from_memory.ok());
}

// ---------------------------------------------------------------------------------------------
// Bad input: errors naming the file, never a crash, a hang or a huge allocation

TEST(MeshIo, NonexistentPathIsNotFound) {
    const std::string path = temp_path("does_not_exist.ply");
    const auto read = read_mesh(path);
    ASSERT_FALSE(read.ok());
    EXPECT_EQ(read.status().code(), StatusCode::not_found);
    EXPECT_NE(read.status().message().find(path), std::string::npos);
}

TEST(MeshIo, DirectoryIsAnError) {
    const std::string path = temp_path("a_directory.ply");
    fs::create_directories(path);
    expect_error_naming(read_mesh(path), path, "directory");
}

TEST(MeshIo, EmptyFileIsAnError) {
    for (const char* name : {"empty.ply", "empty.off", "empty.stl", "empty"}) {
        const std::string path = temp_path(name);
        write_bytes(path, "");
        expect_error_naming(read_mesh(path), path);
    }
}

TEST(MeshIo, EveryTruncationOfABinaryPlyIsAnError) {
    for (bool big_endian : {false, true}) {
        const std::string full = sample_binary_ply(big_endian);
        const std::string path = temp_path(big_endian ? "cut_be.ply" : "cut_le.ply");
        for (std::size_t size = 0; size < full.size(); ++size) {
            write_bytes(path, full.substr(0, size));
            const auto read = read_mesh(path);
            ASSERT_FALSE(read.ok()) << "prefix of " << size << " bytes was read";
            ASSERT_NE(read.status().message().find(path), std::string::npos)
                << read.status().to_string();
        }
    }
    // Cut inside the last vertex, while the body still holds the minimum the header announces
    // (lists take more than their length bytes): the reader itself runs into the end.
    const std::string path = temp_path("cut_vertex.ply");
    const std::string full = sample_binary_ply(false);
    write_bytes(path, full.substr(0, full.size() - 100));
    expect_error_naming(read_mesh(path), path, "file ends inside vertex 5");
    // Cut further: the header's counts alone need more bytes than there are.
    write_bytes(path, full.substr(0, full.size() - 200));
    expect_error_naming(read_mesh(path), path, "bytes after the header can hold");
}

TEST(MeshIo, HugeCountsAreRejectedBeforeAllocating) {
    const std::string ply = temp_path("huge.ply");
    std::string text =
        "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
        "property float y\nproperty float z\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n";
    text += std::string(1000, '\0');
    write_bytes(ply, text);
    expect_error_naming(read_mesh(ply), ply, "4000000000 vertex elements");

    const std::string too_many = temp_path("too_many.ply");
    write_bytes(too_many,
                "ply\nformat ascii 1.0\nelement vertex 18446744073709551615\nproperty float x\n"
                "property float y\nproperty float z\nelement face 1\n"
                "property list uchar int vertex_indices\nend_header\n0 0 0\n");
    expect_error_naming(read_mesh(too_many), too_many, "more than 2^32-1");

    const std::string face_list = temp_path("huge_list.ply");
    BinaryWriter w(false);
    for (float c : {0.f, 0.f, 0.f, 1.f, 0.f, 0.f, 0.f, 1.f, 0.f}) {
        w.put(c);
    }
    w.put(std::uint32_t{4294967295u});  // a list that claims 4e9 indices
    w.put(std::int32_t{0});
    write_bytes(face_list,
                "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                "property float y\nproperty float z\nelement face 1\n"
                "property list uint int vertex_indices\nend_header\n" +
                    w.bytes());
    expect_error_naming(read_mesh(face_list), face_list, "file ends inside face 0");

    // Elements without properties take no bytes: a huge count must not loop either.
    const std::string empty_element = temp_path("empty_element.ply");
    write_bytes(empty_element,
                "ply\nformat ascii 1.0\nelement nothing 18446744073709551615\nelement vertex 3\n"
                "property double x\nproperty double y\nproperty double z\nelement face 1\n"
                "property list uchar int vertex_indices\nend_header\n"
                "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
    const auto read = read_mesh(empty_element);
    EXPECT_TRUE(read.ok()) << read.status().to_string();

    const std::string off = temp_path("huge.off");
    write_bytes(off, "OFF\n4000000000 8000000000 0\n0 0 0\n");
    expect_error_naming(read_mesh(off), off, "header announces 4000000000 vertices");
}

TEST(MeshIo, FaceIndexOutOfRange) {
    const std::string ply = temp_path("out_of_range.ply");
    write_bytes(ply,
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
                "property double z\nelement face 2\nproperty list uchar int vertex_indices\n"
                "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 3\n");
    expect_error_naming(read_mesh(ply), ply,
                        "face 1 has vertex index 3, out of range (3 vertices)");

    const std::string be = temp_path("out_of_range_be.ply");
    BinaryWriter w(true);
    for (double c : {0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0}) {
        w.put(c);
    }
    w.put(std::uint8_t{3});
    for (std::int32_t i : {0, 1, 40}) {
        w.put(i);
    }
    write_bytes(be,
                "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\n"
                "property double y\nproperty double z\nelement face 1\n"
                "property list uchar int vertex_indices\nend_header\n" +
                    w.bytes());
    expect_error_naming(read_mesh(be), be, "face 0 has vertex index 40, out of range");

    const std::string off = temp_path("out_of_range.off");
    write_bytes(off, "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n");
    expect_error_naming(read_mesh(off), off, "face 0 has vertex index 3, out of range");
}

TEST(MeshIo, NegativeIndexAndShortFaces) {
    const std::string negative = temp_path("negative.ply");
    write_bytes(negative,
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
                "property double z\nelement face 1\nproperty list uchar int vertex_indices\n"
                "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n");
    expect_error_naming(read_mesh(negative), negative, "face 0 has negative vertex index -1");

    const std::string negative_off = temp_path("negative.off");
    write_bytes(negative_off, "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n");
    expect_error_naming(read_mesh(negative_off), negative_off, "negative vertex index");

    const std::string line = temp_path("line.ply");
    write_bytes(line,
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
                "property double z\nelement face 2\nproperty list uchar int vertex_indices\n"
                "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n2 0 1\n");
    expect_error_naming(read_mesh(line), line, "face 1 has 2 vertex indices");

    const std::string line_off = temp_path("line.off");
    write_bytes(line_off, "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n");
    expect_error_naming(read_mesh(line_off), line_off, "face 0 has 2 vertex indices");

    const std::string fraction = temp_path("fraction.ply");
    write_bytes(fraction,
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
                "property double z\nelement face 1\nproperty list uchar float vertex_indices\n"
                "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n");
    expect_error_naming(read_mesh(fraction), fraction, "not an integer");
}

TEST(MeshIo, NanCoordinateIsAnError) {
    const std::string ply = temp_path("nan.ply");
    write_bytes(ply,
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
                "property double z\nelement face 1\nproperty list uchar int vertex_indices\n"
                "end_header\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n");
    expect_error_naming(read_mesh(ply), ply, "non-finite");

    const std::string off = temp_path("nan.off");
    write_bytes(off, "OFF\n3 1 0\n0 0 0\n1 0 nan\n0 1 0\n3 0 1 2\n");
    expect_error_naming(read_mesh(off), off, "non-finite");

    // Welding must not see the NaN either (an ordered map cannot hold it): the default options.
    const std::string inf = temp_path("inf.off");
    write_bytes(inf, "OFF\n3 1 0\n0 0 0\n1 0 -inf\n1e999 1 0\n3 0 1 2\n");
    expect_error_naming(read_mesh(inf), inf, "non-finite");
}

TEST(MeshIo, MalformedTextIsAnError) {
    const std::string word = temp_path("word.off");
    write_bytes(word, "OFF\n3 1 0\n0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n");
    expect_error_naming(read_mesh(word), word, "line 4: vertex 1: expected a number");

    const std::string ply_word = temp_path("word.ply");
    write_bytes(ply_word,
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
                "property double z\nelement face 1\nproperty list uchar int vertex_indices\n"
                "end_header\n0 0 0\n1 0x1 0\n0 1 0\n3 0 1 2\n");
    expect_error_naming(read_mesh(ply_word), ply_word, "expected a number");

    const std::string short_off = temp_path("short.off");
    write_bytes(short_off, "OFF\n3 2 0\n0.00 0.00 0.00\n1.00 0.00 0.00\n0.00 1.00 0.00\n3 0 1 2\n");
    expect_error_naming(read_mesh(short_off), short_off, "file ends before face 1");

    const std::string no_end = temp_path("no_end.ply");
    write_bytes(no_end, "ply\nformat ascii 1.0\nelement vertex 3\n");
    expect_error_naming(read_mesh(no_end), no_end, "end_header");

    const std::string bad_type = temp_path("bad_type.ply");
    write_bytes(bad_type,
                "ply\nformat ascii 1.0\nelement vertex 1\nproperty int64 x\nend_header\n");
    expect_error_naming(read_mesh(bad_type), bad_type, "unknown property type 'int64'");

    const std::string no_faces = temp_path("points.ply");
    write_bytes(no_faces,
                "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                "property float z\nend_header\n0 0 0\n");
    expect_error_naming(read_mesh(no_faces), no_faces, "no face element");

    const std::string no_triangles = temp_path("no_triangles.off");
    write_bytes(no_triangles, "OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n");
    expect_error_naming(read_mesh(no_triangles), no_triangles, "no triangles");
}

TEST(MeshIo, GarbageBytesAreAnError) {
    std::mt19937 rng(12345);
    std::string garbage(4096, '\0');
    for (char& c : garbage) {
        c = static_cast<char>(rng() & 0xff);
    }
    for (const char* name : {"garbage.ply", "garbage.off", "garbage.obj", "garbage.stl",
                             "garbage.glb", "garbage.bin"}) {
        const std::string path = temp_path(name);
        write_bytes(path, garbage);
        expect_error_naming(read_mesh(path), path);
    }
    const std::string header_garbage = temp_path("header_garbage.ply");
    write_bytes(header_garbage, "ply\n" + garbage);
    expect_error_naming(read_mesh(header_garbage), header_garbage);
}

// Random byte changes, insertions and cuts of valid files: any status is fine, a crash is not,
// and an error must name the file.
TEST(MeshIo, MutatedFilesNeverCrash) {
    std::mt19937 rng(2024);
    TriangleMesh mesh{sample_vertices(), sample_triangles()};
    const std::string off_path = temp_path("mutate_source.off");
    ASSERT_TRUE(write_off(off_path, mesh).ok());
    const std::vector<std::pair<std::string, std::string>> sources = {
        {"mutated.ply", sample_binary_ply(false)},
        {"mutated_be.ply", sample_binary_ply(true)},
        {"mutated_ascii.ply", sample_ascii_ply()},
        {"mutated.off", read_bytes(off_path)},
    };
    std::size_t ok = 0;
    std::size_t failed = 0;
    for (const auto& [name, source] : sources) {
        const std::string path = temp_path(name);
        for (int round = 0; round < 400; ++round) {
            std::string bytes = source;
            const int edits = 1 + static_cast<int>(rng() % 4);
            for (int e = 0; e < edits && !bytes.empty(); ++e) {
                const std::size_t at = rng() % bytes.size();
                switch (rng() % 4) {
                    case 0:
                        bytes[at] = static_cast<char>(rng() & 0xff);
                        break;
                    case 1:
                        bytes[at] = "0123456789 -.e\n#x"[rng() % 17];
                        break;
                    case 2:
                        bytes.insert(at, 1, "9 \n-"[rng() % 4]);
                        break;
                    default:
                        bytes.erase(at, 1 + rng() % 8);
                        break;
                }
            }
            write_bytes(path, bytes);
            const auto read = read_mesh(path);
            if (read.ok()) {
                ++ok;
                EXPECT_FALSE(read->triangles.empty());
            } else {
                ++failed;
                ASSERT_NE(read.status().message().find(path), std::string::npos)
                    << read.status().to_string();
            }
        }
    }
    std::printf("mutated files: %zu read, %zu rejected\n", ok, failed);
    EXPECT_GT(failed, 0u);
}

}  // namespace
}  // namespace proxima
