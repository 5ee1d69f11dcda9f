#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

#include "massive/store_format.hpp"

namespace proxima::massive::detail {

std::string generation_name(std::uint64_t number) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "gen-%06llu", static_cast<unsigned long long>(number));
    return buf;
}

std::optional<std::uint64_t> parse_generation(std::string_view name) {
    constexpr std::string_view PREFIX = "gen-";
    if (name.size() < PREFIX.size() + 6 || name.size() > PREFIX.size() + 18 ||
        name.substr(0, PREFIX.size()) != PREFIX) {
        return std::nullopt;
    }
    std::uint64_t n = 0;
    for (char c : name.substr(PREFIX.size())) {
        if (c < '0' || c > '9') {
            return std::nullopt;
        }
        n = n * 10 + static_cast<std::uint64_t>(c - '0');
    }
    return n;
}

std::string data_file_name(std::uint64_t index) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "chunks-%04llu.bin", static_cast<unsigned long long>(index));
    return buf;
}

std::uint32_t crc32_of(const void* data, std::size_t size) {
    return static_cast<std::uint32_t>(
        crc32_z(crc32_z(0L, Z_NULL, 0), static_cast<const Bytef*>(data), size));
}

void Fd::reset() {
    if (m_fd >= 0) {
        ::close(m_fd);
        m_fd = -1;
    }
}

Status io_error(const std::string& action, const std::string& path, int err) {
    switch (err) {
        case ENOSPC:
            return {StatusCode::resource_exhausted, "disk full " + action + " '" + path + "'"};
        case EDQUOT:
            return {StatusCode::resource_exhausted,
                    "disk quota exceeded " + action + " '" + path + "'"};
        case EFBIG:
            return {StatusCode::resource_exhausted,
                    "file too large " + action + " '" + path + "' (file size limit reached)"};
        case ENOENT:
            return not_found("'" + path + "': no such file or directory (" + action + ")");
        default:
            return {StatusCode::unavailable,
                    "I/O error " + action + " '" + path + "': " + std::strerror(err)};
    }
}

StatusOr<Fd> open_file(const std::string& path, int flags, int mode) {
    for (;;) {
        const int fd = ::open(path.c_str(), flags | O_CLOEXEC, mode);
        if (fd >= 0) {
            return Fd(fd);
        }
        if (errno != EINTR) {
            return io_error("opening", path, errno);
        }
    }
}

Status write_all(int fd, const void* data, std::size_t size, const std::string& path) {
    const char* p = static_cast<const char*>(data);
    while (size > 0) {
        const ssize_t n = ::write(fd, p, size);
        if (n < 0) {
            if (errno == EINTR) {
                continue;
            }
            return io_error("writing", path, errno);
        }
        if (n == 0) {
            return io_error("writing", path, ENOSPC);
        }
        p += n;
        size -= static_cast<std::size_t>(n);
    }
    return {};
}

Status sync_fd(int fd, const std::string& path) {
    if (::fsync(fd) != 0) {
        return io_error("syncing", path, errno);
    }
    return {};
}

Status close_fd(Fd& fd, const std::string& path) {
    if (!fd.valid()) {
        return {};
    }
    if (::close(fd.release()) != 0 && errno != EINTR) {
        return io_error("closing", path, errno);
    }
    return {};
}

Status sync_dir(const std::string& path) {
    auto fd = open_file(path, O_RDONLY | O_DIRECTORY);
    if (!fd.ok()) {
        return fd.status();
    }
    return sync_fd(fd->get(), path);
}

Status rename_path(const std::string& from, const std::string& to) {
    if (::rename(from.c_str(), to.c_str()) != 0) {
        return io_error("renaming '" + from + "' to", to, errno);
    }
    return {};
}

Status write_file_synced(const std::string& path, std::string_view bytes) {
    auto fd = open_file(path, O_WRONLY | O_CREAT | O_TRUNC);
    if (!fd.ok()) {
        return fd.status();
    }
    if (Status s = write_all(fd->get(), bytes.data(), bytes.size(), path); !s.ok()) {
        return s;
    }
    if (Status s = sync_fd(fd->get(), path); !s.ok()) {
        return s;
    }
    return close_fd(fd.value(), path);
}

Status pread_all(int fd, void* data, std::size_t size, std::uint64_t offset, std::size_t& got,
                 const std::string& path) {
    char* p = static_cast<char*>(data);
    got = 0;
    while (got < size) {
        const ssize_t n = ::pread(fd, p + got, size - got, static_cast<off_t>(offset + got));
        if (n < 0) {
            if (errno == EINTR) {
                continue;
            }
            return io_error("reading", path, errno);
        }
        if (n == 0) {
            break;  // end of file: the caller reports the truncation
        }
        got += static_cast<std::size_t>(n);
    }
    return {};
}

StatusOr<std::string> read_whole_file(const std::string& path) {
    auto fd = open_file(path, O_RDONLY);
    if (!fd.ok()) {
        return fd.status();
    }
    struct stat st {};
    if (::fstat(fd->get(), &st) != 0) {
        return io_error("reading", path, errno);
    }
    std::string bytes(static_cast<std::size_t>(st.st_size), '\0');
    std::size_t got = 0;
    if (Status s = pread_all(fd->get(), bytes.data(), bytes.size(), 0, got, path); !s.ok()) {
        return s;
    }
    bytes.resize(got);
    return bytes;
}

}  // namespace proxima::massive::detail
