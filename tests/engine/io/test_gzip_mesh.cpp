// gzip-compressed mesh files (issue #18: the shared scans are .ply.gz): read transparently, the
// same mesh bit for bit as the uncompressed file, by extension (.ply.gz, .off.gz), by magic bytes
// under any other name, by content inside a bare .gz; several gzip members; and errors, never a
// crash, for corrupt, truncated, doubly compressed data and decompression bombs.

#include <gtest/gtest.h>
#include <zlib.h>

#include <bit>
#include <cstdint>
#include <filesystem>
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

// gzip framing (not zlib's), at the given level.
std::string gzip(const std::string& data, int level = Z_BEST_COMPRESSION) {
    z_stream s{};
    EXPECT_EQ(deflateInit2(&s, level, Z_DEFLATED, 16 + MAX_WBITS, 8, Z_DEFAULT_STRATEGY), Z_OK);
    std::string out(deflateBound(&s, data.size()) + 64, '\0');
    s.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data.data()));
    s.avail_in = static_cast<uInt>(data.size());
    s.next_out = reinterpret_cast<Bytef*>(out.data());
    s.avail_out = static_cast<uInt>(out.size());
    EXPECT_EQ(deflate(&s, Z_FINISH), Z_STREAM_END);
    out.resize(s.total_out);
    deflateEnd(&s);
    return out;
}

// A mesh whose coordinates a float reader or sloppy parser would change.
TriangleMesh sample() {
    TriangleMesh m;
    m.vertices = {{0.1, 1.0 / 3.0, 1e-300},
                  {-2.5, 1e300, 4.9406564584124654e-324},
                  {3.0000000000000004, -0.0, 123456789.123456789},
                  {0.3, -1.0 / 7.0, 2.0 / 3.0}};
    m.triangles = {{0, 1, 2}, {0, 2, 3}, {1, 3, 2}};
    return m;
}

std::string sample_off() {
    const std::string path = temp_path("gz-sample.off");
    EXPECT_TRUE(write_off(path, sample()).ok());
    return read_bytes(path);
}

void expect_sample(const StatusOr<TriangleMesh>& read) {
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    const TriangleMesh want = sample();
    ASSERT_EQ(read->vertices.size(), want.vertices.size());
    for (std::size_t i = 0; i < want.vertices.size(); ++i) {
        for (int k = 0; k < 3; ++k) {
            EXPECT_EQ(std::bit_cast<std::uint64_t>(read->vertices[i][k]),
                      std::bit_cast<std::uint64_t>(want.vertices[i][k]))
                << "vertex " << i;
        }
    }
    EXPECT_EQ(read->triangles, want.triangles);
}

void expect_error(const StatusOr<TriangleMesh>& read, const std::string& name,
                  const std::string& fragment) {
    ASSERT_FALSE(read.ok()) << name << " was read without error";
    EXPECT_EQ(read.status().code(), StatusCode::invalid_argument) << read.status().to_string();
    EXPECT_NE(read.status().message().find("'" + name + "'"), std::string::npos)
        << read.status().to_string();
    EXPECT_NE(read.status().message().find(fragment), std::string::npos)
        << "expected '" << fragment << "' in: " << read.status().to_string();
}

TEST(GzipMesh, CompressedFilesReadBitExactByExtension) {
    const std::string off = sample_off();
    for (const char* name : {"sample.off.gz", "SAMPLE.OFF.GZ"}) {
        const std::string path = temp_path(name);
        write_bytes(path, gzip(off));
        expect_sample(read_mesh(path, no_weld()));
    }
    // A bare .gz, and gzip data under a name no reader claims: PLY or OFF by content.
    for (const char* name : {"sample.gz", "frame-0001"}) {
        const std::string path = temp_path(name);
        write_bytes(path, gzip(off, 1));
        expect_sample(read_mesh(path, no_weld()));
    }
}

TEST(GzipMesh, FromMemoryByFormatAndByMagic) {
    const std::string packed = gzip(sample_off());
    expect_sample(read_mesh_from_memory(packed, "off.gz", "m.off.gz", no_weld()));
    expect_sample(read_mesh_from_memory(packed, ".OFF.GZ", "m.off.gz", no_weld()));
    expect_sample(read_mesh_from_memory(packed, "gz", "m.gz", no_weld()));
    expect_sample(read_mesh_from_memory(packed, "off", "m.off", no_weld()));  // by magic
}

TEST(GzipMesh, ConcatenatedMembersAreOneFile) {
    const std::string off = sample_off();
    const std::size_t half = off.size() / 2;
    const std::string path = temp_path("members.off.gz");
    write_bytes(path, gzip(off.substr(0, half)) + gzip(off.substr(half)));
    expect_sample(read_mesh(path, no_weld()));
}

TEST(GzipMesh, BadDataIsAnErrorNamingTheFile) {
    const std::string packed = gzip(sample_off());
    const std::string truncated = temp_path("truncated.off.gz");
    write_bytes(truncated, packed.substr(0, packed.size() / 2));
    expect_error(read_mesh(truncated), truncated, "truncated");

    std::string flipped = packed;
    flipped[flipped.size() / 2] = static_cast<char>(flipped[flipped.size() / 2] ^ 0x55);
    flipped[12] = static_cast<char>(flipped[12] ^ 0x55);
    const std::string corrupt = temp_path("corrupt.off.gz");
    write_bytes(corrupt, flipped);
    expect_error(read_mesh(corrupt), corrupt, "gzip data");

    const std::string trailing = temp_path("trailing.off.gz");
    write_bytes(trailing, packed + "garbage");
    expect_error(read_mesh(trailing), trailing, "not gzip");

    const std::string twice = temp_path("twice.off.gz");
    write_bytes(twice, gzip(packed));
    expect_error(read_mesh(twice), twice, "compressed twice");

    const std::string plain = temp_path("plain.off.gz");  // not compressed at all
    write_bytes(plain, sample_off());
    expect_error(read_mesh(plain), plain, "gzip data");

    const std::string other = temp_path("other.gz");  // neither PLY nor OFF inside
    write_bytes(other, gzip("solid x\nendsolid x\n"));
    expect_error(read_mesh(other), other, "neither PLY nor OFF");
}

TEST(GzipMesh, DecompressionStopsAtTheLimit) {
    // 64 MiB of zeros compress to ~64 KiB; a limit of 1 MiB stops the reader there.
    const std::string bomb = gzip(std::string(std::size_t{64} << 20, '\0'));
    ASSERT_LT(bomb.size(), std::size_t{1} << 20);
    MeshReadOptions options;
    options.max_uncompressed_bytes = std::uint64_t{1} << 20;
    expect_error(read_mesh_from_memory(bomb, "off.gz", "bomb.off.gz", options), "bomb.off.gz",
                 "more than 1048576 bytes");
}

// The shared scans as they are distributed.
TEST(GzipMesh, SharedScansRead) {
    const fs::path dir = fs::path(PROXIMA_DATA_DIR) / "meshes" / "scans";
    std::error_code ec;
    if (!fs::is_regular_file(dir / "dragon_vrip_res4.ply.gz", ec)) {
        GTEST_SKIP() << "shared data folder not found (PROXIMA_DATA_DIR='" PROXIMA_DATA_DIR "')";
    }
    const auto read = read_mesh((dir / "dragon_vrip_res4.ply.gz").string());
    ASSERT_TRUE(read.ok()) << read.status().to_string();
    EXPECT_EQ(read->triangles.size(), 11102u);
}

}  // namespace
}  // namespace proxima
