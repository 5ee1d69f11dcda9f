// Helpers shared by the subcommands in clients/cli (declared in commands.hpp).

#include <cctype>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "cli/commands.hpp"

namespace proxima::cli {

int fail(const Status& status) {
    std::fprintf(stderr, "proxima: error: %s\n", client::describe_status(status).c_str());
    return 1;
}

// "16M" -> 16 * 1024^2 (bytes) or 16 * 1000^2 (counts); "1.5G", "4096", "64KiB" too.
StatusOr<std::uint64_t> parse_size(const std::string& option, const std::string& text,
                                   std::uint64_t base) {
    auto bad = [&] {
        return invalid_argument(option + " '" + text +
                                "': expected a positive number with an optional K, M, G or T "
                                "suffix");
    };
    std::size_t used = 0;
    double value = 0;
    try {
        value = std::stod(text, &used);
    } catch (const std::exception&) {
        return bad();
    }
    std::string suffix = text.substr(used);
    for (auto& c : suffix) {
        c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    }
    if (suffix.size() > 1 && (suffix.back() == 'B')) {
        suffix.pop_back();  // "MB", "MiB"
        if (!suffix.empty() && suffix.back() == 'I') {
            suffix.pop_back();
        }
    } else if (suffix == "B") {
        suffix.clear();
    }
    double scale = 1;
    if (suffix == "K") {
        scale = static_cast<double>(base);
    } else if (suffix == "M") {
        scale = std::pow(static_cast<double>(base), 2);
    } else if (suffix == "G") {
        scale = std::pow(static_cast<double>(base), 3);
    } else if (suffix == "T") {
        scale = std::pow(static_cast<double>(base), 4);
    } else if (!suffix.empty()) {
        return bad();
    }
    const double result = std::round(value * scale);
    if (!std::isfinite(result) || result < 1 || result > 1.8e19) {
        return bad();
    }
    return static_cast<std::uint64_t>(result);
}

}  // namespace proxima::cli
