#pragma once
// Private to the store (store.cpp): the on-disk layout constants and the POSIX file helpers it
// is built on. Every system call is checked and its failure becomes a Status naming the file:
// ENOSPC/EDQUOT/EFBIG are RESOURCE_EXHAUSTED (the user must free space or raise a limit), any
// other I/O error is UNAVAILABLE.
//
// A generation directory holds:
//   chunks-0000.bin ...  the chunk stream (piece records back to back), cut into chunks of
//                        chunk_bytes, DATA_FILE_BYTES of chunks per file
//   manifest.json        format, options, source, summary, objects, and the size and CRC-32 of
//   manifest.bin         the piece table and the per-chunk CRC-32s (binary, see TABLES_FILE)
//   manifest.crc         "crc32 XXXXXXXX bytes N\n" of manifest.json: a torn or flipped
//                        manifest is DATA_LOSS at open
//   sidecar-NAME         Store::write_sidecar files (header with their own CRC-32)
// Test hooks (environment): PROXIMA_STORE_FAULT=before-gen-rename|after-gen-rename|
// before-current-rename|after-current-rename SIGKILLs the process at that step of commit;
// PROXIMA_STORE_TEST_FILE_BYTES makes data files smaller than DATA_FILE_BYTES.

#include <bit>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "proxima/status.hpp"

namespace proxima::massive::detail {

// Records are memcpy'd to and from disk: the format is little-endian.
static_assert(std::endian::native == std::endian::little, "the store format is little-endian");

inline constexpr char STORE_FORMAT[] = "proxima-store/1";
inline constexpr char MANIFEST_FILE[] = "manifest.json";
inline constexpr char MANIFEST_CRC_FILE[] = "manifest.crc";
inline constexpr char CURRENT_FILE[] = "CURRENT";
inline constexpr char LOCK_FILE[] = "LOCK";

// A piece record: header (magic, piece, object, vertex count, triangle count, reserved), then
// vertices (3 doubles each), triangles (3 uint32 each), source triangles (uint32 each).
inline constexpr std::uint32_t PIECE_MAGIC = 0x31435850;  // "PXC1"
inline constexpr std::uint64_t PIECE_HEADER_BYTES = 24;
inline std::uint64_t piece_record_bytes(std::uint64_t vertex_count, std::uint64_t triangle_count) {
    return PIECE_HEADER_BYTES + vertex_count * 24 + triangle_count * 16;
}

// The manifest's bulk tables, binary (manifest.bin, its size and CRC in manifest.json): 100,000
// pieces load in milliseconds, where the same rows as JSON take most of a second. Header (magic,
// version, piece count, chunk count), one PieceEntry per piece, one CRC-32 per chunk.
inline constexpr char TABLES_FILE[] = "manifest.bin";
inline constexpr std::uint32_t TABLES_MAGIC = 0x31544d50;  // "PMT1"
inline constexpr std::uint64_t TABLES_HEADER_BYTES = 24;
struct PieceEntry {
    std::uint32_t object;
    std::uint32_t vertex_count;
    std::uint32_t triangle_count;
    std::uint32_t reserved;
    double box[6];  // lo x y z, hi x y z
    std::uint64_t offset;
    std::uint64_t bytes;
};
static_assert(sizeof(PieceEntry) == 80, "PieceEntry is written as it is in memory");

// Chunks are grouped into data files of at most this many bytes (a 5 GB model: ~20 files).
inline constexpr std::uint64_t DATA_FILE_BYTES = 256ull << 20;
inline constexpr std::uint64_t MIN_CHUNK_BYTES = 64;
inline constexpr std::uint64_t MAX_CHUNK_BYTES = DATA_FILE_BYTES;

// Sidecar files: header (magic, version, payload size, payload CRC, reserved), then the payload.
inline constexpr std::uint32_t SIDECAR_MAGIC = 0x31435358;  // "XSC1"
inline constexpr std::uint64_t SIDECAR_HEADER_BYTES = 24;

std::string generation_name(std::uint64_t number);  // "gen-000003"
// 3 for "gen-000003"; nullopt for anything else (including "gen-000003.tmp").
std::optional<std::uint64_t> parse_generation(std::string_view name);
std::string data_file_name(std::uint64_t index);  // "chunks-0000.bin"

std::uint32_t crc32_of(const void* data, std::size_t size);

// An owned file descriptor.
class Fd {
  public:
    Fd() = default;
    explicit Fd(int fd) : m_fd(fd) {}
    ~Fd() { reset(); }
    Fd(Fd&& other) noexcept : m_fd(other.release()) {}
    Fd& operator=(Fd&& other) noexcept {
        if (this != &other) {
            reset();
            m_fd = other.release();
        }
        return *this;
    }
    Fd(const Fd&) = delete;
    Fd& operator=(const Fd&) = delete;

    int get() const { return m_fd; }
    bool valid() const { return m_fd >= 0; }
    int release() {
        const int fd = m_fd;
        m_fd = -1;
        return fd;
    }
    void reset();

  private:
    int m_fd = -1;
};

// The Status for a failed system call: `action` is "writing", "opening", "syncing"...
Status io_error(const std::string& action, const std::string& path, int err);

StatusOr<Fd> open_file(const std::string& path, int flags, int mode = 0644);
Status write_all(int fd, const void* data, std::size_t size, const std::string& path);
Status sync_fd(int fd, const std::string& path);
// Closes and reports close's error (NFS and some file systems report write errors there).
Status close_fd(Fd& fd, const std::string& path);
Status sync_dir(const std::string& path);
Status rename_path(const std::string& from, const std::string& to);
// Creates (or truncates) `path` with `bytes`, fsyncs and closes it.
Status write_file_synced(const std::string& path, std::string_view bytes);

// Reads exactly `size` bytes at `offset`; `got` is how many were read before end of file (an
// error only when the read itself fails).
Status pread_all(int fd, void* data, std::size_t size, std::uint64_t offset, std::size_t& got,
                 const std::string& path);
// The whole file (NOT_FOUND when absent).
StatusOr<std::string> read_whole_file(const std::string& path);

}  // namespace proxima::massive::detail
