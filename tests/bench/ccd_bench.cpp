// proxima_ccd_bench: the elementary CCD tests (proxima/ccd/elementary.hpp) on the public CCD
// benchmark of Wang et al. 2021 (PROXIMA_DATA_DIR/ccd-queries, 7,279 queries with ground truth).
// Per data file and in total: queries, false negatives, false positives, capped tests, mean /
// p99 / worst time per query and total seconds, single thread.
//
// No peer runs here: Tight-Inclusion, the reference, is not a Debian package. Its numbers, quoted
// from the data's README (2-core Debian 12 machine like CI's, tolerance 1e-6, double): 0 false
// negatives, 222 false positives, mean 4.0 ms per query, worst 770 ms.
//
// Usage: proxima_ccd_bench [--quick] [--tolerance T] [--min-distance D] [--max-boxes N]
//                          [--repeat R] [FILE.csv ...]
// Without files, every CSV under PROXIMA_DATA_DIR/ccd-queries (the kind from the path).
// --quick: one small file (unit-tests/edge-edge/data_0_1.csv), for the ctest smoke run.
// --repeat R: time each query R times and keep the fastest (steadier timings).
// The last line is a digest of every answer (hit, capped, the toi's bits), to compare builds.

#include <algorithm>
#include <bit>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "proxima/ccd/elementary.hpp"
#include "proxima/io/ccd_queries.hpp"

#include "bench_util.hpp"

namespace {

using namespace proxima;
namespace fs = std::filesystem;

struct Row {
    std::string name;
    std::size_t queries = 0;
    std::size_t positives = 0;
    std::size_t false_negatives = 0;
    std::size_t false_positives = 0;
    std::size_t capped = 0;
    std::uint64_t boxes = 0;
    std::vector<double> seconds;  // per query
};

double total(const std::vector<double>& s) {
    double sum = 0.0;
    for (double x : s) {
        sum += x;
    }
    return sum;
}

double percentile(std::vector<double> s, double p) {
    if (s.empty()) {
        return 0.0;
    }
    std::sort(s.begin(), s.end());
    const auto i = static_cast<std::size_t>(p * static_cast<double>(s.size() - 1) + 0.5);
    return s[std::min(i, s.size() - 1)];
}

void print_row(const Row& r) {
    const double sum = total(r.seconds);
    const double n = static_cast<double>(std::max<std::size_t>(r.queries, 1));
    std::printf(
        "%-52s %6zu %5zu %4zu %4zu %6zu %9.4f %9.4f %9.4f %9.3f %11.1f\n", r.name.c_str(),
        r.queries, r.positives, r.false_negatives, r.false_positives, r.capped, sum / n * 1e3,
        percentile(r.seconds, 0.99) * 1e3,
        r.seconds.empty() ? 0.0 : *std::max_element(r.seconds.begin(), r.seconds.end()) * 1e3, sum,
        static_cast<double>(r.boxes) / n);
}

int usage() {
    std::fprintf(stderr,
                 "usage: proxima_ccd_bench [--quick] [--tolerance T] [--min-distance D] "
                 "[--max-boxes N] [--repeat R] [FILE.csv ...]\n");
    return 2;
}

}  // namespace

int main(int argc, char** argv) {
    ccd::ElementaryOptions options;
    bool quick = false;
    int repeat = 1;
    std::vector<std::string> files;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto value = [&](double& out) {
            if (i + 1 >= argc) {
                return false;
            }
            char* end = nullptr;
            out = std::strtod(argv[++i], &end);
            return end != argv[i] && *end == '\0';
        };
        double x = 0.0;
        if (a == "--quick") {
            quick = true;
        } else if (a == "--tolerance") {
            if (!value(x) || !(x > 0.0)) {
                return usage();
            }
            options.tolerance = x;
        } else if (a == "--min-distance") {
            if (!value(x) || !(x >= 0.0)) {
                return usage();
            }
            options.min_distance = x;
        } else if (a == "--max-boxes") {
            if (!value(x) || !(x >= 1.0) || x > 4e9) {
                return usage();
            }
            options.max_boxes = static_cast<std::uint32_t>(x);
        } else if (a == "--repeat") {
            if (!value(x) || !(x >= 1.0) || x > 1000) {
                return usage();
            }
            repeat = static_cast<int>(x);
        } else if (!a.empty() && a[0] == '-') {
            return usage();
        } else {
            files.push_back(a);
        }
    }
    const fs::path root = fs::path(PROXIMA_DATA_DIR) / "ccd-queries";
    if (files.empty()) {
        if (!fs::is_directory(root)) {
            std::fprintf(stderr, "proxima_ccd_bench: no data at %s (and no files given)\n",
                         root.string().c_str());
            return 1;
        }
        if (quick) {
            files.push_back((root / "unit-tests" / "edge-edge" / "data_0_1.csv").string());
        } else {
            for (const auto& entry : fs::recursive_directory_iterator(root)) {
                if (entry.is_regular_file() && entry.path().extension() == ".csv") {
                    files.push_back(entry.path().string());
                }
            }
            std::sort(files.begin(), files.end());
        }
    }

    std::printf("machine: %u hardware threads (nproc), CPU %s; single-threaded run\n",
                std::thread::hardware_concurrency(), bench::cpu_model().c_str());
    std::printf("options: tolerance %g, min_distance %g, max_boxes %u, repeat %d\n",
                options.tolerance, options.min_distance, options.max_boxes, repeat);
    std::printf(
        "peer: none in this run (Tight-Inclusion is not a Debian package). README reference, "
        "Tight-Inclusion\n      tolerance 1e-6 double on a 2-core machine: 7279 queries, 0 FN, "
        "222 FP, mean 4.0 ms, worst 770 ms (~29 s total)\n\n");
    std::printf("%-52s %6s %5s %4s %4s %6s %9s %9s %9s %9s %11s\n", "file", "queries", "hits", "FN",
                "FP", "capped", "mean ms", "p99 ms", "worst ms", "total s", "boxes/query");

    Row all;
    all.name = "TOTAL";
    std::uint64_t digest = 1469598103934665603ULL;  // FNV-1a over every answer
    auto mix = [&digest](std::uint64_t x) {
        for (int i = 0; i < 8; ++i) {
            digest = (digest ^ ((x >> (8 * i)) & 0xff)) * 1099511628211ULL;
        }
    };
    int status = 0;
    for (const auto& file : files) {
        auto kind = ccd_kind_from_path(file);
        if (!kind) {
            std::fprintf(stderr, "proxima_ccd_bench: %s: cannot tell the kind from the path\n",
                         file.c_str());
            return 1;
        }
        auto queries = read_ccd_queries(file);
        if (!queries.ok()) {
            std::fprintf(stderr, "proxima_ccd_bench: %s\n", queries.status().to_string().c_str());
            return 1;
        }
        Row row;
        std::string name = fs::path(file).lexically_relative(root).string();
        if (name.empty() || name.rfind("..", 0) == 0) {
            name = file;
        }
        row.name = name;
        for (const auto& q : queries.value()) {
            ccd::ElementaryResult r;
            double best = 1e300;
            for (int k = 0; k < repeat; ++k) {
                const auto start = std::chrono::steady_clock::now();
                r = ccd::elementary(*kind, q.points, options);
                const double s =
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
                best = std::min(best, s);
            }
            ++row.queries;
            row.seconds.push_back(best);
            row.boxes += r.boxes;
            mix((r.hit ? 1U : 0U) | (r.capped ? 2U : 0U));
            mix(std::bit_cast<std::uint64_t>(r.toi));
            row.positives += r.hit ? 1 : 0;
            row.capped += r.capped ? 1 : 0;
            if (q.truth) {
                row.false_negatives += (*q.truth && !r.hit) ? 1 : 0;
                row.false_positives += (!*q.truth && r.hit) ? 1 : 0;
            }
        }
        print_row(row);
        std::fflush(stdout);
        all.queries += row.queries;
        all.positives += row.positives;
        all.false_negatives += row.false_negatives;
        all.false_positives += row.false_positives;
        all.capped += row.capped;
        all.boxes += row.boxes;
        all.seconds.insert(all.seconds.end(), row.seconds.begin(), row.seconds.end());
    }
    std::printf("\n");
    print_row(all);
    std::printf("answer digest (hit, capped, toi bits) %016llx\n",
                static_cast<unsigned long long>(digest));
    if (all.false_negatives > 0) {
        std::printf("FALSE NEGATIVES: %zu\n", all.false_negatives);
        status = 1;
    }
    return status;
}
