#include "io/gzip.hpp"

#include <zlib.h>

#include <algorithm>
#include <climits>

namespace proxima::detail {

bool is_gzip(std::string_view data) {
    return data.size() >= 2 && static_cast<unsigned char>(data[0]) == 0x1f &&
           static_cast<unsigned char>(data[1]) == 0x8b;
}

StatusOr<std::string> gunzip(std::string_view data, const std::string& name, std::uint64_t limit) {
    auto bad = [&](const std::string& why) {
        return invalid_argument("mesh file '" + name + "': gzip data " + why);
    };
    z_stream stream{};
    // 16 + MAX_WBITS: gzip framing only (a zlib stream is not a .gz file).
    if (inflateInit2(&stream, 16 + MAX_WBITS) != Z_OK) {
        return bad("cannot be read: zlib failed to start");
    }
    struct End {
        z_stream* s;
        ~End() { inflateEnd(s); }
    } end{&stream};

    std::string out;
    const auto* next = reinterpret_cast<const Bytef*>(data.data());
    std::size_t left = data.size();
    constexpr std::size_t STEP = std::size_t{1} << 20;
    for (;;) {
        // zlib counts in uInt: feed at most UINT_MAX bytes at a time.
        stream.next_in = const_cast<Bytef*>(next);
        stream.avail_in = static_cast<uInt>(std::min<std::size_t>(left, UINT_MAX));
        const std::size_t fed = stream.avail_in;
        if (out.size() >= limit) {
            return bad("decompresses to more than " + std::to_string(limit) +
                       " bytes (the reader's limit)");
        }
        const std::size_t room = std::min<std::uint64_t>(STEP, limit - out.size());
        const std::size_t before = out.size();
        out.resize(before + room);
        stream.next_out = reinterpret_cast<Bytef*>(out.data() + before);
        stream.avail_out = static_cast<uInt>(room);
        const int rc = inflate(&stream, Z_NO_FLUSH);
        out.resize(before + (room - stream.avail_out));
        const std::size_t used = fed - stream.avail_in;
        next += used;
        left -= used;
        if (rc == Z_STREAM_END) {
            if (left == 0) {
                return out;
            }
            if (!is_gzip(std::string_view(reinterpret_cast<const char*>(next), left))) {
                return bad("is followed by " + std::to_string(left) + " bytes that are not gzip");
            }
            inflateReset(&stream);  // the next member
            continue;
        }
        if (rc != Z_OK && rc != Z_BUF_ERROR) {
            return bad(std::string("is corrupt (") +
                       (stream.msg != nullptr ? stream.msg : "zlib error " + std::to_string(rc)) +
                       ")");
        }
        // Every byte consumed, room left for output, and still no end: the file was cut short.
        if (left == 0 && stream.avail_out != 0) {
            return bad("is truncated (the file ends inside the compressed stream)");
        }
    }
}

}  // namespace proxima::detail
