#pragma once
// Sizes as people write them on command lines and in configuration files: "160M", "1.5G",
// "4096", "64KiB". One rule for both programs (proxima, proximad).

#include <cstdint>
#include <string_view>

#include "proxima/status.hpp"

namespace proxima {

// A size with an optional K, M, G or T suffix (any case; "KB", "KiB" and a bare "B" accepted),
// scaled by powers of `base`: both programs use 1024 for every size, bytes and counts of things
// (triangles) alike (README, "Exit status"). A fraction is allowed before a suffix
// ("1.5G"); the result is rounded to a whole number. INVALID_ARGUMENT naming `what`
// ("--cache-bytes") for anything else: no digits, an unknown suffix, nan or inf, below 1 or above
// 2^64 - 1.
StatusOr<std::uint64_t> parse_size(std::string_view what, std::string_view text,
                                   std::uint64_t base = 1024);

}  // namespace proxima
