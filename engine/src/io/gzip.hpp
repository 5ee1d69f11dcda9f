#pragma once
// gzip-compressed mesh files (the shared scans are .ply.gz): decompressed in memory with zlib,
// then read by the same readers as any other file (mesh_io.cpp).

#include <cstdint>
#include <string>
#include <string_view>

#include "proxima/status.hpp"

namespace proxima::detail {

// The gzip magic (1f 8b) at the start of `data`.
bool is_gzip(std::string_view data);

// The decompressed bytes of a gzip stream (several members are concatenated, as gzip does).
// INVALID_ARGUMENT naming `name` for corrupt or truncated data, trailing garbage, or output past
// `limit` bytes (a decompression bomb stops there, without allocating more).
StatusOr<std::string> gunzip(std::string_view data, const std::string& name, std::uint64_t limit);

}  // namespace proxima::detail
