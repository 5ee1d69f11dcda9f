#pragma once
// The public CCD benchmark format (Wang et al. 2021, "A Large Scale Benchmark and an
// Inclusion-Based Algorithm for Continuous Collision Detection"): CSV, 8 rows per query, one row
// per point in the order of proxima/ccd/elementary.hpp, each row
//     x_num, x_den, y_num, y_den, z_num, z_den[, truth]
// with arbitrary-precision integers (the coordinates are exact rationals) and an optional 0/1
// ground-truth flag (1: the primitives touch at some t in [0, 1]), the same on all 8 rows.

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "proxima/ccd/elementary.hpp"
#include "proxima/status.hpp"

namespace proxima {

struct CcdQuery {
    // Each coordinate is the double nearest to the exact rational (ties to even, as a correctly
    // rounded conversion), so it is within half an ulp of it.
    ccd::CcdPoints points{};
    std::optional<bool> truth;  // the file's 7th column, when present
};

// Reads every query of the file. Errors (invalid_argument, not_found for a missing file) name the
// file and the line: a row without 6 or 7 columns (or with a different count than the first
// row), a column that is not an integer, a zero denominator, a coordinate whose magnitude exceeds
// the largest double, a truth flag other than 0 / 1 or differing within a query, a row count that
// is not a multiple of 8. An empty file holds no queries.
StatusOr<std::vector<CcdQuery>> read_ccd_queries(const std::string& path);

// The parser behind read_ccd_queries, on text already in memory (the fuzz target feeds it
// directly); `path` is used only in messages.
StatusOr<std::vector<CcdQuery>> parse_ccd_queries(std::string_view text, const std::string& path);

// The kind the benchmark's folder names give: a path containing "vertex-face" is vertex_face, one
// containing "edge-edge" edge_edge; none or both: nullopt.
std::optional<ccd::CcdKind> ccd_kind_from_path(std::string_view path);

// "vf" / "vertex-face" / "vertex_face" and "ee" / "edge-edge" / "edge_edge".
std::optional<ccd::CcdKind> parse_ccd_kind(std::string_view name);

}  // namespace proxima
