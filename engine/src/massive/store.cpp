#include "proxima/massive/store.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <numeric>
#include <set>
#include <system_error>

#include <assimp/Importer.hpp>
#include <nlohmann/json.hpp>

#include "massive/kd_split.hpp"
#include "massive/scene_file.hpp"
#include "massive/store_format.hpp"
#include "proxima/io/mesh_io.hpp"

namespace proxima::massive {

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using namespace detail;

static_assert(sizeof(Vec3) == 24 && sizeof(TriangleIndices) == 12,
              "piece records are memcpy'd from these arrays");

std::string join(const std::string& dir, const std::string& name) {
    return (fs::path(dir) / name).string();
}

// Test hook for the crash tests: PROXIMA_STORE_FAULT=<point> kills the process (SIGKILL, as a
// power cut would) when commit reaches that point, so every step of the switch can be hit.
void fault_point(const char* point) {
    const char* want = std::getenv("PROXIMA_STORE_FAULT");
    if (want != nullptr && std::strcmp(want, point) == 0) {
        ::raise(SIGKILL);
    }
}

Status with_context(const Status& s, const std::string& context) {
    return {s.code(), context + ": " + s.message()};
}

// Removes a directory tree, ignoring errors (cleanup of something already abandoned).
void remove_tree(const std::string& path) {
    std::error_code ec;
    fs::remove_all(path, ec);
}

// "pieces 4..9 not served" for the pieces whose records overlap bytes [begin, end).
std::string pieces_in_range(const std::vector<PieceInfo>& pieces, std::uint64_t begin,
                            std::uint64_t end) {
    auto first = std::partition_point(pieces.begin(), pieces.end(), [&](const PieceInfo& p) {
        return p.offset + p.bytes <= begin;
    });
    auto last = std::partition_point(first, pieces.end(),
                                     [&](const PieceInfo& p) { return p.offset < end; });
    if (first == last) {
        return "no piece affected";
    }
    const auto a = first - pieces.begin();
    const auto b = (last - pieces.begin()) - 1;
    if (a == b) {
        return "piece " + std::to_string(a) + " not served";
    }
    return "pieces " + std::to_string(a) + ".." + std::to_string(b) + " not served";
}

Aabb box_of(const std::vector<Vec3>& vertices) {
    Aabb box;
    for (const auto& v : vertices) {
        box.extend(v);
    }
    return box;
}

json box_json(const Aabb& b) {
    return json::array({b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z});
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// StoreWriter

struct StoreWriter::Impl {
    std::string dir;
    StoreOptions options;
    Fd lock;
    std::string generation;  // "gen-000004"
    std::string tmp_dir;     // dir/gen-000004.tmp
    std::string gen_dir;     // dir/gen-000004
    bool renamed = false;    // tmp_dir has become gen_dir
    bool committed = false;
    Status failed;  // the first error: the import is aborted

    std::uint64_t chunks_per_file = 1;
    // The chunk stream: `buf` holds chunks not yet written, starting at chunk `written_chunks`;
    // the chunk being filled starts at buf[chunk_start].
    std::vector<char> buf;
    std::size_t chunk_start = 0;
    std::uint64_t flush_bytes = 0;
    std::uint64_t stream_bytes = 0;
    std::uint64_t written_chunks = 0;
    std::vector<std::uint32_t> chunk_crcs;
    Fd file;
    std::string file_path;
    std::uint64_t file_index = 0;
    std::uint64_t files = 0;

    std::vector<ObjectInfo> objects;
    std::vector<PieceInfo> pieces;
    StoreSummary summary;

    std::string what() const { return "store '" + dir + "'"; }

    Status fail(Status s) {
        if (failed.ok()) {
            failed = s;
        }
        file.reset();
        if (!tmp_dir.empty()) {  // empty when create() failed before choosing a generation
            remove_tree(renamed ? gen_dir : tmp_dir);
        }
        return s;
    }

    Status flush() {
        if (buf.empty()) {
            return {};
        }
        const std::uint64_t index = written_chunks / chunks_per_file;
        if (!file.valid() || index != file_index) {
            if (Status s = close_file(); !s.ok()) {
                return s;
            }
            file_index = index;
            file_path = join(tmp_dir, data_file_name(index));
            auto f = open_file(file_path, O_WRONLY | O_CREAT | O_TRUNC);
            if (!f.ok()) {
                return f.status();
            }
            file = std::move(f).value();
            files = index + 1;
        }
        if (Status s = write_all(file.get(), buf.data(), buf.size(), file_path); !s.ok()) {
            return s;
        }
        written_chunks = chunk_crcs.size();
        buf.clear();
        chunk_start = 0;
        return {};
    }

    Status close_file() {
        if (!file.valid()) {
            return {};
        }
        if (Status s = sync_fd(file.get(), file_path); !s.ok()) {
            return s;
        }
        return close_fd(file, file_path);
    }

    Status finish_chunk() {
        chunk_crcs.push_back(crc32_of(buf.data() + chunk_start, buf.size() - chunk_start));
        chunk_start = buf.size();
        const bool file_full = chunk_crcs.size() % chunks_per_file == 0;
        if (file_full || buf.size() >= flush_bytes) {
            if (Status s = flush(); !s.ok()) {
                return s;
            }
            if (file_full) {
                return close_file();
            }
        }
        return {};
    }

    Status append(const void* data, std::size_t size) {
        const char* p = static_cast<const char*>(data);
        const std::size_t chunk = options.chunk_bytes;
        while (size > 0) {
            const std::size_t take = std::min(size, chunk - (buf.size() - chunk_start));
            buf.insert(buf.end(), p, p + take);
            p += take;
            size -= take;
            stream_bytes += take;
            if (buf.size() - chunk_start == chunk) {
                if (Status s = finish_chunk(); !s.ok()) {
                    return s;
                }
            }
        }
        return {};
    }

    Status write_piece(std::uint32_t object, const std::vector<Vec3>& vertices,
                       const std::vector<TriangleIndices>& triangles,
                       const std::vector<std::uint32_t>* source) {
        PieceInfo info;
        info.object = object;
        info.box = box_of(vertices);
        info.vertex_count = static_cast<std::uint32_t>(vertices.size());
        info.triangle_count = static_cast<std::uint32_t>(triangles.size());
        info.offset = stream_bytes;
        info.bytes = piece_record_bytes(vertices.size(), triangles.size());
        const std::uint32_t header[6] = {PIECE_MAGIC,
                                         static_cast<std::uint32_t>(pieces.size()),
                                         object,
                                         info.vertex_count,
                                         info.triangle_count,
                                         0};
        static_assert(sizeof header == PIECE_HEADER_BYTES);
        Status s = append(header, sizeof header);
        if (s.ok()) {
            s = append(vertices.data(), vertices.size() * sizeof(Vec3));
        }
        if (s.ok()) {
            s = append(triangles.data(), triangles.size() * sizeof(TriangleIndices));
        }
        if (s.ok() && source != nullptr) {
            s = append(source->data(), source->size() * sizeof(std::uint32_t));
        } else if (s.ok()) {
            // An unsplit object: source triangle k is k, written in blocks.
            std::vector<std::uint32_t> ids(std::min<std::size_t>(triangles.size(), 1u << 16));
            for (std::size_t t = 0; t < triangles.size() && s.ok(); t += ids.size()) {
                const std::size_t n = std::min(ids.size(), triangles.size() - t);
                for (std::size_t k = 0; k < n; ++k) {
                    ids[k] = static_cast<std::uint32_t>(t + k);
                }
                s = append(ids.data(), n * sizeof(std::uint32_t));
            }
        }
        if (!s.ok()) {
            return s;
        }
        pieces.push_back(info);
        return {};
    }

    // The binary tables (pieces, chunk CRCs): see TABLES_FILE.
    std::string tables() const {
        std::string out(TABLES_HEADER_BYTES + pieces.size() * sizeof(PieceEntry) +
                            chunk_crcs.size() * sizeof(std::uint32_t),
                        '\0');
        const std::uint32_t head[2] = {TABLES_MAGIC, 1};
        const std::uint64_t counts[2] = {pieces.size(), chunk_crcs.size()};
        std::memcpy(out.data(), head, sizeof head);
        std::memcpy(out.data() + 8, counts, sizeof counts);
        char* p = out.data() + TABLES_HEADER_BYTES;
        for (const auto& piece : pieces) {
            const PieceEntry e{piece.object,
                               piece.vertex_count,
                               piece.triangle_count,
                               0,
                               {piece.box.lo.x, piece.box.lo.y, piece.box.lo.z, piece.box.hi.x,
                                piece.box.hi.y, piece.box.hi.z},
                               piece.offset,
                               piece.bytes};
            std::memcpy(p, &e, sizeof e);
            p += sizeof e;
        }
        std::memcpy(p, chunk_crcs.data(), chunk_crcs.size() * sizeof(std::uint32_t));
        return out;
    }

    std::string manifest(const std::string& tables) const {
        json doc;
        doc["format"] = STORE_FORMAT;
        doc["source"] = options.source;
        doc["options"] = {{"max_piece_bytes", options.max_piece_bytes},
                          {"chunk_bytes", options.chunk_bytes}};
        doc["summary"] = {{"objects", summary.objects},
                          {"pieces", summary.pieces},
                          {"split_objects", summary.split_objects},
                          {"triangles", summary.triangles},
                          {"vertices", summary.vertices},
                          {"chunks", summary.chunks},
                          {"bytes", summary.bytes}};
        doc["chunk_files"] = {{"chunks_per_file", chunks_per_file}, {"files", files}};
        doc["tables"] = {{"file", TABLES_FILE},
                         {"bytes", tables.size()},
                         {"crc32", crc32_of(tables.data(), tables.size())},
                         {"piece_entry",
                          "object u32, vertices u32, triangles u32, 0 u32, box f64 x 6 (lo, hi), "
                          "offset u64, bytes u64; then one chunk crc32 u32 per chunk"}};
        json objs = json::array();
        for (const auto& o : objects) {
            objs.push_back({{"name", o.name},
                            {"box", box_json(o.box)},
                            {"vertices", o.vertex_count},
                            {"triangles", o.triangle_count},
                            {"first_piece", o.first_piece},
                            {"pieces", o.piece_count}});
        }
        doc["objects"] = std::move(objs);
        // Names that are not UTF-8 (file names on Linux) are kept readable, not refused.
        return doc.dump(-1, ' ', false, json::error_handler_t::replace);
    }

    // Removes every stale temporary and, with `generations`, every other generation: we hold
    // the lock, so nothing else is writing, and readers of an old generation keep their open
    // descriptors.
    void remove_others(bool generations) const {
        std::error_code ec;
        for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
            const std::string name = it->path().filename().string();
            const bool tmp = name.size() > 4 && name.compare(name.size() - 4, 4, ".tmp") == 0;
            const bool old_gen =
                generations && parse_generation(name).has_value() && name != generation;
            const bool tmp_gen = tmp && parse_generation(name.substr(0, name.size() - 4));
            if (old_gen || tmp_gen || name == std::string(CURRENT_FILE) + ".tmp") {
                remove_tree(it->path().string());
            }
        }
    }
};

StatusOr<std::unique_ptr<StoreWriter>> StoreWriter::create(const std::string& dir,
                                                           const StoreOptions& options) {
    const std::string what = "store '" + dir + "'";
    if (options.chunk_bytes < MIN_CHUNK_BYTES || options.chunk_bytes > MAX_CHUNK_BYTES) {
        return invalid_argument(what + ": chunk size " + std::to_string(options.chunk_bytes) +
                                " out of range [" + std::to_string(MIN_CHUNK_BYTES) + ", " +
                                std::to_string(MAX_CHUNK_BYTES) + "]");
    }
    if (options.max_piece_bytes < piece_weight(3, 1)) {
        return invalid_argument(what + ": maximum piece size " +
                                std::to_string(options.max_piece_bytes) +
                                " is below the weight of a single triangle (" +
                                std::to_string(piece_weight(3, 1)) + " bytes)");
    }
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec || !fs::is_directory(dir, ec)) {
        return Status(StatusCode::unavailable,
                      what + ": cannot create the directory" +
                          (ec ? ": " + ec.message() : std::string(" (a file is in the way)")));
    }
    std::unique_ptr<StoreWriter> writer(new StoreWriter());
    writer->m_impl = std::make_unique<Impl>();
    Impl& w = *writer->m_impl;
    w.dir = dir;
    w.options = options;

    auto lock = open_file(join(dir, LOCK_FILE), O_RDWR | O_CREAT);
    if (!lock.ok()) {
        return with_context(lock.status(), what);
    }
    if (::flock(lock->get(), LOCK_EX | LOCK_NB) != 0) {
        if (errno == EWOULDBLOCK) {
            return failed_precondition("an import into '" + dir + "' is already running (" +
                                       join(dir, LOCK_FILE) + " is locked)");
        }
        return with_context(io_error("locking", join(dir, LOCK_FILE), errno), what);
    }
    w.lock = std::move(lock).value();

    // The next generation number is above every generation present, complete or not.
    std::uint64_t last = 0;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
        std::string name = it->path().filename().string();
        if (name.size() > 4 && name.compare(name.size() - 4, 4, ".tmp") == 0) {
            name.resize(name.size() - 4);
        }
        if (auto n = parse_generation(name)) {
            last = std::max(last, *n);
        }
    }
    if (ec) {
        return Status(StatusCode::unavailable,
                      what + ": cannot list the directory: " + ec.message());
    }
    w.generation = generation_name(last + 1);
    w.tmp_dir = join(dir, w.generation + ".tmp");
    w.gen_dir = join(dir, w.generation);
    // Stale temporaries from killed imports go first: they may hold gigabytes.
    w.remove_others(false);
    if (::mkdir(w.tmp_dir.c_str(), 0755) != 0) {
        return with_context(io_error("creating", w.tmp_dir, errno), what);
    }
    std::uint64_t file_bytes = DATA_FILE_BYTES;
    // Test hook: small data files, so tests cover pieces and reads that cross files.
    if (const char* e = std::getenv("PROXIMA_STORE_TEST_FILE_BYTES"); e != nullptr) {
        file_bytes = std::clamp<std::uint64_t>(std::strtoull(e, nullptr, 10), 1, DATA_FILE_BYTES);
    }
    w.chunks_per_file = std::max<std::uint64_t>(1, file_bytes / options.chunk_bytes);
    w.flush_bytes = std::max<std::uint64_t>(options.chunk_bytes, 4ull << 20);
    w.buf.reserve(static_cast<std::size_t>(w.flush_bytes + options.chunk_bytes));
    w.summary.path = dir;
    w.summary.generation = w.generation;
    return writer;
}

StoreWriter::~StoreWriter() {
    if (m_impl && !m_impl->committed && m_impl->failed.ok()) {
        (void)m_impl->fail(Status(StatusCode::cancelled, "the writer was destroyed"));
    }
}

Status StoreWriter::add(const ModelObject& object) {
    Impl& w = *m_impl;
    if (!w.failed.ok()) {
        return failed_precondition(
            w.what() + ": the import was aborted by an earlier error: " + w.failed.to_string());
    }
    if (w.committed) {
        return failed_precondition(w.what() + ": the import is already committed");
    }
    const std::string what = "object '" + object.name + "'";
    if (Status s = validate_mesh(object.mesh, what); !s.ok()) {
        return w.fail(s);
    }
    // Object and piece indices are 32-bit in the format.
    if (w.objects.size() >= std::numeric_limits<std::uint32_t>::max() - 1 ||
        w.pieces.size() + object.mesh.triangles.size() >=
            std::numeric_limits<std::uint32_t>::max()) {
        return w.fail({StatusCode::resource_exhausted,
                       w.what() + ": too many objects or pieces for one store"});
    }
    const auto& mesh = object.mesh;
    const auto index = static_cast<std::uint32_t>(w.objects.size());
    ObjectInfo info;
    info.name = object.name;
    info.box = box_of(mesh.vertices);
    info.vertex_count = mesh.vertices.size();
    info.triangle_count = mesh.triangles.size();
    info.first_piece = static_cast<std::uint32_t>(w.pieces.size());

    Status s;
    if (piece_weight(mesh.vertices.size(), mesh.triangles.size()) <= w.options.max_piece_bytes) {
        s = w.write_piece(index, mesh.vertices, mesh.triangles, nullptr);
    } else {
        const auto split = detail::kd_split(mesh, w.options.max_piece_bytes);
        detail::PieceBuilder builder(mesh);
        for (std::size_t k = 0; k < split.size() && s.ok(); ++k) {
            const PieceGeometry piece = builder.make(split[k]);
            s = w.write_piece(index, piece.vertices, piece.triangles, &piece.source_triangles);
        }
        ++w.summary.split_objects;
    }
    if (!s.ok()) {
        return w.fail(with_context(s, w.what()));
    }
    info.piece_count = static_cast<std::uint32_t>(w.pieces.size()) - info.first_piece;
    w.summary.objects += 1;
    w.summary.triangles += info.triangle_count;
    w.summary.vertices += info.vertex_count;
    w.objects.push_back(std::move(info));
    return {};
}

StatusOr<StoreSummary> StoreWriter::commit(const ProgressFn& progress) {
    Impl& w = *m_impl;
    if (!w.failed.ok()) {
        return failed_precondition(
            w.what() + ": the import was aborted by an earlier error: " + w.failed.to_string());
    }
    if (w.committed) {
        return failed_precondition(w.what() + ": the import is already committed");
    }
    auto report = [&](std::uint64_t done) {
        if (progress) {
            progress({"syncing", done, 4, "steps"});
        }
    };
    report(0);
    // The last chunk may be short.
    if (w.buf.size() > w.chunk_start) {
        if (Status s = w.finish_chunk(); !s.ok()) {
            return w.fail(with_context(s, w.what()));
        }
    }
    Status s = w.flush();
    if (s.ok()) {
        s = w.close_file();
    }
    if (!s.ok()) {
        return w.fail(with_context(s, w.what()));
    }
    report(1);
    w.summary.pieces = w.pieces.size();
    w.summary.chunks = w.chunk_crcs.size();
    w.summary.bytes = w.stream_bytes;

    const std::string tables = w.tables();
    const std::string manifest = w.manifest(tables);
    char crc_line[64];
    std::snprintf(crc_line, sizeof crc_line, "crc32 %08x bytes %llu\n",
                  crc32_of(manifest.data(), manifest.size()),
                  static_cast<unsigned long long>(manifest.size()));
    s = write_file_synced(join(w.tmp_dir, TABLES_FILE), tables);
    if (s.ok()) {
        s = write_file_synced(join(w.tmp_dir, MANIFEST_FILE), manifest);
    }
    if (s.ok()) {
        s = write_file_synced(join(w.tmp_dir, MANIFEST_CRC_FILE), crc_line);
    }
    if (s.ok()) {
        s = sync_dir(w.tmp_dir);
    }
    if (!s.ok()) {
        return w.fail(with_context(s, w.what()));
    }
    report(2);

    fault_point("before-gen-rename");
    s = rename_path(w.tmp_dir, w.gen_dir);
    if (!s.ok()) {
        return w.fail(with_context(s, w.what()));
    }
    w.renamed = true;
    s = sync_dir(w.dir);
    if (!s.ok()) {
        return w.fail(with_context(s, w.what()));
    }
    fault_point("after-gen-rename");

    // The switch: CURRENT names the new generation or the old one, never anything torn.
    const std::string current = join(w.dir, CURRENT_FILE);
    const std::string current_tmp = current + ".tmp";
    s = write_file_synced(current_tmp, w.generation + "\n");
    if (s.ok()) {
        fault_point("before-current-rename");
        s = rename_path(current_tmp, current);
    }
    if (!s.ok()) {
        std::error_code ec;
        fs::remove(current_tmp, ec);
        return w.fail(with_context(s, w.what()));
    }
    w.committed = true;
    fault_point("after-current-rename");
    s = sync_dir(w.dir);
    if (!s.ok()) {
        // CURRENT already names the new generation: nothing to undo, but it may not be durable.
        return with_context(s, w.what() + ": the new generation " + w.generation +
                                   " is live but may not survive a crash");
    }
    report(3);
    w.remove_others(true);
    report(4);
    return w.summary;
}

// ---------------------------------------------------------------------------------------------
// Store

struct Store::Impl {
    std::string dir;
    std::string generation;
    std::string gen_dir;
    StoreSummary summary;
    std::vector<ObjectInfo> objects;
    std::vector<PieceInfo> pieces;
    std::vector<std::uint32_t> chunk_crcs;
    std::uint64_t chunk_bytes = 0;
    std::uint64_t chunks_per_file = 1;
    std::vector<Fd> files;  // invalid where the file could not be opened
    std::vector<std::string> file_errors;
    mutable std::atomic<std::uint64_t> bytes_read{0};
    mutable std::atomic<std::uint64_t> pieces_read{0};
    mutable std::atomic<std::uint64_t> sidecar_tmp_counter{0};

    std::string what() const { return "store '" + dir + "'"; }

    std::uint64_t chunk_length(std::uint64_t k) const {
        return std::min(chunk_bytes, summary.bytes - k * chunk_bytes);
    }

    Status chunk_error(std::uint64_t k, const std::string& problem) const {
        const std::uint64_t begin = k * chunk_bytes;
        return data_loss(what() + ": chunk " + std::to_string(k) + " (" + generation + ", file " +
                         data_file_name(k / chunks_per_file) + "): " + problem + "; " +
                         pieces_in_range(pieces, begin, begin + chunk_length(k)));
    }

    // Reads chunks [first, last] to `dst` (room for all of them) and checks each one's CRC.
    Status read_chunks(std::uint64_t first, std::uint64_t last, char* dst_first) const {
        std::uint64_t k = first;
        while (k <= last) {
            const std::uint64_t f = k / chunks_per_file;
            const std::uint64_t end = std::min(last, (f + 1) * chunks_per_file - 1);
            const std::uint64_t bytes = end * chunk_bytes + chunk_length(end) - k * chunk_bytes;
            char* dst = dst_first + (k - first) * chunk_bytes;
            if (f >= files.size() || !files[f].valid()) {
                return chunk_error(k, "data file unavailable: " +
                                          (f < file_errors.size() ? file_errors[f] : "missing"));
            }
            const std::string path = join(gen_dir, data_file_name(f));
            std::size_t got = 0;
            const std::uint64_t at = (k % chunks_per_file) * chunk_bytes;
            if (Status s = pread_all(files[f].get(), dst, bytes, at, got, path); !s.ok()) {
                return with_context(s, what() + ": chunk " + std::to_string(k));
            }
            bytes_read += got;
            if (got < bytes) {
                return chunk_error(k + got / chunk_bytes, "truncated (" + path + " ends at byte " +
                                                              std::to_string(at + got) + ")");
            }
            for (std::uint64_t c = k; c <= end; ++c) {
                const char* data = dst_first + (c - first) * chunk_bytes;
                if (crc32_of(data, chunk_length(c)) != chunk_crcs[c]) {
                    return chunk_error(c, "checksum mismatch");
                }
            }
            k = end + 1;
        }
        return {};
    }

    std::uint64_t span_bytes(std::uint64_t first, std::uint64_t last) const {
        return last * chunk_bytes + chunk_length(last) - first * chunk_bytes;
    }

    // Recently read, checked chunks at the ends of pieces. A piece's first and last chunk are
    // usually shared with its neighbours (inner chunks never are), so pieces read in stream
    // order cost one read and one CRC per chunk, not one per piece: with 1 MiB chunks and
    // 10 KB pieces that is the difference between 1 and 100 chunk reads per chunk.
    struct CachedChunk {
        std::uint64_t index = 0;
        std::uint64_t used = 0;
        std::shared_ptr<const std::vector<char>> data;
    };
    mutable std::mutex cache_mutex;
    mutable std::vector<CachedChunk> cache;
    mutable std::uint64_t cache_clock = 0;
    std::size_t cache_capacity = 2;

    StatusOr<std::shared_ptr<const std::vector<char>>> edge_chunk(std::uint64_t k) const {
        {
            std::lock_guard<std::mutex> lock(cache_mutex);
            for (auto& c : cache) {
                if (c.index == k) {
                    c.used = ++cache_clock;
                    return c.data;
                }
            }
        }
        auto data = std::make_shared<std::vector<char>>(chunk_length(k));
        if (Status s = read_chunks(k, k, data->data()); !s.ok()) {
            return s;
        }
        std::lock_guard<std::mutex> lock(cache_mutex);
        if (cache.size() < cache_capacity) {
            cache.push_back({k, ++cache_clock, data});
        } else {
            auto oldest = std::min_element(
                cache.begin(), cache.end(),
                [](const CachedChunk& a, const CachedChunk& b) { return a.used < b.used; });
            *oldest = {k, ++cache_clock, data};
        }
        return std::shared_ptr<const std::vector<char>>(std::move(data));
    }

    // The bytes [begin, end) of the stream, every chunk they touch checked.
    Status read_range(std::uint64_t begin, std::uint64_t end, char* out) const {
        const std::uint64_t last = (end - 1) / chunk_bytes;
        std::uint64_t c = begin / chunk_bytes;
        while (c <= last) {
            const std::uint64_t cb = c * chunk_bytes;
            if (cb >= begin && cb + chunk_length(c) <= end) {
                // A run of inner chunks: read straight into place.
                std::uint64_t run = c;
                while (run < last && (run + 1) * chunk_bytes + chunk_length(run + 1) <= end) {
                    ++run;
                }
                if (Status s = read_chunks(c, run, out + (cb - begin)); !s.ok()) {
                    return s;
                }
                c = run + 1;
                continue;
            }
            auto chunk = edge_chunk(c);
            if (!chunk.ok()) {
                return chunk.status();
            }
            const std::uint64_t lo = std::max(begin, cb);
            const std::uint64_t hi = std::min(end, cb + chunk_length(c));
            std::memcpy(out + (lo - begin), chunk.value()->data() + (lo - cb), hi - lo);
            ++c;
        }
        return {};
    }

    Status load_manifest(const json& doc, const std::string& tables);
};

namespace {

// Strict accessors: a manifest that parses but does not have the expected shape is corrupt.
struct ManifestError {
    std::string what;
};

const json& field(const json& j, const char* key) {
    if (!j.is_object() || !j.contains(key)) {
        throw ManifestError{std::string("missing '") + key + "'"};
    }
    return j[key];
}

std::uint64_t as_u64(const json& j, const char* what) {
    if (!j.is_number_unsigned()) {
        throw ManifestError{std::string("'") + what + "' is not an unsigned integer"};
    }
    return j.get<std::uint64_t>();
}

std::uint32_t as_u32(const json& j, const char* what) {
    const std::uint64_t v = as_u64(j, what);
    if (v > std::numeric_limits<std::uint32_t>::max()) {
        throw ManifestError{std::string("'") + what + "' out of range"};
    }
    return static_cast<std::uint32_t>(v);
}

double as_double(const json& j, const char* what) {
    if (!j.is_number()) {
        throw ManifestError{std::string("'") + what + "' is not a number"};
    }
    return j.get<double>();
}

Aabb as_box(const json& j, std::size_t at) {
    Aabb b;
    b.lo = {as_double(j[at], "box"), as_double(j[at + 1], "box"), as_double(j[at + 2], "box")};
    b.hi = {as_double(j[at + 3], "box"), as_double(j[at + 4], "box"), as_double(j[at + 5], "box")};
    return b;
}

}  // namespace

Status Store::Impl::load_manifest(const json& doc, const std::string& tables) {
    try {
        const auto& format = field(doc, "format");
        if (!format.is_string() || format.get<std::string>() != STORE_FORMAT) {
            throw ManifestError{"unknown format " + format.dump()};
        }
        const auto& options = field(doc, "options");
        chunk_bytes = as_u64(field(options, "chunk_bytes"), "chunk_bytes");
        if (chunk_bytes < MIN_CHUNK_BYTES || chunk_bytes > MAX_CHUNK_BYTES) {
            throw ManifestError{"chunk size out of range"};
        }
        const auto& cf = field(doc, "chunk_files");
        chunks_per_file = as_u64(field(cf, "chunks_per_file"), "chunks_per_file");
        const std::uint64_t file_count = as_u64(field(cf, "files"), "files");
        if (chunks_per_file == 0 || chunks_per_file * chunk_bytes > DATA_FILE_BYTES * 2) {
            throw ManifestError{"chunks per file out of range"};
        }
        const auto& s = field(doc, "summary");
        summary.objects = as_u64(field(s, "objects"), "objects");
        summary.pieces = as_u64(field(s, "pieces"), "pieces");
        summary.split_objects = as_u64(field(s, "split_objects"), "split_objects");
        summary.triangles = as_u64(field(s, "triangles"), "triangles");
        summary.vertices = as_u64(field(s, "vertices"), "vertices");
        summary.chunks = as_u64(field(s, "chunks"), "chunks");
        summary.bytes = as_u64(field(s, "bytes"), "bytes");

        const auto& objs = field(doc, "objects");
        if (!objs.is_array() || objs.size() != summary.objects) {
            throw ManifestError{"object count does not match the summary"};
        }
        objects.reserve(objs.size());
        for (const auto& o : objs) {
            ObjectInfo info;
            const auto& name = field(o, "name");
            if (!name.is_string()) {
                throw ManifestError{"object name is not a string"};
            }
            info.name = name.get<std::string>();
            const auto& box = field(o, "box");
            if (!box.is_array() || box.size() != 6) {
                throw ManifestError{"object box is not 6 numbers"};
            }
            info.box = as_box(box, 0);
            info.vertex_count = as_u64(field(o, "vertices"), "vertices");
            info.triangle_count = as_u64(field(o, "triangles"), "triangles");
            info.first_piece = as_u32(field(o, "first_piece"), "first_piece");
            info.piece_count = as_u32(field(o, "pieces"), "pieces");
            objects.push_back(std::move(info));
        }
        // The binary tables, checked against the size and CRC the manifest gives.
        const auto& t = field(doc, "tables");
        const auto& file = field(t, "file");
        if (!file.is_string() || file.get<std::string>() != TABLES_FILE) {
            throw ManifestError{"unknown tables file " + file.dump()};
        }
        if (tables.size() != as_u64(field(t, "bytes"), "bytes") ||
            crc32_of(tables.data(), tables.size()) != as_u32(field(t, "crc32"), "crc32")) {
            throw ManifestError{std::string(TABLES_FILE) + " is corrupt (checksum mismatch)"};
        }
        std::uint32_t head[2];
        std::uint64_t counts[2];
        if (tables.size() < TABLES_HEADER_BYTES) {
            throw ManifestError{std::string(TABLES_FILE) + " is truncated"};
        }
        std::memcpy(head, tables.data(), sizeof head);
        std::memcpy(counts, tables.data() + 8, sizeof counts);
        if (head[0] != TABLES_MAGIC || head[1] != 1 || counts[0] != summary.pieces ||
            counts[1] != summary.chunks ||
            tables.size() != TABLES_HEADER_BYTES + counts[0] * sizeof(PieceEntry) +
                                 counts[1] * sizeof(std::uint32_t)) {
            throw ManifestError{std::string(TABLES_FILE) + " does not match the summary"};
        }
        const char* p = tables.data() + TABLES_HEADER_BYTES;
        pieces.resize(summary.pieces);
        for (auto& piece : pieces) {
            PieceEntry e;
            std::memcpy(&e, p, sizeof e);
            p += sizeof e;
            piece.object = e.object;
            piece.vertex_count = e.vertex_count;
            piece.triangle_count = e.triangle_count;
            piece.box.lo = {e.box[0], e.box[1], e.box[2]};
            piece.box.hi = {e.box[3], e.box[4], e.box[5]};
            piece.offset = e.offset;
            piece.bytes = e.bytes;
        }
        chunk_crcs.resize(summary.chunks);
        std::memcpy(chunk_crcs.data(), p, chunk_crcs.size() * sizeof(std::uint32_t));

        // Everything read_piece relies on: pieces tile the stream in order, each object owns a
        // contiguous run of them, the chunks cover the stream, the files cover the chunks.
        std::uint64_t offset = 0;
        for (std::size_t i = 0; i < pieces.size(); ++i) {
            const auto& p = pieces[i];
            if (p.offset != offset ||
                p.bytes != piece_record_bytes(p.vertex_count, p.triangle_count) ||
                p.object >= objects.size() || p.triangle_count == 0) {
                throw ManifestError{"piece " + std::to_string(i) + " is inconsistent"};
            }
            offset += p.bytes;
        }
        if (offset != summary.bytes) {
            throw ManifestError{"pieces do not add up to the stream size"};
        }
        std::uint64_t next_piece = 0;
        std::uint64_t triangles = 0;
        for (std::size_t i = 0; i < objects.size(); ++i) {
            const auto& o = objects[i];
            if (o.first_piece != next_piece || o.piece_count == 0 ||
                std::uint64_t{o.first_piece} + o.piece_count > pieces.size()) {
                throw ManifestError{"the pieces of object " + std::to_string(i) +
                                    " are inconsistent"};
            }
            for (std::uint32_t k = o.first_piece; k < o.first_piece + o.piece_count; ++k) {
                if (pieces[k].object != i) {
                    throw ManifestError{"piece " + std::to_string(k) + " names the wrong object"};
                }
            }
            next_piece += o.piece_count;
            triangles += o.triangle_count;
        }
        if (next_piece != pieces.size() || triangles != summary.triangles) {
            throw ManifestError{"objects and pieces do not add up"};
        }
        if (summary.chunks != (summary.bytes + chunk_bytes - 1) / chunk_bytes ||
            file_count != (summary.chunks + chunks_per_file - 1) / chunks_per_file) {
            throw ManifestError{"chunk or file count does not match the stream size"};
        }
        files.resize(file_count);
        file_errors.resize(file_count);
        cache_capacity =
            static_cast<std::size_t>(std::clamp<std::uint64_t>((16ull << 20) / chunk_bytes, 2, 16));
    } catch (const ManifestError& e) {
        return data_loss(what() + ": the manifest of " + generation + " is malformed: " + e.what);
    } catch (const json::exception& e) {
        return data_loss(what() + ": the manifest of " + generation + " is malformed: " + e.what());
    }
    return {};
}

StatusOr<std::shared_ptr<Store>> Store::open(const std::string& dir) {
    const std::string what = "store '" + dir + "'";
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) {
        return not_found(what + ": no such directory");
    }
    const std::string current_path = join(dir, CURRENT_FILE);
    auto read_current = [&]() -> StatusOr<std::string> {
        auto bytes = read_whole_file(current_path);
        if (!bytes.ok()) {
            if (bytes.status().code() == StatusCode::not_found) {
                return not_found(what + ": no store here (no CURRENT file)");
            }
            return with_context(bytes.status(), what);
        }
        std::string name = bytes.value();
        if (!name.empty() && name.back() == '\n') {
            name.pop_back();
        }
        if (!parse_generation(name)) {
            return data_loss(what + ": CURRENT does not name a generation: '" +
                             bytes.value().substr(0, 40) + "'");
        }
        return name;
    };
    // An import finishing meanwhile removes the generation we are opening: when a file is
    // missing and CURRENT changed, open the new one.
    for (int attempt = 0;; ++attempt) {
        auto generation = read_current();
        if (!generation.ok()) {
            return generation.status();
        }
        auto changed = [&]() -> bool {
            if (attempt >= 5) {
                return false;
            }
            auto again = read_current();
            return again.ok() && again.value() != generation.value();
        };
        std::shared_ptr<Store> store(new Store());
        store->m_impl = std::make_unique<Impl>();
        Impl& st = *store->m_impl;
        st.dir = dir;
        st.generation = generation.value();
        st.gen_dir = join(dir, st.generation);
        const std::string manifest_path = join(st.gen_dir, MANIFEST_FILE);
        auto manifest = read_whole_file(manifest_path);
        auto crc_line = manifest.ok() ? read_whole_file(join(st.gen_dir, MANIFEST_CRC_FILE))
                                      : StatusOr<std::string>(manifest.status());
        auto tables = crc_line.ok() ? read_whole_file(join(st.gen_dir, TABLES_FILE))
                                    : StatusOr<std::string>(crc_line.status());
        if (!tables.ok()) {
            const Status& missing = tables.status();
            if (missing.code() == StatusCode::not_found) {
                if (changed()) {
                    continue;
                }
                return data_loss(what + ": CURRENT names " + st.generation +
                                 " but its manifest is incomplete: " + missing.message());
            }
            return with_context(missing, what);
        }
        unsigned crc = 0;
        unsigned long long size = 0;
        char tail = 0;
        if (std::sscanf(crc_line->c_str(), "crc32 %8x bytes %llu%c", &crc, &size, &tail) != 3 ||
            tail != '\n' || size != manifest->size() ||
            crc != crc32_of(manifest->data(), manifest->size())) {
            return data_loss(what + ": the manifest of " + st.generation +
                             " is corrupt (checksum mismatch)");
        }
        json doc;
        try {
            doc = json::parse(manifest.value());
        } catch (const json::exception& e) {
            return data_loss(what + ": the manifest of " + st.generation +
                             " is malformed: " + e.what());
        }
        if (Status s = st.load_manifest(doc, tables.value()); !s.ok()) {
            return s;
        }
        st.summary.path = dir;
        st.summary.generation = st.generation;
        bool vanished = false;
        for (std::size_t f = 0; f < st.files.size(); ++f) {
            const std::string path = join(st.gen_dir, data_file_name(f));
            auto fd = open_file(path, O_RDONLY);
            if (fd.ok()) {
                st.files[f] = std::move(fd).value();
            } else {
                vanished = vanished || fd.status().code() == StatusCode::not_found;
                st.file_errors[f] = fd.status().message();
            }
        }
        if (vanished && changed()) {
            continue;
        }
        return store;
    }
}

Store::~Store() = default;

const StoreSummary& Store::summary() const {
    return m_impl->summary;
}
const std::vector<ObjectInfo>& Store::objects() const {
    return m_impl->objects;
}
const std::vector<PieceInfo>& Store::pieces() const {
    return m_impl->pieces;
}

StatusOr<PieceGeometry> Store::read_piece(std::uint32_t piece) const {
    const Impl& st = *m_impl;
    if (piece >= st.pieces.size()) {
        return invalid_argument(st.what() + ": piece " + std::to_string(piece) + " out of range (" +
                                std::to_string(st.pieces.size()) + " pieces)");
    }
    const PieceInfo& info = st.pieces[piece];
    std::vector<char> record(info.bytes);
    if (Status s = st.read_range(info.offset, info.offset + info.bytes, record.data()); !s.ok()) {
        return s;
    }
    const char* p = record.data();
    std::uint32_t header[6];
    std::memcpy(header, p, sizeof header);
    auto mismatch = [&](const std::string& what) {
        return data_loss(st.what() + ": piece " + std::to_string(piece) + " (" + st.generation +
                         "): the record does not match the manifest: " + what);
    };
    if (header[0] != PIECE_MAGIC || header[1] != piece || header[2] != info.object ||
        header[3] != info.vertex_count || header[4] != info.triangle_count) {
        return mismatch("header");
    }
    p += PIECE_HEADER_BYTES;
    PieceGeometry g;
    g.vertices.resize(info.vertex_count);
    g.triangles.resize(info.triangle_count);
    g.source_triangles.resize(info.triangle_count);
    std::memcpy(g.vertices.data(), p, g.vertices.size() * sizeof(Vec3));
    p += g.vertices.size() * sizeof(Vec3);
    std::memcpy(g.triangles.data(), p, g.triangles.size() * sizeof(TriangleIndices));
    p += g.triangles.size() * sizeof(TriangleIndices);
    std::memcpy(g.source_triangles.data(), p, g.source_triangles.size() * sizeof(std::uint32_t));
    const std::uint64_t object_triangles = st.objects[info.object].triangle_count;
    bool identity = true;
    for (std::size_t t = 0; t < g.triangles.size(); ++t) {
        const auto& tri = g.triangles[t];
        if (tri[0] >= info.vertex_count || tri[1] >= info.vertex_count ||
            tri[2] >= info.vertex_count || g.source_triangles[t] >= object_triangles) {
            return mismatch("triangle " + std::to_string(t) + " out of range");
        }
        identity = identity && g.source_triangles[t] == t;
    }
    if (identity) {
        g.source_triangles = {};  // PieceGeometry::source(t) == t: nothing to keep resident
    }
    st.pieces_read += 1;
    return g;
}

std::vector<std::uint32_t> PieceGeometry::source_ids() const {
    if (!source_triangles.empty()) {
        return source_triangles;
    }
    std::vector<std::uint32_t> ids(triangles.size());
    std::iota(ids.begin(), ids.end(), 0u);
    return ids;
}

Status Store::verify(const ProgressFn& progress) const {
    const Impl& st = *m_impl;
    const std::uint64_t batch = std::max<std::uint64_t>(1, (8ull << 20) / st.chunk_bytes);
    std::vector<char> data;
    std::uint64_t done = 0;
    if (progress) {
        progress({"verifying", 0, st.summary.bytes, "bytes"});
    }
    for (std::uint64_t k = 0; k < st.summary.chunks; k += batch) {
        const std::uint64_t last = std::min(st.summary.chunks, k + batch) - 1;
        data.resize(st.span_bytes(k, last));
        if (Status s = st.read_chunks(k, last, data.data()); !s.ok()) {
            return s;
        }
        done += data.size();
        if (progress) {
            progress({"verifying", done, st.summary.bytes, "bytes"});
        }
    }
    return {};
}

namespace {

Status check_sidecar_name(const std::string& name) {
    const bool ok =
        !name.empty() && name.size() <= 100 && name[0] != '.' &&
        std::all_of(name.begin(), name.end(), [](char c) {
            return std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '-';
        });
    if (!ok) {
        return invalid_argument("sidecar name '" + name +
                                "': expected 1 to 100 letters, digits, '.', '_' or '-', not "
                                "starting with '.'");
    }
    return {};
}

std::string sidecar_file(const std::string& name) {
    return "sidecar-" + name;
}

}  // namespace

Status Store::write_sidecar(const std::string& name, const std::string& bytes) const {
    const Impl& st = *m_impl;
    if (Status s = check_sidecar_name(name); !s.ok()) {
        return with_context(s, st.what());
    }
    const std::string path = join(st.gen_dir, sidecar_file(name));
    // Unique per writer, so concurrent writers of the same sidecar never share a temporary.
    const std::string tmp = path + ".tmp." + std::to_string(::getpid()) + "." +
                            std::to_string(st.sidecar_tmp_counter.fetch_add(1));
    std::string out(SIDECAR_HEADER_BYTES, '\0');
    const std::uint64_t size = bytes.size();
    const std::uint32_t crc = crc32_of(bytes.data(), bytes.size());
    const std::uint32_t head[2] = {SIDECAR_MAGIC, 1};
    std::memcpy(out.data(), head, 8);
    std::memcpy(out.data() + 8, &size, 8);
    std::memcpy(out.data() + 16, &crc, 4);
    out += bytes;
    Status s = write_file_synced(tmp, out);
    if (s.ok()) {
        s = rename_path(tmp, path);
    }
    if (s.ok()) {
        s = sync_dir(st.gen_dir);
    }
    if (!s.ok()) {
        std::error_code ec;
        fs::remove(tmp, ec);
        if (s.code() == StatusCode::not_found) {
            // The generation was replaced by a newer import and removed.
            return Status(StatusCode::unavailable, st.what() + ": sidecar '" + name +
                                                       "': generation " + st.generation +
                                                       " is no longer live (" + s.message() + ")");
        }
        return with_context(s, st.what() + ": sidecar '" + name + "'");
    }
    return {};
}

StatusOr<std::string> Store::read_sidecar(const std::string& name) const {
    const Impl& st = *m_impl;
    if (Status s = check_sidecar_name(name); !s.ok()) {
        return with_context(s, st.what());
    }
    const std::string path = join(st.gen_dir, sidecar_file(name));
    auto data = read_whole_file(path);
    if (!data.ok()) {
        if (data.status().code() == StatusCode::not_found) {
            return not_found(st.what() + ": no sidecar '" + name + "' in " + st.generation);
        }
        return with_context(data.status(), st.what() + ": sidecar '" + name + "'");
    }
    const std::string& d = data.value();
    std::uint32_t head[2] = {0, 0};
    std::uint64_t size = 0;
    std::uint32_t crc = 0;
    if (d.size() >= SIDECAR_HEADER_BYTES) {
        std::memcpy(head, d.data(), 8);
        std::memcpy(&size, d.data() + 8, 8);
        std::memcpy(&crc, d.data() + 16, 4);
    }
    if (d.size() < SIDECAR_HEADER_BYTES || head[0] != SIDECAR_MAGIC || head[1] != 1 ||
        size != d.size() - SIDECAR_HEADER_BYTES ||
        crc != crc32_of(d.data() + SIDECAR_HEADER_BYTES, size)) {
        return data_loss(st.what() + ": sidecar '" + name + "' (" + st.generation +
                         ") is corrupt (checksum or size mismatch)");
    }
    return d.substr(SIDECAR_HEADER_BYTES);
}

std::uint64_t Store::bytes_read() const {
    return m_impl->bytes_read.load(std::memory_order_relaxed);
}
std::uint64_t Store::pieces_read() const {
    return m_impl->pieces_read.load(std::memory_order_relaxed);
}

// ---------------------------------------------------------------------------------------------
// import_files

namespace {

bool ends_with_ci(const std::string& s, const std::string& suffix) {
    if (s.size() < suffix.size()) {
        return false;
    }
    for (std::size_t i = 0; i < suffix.size(); ++i) {
        if (std::tolower(static_cast<unsigned char>(s[s.size() - suffix.size() + i])) !=
            suffix[i]) {
            return false;
        }
    }
    return true;
}

// Files a directory import takes: the native formats and assimp's, less extensions that name
// other things as often as meshes.
bool is_mesh_file_name(const fs::path& p) {
    std::string ext = p.extension().string();
    for (auto& c : ext) {
        c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    }
    if (ext == ".ply" || ext == ".off") {
        return true;
    }
    static const std::set<std::string> GENERIC = {".json", ".xml", ".raw", ".prj", ".txt", ""};
    if (GENERIC.count(ext) != 0) {
        return false;
    }
    static const Assimp::Importer IMPORTER;
    return IMPORTER.IsExtensionSupported(ext);
}

// One object to import: a mesh file, or an object of a scene file.
struct ImportItem {
    std::string name;
    std::string mesh_path;                              // a mesh file, or
    const detail::SceneObject* scene_object = nullptr;  // a scene object
    std::string scene_path;
};

}  // namespace

StatusOr<StoreSummary> import_files(const std::vector<std::string>& inputs,
                                    const std::string& store_dir, const StoreOptions& options,
                                    const ProgressFn& progress) {
    if (inputs.empty()) {
        return invalid_argument("import into '" + store_dir + "': no input files");
    }
    // Plan everything first: a bad scene file or a missing input fails before anything is
    // written.
    std::vector<std::unique_ptr<detail::SceneFile>> scenes;  // items point into them
    std::vector<ImportItem> items;
    for (const auto& input : inputs) {
        std::error_code ec;
        const auto status = fs::status(input, ec);
        if (ec || !fs::exists(status)) {
            return not_found("input '" + input + "': no such file or directory");
        }
        if (fs::is_directory(status)) {
            std::vector<std::pair<std::string, std::string>> found;  // relative name, path
            fs::recursive_directory_iterator it(input, ec);
            for (fs::recursive_directory_iterator end; !ec && it != end; it.increment(ec)) {
                const std::string leaf = it->path().filename().string();
                if (!leaf.empty() && leaf[0] == '.') {
                    if (it->is_directory(ec)) {
                        it.disable_recursion_pending();
                    }
                    continue;
                }
                if (it->is_regular_file(ec) && is_mesh_file_name(it->path())) {
                    found.emplace_back(fs::relative(it->path(), input).generic_string(),
                                       it->path().string());
                }
            }
            if (ec) {
                return Status(StatusCode::unavailable,
                              "input directory '" + input + "': cannot be listed: " + ec.message());
            }
            if (found.empty()) {
                return invalid_argument("input directory '" + input + "': no mesh files in it");
            }
            std::sort(found.begin(), found.end());
            for (auto& [name, path] : found) {
                items.push_back({name, path, nullptr, {}});
            }
        } else if (ends_with_ci(input, ".json")) {
            auto scene = detail::parse_scene_file(input);
            if (!scene.ok()) {
                return scene.status();
            }
            scenes.push_back(std::make_unique<detail::SceneFile>(std::move(scene).value()));
            for (const auto& o : scenes.back()->objects) {
                items.push_back({o.name, {}, &o, input});
            }
        } else {
            items.push_back({input, input, nullptr, {}});
        }
    }
    if (items.empty()) {
        return invalid_argument("import into '" + store_dir + "': the inputs hold no objects");
    }

    // How many scene objects still need each mesh file: a mesh is read once and dropped after
    // its last use, so instances cost one read and memory stays bounded.
    std::map<std::string, std::size_t> last_use;
    for (std::size_t i = 0; i < items.size(); ++i) {
        if (items[i].scene_object != nullptr) {
            for (const auto& part : items[i].scene_object->parts) {
                last_use[part.mesh_path] = i;
            }
        }
    }
    std::map<std::string, TriangleMesh> cache;

    auto writer = StoreWriter::create(store_dir, options);
    if (!writer.ok()) {
        return writer.status();
    }
    if (progress) {
        progress({"reading", 0, items.size(), "objects"});
    }
    for (std::size_t i = 0; i < items.size(); ++i) {
        const auto& item = items[i];
        ModelObject object;
        object.name = item.name;
        if (item.scene_object == nullptr) {
            auto mesh = read_mesh(item.mesh_path);
            if (!mesh.ok()) {
                return mesh.status();
            }
            object.mesh = std::move(mesh).value();
        } else {
            auto& out = object.mesh;
            for (std::size_t k = 0; k < item.scene_object->parts.size(); ++k) {
                const auto& part = item.scene_object->parts[k];
                auto it = cache.find(part.mesh_path);
                if (it == cache.end()) {
                    auto mesh = read_mesh(part.mesh_path);
                    if (!mesh.ok()) {
                        return Status(mesh.status().code(), "scene file '" + item.scene_path +
                                                                "', object '" + item.name +
                                                                "', mesh '" + part.mesh_key +
                                                                "': " + mesh.status().message());
                    }
                    it = cache.emplace(part.mesh_path, std::move(mesh).value()).first;
                }
                const TriangleMesh& m = it->second;
                if (out.vertices.size() + m.vertices.size() >
                    std::numeric_limits<std::uint32_t>::max()) {
                    return invalid_argument("scene file '" + item.scene_path + "', object '" +
                                            item.name + "': more than 2^32 vertices");
                }
                const auto base = static_cast<std::uint32_t>(out.vertices.size());
                if (part.transform) {
                    for (const auto& v : m.vertices) {
                        out.vertices.push_back(part.transform->apply(v));
                    }
                } else {
                    out.vertices.insert(out.vertices.end(), m.vertices.begin(), m.vertices.end());
                }
                for (const auto& t : m.triangles) {
                    out.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
                }
            }
            for (const auto& part : item.scene_object->parts) {
                if (last_use[part.mesh_path] == i) {
                    cache.erase(part.mesh_path);
                }
            }
        }
        if (Status s = writer.value()->add(object); !s.ok()) {
            return s;
        }
        if (progress) {
            progress({"reading", i + 1, items.size(), "objects"});
        }
    }
    return writer.value()->commit(progress);
}

}  // namespace proxima::massive
