#pragma once
// The on-disk model store (seed 001 §4.2.1, §6): a massive model's objects, split into pieces of
// bounded size by a k-d tree over triangle centres, written as fixed-size chunks with a CRC-32 per
// chunk, described by a checksummed manifest.
//
// Layout of a store directory:
//   CURRENT               the name of the live generation ("gen-000003"), replaced atomically
//   LOCK                  flock'ed by an import (one import at a time per store)
//   gen-000003/           one complete, immutable import: manifest.json (objects, summary, the
//                         size and CRC of manifest.bin), manifest.crc (CRC of manifest.json),
//                         manifest.bin (piece table and chunk CRCs), chunks-NNNN.bin (data files
//                         of fixed-size chunks) and sidecar-* files (persisted schedules)
//   gen-000004.tmp/       an import in progress (ignored by readers, removed by the next import)
// An import writes a new generation beside the old one, fsyncs it, then renames CURRENT.tmp over
// CURRENT: a kill -9 at any point leaves the previous generation (or no store) valid, never a torn
// one. A chunk whose CRC does not match is reported (DATA_LOSS naming the chunk) and its pieces are
// never served.

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "proxima/massive/model.hpp"

namespace proxima::massive {

struct StoreOptions {
    // Objects whose piece_weight exceeds this are split by the k-d tree until every piece fits.
    std::uint64_t max_piece_bytes = DEFAULT_CACHE_BYTES / SPLIT_FRACTION;
    // Fixed chunk size (the last chunk may be shorter). A read checks whole chunks: 64 KiB keeps
    // random piece reads within ~1.3x of the bytes needed (1 MiB: ~5x on the 15M plant).
    std::uint64_t chunk_bytes = 64ull << 10;
    std::string source;  // free text kept in the manifest ("plant 15M seed 1")
};

struct ObjectInfo {
    std::string name;
    Aabb box;
    std::uint64_t vertex_count = 0;
    std::uint64_t triangle_count = 0;
    std::uint32_t first_piece = 0;  // pieces first_piece .. first_piece + piece_count - 1
    std::uint32_t piece_count = 0;
};

struct PieceInfo {
    std::uint32_t object = 0;  // index in objects()
    Aabb box;
    std::uint32_t vertex_count = 0;
    std::uint32_t triangle_count = 0;
    std::uint64_t offset = 0;  // byte range of the piece record in the chunk stream
    std::uint64_t bytes = 0;
    std::uint64_t weight() const { return piece_weight(vertex_count, triangle_count); }
};

// A piece as read from disk: its own compact vertex array (exact copies of the object's
// coordinates), triangles indexing it, and for each triangle its index in the whole object.
// `source_triangles` is empty when that index is the triangle's own (a piece that is its whole
// object, in order: most pieces), so resident pieces do not spend 4 bytes a triangle on it.
struct PieceGeometry {
    std::vector<Vec3> vertices;
    std::vector<TriangleIndices> triangles;
    std::vector<std::uint32_t> source_triangles;

    // Triangle t's index in the whole object.
    std::uint32_t source(std::size_t t) const {
        return source_triangles.empty() ? static_cast<std::uint32_t>(t) : source_triangles[t];
    }
    // The map for a TreeRef or LazyBvh: null when it is the identity.
    const std::vector<std::uint32_t>* source_map() const {
        return source_triangles.empty() ? nullptr : &source_triangles;
    }
    // Every triangle's index in the whole object, in piece order.
    std::vector<std::uint32_t> source_ids() const;
};

struct StoreSummary {
    std::string path;
    std::string generation;
    std::uint64_t objects = 0;
    std::uint64_t pieces = 0;
    std::uint64_t split_objects = 0;  // objects that were split into more than one piece
    std::uint64_t triangles = 0;
    std::uint64_t vertices = 0;
    std::uint64_t chunks = 0;
    std::uint64_t bytes = 0;  // chunk bytes on disk
};

// Writes one new generation. Objects are validated (validate_mesh) as they are added; the first
// error aborts the import (the partial generation is removed, the previous one stays live).
class StoreWriter {
  public:
    static StatusOr<std::unique_ptr<StoreWriter>> create(const std::string& dir,
                                                         const StoreOptions& options = {});
    ~StoreWriter();  // without commit(): removes the partial generation
    StoreWriter(const StoreWriter&) = delete;
    StoreWriter& operator=(const StoreWriter&) = delete;

    Status add(const ModelObject& object);
    // Writes the manifest, fsyncs, switches CURRENT, removes older generations.
    StatusOr<StoreSummary> commit(const ProgressFn& progress = {});

  private:
    StoreWriter() = default;
    struct Impl;
    std::unique_ptr<Impl> m_impl;
};

class Store {
  public:
    // Opens the live generation: NOT_FOUND when there is none, DATA_LOSS when the manifest is
    // corrupt. Reads only the manifest (chunks are read, and checked, piece by piece).
    static StatusOr<std::shared_ptr<Store>> open(const std::string& dir);
    ~Store();

    const StoreSummary& summary() const;
    const std::vector<ObjectInfo>& objects() const;
    const std::vector<PieceInfo>& pieces() const;

    // Thread-safe. Reads the piece's chunks, checks their CRCs, decodes: DATA_LOSS ("store
    // DIR: chunk 17 of gen-000003: checksum mismatch") if any chunk is corrupt, UNAVAILABLE on
    // an I/O error.
    StatusOr<PieceGeometry> read_piece(std::uint32_t piece) const;
    // Every chunk's CRC, with progress; the first corrupt chunk is the error.
    Status verify(const ProgressFn& progress = {}) const;

    // Small files kept with the live generation (the persisted overlap-graph schedules): written
    // atomically (tmp + fsync + rename) with their own CRC; NOT_FOUND when absent, DATA_LOSS when
    // corrupt.
    Status write_sidecar(const std::string& name, const std::string& bytes) const;
    StatusOr<std::string> read_sidecar(const std::string& name) const;

    // Counters since open: bytes and pieces read from disk.
    std::uint64_t bytes_read() const;
    std::uint64_t pieces_read() const;

  private:
    Store() = default;
    struct Impl;
    std::unique_ptr<Impl> m_impl;
};

// Imports mesh files into a store: each path is a mesh file (one object), a directory (every mesh
// file under it, sorted, one object each) or a scene file (*.json, format "proxima-scene/1"):
//   {"format": "proxima-scene/1",
//    "meshes": {"chair": "furniture/chair.obj"},          // relative to the scene file, or
//    absolute "objects": [{"name": "room-1/chair-2",
//                 "parts": [{"mesh": "chair", "transform": [12 numbers, row-major 3x4]}]}]}
// An object is the union of its parts (each part a mesh under an Affine; transform optional);
// a mesh used by several objects is read once (instances).
StatusOr<StoreSummary> import_files(const std::vector<std::string>& inputs,
                                    const std::string& store_dir, const StoreOptions& options,
                                    const ProgressFn& progress = {});

}  // namespace proxima::massive
