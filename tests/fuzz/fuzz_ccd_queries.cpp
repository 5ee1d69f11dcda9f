// Fuzz target: the public CCD benchmark's CSV reader (parse_ccd_queries, behind read_ccd_queries
// and `proxima ccd-queries`), then the elementary test on the first query it reads, both kinds.
// The reader's promises are checked: finite coordinates (each the double nearest to the file's
// rational), a truth flag on every query or on none. The elementary test gets a small work bound
// so each execution stays fast; its own promises (a time of impact in [0, 1], capped implies hit)
// must hold for every finite input, however large or degenerate.

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string_view>

#include "proxima/ccd/elementary.hpp"
#include "proxima/io/ccd_queries.hpp"

namespace {

void check(bool condition, const char* what) {
    if (!condition) {
        std::fprintf(stderr, "fuzz_ccd_queries: broken promise: %s\n", what);
        std::abort();
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string_view text(reinterpret_cast<const char*>(data), size);
    const auto read = proxima::parse_ccd_queries(text, "fuzz.csv");
    if (!read.ok()) {
        check(!read.status().message().empty(), "an error says why");
        return 0;
    }
    const auto& queries = read.value();
    for (const auto& query : queries) {
        check(query.truth.has_value() == queries.front().truth.has_value(),
              "a truth flag on every query or on none");
        for (const auto& p : query.points) {
            check(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z),
                  "coordinates are finite");
        }
    }
    if (queries.empty()) {
        return 0;
    }
    proxima::ccd::ElementaryOptions options;
    options.max_boxes = 64;
    for (const auto kind : {proxima::ccd::CcdKind::vertex_face, proxima::ccd::CcdKind::edge_edge}) {
        const auto result = proxima::ccd::elementary(kind, queries.front().points, options);
        check(result.toi >= 0.0 && result.toi <= 1.0, "time of impact in [0, 1]");
        check(!result.capped || result.hit, "capped implies hit");
        check(result.boxes <= options.max_boxes + 8, "work bound held");
    }
    return 0;
}
