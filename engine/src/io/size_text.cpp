#include "proxima/io/size_text.hpp"

#include <cctype>
#include <charconv>
#include <cmath>
#include <string>

namespace proxima {

StatusOr<std::uint64_t> parse_size(std::string_view what, std::string_view text,
                                   std::uint64_t base) {
    auto bad = [&] {
        return invalid_argument(std::string(what) + " '" + std::string(text.substr(0, 40)) +
                                "': expected a positive number with an optional K, M, G or T "
                                "suffix (powers of " +
                                std::to_string(base) + "), e.g. 160M");
    };
    // Digits and an optional fraction only: no sign, no exponent, no "nan"/"inf".
    std::size_t used = 0;
    while (used < text.size() &&
           (std::isdigit(static_cast<unsigned char>(text[used])) != 0 || text[used] == '.')) {
        ++used;
    }
    double value = 0.0;
    const auto number = text.substr(0, used);
    if (number.empty() || number.front() == '.' ||
        std::from_chars(number.data(), number.data() + number.size(), value).ptr !=
            number.data() + number.size()) {
        return bad();
    }
    std::string suffix(text.substr(used));
    for (auto& c : suffix) {
        c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    }
    if (suffix.size() > 1 && suffix.back() == 'B') {
        suffix.pop_back();  // "MB", "MiB"
        if (!suffix.empty() && suffix.back() == 'I') {
            suffix.pop_back();
        }
    } else if (suffix == "B") {
        suffix.clear();
    }
    int power = 0;
    if (suffix == "K") {
        power = 1;
    } else if (suffix == "M") {
        power = 2;
    } else if (suffix == "G") {
        power = 3;
    } else if (suffix == "T") {
        power = 4;
    } else if (!suffix.empty()) {
        return bad();
    }
    const double result = std::round(value * std::pow(static_cast<double>(base), power));
    // 2^64 is the first double past the largest uint64_t.
    if (!std::isfinite(result) || result < 1 || result >= 18446744073709551616.0) {
        return bad();
    }
    return static_cast<std::uint64_t>(result);
}

}  // namespace proxima
