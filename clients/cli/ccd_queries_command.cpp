// proxima ccd-queries: the elementary CCD tests (proxima/ccd/elementary.hpp) on files of the
// public CCD benchmark format (proxima/io/ccd_queries.hpp), with the counts of false negatives and
// false positives against the files' ground truth and the time spent in the tests.
//
//   proxima ccd-queries [--kind vf|ee] [--json] [--min-distance D] [--tolerance T]
//                       [--max-boxes N] FILE.csv...
//
// JSON: {"results": [bool per query], "tois": [time of impact per query, null when no contact],
//        "false_negative_count": N, "false_positive_count": N, "seconds": S,
//        "worst_seconds": S, "capped_tests": N, "query_count": N, "kind": "vf" | "ee" | "mixed"}
// with the queries of all files in order; the false counts are null when no file has the truth
// column. `seconds` is the time in the elementary tests (reading excluded), single thread.

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli/commands.hpp"
#include "proxima/ccd/elementary.hpp"
#include "proxima/io/ccd_queries.hpp"
#include "proxima/status.hpp"

namespace proxima::cli {

namespace {

struct CcdQueriesArgs {
    std::string kind;
    JsonOutput output;
    double min_distance = 0.0;
    double tolerance = ccd::ElementaryOptions{}.tolerance;
    double toi_tolerance = ccd::ElementaryOptions{}.toi_tolerance;
    std::uint32_t max_boxes = ccd::ElementaryOptions{}.max_boxes;
    std::vector<std::string> files;
};

struct FileSummary {
    std::string path;
    ccd::CcdKind kind = ccd::CcdKind::vertex_face;
    std::size_t queries = 0;
    std::size_t hits = 0;
    std::size_t with_truth = 0;
    std::size_t colliding = 0;
    std::size_t false_negatives = 0;
    std::size_t false_positives = 0;
    std::size_t capped = 0;
    double seconds = 0.0;
};

int run_ccd_queries(const CcdQueriesArgs& args) {
    ccd::ElementaryOptions options;
    options.min_distance = args.min_distance;
    options.tolerance = args.tolerance;
    options.toi_tolerance = args.toi_tolerance;
    options.max_boxes = args.max_boxes;

    std::optional<ccd::CcdKind> forced;
    if (!args.kind.empty()) {
        forced = parse_ccd_kind(args.kind);
        if (!forced) {
            return fail(invalid_argument("unknown kind '" + args.kind + "' (expected vf or ee)"));
        }
    }
    // Every file is read and its kind settled before any test runs: a bad file fails fast.
    std::vector<std::vector<CcdQuery>> contents;
    std::vector<FileSummary> files;
    for (const auto& path : args.files) {
        FileSummary f;
        f.path = path;
        if (forced) {
            f.kind = *forced;
        } else if (auto k = ccd_kind_from_path(path)) {
            f.kind = *k;
        } else {
            return fail(invalid_argument("cannot tell the kind of '" + path +
                                         "' from its path (no 'vertex-face' or 'edge-edge' in "
                                         "it): pass --kind vf or --kind ee"));
        }
        auto read = read_ccd_queries(path);
        if (!read.ok()) {
            return fail(read.status());
        }
        contents.push_back(std::move(read).value());
        files.push_back(f);
    }

    nlohmann::json results = nlohmann::json::array();
    nlohmann::json tois = nlohmann::json::array();
    double worst = 0.0;
    for (std::size_t i = 0; i < files.size(); ++i) {
        auto& f = files[i];
        for (const auto& q : contents[i]) {
            const auto start = std::chrono::steady_clock::now();
            const auto r = ccd::elementary(f.kind, q.points, options);
            const double s =
                std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            f.seconds += s;
            worst = std::max(worst, s);
            ++f.queries;
            f.hits += r.hit ? 1 : 0;
            f.capped += r.capped ? 1 : 0;
            if (q.truth) {
                ++f.with_truth;
                f.colliding += *q.truth ? 1 : 0;
                f.false_negatives += (*q.truth && !r.hit) ? 1 : 0;
                f.false_positives += (!*q.truth && r.hit) ? 1 : 0;
            }
            results.push_back(r.hit);
            tois.push_back(r.hit ? nlohmann::json(r.toi) : nlohmann::json());
        }
    }

    FileSummary all;
    bool mixed = false;
    for (const auto& f : files) {
        all.queries += f.queries;
        all.hits += f.hits;
        all.with_truth += f.with_truth;
        all.colliding += f.colliding;
        all.false_negatives += f.false_negatives;
        all.false_positives += f.false_positives;
        all.capped += f.capped;
        all.seconds += f.seconds;
        mixed = mixed || f.kind != files.front().kind;
    }
    const bool have_truth = all.with_truth > 0;
    if (args.output.wanted()) {
        nlohmann::json j = {{"results", std::move(results)},
                            {"tois", std::move(tois)},
                            {"false_negative_count",
                             have_truth ? nlohmann::json(all.false_negatives) : nlohmann::json()},
                            {"false_positive_count",
                             have_truth ? nlohmann::json(all.false_positives) : nlohmann::json()},
                            {"seconds", all.seconds},
                            {"worst_seconds", worst},
                            {"capped_tests", all.capped},
                            {"query_count", all.queries},
                            {"kind", mixed ? "mixed" : ccd::ccd_kind_name(files.front().kind)}};
        return emit_json(j, args.output,
                         "ccd-queries: " + std::to_string(all.queries) + " queries, " +
                             std::to_string(all.hits) + " reported in contact");
    }
    for (const auto& f : files) {
        std::printf("%s: %zu %s queries, %zu reported in contact", f.path.c_str(), f.queries,
                    ccd::ccd_kind_name(f.kind), f.hits);
        if (f.with_truth > 0) {
            std::printf(" (%zu colliding): %zu false negatives, %zu false positives", f.colliding,
                        f.false_negatives, f.false_positives);
        }
        std::printf(", %zu capped, %.3f ms\n", f.capped, f.seconds * 1e3);
    }
    if (files.size() > 1) {
        std::printf("total: %zu queries, %zu reported in contact", all.queries, all.hits);
        if (have_truth) {
            std::printf(" (%zu colliding): %zu false negatives, %zu false positives", all.colliding,
                        all.false_negatives, all.false_positives);
        }
        std::printf(", %zu capped\n", all.capped);
    }
    std::printf("time in the tests: %.3f s, mean %.4f ms, worst %.4f ms per query\n", all.seconds,
                all.queries > 0 ? all.seconds / static_cast<double>(all.queries) * 1e3 : 0.0,
                worst * 1e3);
    return 0;
}

}  // namespace

void add_ccd_queries_command(CLI::App& app, int& exit_code) {
    auto args = std::make_shared<CcdQueriesArgs>();
    auto* cmd = app.add_subcommand(
        "ccd-queries",
        "Run the elementary CCD tests on files of the public CCD benchmark (8 rows per query, "
        "rational coordinates, optional ground truth)");
    cmd->add_option("--kind", args->kind,
                    "vf (vertex-face) or ee (edge-edge); default: from the path "
                    "('vertex-face' / 'edge-edge')")
        ->check(CLI::IsMember({"vf", "ee"}));
    add_json_output(*cmd, args->output);
    cmd->add_option("--min-distance", args->min_distance,
                    "Report contact when the primitives come within this distance")
        ->check(non_negative_number())
        ->capture_default_str();
    cmd->add_option("--tolerance", args->tolerance,
                    "Distance band: regions within min distance + this are reported as contact")
        ->check(positive_number())
        ->capture_default_str();
    cmd->add_option("--toi-tolerance", args->toi_tolerance,
                    "Precision of each time of impact, a fraction of the step in [0, 1]")
        ->check(CLI::Range(0.0, 1.0))
        ->capture_default_str();
    cmd->add_option("--max-boxes", args->max_boxes, "Work bound per query (regions examined)")
        ->check(whole_number(1, 4'000'000'000))
        ->capture_default_str();
    cmd->add_option("files", args->files, "CSV files of the benchmark format")->required();
    cmd->callback([args, &exit_code] { exit_code = run_ccd_queries(*args); });
}

}  // namespace proxima::cli
