// The on-disk model store: exact round trips through the k-d split, deterministic bytes, corrupt
// chunks and manifests reported as DATA_LOSS (never served, never a crash), atomic generations
// under kill -9 at any moment, the import lock, scene files, sidecars and a full disk.

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <numeric>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "proxima/io/mesh_io.hpp"
#include "proxima/massive/store.hpp"

namespace proxima::massive {
namespace {

namespace fs = std::filesystem;

// A fresh directory per test and process (ctest runs test cases as parallel processes).
class TempDir {
  public:
    explicit TempDir(const std::string& name)
        : m_path(::testing::TempDir() + "proxima_store_" + std::to_string(::getpid()) + "_" +
                 name) {
        fs::remove_all(m_path);
        fs::create_directories(m_path);
    }
    ~TempDir() {
        std::error_code ec;
        fs::remove_all(m_path, ec);
    }
    std::string operator/(const std::string& name) const { return m_path + "/" + name; }
    const std::string& path() const { return m_path; }

  private:
    std::string m_path;
};

std::string read_bytes(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void write_bytes(const std::string& path, const std::string& bytes) {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    ASSERT_TRUE(out.good()) << path;
}

void flip_byte(const std::string& path, std::uint64_t offset) {
    std::string bytes = read_bytes(path);
    ASSERT_LT(offset, bytes.size()) << path;
    bytes[offset] = static_cast<char>(bytes[offset] ^ 0x5a);
    write_bytes(path, bytes);
}

bool same_bits(const Vec3& a, const Vec3& b) {
    return std::bit_cast<std::uint64_t>(a.x) == std::bit_cast<std::uint64_t>(b.x) &&
           std::bit_cast<std::uint64_t>(a.y) == std::bit_cast<std::uint64_t>(b.y) &&
           std::bit_cast<std::uint64_t>(a.z) == std::bit_cast<std::uint64_t>(b.z);
}

bool same_box(const Aabb& a, const Aabb& b) {
    return same_bits(a.lo, b.lo) && same_bits(a.hi, b.hi);
}

Aabb box_of(const std::vector<Vec3>& vertices) {
    Aabb box;
    for (const auto& v : vertices) {
        box.extend(v);
    }
    return box;
}

TriangleMesh make_box(Vec3 c, Vec3 h) {
    TriangleMesh m;
    for (int i = 0; i < 8; ++i) {
        m.vertices.push_back({c.x + ((i & 1) ? h.x : -h.x), c.y + ((i & 2) ? h.y : -h.y),
                              c.z + ((i & 4) ? h.z : -h.z)});
    }
    m.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                   {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
    return m;
}

// A UV sphere with coordinates that are not round numbers (exactness is tested on them).
TriangleMesh make_sphere(Vec3 c, double r, int rings, int segments) {
    TriangleMesh m;
    m.vertices.push_back({c.x, c.y, c.z + r});
    for (int i = 1; i < rings; ++i) {
        const double th = std::numbers::pi * i / rings;
        for (int j = 0; j < segments; ++j) {
            const double ph = 2 * std::numbers::pi * j / segments;
            m.vertices.push_back({c.x + r * std::sin(th) * std::cos(ph),
                                  c.y + r * std::sin(th) * std::sin(ph), c.z + r * std::cos(th)});
        }
    }
    m.vertices.push_back({c.x, c.y, c.z - r});
    const auto south = static_cast<std::uint32_t>(m.vertices.size() - 1);
    auto ring = [&](int i, int j) {
        return static_cast<std::uint32_t>(1 + (i - 1) * segments + (j % segments));
    };
    for (int j = 0; j < segments; ++j) {
        m.triangles.push_back({0, ring(1, j), ring(1, j + 1)});
        m.triangles.push_back({south, ring(rings - 1, j + 1), ring(rings - 1, j)});
    }
    for (int i = 1; i + 1 < rings; ++i) {
        for (int j = 0; j < segments; ++j) {
            m.triangles.push_back({ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)});
            m.triangles.push_back({ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)});
        }
    }
    return m;
}

// Some small objects that stay whole and some large ones that are split.
std::vector<ModelObject> small_model(int scale = 1) {
    std::vector<ModelObject> objects;
    objects.push_back({"box-a", make_box({0.1, 0.2, 0.3}, {1.0 / 3, 0.7, 0.9})});
    objects.push_back({"sphere-big", make_sphere({3.3, -1.7, 0.25}, 2.1, 40 * scale, 60 * scale)});
    objects.push_back({"box-b", make_box({-4.5, 1e-3, 7.25}, {0.01, 2.5, 1e-7})});
    objects.push_back({"sphere-mid", make_sphere({-2, 5, 1}, 0.9, 16, 24)});
    objects.push_back({"sphere-huge", make_sphere({10, 10, 10}, 5.0 / 7, 80 * scale, 90)});
    return objects;
}

Status write_store(const std::string& dir, const std::vector<ModelObject>& objects,
                   const StoreOptions& options) {
    auto writer = StoreWriter::create(dir, options);
    if (!writer.ok()) {
        return writer.status();
    }
    for (const auto& o : objects) {
        if (Status s = writer.value()->add(o); !s.ok()) {
            return s;
        }
    }
    auto summary = writer.value()->commit();
    return summary.ok() ? Status() : summary.status();
}

std::vector<std::string> dir_entries(const std::string& dir) {
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(dir)) {
        names.push_back(e.path().filename().string());
    }
    std::sort(names.begin(), names.end());
    return names;
}

// Every piece, reassembled through source_triangles, gives exactly the objects' triangles; boxes
// are exact; unsplit objects are stored as they are; every piece fits the limit.
void expect_store_matches(const Store& store, const std::vector<ModelObject>& objects,
                          std::uint64_t max_piece_bytes) {
    ASSERT_EQ(store.objects().size(), objects.size());
    std::uint64_t triangles = 0;
    for (std::size_t i = 0; i < objects.size(); ++i) {
        const auto& mesh = objects[i].mesh;
        const auto& info = store.objects()[i];
        triangles += mesh.triangles.size();
        EXPECT_EQ(info.name, objects[i].name);
        EXPECT_EQ(info.vertex_count, mesh.vertices.size());
        EXPECT_EQ(info.triangle_count, mesh.triangles.size());
        EXPECT_TRUE(same_box(info.box, box_of(mesh.vertices))) << objects[i].name;
        ASSERT_GE(info.piece_count, 1u);
        const bool fits =
            piece_weight(mesh.vertices.size(), mesh.triangles.size()) <= max_piece_bytes;
        EXPECT_EQ(info.piece_count == 1, fits) << objects[i].name;
        std::vector<int> seen(mesh.triangles.size(), 0);
        for (std::uint32_t p = info.first_piece; p < info.first_piece + info.piece_count; ++p) {
            const PieceInfo& pi = store.pieces()[p];
            EXPECT_EQ(pi.object, i);
            EXPECT_LE(pi.weight(), max_piece_bytes) << "piece " << p;
            auto g = store.read_piece(p);
            ASSERT_TRUE(g.ok()) << g.status().to_string();
            EXPECT_EQ(g->vertices.size(), pi.vertex_count);
            EXPECT_EQ(g->triangles.size(), pi.triangle_count);
            EXPECT_TRUE(same_box(pi.box, box_of(g->vertices))) << "piece " << p;
            if (fits) {
                ASSERT_EQ(g->vertices.size(), mesh.vertices.size());
                for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
                    ASSERT_TRUE(same_bits(g->vertices[v], mesh.vertices[v]));
                }
                EXPECT_EQ(g->triangles, mesh.triangles);
                // The whole object in order: no per-triangle map is kept resident.
                EXPECT_TRUE(g->source_triangles.empty()) << objects[i].name;
                EXPECT_EQ(g->source_map(), nullptr);
            }

            std::vector<char> used(g->vertices.size(), 0);
            const auto ids = g->source_ids();
            ASSERT_EQ(ids.size(), g->triangles.size());
            // A map is kept exactly when it is not the identity (a split piece's, mostly).
            std::vector<std::uint32_t> in_order(ids.size());
            std::iota(in_order.begin(), in_order.end(), 0u);
            EXPECT_EQ(g->source_triangles.empty(), ids == in_order) << "piece " << p;
            EXPECT_EQ(g->source_map() == nullptr, ids == in_order) << "piece " << p;
            for (std::size_t t = 0; t < g->triangles.size(); ++t) {
                const auto s = g->source(t);
                ASSERT_EQ(ids[t], s);
                ASSERT_LT(s, mesh.triangles.size());
                ++seen[s];
                for (int k = 0; k < 3; ++k) {
                    used[g->triangles[t][k]] = 1;
                    ASSERT_TRUE(same_bits(g->vertices[g->triangles[t][k]],
                                          mesh.vertices[mesh.triangles[s][k]]))
                        << "object " << i << " piece " << p << " triangle " << t;
                }
            }
            if (!fits) {
                // Compact: a split piece keeps only the vertices its triangles use.
                EXPECT_TRUE(std::all_of(used.begin(), used.end(), [](char u) { return u; }));
            }
        }
        EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](int n) { return n == 1; }))
            << "every triangle of " << objects[i].name << " in exactly one piece";
    }
    EXPECT_EQ(store.summary().triangles, triangles);
    EXPECT_EQ(store.summary().objects, objects.size());
    EXPECT_EQ(store.summary().pieces, store.pieces().size());
}

TEST(Store, RoundTripWithoutSplitting) {
    TempDir tmp("roundtrip");
    const auto objects = small_model();
    StoreOptions options;  // the default limit: nothing here is split
    ASSERT_TRUE(write_store(tmp.path(), objects, options).ok());
    auto store = Store::open(tmp.path());
    ASSERT_TRUE(store.ok()) << store.status().to_string();
    EXPECT_EQ(store.value()->pieces().size(), objects.size());
    EXPECT_EQ(store.value()->summary().split_objects, 0u);
    EXPECT_EQ(store.value()->summary().generation, "gen-000001");
    expect_store_matches(*store.value(), objects, options.max_piece_bytes);
    EXPECT_EQ(store.value()->pieces_read(), objects.size());
    EXPECT_GT(store.value()->bytes_read(), 0u);
    EXPECT_TRUE(store.value()->verify().ok());
    EXPECT_EQ(dir_entries(tmp.path()), (std::vector<std::string>{"CURRENT", "LOCK", "gen-000001"}));
}

TEST(Store, SplitPiecesFitAndReassembleExactly) {
    TempDir tmp("split");
    const auto objects = small_model();
    StoreOptions options;
    options.max_piece_bytes = 40'000;
    options.chunk_bytes = 4096;
    ASSERT_TRUE(write_store(tmp.path(), objects, options).ok());
    auto store = Store::open(tmp.path());
    ASSERT_TRUE(store.ok()) << store.status().to_string();
    EXPECT_GT(store.value()->pieces().size(), 20u);
    EXPECT_EQ(store.value()->summary().split_objects, 3u);
    expect_store_matches(*store.value(), objects, options.max_piece_bytes);
    EXPECT_TRUE(store.value()->verify().ok());
}

TEST(Store, TinyPiecesAndDegenerateCentres) {
    // All centres equal: the median split falls back on triangle indices and still halves.
    TempDir tmp("degenerate");
    TriangleMesh flat;
    for (std::uint32_t i = 0; i < 200; ++i) {
        flat.vertices.push_back({0, 0, 0});
        flat.vertices.push_back({1, 0, 0});
        flat.vertices.push_back({0, 1, 0});
        flat.triangles.push_back({3 * i, 3 * i + 1, 3 * i + 2});
    }
    std::vector<ModelObject> objects{{"stack", flat}, {"box", make_box({0, 0, 0}, {1, 1, 1})}};
    StoreOptions options;
    options.max_piece_bytes = piece_weight(3, 1);  // one triangle per piece
    options.chunk_bytes = 64;
    ASSERT_TRUE(write_store(tmp.path(), objects, options).ok());
    auto store = Store::open(tmp.path());
    ASSERT_TRUE(store.ok()) << store.status().to_string();
    EXPECT_EQ(store.value()->pieces().size(), 212u);
    expect_store_matches(*store.value(), objects, options.max_piece_bytes);

    options.max_piece_bytes = piece_weight(3, 1) - 1;
    auto refused = StoreWriter::create(tmp / "other", options);
    EXPECT_EQ(refused.status().code(), StatusCode::invalid_argument);
}

TEST(Store, DeterministicBytes) {
    TempDir tmp("determinism");
    const auto objects = small_model();
    StoreOptions options;
    options.max_piece_bytes = 30'000;
    options.chunk_bytes = 1000;
    options.source = "test model";
    ASSERT_TRUE(write_store(tmp / "one", objects, options).ok());
    ASSERT_TRUE(write_store(tmp / "two", objects, options).ok());
    // A second import into the same directory: a new generation with the same bytes.
    ASSERT_TRUE(write_store(tmp / "two", objects, options).ok());
    const auto one = tmp / "one/gen-000001";
    const auto two = tmp / "two/gen-000002";
    EXPECT_EQ(dir_entries(one), dir_entries(two));
    EXPECT_EQ(dir_entries(tmp / "two"),
              (std::vector<std::string>{"CURRENT", "LOCK", "gen-000002"}));
    for (const auto& name : dir_entries(one)) {
        EXPECT_EQ(read_bytes(one + "/" + name), read_bytes(two + "/" + name)) << name;
    }
}

TEST(Store, PiecesAcrossDataFiles) {
    // Small data files (a test hook), so pieces and verify cross file boundaries.
    TempDir tmp("files");
    const auto objects = small_model();
    StoreOptions options;
    options.max_piece_bytes = 100'000;
    options.chunk_bytes = 3000;
    ::setenv("PROXIMA_STORE_TEST_FILE_BYTES", "20000", 1);
    const Status written = write_store(tmp.path(), objects, options);
    ::unsetenv("PROXIMA_STORE_TEST_FILE_BYTES");
    ASSERT_TRUE(written.ok()) << written.to_string();
    auto store = Store::open(tmp.path());
    ASSERT_TRUE(store.ok()) << store.status().to_string();
    EXPECT_TRUE(fs::exists(tmp / "gen-000001/chunks-0010.bin"));
    expect_store_matches(*store.value(), objects, options.max_piece_bytes);
    EXPECT_TRUE(store.value()->verify().ok());
}

TEST(Store, ConcurrentReadsAgree) {
    TempDir tmp("threads");
    const auto objects = small_model();
    StoreOptions options;
    options.max_piece_bytes = 30'000;
    options.chunk_bytes = 2048;
    ASSERT_TRUE(write_store(tmp.path(), objects, options).ok());
    auto opened = Store::open(tmp.path());
    ASSERT_TRUE(opened.ok());
    const Store& store = *opened.value();
    std::vector<PieceGeometry> expected;
    for (std::uint32_t p = 0; p < store.pieces().size(); ++p) {
        expected.push_back(store.read_piece(p).value());
    }
    std::vector<int> failures(4, 0);
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t) {
        threads.emplace_back([&, t] {
            for (int round = 0; round < 5; ++round) {
                for (std::uint32_t p = 0; p < store.pieces().size(); ++p) {
                    auto g = store.read_piece((p * 7 + t) % store.pieces().size());
                    const auto& e = expected[(p * 7 + t) % store.pieces().size()];
                    if (!g.ok() || g->triangles != e.triangles ||
                        g->source_triangles != e.source_triangles) {
                        ++failures[t];
                    }
                }
            }
        });
    }
    for (auto& t : threads) {
        t.join();
    }
    EXPECT_EQ(failures, std::vector<int>(4, 0));
    EXPECT_EQ(store.pieces_read(), store.pieces().size() * 21);
}

TEST(Store, CorruptChunkIsReportedAndNeverServed) {
    TempDir tmp("corrupt_chunk");
    const auto objects = small_model();
    StoreOptions options;
    options.max_piece_bytes = 30'000;
    options.chunk_bytes = 4096;
    ASSERT_TRUE(write_store(tmp.path(), objects, options).ok());
    const std::string data = tmp / "gen-000001/chunks-0000.bin";
    const std::uint64_t size = fs::file_size(data);
    const std::uint64_t offset = size / 2 + 17;
    const std::uint64_t chunk = offset / options.chunk_bytes;
    flip_byte(data, offset);

    auto opened = Store::open(tmp.path());
    ASSERT_TRUE(opened.ok()) << "chunks are checked piece by piece, not at open";
    const Store& store = *opened.value();
    int bad = 0;
    for (std::uint32_t p = 0; p < store.pieces().size(); ++p) {
        const auto& pi = store.pieces()[p];
        const bool touches = pi.offset / options.chunk_bytes <= chunk &&
                             (pi.offset + pi.bytes - 1) / options.chunk_bytes >= chunk;
        auto g = store.read_piece(p);
        if (touches) {
            ++bad;
            ASSERT_FALSE(g.ok()) << "piece " << p;
            EXPECT_EQ(g.status().code(), StatusCode::data_loss);
            EXPECT_NE(g.status().message().find("chunk " + std::to_string(chunk) + " "),
                      std::string::npos)
                << g.status().message();
            EXPECT_NE(g.status().message().find("checksum mismatch"), std::string::npos);
            EXPECT_NE(g.status().message().find("gen-000001"), std::string::npos);
            EXPECT_NE(g.status().message().find("not served"), std::string::npos);
        } else {
            EXPECT_TRUE(g.ok()) << "piece " << p << ": " << g.status().to_string();
        }
    }
    EXPECT_GE(bad, 1);
    const Status verified = store.verify();
    EXPECT_EQ(verified.code(), StatusCode::data_loss);
    EXPECT_NE(verified.message().find("chunk " + std::to_string(chunk) + " "), std::string::npos)
        << verified.message();
}

TEST(Store, CorruptManifestFailsOpen) {
    TempDir tmp("corrupt_manifest");
    ASSERT_TRUE(write_store(tmp.path(), small_model(), {}).ok());
    const std::string manifest = tmp / "gen-000001/manifest.json";
    const std::string good = read_bytes(manifest);
    for (std::uint64_t offset : {std::uint64_t{5}, good.size() / 2, good.size() - 2}) {
        flip_byte(manifest, offset);
        auto store = Store::open(tmp.path());
        EXPECT_EQ(store.status().code(), StatusCode::data_loss) << offset;
        EXPECT_NE(store.status().message().find("manifest"), std::string::npos);
        write_bytes(manifest, good);
    }
    ASSERT_TRUE(Store::open(tmp.path()).ok());
    // The binary tables (pieces, chunk checksums): corrupt, truncated, missing.
    const std::string tables = tmp / "gen-000001/manifest.bin";
    const std::string good_tables = read_bytes(tables);
    for (std::uint64_t offset : {std::uint64_t{0}, std::uint64_t{30}, good_tables.size() - 1}) {
        flip_byte(tables, offset);
        auto store = Store::open(tmp.path());
        EXPECT_EQ(store.status().code(), StatusCode::data_loss) << offset;
        EXPECT_NE(store.status().message().find("manifest.bin"), std::string::npos)
            << store.status().message();
        write_bytes(tables, good_tables);
    }
    write_bytes(tables, good_tables.substr(0, 40));
    EXPECT_EQ(Store::open(tmp.path()).status().code(), StatusCode::data_loss);
    fs::remove(tables);
    EXPECT_EQ(Store::open(tmp.path()).status().code(), StatusCode::data_loss);
    write_bytes(tables, good_tables);
    ASSERT_TRUE(Store::open(tmp.path()).ok());
    // A truncated manifest, a missing checksum file, a CURRENT naming nothing.
    write_bytes(manifest, good.substr(0, good.size() / 3));
    EXPECT_EQ(Store::open(tmp.path()).status().code(), StatusCode::data_loss);
    write_bytes(manifest, good);
    fs::remove(tmp / "gen-000001/manifest.crc");
    EXPECT_EQ(Store::open(tmp.path()).status().code(), StatusCode::data_loss);
    write_bytes(tmp / "CURRENT", "gen-000009\n");
    EXPECT_EQ(Store::open(tmp.path()).status().code(), StatusCode::data_loss);
    write_bytes(tmp / "CURRENT", "garbage");
    EXPECT_EQ(Store::open(tmp.path()).status().code(), StatusCode::data_loss);
    // A new import replaces the damaged store.
    ASSERT_TRUE(write_store(tmp.path(), small_model(), {}).ok());
    EXPECT_TRUE(Store::open(tmp.path()).ok());
}

TEST(Store, TruncatedOrMissingChunkFileIsAnErrorNotACrash) {
    TempDir tmp("truncated");
    const auto objects = small_model();
    StoreOptions options;
    options.max_piece_bytes = 30'000;
    options.chunk_bytes = 4096;
    ASSERT_TRUE(write_store(tmp.path(), objects, options).ok());
    const std::string data = tmp / "gen-000001/chunks-0000.bin";
    const std::string good = read_bytes(data);
    for (std::size_t keep : {good.size() / 2, good.size() - 1, std::size_t{0}}) {
        write_bytes(data, good.substr(0, keep));
        auto opened = Store::open(tmp.path());
        ASSERT_TRUE(opened.ok());
        const Store& store = *opened.value();
        int failed = 0;
        for (std::uint32_t p = 0; p < store.pieces().size(); ++p) {
            auto g = store.read_piece(p);
            const auto& pi = store.pieces()[p];
            if (pi.offset + pi.bytes <= keep / options.chunk_bytes * options.chunk_bytes) {
                EXPECT_TRUE(g.ok()) << g.status().to_string();
            } else if (!g.ok()) {
                ++failed;
                EXPECT_TRUE(g.status().code() == StatusCode::data_loss ||
                            g.status().code() == StatusCode::unavailable);
            }
        }
        EXPECT_GE(failed, 1);
        EXPECT_EQ(store.verify().code(), StatusCode::data_loss);
    }
    fs::remove(data);
    auto opened = Store::open(tmp.path());
    ASSERT_TRUE(opened.ok());
    EXPECT_EQ(opened.value()->read_piece(0).status().code(), StatusCode::data_loss);
    EXPECT_EQ(opened.value()->verify().code(), StatusCode::data_loss);
}

TEST(Store, MissingStoreIsNotFound) {
    TempDir tmp("missing");
    EXPECT_EQ(Store::open(tmp / "nothing").status().code(), StatusCode::not_found);
    EXPECT_EQ(Store::open(tmp.path()).status().code(), StatusCode::not_found);
}

TEST(Store, WriterWithoutCommitLeavesThePreviousStore) {
    TempDir tmp("abandon");
    auto first = small_model();
    ASSERT_TRUE(write_store(tmp.path(), first, {}).ok());
    const std::string manifest = read_bytes(tmp / "gen-000001/manifest.json");
    {
        auto writer = StoreWriter::create(tmp.path());
        ASSERT_TRUE(writer.ok());
        ASSERT_TRUE(writer.value()->add({"other", make_box({9, 9, 9}, {1, 1, 1})}).ok());
        EXPECT_TRUE(fs::exists(tmp / "gen-000002.tmp"));
    }
    EXPECT_EQ(dir_entries(tmp.path()), (std::vector<std::string>{"CURRENT", "LOCK", "gen-000001"}));
    auto store = Store::open(tmp.path());
    ASSERT_TRUE(store.ok());
    EXPECT_EQ(store.value()->summary().generation, "gen-000001");
    expect_store_matches(*store.value(), first, StoreOptions{}.max_piece_bytes);

    // An invalid object aborts the import: removed at once, the previous store stays.
    {
        auto writer = StoreWriter::create(tmp.path());
        ASSERT_TRUE(writer.ok());
        TriangleMesh bad = make_box({0, 0, 0}, {1, 1, 1});
        bad.vertices[3].y = std::nan("");
        const Status s = writer.value()->add({"bad-object", bad});
        EXPECT_EQ(s.code(), StatusCode::invalid_argument);
        EXPECT_NE(s.message().find("bad-object"), std::string::npos) << s.message();
        EXPECT_FALSE(fs::exists(tmp / "gen-000002.tmp"));
        EXPECT_EQ(writer.value()->add({"ok", make_box({0, 0, 0}, {1, 1, 1})}).code(),
                  StatusCode::failed_precondition);
        EXPECT_EQ(writer.value()->commit().status().code(), StatusCode::failed_precondition);
    }
    EXPECT_EQ(read_bytes(tmp / "gen-000001/manifest.json"), manifest);
    EXPECT_EQ(read_bytes(tmp / "CURRENT"), "gen-000001\n");
}

TEST(Store, SecondWriterIsRefused) {
    TempDir tmp("lock");
    auto first = StoreWriter::create(tmp.path());
    ASSERT_TRUE(first.ok());
    auto second = StoreWriter::create(tmp.path());
    ASSERT_FALSE(second.ok());
    EXPECT_EQ(second.status().code(), StatusCode::failed_precondition);
    EXPECT_NE(second.status().message().find("already running"), std::string::npos);
    ASSERT_TRUE(first.value()->add({"a", make_box({0, 0, 0}, {1, 1, 1})}).ok());
    ASSERT_TRUE(first.value()->commit().ok());
    EXPECT_EQ(StoreWriter::create(tmp.path()).status().code(), StatusCode::failed_precondition)
        << "the lock is held until the writer is destroyed";
    first.value().reset();
    EXPECT_TRUE(StoreWriter::create(tmp.path()).ok());
    EXPECT_TRUE(Store::open(tmp.path()).ok());
}

// ---- kill -9 ----------------------------------------------------------------------------------

// The model a killed child imports: tens of megabytes, generated object by object while writing.
StoreOptions big_options() {
    StoreOptions options;
    options.max_piece_bytes = 2'000'000;
    options.chunk_bytes = 64 * 1024;
    options.source = "kill test model";
    return options;
}

Status write_big_store(const std::string& dir) {
    auto writer = StoreWriter::create(dir, big_options());
    if (!writer.ok()) {
        return writer.status();
    }
    for (int i = 0; i < 24; ++i) {
        const Vec3 c{i * 3.0, (i % 5) * 1.5, (i % 3) * 0.25};
        if (Status s = writer.value()->add(
                {"sphere-" + std::to_string(i), make_sphere(c, 1.0 + i / 7.0, 150, 200)});
            !s.ok()) {
            return s;
        }
    }
    auto summary = writer.value()->commit();
    return summary.ok() ? Status() : summary.status();
}

// Runs write_big_store in a child (with PROXIMA_STORE_FAULT = fault when given), kills it with
// SIGKILL after `delay` seconds (never when delay < 0), and returns how it ended.
struct ChildEnd {
    bool killed = false;
    int exit_code = -1;
    double seconds = 0;
};

ChildEnd import_in_child(const std::string& dir, double delay, const char* fault = nullptr) {
    const auto start = std::chrono::steady_clock::now();
    const pid_t pid = ::fork();
    if (pid == 0) {
        if (fault != nullptr) {
            ::setenv("PROXIMA_STORE_FAULT", fault, 1);
        }
        const Status s = write_big_store(dir);
        if (!s.ok()) {
            std::fprintf(stderr, "child import failed: %s\n", s.to_string().c_str());
        }
        ::_exit(s.ok() ? 0 : 3);
    }
    if (delay >= 0) {
        std::this_thread::sleep_for(std::chrono::duration<double>(delay));
        ::kill(pid, SIGKILL);
    }
    int status = 0;
    ::waitpid(pid, &status, 0);
    ChildEnd end;
    end.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    end.killed = WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
    end.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    return end;
}

// The live generation's files equal those of a reference store, byte for byte.
bool same_generation_files(const std::string& dir, const std::string& ref_dir) {
    const auto gen = read_bytes(dir + "/CURRENT");
    const auto ref_gen = read_bytes(ref_dir + "/CURRENT");
    const std::string a = dir + "/" + gen.substr(0, gen.size() - 1);
    const std::string b = ref_dir + "/" + ref_gen.substr(0, ref_gen.size() - 1);
    if (dir_entries(a) != dir_entries(b)) {
        return false;
    }
    for (const auto& name : dir_entries(a)) {
        if (read_bytes(a + "/" + name) != read_bytes(b + "/" + name)) {
            return false;
        }
    }
    return true;
}

TEST(StoreCrash, KillDuringImportLeavesOldOrNewStore) {
    TempDir tmp("kill");
    const auto model_a = small_model();
    StoreOptions options_a;
    options_a.max_piece_bytes = 30'000;
    ASSERT_TRUE(write_store(tmp / "ref-a", model_a, options_a).ok());
    // Store B is written by a child too, so the parent never holds the big model.
    const ChildEnd full = import_in_child(tmp / "ref-b", -1);
    ASSERT_EQ(full.exit_code, 0);
    const std::uint64_t b_bytes = Store::open(tmp / "ref-b").value()->summary().bytes;
    EXPECT_GT(b_bytes, 20u << 20) << "the killed import should write tens of megabytes";
    const double duration = full.seconds;

    const std::string dir = tmp / "live";
    int saw_a = 0;
    int saw_b = 0;
    auto check_after_kill = [&](const std::string& what) {
        SCOPED_TRACE(what);
        auto store = Store::open(dir);
        ASSERT_TRUE(store.ok()) << store.status().to_string();
        ASSERT_TRUE(store.value()->verify().ok());
        const bool is_b = store.value()->summary().bytes == b_bytes;
        if (is_b) {
            ++saw_b;
            EXPECT_TRUE(same_generation_files(dir, tmp / "ref-b"));
        } else {
            ++saw_a;
            EXPECT_TRUE(same_generation_files(dir, tmp / "ref-a"));
            expect_store_matches(*store.value(), model_a, options_a.max_piece_bytes);
        }
        // The next import succeeds and leaves nothing stale behind.
        ASSERT_TRUE(write_store(dir, model_a, options_a).ok());
        const auto entries = dir_entries(dir);
        ASSERT_EQ(entries.size(), 3u) << ::testing::PrintToString(entries);
        EXPECT_TRUE(same_generation_files(dir, tmp / "ref-a"));
    };

    ASSERT_TRUE(write_store(dir, model_a, options_a).ok());
    for (int i = 0; i <= 10; ++i) {
        const double delay = duration * i / 10.0;
        const ChildEnd end = import_in_child(dir, delay);
        EXPECT_TRUE(end.killed || end.exit_code == 0);
        check_after_kill("kill after " + std::to_string(delay) + " s");
    }
    for (const char* fault : {"before-gen-rename", "after-gen-rename", "before-current-rename",
                              "after-current-rename"}) {
        const ChildEnd end = import_in_child(dir, -1, fault);
        EXPECT_TRUE(end.killed) << fault;
        check_after_kill(fault);
    }
    EXPECT_GE(saw_a, 4);  // at least the first kill and the three faults before the switch
    EXPECT_GE(saw_b, 1);  // the fault after the switch
    std::printf("[ kill -9 ] import %.2f s; %d kills left store A, %d store B\n", duration, saw_a,
                saw_b);
}

TEST(StoreCrash, KillDuringFirstImportLeavesNoStoreOrAComplete) {
    TempDir tmp("kill_first");
    const ChildEnd full = import_in_child(tmp / "ref", -1);
    ASSERT_EQ(full.exit_code, 0);
    for (int i = 0; i <= 5; ++i) {
        const std::string dir = tmp / ("live-" + std::to_string(i));
        import_in_child(dir, full.seconds * i / 5.0);
        auto store = Store::open(dir);
        if (store.ok()) {
            EXPECT_TRUE(store.value()->verify().ok());
            EXPECT_TRUE(same_generation_files(dir, tmp / "ref"));
        } else {
            EXPECT_EQ(store.status().code(), StatusCode::not_found) << store.status().to_string();
        }
        ASSERT_TRUE(write_store(dir, small_model(), {}).ok());
        EXPECT_EQ(dir_entries(dir).size(), 3u);
    }
    for (const char* fault : {"before-gen-rename", "after-gen-rename", "before-current-rename"}) {
        const std::string dir = tmp / fault;
        EXPECT_TRUE(import_in_child(dir, -1, fault).killed);
        EXPECT_EQ(Store::open(dir).status().code(), StatusCode::not_found) << fault;
    }
}

TEST(StoreCrash, FileSizeLimitIsAClearErrorAndKeepsThePreviousStore) {
    // RLIMIT_FSIZE makes write() fail with EFBIG, the closest cheap stand-in for ENOSPC: the same
    // path (a failed write during import) must give a clear error and clean up.
    TempDir tmp("efbig");
    const auto model_a = small_model();
    ASSERT_TRUE(write_store(tmp.path(), model_a, {}).ok());
    const std::string manifest = read_bytes(tmp / "gen-000001/manifest.json");
    int fds[2];
    ASSERT_EQ(::pipe(fds), 0);
    const pid_t pid = ::fork();
    if (pid == 0) {
        ::close(fds[0]);
        ::signal(SIGXFSZ, SIG_IGN);
        rlimit limit{1 << 20, 1 << 20};
        ::setrlimit(RLIMIT_FSIZE, &limit);
        const Status s = write_big_store(tmp.path());
        const std::string out = std::to_string(static_cast<int>(s.code())) + " " + s.message();
        (void)!::write(fds[1], out.data(), out.size());
        ::_exit(0);
    }
    ::close(fds[1]);
    std::string reply;
    char buf[512];
    for (ssize_t n; (n = ::read(fds[0], buf, sizeof buf)) > 0;) {
        reply.append(buf, static_cast<std::size_t>(n));
    }
    ::close(fds[0]);
    int status = 0;
    ::waitpid(pid, &status, 0);
    ASSERT_TRUE(WIFEXITED(status));
    EXPECT_EQ(reply.substr(0, reply.find(' ')),
              std::to_string(static_cast<int>(StatusCode::resource_exhausted)))
        << reply;
    EXPECT_NE(reply.find("file too large"), std::string::npos) << reply;
    EXPECT_NE(reply.find("chunks-0000.bin"), std::string::npos) << reply;
    EXPECT_EQ(dir_entries(tmp.path()), (std::vector<std::string>{"CURRENT", "LOCK", "gen-000001"}));
    EXPECT_EQ(read_bytes(tmp / "gen-000001/manifest.json"), manifest);
    auto store = Store::open(tmp.path());
    ASSERT_TRUE(store.ok());
    EXPECT_TRUE(store.value()->verify().ok());
}

// ---- import_files ----------------------------------------------------------------------------

TEST(Import, MeshFilesAndDirectories) {
    TempDir tmp("import_dir");
    fs::create_directories(tmp / "in/sub");
    const auto box = make_box({1, 2, 3}, {0.5, 0.25, 0.125});
    const auto sphere = make_sphere({0.3, 0.1, 0.7}, 1.0 / 3, 10, 12);
    ASSERT_TRUE(write_off(tmp / "in/b.off", box).ok());
    ASSERT_TRUE(write_off(tmp / "in/sub/a.off", sphere).ok());
    write_bytes(tmp / "in/readme.txt", "not a mesh");
    write_bytes(tmp / "in/.hidden.off", "not read");
    ASSERT_TRUE(write_off(tmp / "single.off", box).ok());

    std::vector<Progress> seen;
    auto summary = import_files({tmp / "in", tmp / "single.off"}, tmp / "store", {},
                                [&](const Progress& p) { seen.push_back(p); });
    ASSERT_TRUE(summary.ok()) << summary.status().to_string();
    EXPECT_EQ(summary->objects, 3u);
    auto store = Store::open(tmp / "store");
    ASSERT_TRUE(store.ok());
    const auto& objects = store.value()->objects();
    ASSERT_EQ(objects.size(), 3u);
    EXPECT_EQ(objects[0].name, "b.off");
    EXPECT_EQ(objects[1].name, "sub/a.off");
    EXPECT_EQ(objects[2].name, tmp / "single.off");
    expect_store_matches(*store.value(),
                         {{"b.off", read_mesh(tmp / "in/b.off").value()},
                          {"sub/a.off", read_mesh(tmp / "in/sub/a.off").value()},
                          {tmp / "single.off", read_mesh(tmp / "single.off").value()}},
                         StoreOptions{}.max_piece_bytes);
    ASSERT_FALSE(seen.empty());
    EXPECT_EQ(seen.front().step, "reading");
    EXPECT_TRUE(std::any_of(seen.begin(), seen.end(), [](const Progress& p) {
        return p.step == "reading" && p.done == 3 && p.total == 3;
    }));
    EXPECT_EQ(seen.back().step, "syncing");
    EXPECT_EQ(seen.back().done, seen.back().total);

    EXPECT_EQ(import_files({tmp / "nope.off"}, tmp / "store2", {}).status().code(),
              StatusCode::not_found);
    EXPECT_EQ(import_files({}, tmp / "store2", {}).status().code(), StatusCode::invalid_argument);
    fs::create_directories(tmp / "empty");
    EXPECT_EQ(import_files({tmp / "empty"}, tmp / "store2", {}).status().code(),
              StatusCode::invalid_argument);
}

TEST(Import, SceneFileAppliesTransformsAndSharesInstances) {
    TempDir tmp("scene");
    fs::create_directories(tmp / "meshes");
    ASSERT_TRUE(write_off(tmp / "meshes/box.off", make_box({0.1, 0.2, 0.3}, {1, 2, 3})).ok());
    ASSERT_TRUE(write_off(tmp / "meshes/ball.off", make_sphere({0, 0, 0}, 0.7, 8, 10)).ok());
    const double c = std::cos(0.3);
    const double s = std::sin(0.3);
    Affine rot;
    rot.m = {c, -s, 0, 10.125, s, c, 0, -3.5, 0, 0, 1, 0.1};
    Affine scale;
    scale.m = {2, 0, 0, 1, 0, 0.5, 0, 2, 0, 0, 3, 3};
    nlohmann::json scene = {
        {"format", "proxima-scene/1"},
        {"meshes", {{"box", "meshes/box.off"}, {"ball", tmp / "meshes/ball.off"}}},
        {"objects",
         {{{"name", "room/box-1"}, {"parts", {{{"mesh", "box"}, {"transform", rot.m}}}}},
          {{"name", "room/box-and-ball"},
           {"parts", {{{"mesh", "box"}, {"transform", scale.m}}, {{"mesh", "ball"}}}}},
          {{"name", "room/ball-2"}, {"parts", {{{"mesh", "ball"}, {"transform", rot.m}}}}}}}};
    write_bytes(tmp / "scene.json", scene.dump(2));
    auto summary = import_files({tmp / "scene.json"}, tmp / "store", {});
    ASSERT_TRUE(summary.ok()) << summary.status().to_string();

    const TriangleMesh box = read_mesh(tmp / "meshes/box.off").value();
    const TriangleMesh ball = read_mesh(tmp / "meshes/ball.off").value();
    auto transformed = [](const TriangleMesh& m, const Affine* a) {
        TriangleMesh out = m;
        if (a != nullptr) {
            for (auto& v : out.vertices) {
                v = a->apply(v);
            }
        }
        return out;
    };
    auto both = transformed(box, &scale);
    const auto base = static_cast<std::uint32_t>(both.vertices.size());
    both.vertices.insert(both.vertices.end(), ball.vertices.begin(), ball.vertices.end());
    for (auto t : ball.triangles) {
        both.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
    }
    auto store = Store::open(tmp / "store");
    ASSERT_TRUE(store.ok());
    expect_store_matches(*store.value(),
                         {{"room/box-1", transformed(box, &rot)},
                          {"room/box-and-ball", both},
                          {"room/ball-2", transformed(ball, &rot)}},
                         StoreOptions{}.max_piece_bytes);
}

TEST(Import, BadSceneFilesNameTheFileAndThePath) {
    TempDir tmp("bad_scene");
    ASSERT_TRUE(write_off(tmp / "box.off", make_box({0, 0, 0}, {1, 1, 1})).ok());
    ASSERT_TRUE(write_store(tmp / "store", small_model(), {}).ok());
    const std::string manifest = read_bytes(tmp / "store/gen-000001/manifest.json");
    struct Case {
        std::string json;
        StatusCode code;
        std::vector<std::string> words;
    };
    const std::string meshes = R"("meshes": {"box": "box.off"})";
    const std::vector<Case> cases = {
        {R"({"format": "proxima-scene/2", )" + meshes + R"(, "objects": []})",
         StatusCode::invalid_argument,
         {"format", "proxima-scene/2"}},
        {R"({)" + meshes + R"(, "objects": []})", StatusCode::invalid_argument, {"format"}},
        {R"({"format": "proxima-scene/1", )" + meshes +
             R"(, "objects": [{"name": "a", "parts": [{"mesh": "chair"}]}]})",
         StatusCode::invalid_argument,
         {"objects[0].parts[0].mesh", "chair"}},
        {R"({"format": "proxima-scene/1", )" + meshes +
             R"(, "objects": [{"name": "a", "parts": [{"mesh": "box"}]},
                {"name": "b", "parts": [{"mesh": "box", "transform": [1,0,0,0,0,1,0,0,0,0,1]}]}]})",
         StatusCode::invalid_argument,
         {"objects[1].parts[0].transform", "12 finite numbers", "11"}},
        {R"({"format": "proxima-scene/1", )" + meshes +
             R"(, "objects": [{"name": "a", "parts": [{"mesh": "box", "transform":
                [1,0,0,0,0,1,0,0,0,0,"x",0]}]}]})",
         StatusCode::invalid_argument,
         {"objects[0].parts[0].transform[10]"}},
        {R"({"format": "proxima-scene/1", )" + meshes +
             R"(, "objects": [{"name": "a", "parts": [{"mesh": "box", "transform":
                [1,0,0,0,0,1,0,0,0,0,1,1e999]}]}]})",
         StatusCode::invalid_argument,
         {"1e999"}},
        {R"({"format": "proxima-scene/1", )" + meshes + R"(, "objects": [{"parts": []}]})",
         StatusCode::invalid_argument,
         {"objects[0].name"}},
        {R"({"format": "proxima-scene/1", "objects": []})",
         StatusCode::invalid_argument,
         {"meshes"}},
        {R"({"format": "proxima-scene/1", "meshes": {"box": "missing.off"},
             "objects": [{"name": "a", "parts": [{"mesh": "box"}]}]})",
         StatusCode::not_found,
         {"missing.off", "object 'a'"}},
        {R"({"format": )", StatusCode::invalid_argument, {"not valid JSON"}},
    };
    for (std::size_t i = 0; i < cases.size(); ++i) {
        const std::string path = tmp / ("scene-" + std::to_string(i) + ".json");
        write_bytes(path, cases[i].json);
        auto r = import_files({path}, tmp / "store", {});
        ASSERT_FALSE(r.ok()) << i;
        EXPECT_EQ(r.status().code(), cases[i].code) << i << ": " << r.status().to_string();
        EXPECT_NE(r.status().message().find(path), std::string::npos) << r.status().message();
        for (const auto& w : cases[i].words) {
            EXPECT_NE(r.status().message().find(w), std::string::npos)
                << i << ": '" << w << "' not in " << r.status().message();
        }
    }
    EXPECT_EQ(dir_entries(tmp / "store"),
              (std::vector<std::string>{"CURRENT", "LOCK", "gen-000001"}));
    EXPECT_EQ(read_bytes(tmp / "store/gen-000001/manifest.json"), manifest);
}

// ---- sidecars --------------------------------------------------------------------------------

TEST(Store, SidecarRoundTripAndCorruption) {
    TempDir tmp("sidecar");
    ASSERT_TRUE(write_store(tmp.path(), small_model(), {}).ok());
    auto opened = Store::open(tmp.path());
    ASSERT_TRUE(opened.ok());
    const Store& store = *opened.value();
    EXPECT_EQ(store.read_sidecar("schedule").status().code(), StatusCode::not_found);
    std::string payload("binary\0payload", 14);
    for (int i = 0; i < 1000; ++i) {
        payload.push_back(static_cast<char>(i * 37));
    }
    ASSERT_TRUE(store.write_sidecar("schedule", payload).ok());
    EXPECT_EQ(store.read_sidecar("schedule").value(), payload);
    ASSERT_TRUE(store.write_sidecar("schedule", "replaced").ok());
    EXPECT_EQ(store.read_sidecar("schedule").value(), "replaced");
    ASSERT_TRUE(store.write_sidecar("empty", "").ok());
    EXPECT_EQ(store.read_sidecar("empty").value(), "");
    // A reopened store sees it too.
    EXPECT_EQ(Store::open(tmp.path()).value()->read_sidecar("schedule").value(), "replaced");

    const std::string file = tmp / "gen-000001/sidecar-schedule";
    flip_byte(file, fs::file_size(file) - 3);
    EXPECT_EQ(store.read_sidecar("schedule").status().code(), StatusCode::data_loss);
    write_bytes(file, "short");
    EXPECT_EQ(store.read_sidecar("schedule").status().code(), StatusCode::data_loss);
    for (const char* bad : {"", "../x", "a/b", ".hidden"}) {
        EXPECT_EQ(store.write_sidecar(bad, "x").code(), StatusCode::invalid_argument) << bad;
    }
    // Sidecars belong to their generation: a new import starts without them.
    ASSERT_TRUE(write_store(tmp.path(), small_model(), {}).ok());
    EXPECT_EQ(Store::open(tmp.path()).value()->read_sidecar("schedule").status().code(),
              StatusCode::not_found);
    // The old Store still reads pieces from its removed generation (descriptors stay open).
    EXPECT_TRUE(store.read_piece(0).ok());
}

}  // namespace
}  // namespace proxima::massive
