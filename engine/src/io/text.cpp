#include "io/text.hpp"

#include <array>
#include <charconv>
#include <cstdio>
#include <cstdlib>
#include <system_error>

namespace proxima::detail {

std::string printable(std::string_view text, std::size_t limit) {
    std::string out;
    for (std::size_t i = 0; i < text.size() && i < limit; ++i) {
        const auto c = static_cast<unsigned char>(text[i]);
        if (c >= 0x20 && c < 0x7f) {
            out += static_cast<char>(c);
        } else {
            std::array<char, 8> buf{};
            std::snprintf(buf.data(), buf.size(), "\\x%02x", static_cast<unsigned>(c));
            out += buf.data();
        }
    }
    if (text.size() > limit) {
        out += "...";
    }
    return out;
}

bool parse_double(std::string_view token, double& out) {
    if (!token.empty() && token[0] == '+') {
        token.remove_prefix(1);  // from_chars does not take a leading '+', C and Python write it
        if (!token.empty() && (token[0] == '+' || token[0] == '-')) {
            return false;
        }
    }
    if (token.empty()) {
        return false;
    }
    const char* last = token.data() + token.size();
    const auto [ptr, ec] = std::from_chars(token.data(), last, out);
    if (ptr != last) {
        return false;
    }
    if (ec == std::errc::result_out_of_range) {
        // from_chars leaves `out` alone on overflow and underflow; strtod gives the nearest
        // double (0 or +-HUGE_VAL; an infinity is then rejected as non-finite).
        const std::string copy(token);
        char* end = nullptr;
        out = std::strtod(copy.c_str(), &end);
        return end == copy.c_str() + copy.size();
    }
    return ec == std::errc{};
}

}  // namespace proxima::detail
