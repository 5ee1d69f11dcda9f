// The MD2 keyframe reader (proxima/io/md2.hpp): a model written here reads back exactly, malformed
// headers are errors naming the problem, and every truncation and many random corruptions of a
// valid file are errors or valid keyframes, never a read out of bounds (the sanitizer builds run
// this too).
#include <gtest/gtest.h>

#include <bit>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "proxima/io/md2.hpp"

namespace proxima {
namespace {

void put32(std::string& s, std::size_t at, std::uint32_t v) {
    for (int k = 0; k < 4; ++k) {
        s[at + static_cast<std::size_t>(k)] = static_cast<char>((v >> (8 * k)) & 0xff);
    }
}

void append32(std::string& s, std::uint32_t v) {
    s.append(4, '\0');
    put32(s, s.size() - 4, v);
}

void append16(std::string& s, std::uint16_t v) {
    s.push_back(static_cast<char>(v & 0xff));
    s.push_back(static_cast<char>(v >> 8));
}

// A tetrahedron with `frames` keyframes: frame f scales by 0.5 + f and translates by (f, 0, -1).
std::string tetrahedron_md2(std::uint32_t frames) {
    const std::uint32_t nv = 4;
    const std::uint32_t nt = 4;
    const std::uint32_t frame_size = 40 + 4 * nv;
    const std::uint32_t ofs_tris = 68;
    const std::uint32_t ofs_frames = ofs_tris + 12 * nt;
    const std::uint32_t ofs_end = ofs_frames + frames * frame_size;
    std::string s = "IDP2";
    for (std::uint32_t v : {8u, 64u, 64u, frame_size, 0u, nv, 0u, nt, 0u, frames, 68u, 68u,
                            ofs_tris, ofs_frames, ofs_end, ofs_end}) {
        append32(s, v);
    }
    const std::uint16_t tris[4][3] = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    for (const auto& t : tris) {
        for (auto v : t) {
            append16(s, v);
        }
        for (int k = 0; k < 3; ++k) {
            append16(s, 0);
        }
    }
    const std::uint8_t corners[4][3] = {{0, 0, 0}, {10, 0, 0}, {0, 10, 0}, {0, 0, 10}};
    for (std::uint32_t f = 0; f < frames; ++f) {
        const float scale = 0.5F + static_cast<float>(f);
        for (int k = 0; k < 3; ++k) {
            append32(s, std::bit_cast<std::uint32_t>(scale));
        }
        for (float t : {static_cast<float>(f), 0.0F, -1.0F}) {
            append32(s, std::bit_cast<std::uint32_t>(t));
        }
        std::string name = "pose" + std::to_string(f);
        name.resize(16, '\0');
        s += name;
        for (const auto& c : corners) {
            s.push_back(static_cast<char>(c[0]));
            s.push_back(static_cast<char>(c[1]));
            s.push_back(static_cast<char>(c[2]));
            s.push_back('\0');
        }
    }
    return s;
}

TEST(Md2, ReadsKeyframes) {
    auto md2 = parse_md2("tet.md2", tetrahedron_md2(3));
    ASSERT_TRUE(md2.ok()) << md2.status().to_string();
    EXPECT_EQ(md2->vertex_count, 4u);
    ASSERT_EQ(md2->triangles.size(), 4u);
    EXPECT_EQ(md2->triangles[3], (TriangleIndices{1, 2, 3}));
    ASSERT_EQ(md2->frames.size(), 3u);
    EXPECT_EQ(md2->names, (std::vector<std::string>{"pose0", "pose1", "pose2"}));
    // Frame 2: scale 2.5, translate (2, 0, -1); vertex 1 is (10, 0, 0).
    EXPECT_EQ(md2->frames[2][1], (Vec3{27.0, 0.0, -1.0}));
    EXPECT_EQ(md2->frames[0][3], (Vec3{0.0, 0.0, 4.0}));
}

TEST(Md2, MalformedHeadersAreErrors) {
    const std::string good = tetrahedron_md2(2);
    auto fails = [](std::string data, const std::string& says) {
        auto r = parse_md2("m.md2", data);
        ASSERT_FALSE(r.ok()) << says;
        EXPECT_EQ(r.status().code(), StatusCode::invalid_argument);
        EXPECT_NE(r.status().message().find(says), std::string::npos) << r.status().message();
    };
    fails(good.substr(0, 40), "header");
    std::string s = good;
    s[0] = 'X';
    fails(s, "magic");
    s = good;
    put32(s, 4, 7);
    fails(s, "version 7");
    s = good;
    put32(s, 24, 0xffffffffu);  // vertices
    fails(s, "vertices");
    s = good;
    put32(s, 40, 1000);  // frames beyond the file
    fails(s, "frames lie outside");
    s = good;
    put32(s, 52, 0xfffffff0u);  // triangles' offset
    fails(s, "triangles lie outside");
    s = good;
    put32(s, 16, 40);  // frame size without room for the vertices
    fails(s, "too small");
    s = good;
    s[68] = 9;  // triangle 0's first vertex
    fails(s, "names vertex 9");
    s = good;
    put32(s, 68 + 48, 0x7f800000u);  // frame 0's scale x: infinity
    fails(s, "non-finite");
}

TEST(Md2, TruncationsAndCorruptionsNeverReadOutOfBounds) {
    const std::string good = tetrahedron_md2(3);
    for (std::size_t n = 0; n < good.size(); ++n) {
        EXPECT_FALSE(parse_md2("cut.md2", good.substr(0, n)).ok()) << n << " bytes";
    }
    std::mt19937 rng(0x3d2);
    for (int i = 0; i < 4000; ++i) {
        std::string s = good;
        const int flips = 1 + static_cast<int>(rng() % 4);
        for (int k = 0; k < flips; ++k) {
            s[rng() % s.size()] = static_cast<char>(rng() & 0xff);
        }
        auto r = parse_md2("fuzz.md2", s);
        if (r.ok()) {
            for (const auto& t : r->triangles) {
                for (auto v : t) {
                    ASSERT_LT(v, r->vertex_count);
                }
            }
            for (const auto& f : r->frames) {
                ASSERT_EQ(f.size(), r->vertex_count);
            }
        }
    }
}

TEST(Md2, MissingFileIsNotFound) {
    EXPECT_EQ(read_md2("/nonexistent/model.md2").status().code(), StatusCode::not_found);
}

}  // namespace
}  // namespace proxima
