// Per-query driver for the peer (Tight-Inclusion) in tests/bench/ti_compare.py: the same calls,
// settings and timing as ../shared/peers/tight-inclusion/ti_queries.cpp, but it prints each
// query's answer, time of impact and time, which ti_queries does not. Not part of the product and
// not built by CMake: ti_compare.py compiles it against the objects of the peer's build.sh.
//
//   ti_toi_driver --kind vf|ee FILE [TOLERANCE]
//
// FILE: one query per line, `truth x y z x y z ...` (truth -1, 0 or 1, then the 24 coordinates
// of the 8 points in the benchmark's row order as C hex floats, already rounded to the nearest
// double by ti_compare.py). Every line is read before any test runs; only the CCD calls are timed
// (std::chrono::steady_clock around each call). Output, one line per query:
// `hit toi seconds output_tolerance` (hit 0/1, toi as a hex float, %a).
//
// Settings as ti_queries: err = {-1,-1,-1}, ms = 0, tolerance = 1e-6 (or TOLERANCE, to see where
// the peer's toi converges), t_max = 1, max_itr = 1e6, no_zero_toi = false, BREADTH_FIRST_SEARCH.

#include <tight_inclusion/ccd.hpp>

#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace {

struct Query {
    std::array<double, 24> p{};
};

bool read_queries(const char* path, std::vector<Query>& out) {
    std::ifstream in(path);
    if (!in) {
        std::fprintf(stderr, "cannot open %s\n", path);
        return false;
    }
    std::string line;
    std::size_t lineno = 0;
    while (std::getline(in, line)) {
        ++lineno;
        if (line.empty())
            continue;
        std::istringstream fields(line);
        std::string field;
        fields >> field;  // the truth column (unused here: ti_compare.py compares)
        Query q;
        for (double& x : q.p) {
            if (!(fields >> field)) {
                std::fprintf(stderr, "%s:%zu: expected 25 fields\n", path, lineno);
                return false;
            }
            char* end = nullptr;
            x = std::strtod(field.c_str(), &end);
            if (end == field.c_str() || *end != '\0') {
                std::fprintf(stderr, "%s:%zu: bad number '%s'\n", path, lineno, field.c_str());
                return false;
            }
        }
        out.push_back(q);
    }
    return true;
}

}  // namespace

int main(int argc, char** argv) {
    if ((argc != 4 && argc != 5) || std::strcmp(argv[1], "--kind") != 0 ||
        (std::strcmp(argv[2], "vf") != 0 && std::strcmp(argv[2], "ee") != 0)) {
        std::fprintf(stderr, "usage: %s --kind vf|ee FILE [TOLERANCE]\n", argv[0]);
        return 2;
    }
    const bool ee = std::strcmp(argv[2], "ee") == 0;
    std::vector<Query> queries;
    if (!read_queries(argv[3], queries))
        return 1;

    const ticcd::Array3 err(-1, -1, -1);
    const double ms = 0.0;
    const double tolerance = argc == 5 ? std::strtod(argv[4], nullptr) : 1e-6;
    if (!(tolerance > 0.0)) {
        std::fprintf(stderr, "TOLERANCE must be a positive number\n");
        return 2;
    }
    const double t_max = 1.0;
    const long max_itr = 1000000;
    const bool no_zero_toi = false;
    const auto method = ticcd::CCDRootFindingMethod::BREADTH_FIRST_SEARCH;

    struct Answer {
        bool hit;
        double toi;
        double seconds;
        double output_tolerance;
    };
    std::vector<Answer> answers(queries.size());
    for (std::size_t i = 0; i < queries.size(); ++i) {
        const auto& p = queries[i].p;
        ticcd::Vector3 v[8];
        for (int r = 0; r < 8; ++r)
            v[r] = ticcd::Vector3(p[3 * r], p[3 * r + 1], p[3 * r + 2]);
        double toi = 0.0;
        double output_tolerance = tolerance;
        const auto start = std::chrono::steady_clock::now();
        const bool hit = ee ? ticcd::edgeEdgeCCD(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7],
                                                 err, ms, toi, tolerance, t_max, max_itr,
                                                 output_tolerance, no_zero_toi, method)
                            : ticcd::vertexFaceCCD(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7],
                                                   err, ms, toi, tolerance, t_max, max_itr,
                                                   output_tolerance, no_zero_toi, method);
        const double s =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        answers[i] = {hit, toi, s, output_tolerance};
    }
    for (const auto& a : answers) {
        std::printf("%d %a %.9g %.9g\n", a.hit ? 1 : 0, a.toi, a.seconds, a.output_tolerance);
    }
    return 0;
}
