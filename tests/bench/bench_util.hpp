#pragma once
// Small helpers every benchmark tool shares: the machine it ran on, medians, fixed-point columns.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

namespace proxima::bench {

// "model name" of the first CPU in /proc/cpuinfo, or "unknown".
inline std::string cpu_model() {
    std::ifstream cpuinfo("/proc/cpuinfo");
    for (std::string line; std::getline(cpuinfo, line);) {
        if (line.rfind("model name", 0) == 0) {
            const auto colon = line.find(':');
            return colon == std::string::npos ? line : line.substr(colon + 2);
        }
    }
    return "unknown";
}

// The 1-minute load average from /proc/loadavg, or "?".
inline std::string load_average() {
    std::string one = "?";
    std::ifstream("/proc/loadavg") >> one;
    return one;
}

// Median (mean of the two middle values for an even count); NaN for none.
inline double median(std::vector<double> v) {
    if (v.empty()) {
        return std::nan("");
    }
    std::sort(v.begin(), v.end());
    const std::size_t n = v.size();
    return n % 2 == 1 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// `v` with `digits` decimals, "-" when not finite.
inline std::string fixed(double v, int digits = 2) {
    if (!std::isfinite(v)) {
        return "-";
    }
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.*f", digits, v);
    return buf;
}

}  // namespace proxima::bench
