// proxima models, verify and review: massive models (seed 001, IMMPACT) on a proximad daemon
// (--server, the daemon's --models DIR) or in a local store written by `proxima import` (--store).
// The local and server modes build the same engine results (ObjectPairResult, AvatarResult) and
// print them through the same JSON code, so their outputs differ only in statistics and timings.
//
//   proxima models --server ADDR [--json]
//   proxima verify (--store DIR | --server ADDR --model NAME) --tolerance D [--cache-bytes M]
//                  [--brute-force] [--json | --out FILE] [--quiet]
//   proxima review (--store DIR | --server ADDR --model NAME) --avatar MESHFILE --path PATHFILE
//                  [--room R] [--member NAME] [--tolerance D] [--no-nearest] [--cache-bytes M]
//                  [--json | --out FILE] [--quiet]
//   proxima region --server ADDR --model NAME [--center X,Y,Z] [--radius R] [--room R]
//                  [--objects I,J,...] [--max-triangles N] [--float64] [--obj FILE]
//                  [--json | --out FILE] [--quiet]
//
// A path file has one avatar pose per line: 12 numbers, the row-major 3x4 affine map
// (a00 a01 a02 tx a10 a11 a12 ty a20 a21 a22 tz) applied to the avatar's own coordinates, or 3
// numbers "x y z", a translation. Numbers are separated by spaces, tabs or commas; empty lines
// and lines starting with '#' are skipped.

#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <tuple>
#include <variant>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli/commands.hpp"
#include "client/proxima_client.hpp"
#include "common/json_output.hpp"
#include "common/progress.hpp"
#include "proxima/io/mesh_io.hpp"
#include "proxima/massive/avatar.hpp"
#include "proxima/massive/cache.hpp"
#include "proxima/massive/store.hpp"
#include "proxima/massive/verify.hpp"

namespace proxima::cli {

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
    return std::chrono::duration<double>(Clock::now() - start).count();
}

StatusOr<std::unique_ptr<client::Client>> connect(const std::string& address,
                                                  const ServerFlags& flags) {
    // float64 vertices (the default): the avatar the daemon poses is bit-identical to ours.
    return connect_server(address, flags);
}

// Writes `doc` to `file`, or to standard output when `file` is empty.
// The one-line summaries after --out FILE.
std::string verify_summary(const nlohmann::json& doc) {
    return "verify: " + std::to_string(doc["pairs"].size()) + " object pairs within " +
           doc["tolerance"].dump();
}
std::string review_summary(const nlohmann::json& doc) {
    const auto& latency = doc["latency_ms"];
    return "review: " + std::to_string(doc["poses"].size()) + " poses" +
           (latency.contains("p99") ? ", p99 " + latency["p99"].dump() + " ms" : std::string());
}

nlohmann::json cache_json(const massive::CacheStats& c) {
    return {{"budget_bytes", c.budget_bytes},
            {"resident_bytes", c.resident_bytes},
            {"peak_bytes", c.peak_bytes},
            {"loads", c.loads},
            {"prefetch_loads", c.prefetch_loads},
            {"triangles_loaded", c.triangles_loaded},
            {"bytes_loaded", c.bytes_loaded},
            {"hits", c.hits},
            {"misses", c.misses},
            {"waits", c.waits},
            {"evictions", c.evictions},
            {"blocked_seconds", c.blocked_seconds}};
}

// --- models ------------------------------------------------------------------------------------

struct ModelsArgs {
    std::string server;
    ServerFlags server_flags;
    JsonOutput output;
};

int run_models(const ModelsArgs& args) {
    auto c = connect(args.server, args.server_flags);
    if (!c.ok()) {
        return fail(c.status());
    }
    auto list = c.value()->list_models();
    if (!list.ok()) {
        return fail(list.status());
    }
    const auto& l = list.value();
    if (args.output.wanted()) {
        nlohmann::json models = nlohmann::json::array();
        for (const auto& m : l.models) {
            models.push_back({{"name", m.name},
                              {"generation", m.generation},
                              {"object_count", m.objects},
                              {"piece_count", m.pieces},
                              {"split_object_count", m.split_objects},
                              {"triangle_count", m.triangles},
                              {"vertex_count", m.vertices},
                              {"chunk_count", m.chunks},
                              {"bytes", m.bytes},
                              {"box", client::box_json(m.box)}});
        }
        nlohmann::json unavailable = nlohmann::json::array();
        for (const auto& [name, status] : l.unavailable) {
            unavailable.push_back({{"name", name}, {"status", status}});
        }
        nlohmann::json doc = {{"server", args.server},
                              {"models_dir", l.models_dir},
                              {"models", models},
                              {"unavailable", unavailable},
                              {"cache", cache_json(l.cache)}};
        return emit_json(
            doc, args.output,
            "models: " + std::to_string(l.models.size()) + " served by " + args.server);
    }
    if (l.models_dir.empty()) {
        std::printf("proximad at %s serves no models (start it with --models DIR)\n",
                    args.server.c_str());
    } else {
        std::printf(
            "models in %s (cache %s):\n", l.models_dir.c_str(),
            client::format_amount(static_cast<double>(l.cache_budget_bytes), "bytes").c_str());
    }
    for (const auto& m : l.models) {
        std::printf("  %-24s %s  %llu objects, %llu pieces, %llu triangles\n", m.name.c_str(),
                    m.generation.c_str(), static_cast<unsigned long long>(m.objects),
                    static_cast<unsigned long long>(m.pieces),
                    static_cast<unsigned long long>(m.triangles));
    }
    for (const auto& [name, status] : l.unavailable) {
        std::printf("  %-24s unavailable: %s\n", name.c_str(), status.c_str());
    }
    const auto& cs = l.cache;
    std::printf(
        "cache: %s resident (peak %s), %llu loads, %llu hits, %llu misses, %llu evictions\n",
        client::format_amount(static_cast<double>(cs.resident_bytes), "bytes").c_str(),
        client::format_amount(static_cast<double>(cs.peak_bytes), "bytes").c_str(),
        static_cast<unsigned long long>(cs.loads), static_cast<unsigned long long>(cs.hits),
        static_cast<unsigned long long>(cs.misses), static_cast<unsigned long long>(cs.evictions));
    return 0;
}

// --- verify ------------------------------------------------------------------------------------

struct VerifyArgs {
    std::string store;
    std::string server;
    ServerFlags server_flags;
    std::string model;
    double tolerance = 0.0;
    std::string cache_bytes;
    bool brute_force = false;
    std::string shard;               // "I/N"
    std::vector<std::string> merge;  // shard outputs
    bool reproducible = false;
    bool tolerance_given = false;
    JsonOutput output;
    bool quiet = false;
};

// The stats fields that vary from run to run (timings, the cache's counters, whether the
// schedule was read from the store): --reproducible leaves them out, so that the output depends
// on the store, the tolerance and the cache budget alone, and a merge of shards equals a single
// run byte for byte (docs/massive.md, "Shards").
void drop_run_fields(nlohmann::json& stats) {
    for (const char* key :
         {"plan_seconds", "seconds", "wall_seconds", "schedule_from_store", "cache"}) {
        stats.erase(key);
    }
}

nlohmann::json pair_json(const massive::ObjectPairResult& p, const std::string& name_a,
                         const std::string& name_b) {
    // The closest-pair shape of every command (docs/api.md, "JSON output"), with the names.
    return {{"object", p.object_a},
            {"name", name_a},
            {"triangle", p.triangle_a},
            {"point", client::point_json(p.point_a)},
            {"other", p.object_b},
            {"other_name", name_b},
            {"other_triangle", p.triangle_b},
            {"other_point", client::point_json(p.point_b)},
            {"distance", p.distance}};
}

nlohmann::json verify_stats_json(const massive::VerifyStats& s) {
    return {{"object_count", s.objects},
            {"piece_count", s.pieces},
            {"triangle_count", s.model_triangles},
            {"subgraph_count", s.subgraphs},
            {"piece_pair_count", s.edges},
            {"object_pair_count", s.object_pairs},
            {"pair_count", s.pairs_found},
            {"exact_tests", s.exact_tests},
            {"plan_seconds", s.plan_seconds},
            {"seconds", s.seconds},
            {"schedule_from_store", s.schedule_from_store},
            {"cache", cache_json(s.cache)}};
}

// Pairs sorted by (object_a, object_b): the reference's order, whatever order they arrived in.
struct NamedPairs {
    std::vector<massive::ObjectPairResult> pairs;
    std::vector<std::pair<std::string, std::string>> names;

    nlohmann::json json() const {
        std::vector<std::size_t> order(pairs.size());
        for (std::size_t k = 0; k < order.size(); ++k) {
            order[k] = k;
        }
        std::sort(order.begin(), order.end(), [&](std::size_t x, std::size_t y) {
            return std::tie(pairs[x].object_a, pairs[x].object_b) <
                   std::tie(pairs[y].object_a, pairs[y].object_b);
        });
        nlohmann::json out = nlohmann::json::array();
        for (auto k : order) {
            out.push_back(pair_json(pairs[k], names[k].first, names[k].second));
        }
        return out;
    }
};

int run_verify_local(const VerifyArgs& args, std::uint64_t cache_bytes) {
    auto opened = massive::Store::open(args.store);
    if (!opened.ok()) {
        return fail(opened.status());
    }
    const std::shared_ptr<const massive::Store> store = opened.value();
    const auto& objects = store->objects();
    NamedPairs found;
    auto add = [&](const massive::ObjectPairResult& p) {
        found.pairs.push_back(p);
        found.names.emplace_back(objects[p.object_a].name, objects[p.object_b].name);
    };
    nlohmann::json doc = {{"store", args.store},
                          {"generation", store->summary().generation},
                          {"tolerance", args.tolerance},
                          {"method", args.brute_force ? "brute-force" : "static"}};
    const auto start = Clock::now();
    if (args.brute_force) {
        if (!args.quiet) {
            std::fprintf(stderr, "brute force: every object pair of %llu objects in memory\n",
                         static_cast<unsigned long long>(objects.size()));
        }
        auto pairs = massive::verify_brute_force(*store, args.tolerance);
        if (!pairs.ok()) {
            return fail(pairs.status());
        }
        for (const auto& p : pairs.value()) {
            add(p);
        }
        doc["stats"] = {{"pair_count", found.pairs.size()},
                        {"object_count", objects.size()},
                        {"seconds", seconds_since(start)}};
    } else {
        massive::GeometryCache cache(cache_bytes);
        client::ProgressPrinter printer(args.quiet);
        massive::VerifyOptions options;
        options.tolerance = args.tolerance;
        auto stats =
            massive::verify_static(store, cache, options, add, nullptr, printer.callback());
        printer.finish();
        if (!stats.ok()) {
            return fail(stats.status());
        }
        doc["stats"] = verify_stats_json(stats.value());
        doc["stats"]["wall_seconds"] = seconds_since(start);
    }
    if (args.reproducible) {
        drop_run_fields(doc["stats"]);
    }
    doc["pairs"] = found.json();
    return emit_json(doc, args.output, verify_summary(doc));
}

// Shard I/N: the I-th of N work-balanced groups of the schedule's subgraphs, in this process.
int run_verify_shard(const VerifyArgs& args, std::uint64_t cache_bytes, std::uint32_t index,
                     std::uint32_t count) {
    auto opened = massive::Store::open(args.store);
    if (!opened.ok()) {
        return fail(opened.status());
    }
    const std::shared_ptr<const massive::Store> store = opened.value();
    const auto& objects = store->objects();
    massive::GeometryCache cache(cache_bytes);
    client::ProgressPrinter printer(args.quiet);
    massive::VerifyOptions options;
    options.tolerance = args.tolerance;
    std::vector<massive::ShardPair> pairs;
    massive::ShardStats shard;
    const auto start = Clock::now();
    auto stats = massive::verify_shard(store, cache, options, index, count, &pairs, &shard,
                                       printer.callback());
    printer.finish();
    if (!stats.ok()) {
        return fail(stats.status());
    }
    nlohmann::json doc = {{"store", args.store},
                          {"generation", store->summary().generation},
                          {"tolerance", args.tolerance},
                          {"cache_bytes", cache_bytes},
                          {"method", "static"},
                          {"shard",
                           {{"index", shard.index},
                            {"count", shard.count},
                            {"subgraph_count", shard.subgraphs},
                            {"piece_pair_count", shard.edges},
                            {"work", shard.work}}}};
    doc["stats"] = verify_stats_json(stats.value());
    doc["stats"]["wall_seconds"] = seconds_since(start);
    if (args.reproducible) {
        drop_run_fields(doc["stats"]);
    }
    nlohmann::json out = nlohmann::json::array();
    for (const auto& p : pairs) {
        auto j = pair_json(p.pair, objects[p.pair.object_a].name, objects[p.pair.object_b].name);
        j["squared_distance"] = p.squared_distance;
        out.push_back(std::move(j));
    }
    doc["pairs"] = std::move(out);
    return emit_json(doc, args.output,
                     "verify shard " + std::to_string(index) + "/" + std::to_string(count) + ": " +
                         std::to_string(pairs.size()) + " object pairs within " +
                         doc["tolerance"].dump());
}

StatusOr<Vec3> point_from_json(const nlohmann::json& j) {
    if (!j.is_array() || j.size() != 3 || !j[0].is_number() || !j[1].is_number() ||
        !j[2].is_number()) {
        return invalid_argument("a point is not [x, y, z]");
    }
    return Vec3{j[0].get<double>(), j[1].get<double>(), j[2].get<double>()};
}

// --merge FILE...: the shards' outputs combined into the single run's output.
int run_verify_merge(const VerifyArgs& args) {
    struct Shard {
        std::string file;
        nlohmann::json doc;
    };
    std::vector<Shard> shards;
    for (const auto& file : args.merge) {
        std::ifstream in(file, std::ios::binary);
        if (!in) {
            return fail(not_found("--merge: cannot read '" + file + "'"));
        }
        nlohmann::json doc = nlohmann::json::parse(in, nullptr, false);
        if (doc.is_discarded() || !doc.is_object()) {
            return fail(invalid_argument("--merge: '" + file + "' is not JSON"));
        }
        if (!doc.contains("shard") || !doc["shard"].is_object() ||
            !doc["shard"].contains("index") || !doc["shard"].contains("count") ||
            !doc["shard"]["index"].is_number_unsigned() ||
            !doc["shard"]["count"].is_number_unsigned() || doc["shard"]["count"] == 0 ||
            !doc.contains("pairs") || !doc["pairs"].is_array() || !doc.contains("stats") ||
            !doc["stats"].is_object()) {
            return fail(invalid_argument("--merge: '" + file +
                                         "' is not the output of proxima verify --shard I/N"));
        }
        shards.push_back({file, std::move(doc)});
    }
    const auto& first = shards.front();
    const auto count = first.doc["shard"]["count"].get<std::uint64_t>();
    // Every shard must be of the same run: model, generation, tolerance, cache budget, N.
    for (const auto& s : shards) {
        for (const char* key : {"store", "generation", "tolerance", "cache_bytes"}) {
            if (s.doc.value(key, nlohmann::json()) != first.doc.value(key, nlohmann::json())) {
                return fail(failed_precondition(
                    std::string("--merge: the shards are of different runs: '") + first.file +
                    "' has " + key + " " + first.doc.value(key, nlohmann::json()).dump() + ", '" +
                    s.file + "' has " + s.doc.value(key, nlohmann::json()).dump()));
            }
        }
        if (s.doc["shard"]["count"].get<std::uint64_t>() != count) {
            return fail(failed_precondition("--merge: the shards are of different runs: '" +
                                            first.file + "' is one of " + std::to_string(count) +
                                            " shards, '" + s.file + "' one of " +
                                            s.doc["shard"]["count"].dump()));
        }
        for (const char* key : {"object_count", "piece_count", "triangle_count", "subgraph_count",
                                "piece_pair_count", "object_pair_count"}) {
            if (s.doc["stats"].value(key, nlohmann::json()) !=
                first.doc["stats"].value(key, nlohmann::json())) {
                return fail(failed_precondition(std::string("--merge: the shards disagree on ") +
                                                "stats." + key + ": '" + first.file + "' and '" +
                                                s.file + "'"));
            }
        }
    }
    std::vector<std::string> seen(count);
    for (const auto& s : shards) {
        const auto i = s.doc["shard"]["index"].get<std::uint64_t>();
        if (i >= count) {
            return fail(invalid_argument("--merge: '" + s.file + "' says shard " +
                                         std::to_string(i) + " of " + std::to_string(count)));
        }
        if (!seen[i].empty()) {
            return fail(invalid_argument("--merge: shard " + std::to_string(i) + "/" +
                                         std::to_string(count) + " given twice: '" + seen[i] +
                                         "' and '" + s.file + "'"));
        }
        seen[i] = s.file;
    }
    std::string missing;
    for (std::size_t i = 0; i < count; ++i) {
        if (seen[i].empty()) {
            missing += (missing.empty() ? "" : ", ") + std::to_string(i);
        }
    }
    if (!missing.empty()) {
        return fail(failed_precondition("--merge: shard(s) " + missing + " of " +
                                        std::to_string(count) + " missing"));
    }
    // The pairs, and their names (an object's name is the same in every shard).
    std::vector<std::vector<massive::ShardPair>> all;
    std::map<std::uint32_t, std::string> names;
    for (const auto& s : shards) {
        auto& list = all.emplace_back();
        for (const auto& j : s.doc["pairs"]) {
            massive::ShardPair p;
            try {
                p.pair.object_a = j.at("object").get<std::uint32_t>();
                p.pair.object_b = j.at("other").get<std::uint32_t>();
                p.pair.triangle_a = j.at("triangle").get<std::uint32_t>();
                p.pair.triangle_b = j.at("other_triangle").get<std::uint32_t>();
                p.pair.distance = j.at("distance").get<double>();
                p.squared_distance = j.at("squared_distance").get<double>();
                auto a = point_from_json(j.at("point"));
                auto b = point_from_json(j.at("other_point"));
                if (!a.ok() || !b.ok()) {
                    return fail(invalid_argument("--merge: '" + s.file +
                                                 "': " + (a.ok() ? b : a).status().message()));
                }
                p.pair.point_a = a.value();
                p.pair.point_b = b.value();
                names[p.pair.object_a] = j.at("name").get<std::string>();
                names[p.pair.object_b] = j.at("other_name").get<std::string>();
            } catch (const nlohmann::json::exception& e) {
                return fail(invalid_argument("--merge: '" + s.file + "': a pair is malformed (" +
                                             e.what() + ")"));
            }
            list.push_back(p);
        }
    }
    NamedPairs found;
    for (const auto& p : massive::merge_shard_pairs(all)) {
        found.pairs.push_back(p);
        found.names.emplace_back(names[p.object_a], names[p.object_b]);
    }
    // The single run's document: same keys; counts of the whole model from any shard, the
    // shards' exact tests summed, their run fields combined (timings: the slowest shard; cache
    // counters: summed, peak: the largest).
    nlohmann::json stats = first.doc["stats"];
    stats["pair_count"] = found.pairs.size();
    std::uint64_t exact = 0;
    for (const auto& s : shards) {
        exact += s.doc["stats"].value("exact_tests", std::uint64_t{0});
    }
    stats["exact_tests"] = exact;
    if (!args.reproducible && stats.contains("seconds")) {
        for (const auto& s : shards) {
            const auto& st = s.doc["stats"];
            for (const char* key : {"plan_seconds", "seconds", "wall_seconds"}) {
                stats[key] = std::max(stats.value(key, 0.0), st.value(key, 0.0));
            }
            stats["schedule_from_store"] =
                stats.value("schedule_from_store", true) && st.value("schedule_from_store", true);
        }
        if (stats.contains("cache")) {
            auto& cache = stats["cache"];
            for (auto it = cache.begin(); it != cache.end(); ++it) {
                const std::string& key = it.key();
                if (key == "budget_bytes" || !it.value().is_number()) {
                    continue;
                }
                const bool largest = key == "peak_bytes" || key == "resident_bytes";
                double combined = 0;
                for (const auto& s : shards) {
                    const double v = s.doc["stats"]["cache"].value(key, 0.0);
                    combined = largest ? std::max(combined, v) : combined + v;
                }
                if (it.value().is_number_float()) {
                    it.value() = combined;
                } else {
                    it.value() = static_cast<std::uint64_t>(combined);
                }
            }
        }
    } else {
        drop_run_fields(stats);
    }
    if (args.reproducible) {
        drop_run_fields(stats);
    }
    nlohmann::json doc = {{"store", first.doc["store"]},
                          {"generation", first.doc["generation"]},
                          {"tolerance", first.doc["tolerance"]},
                          {"method", "static"}};
    doc["stats"] = std::move(stats);
    doc["pairs"] = found.json();
    return emit_json(doc, args.output, verify_summary(doc));
}

int run_verify_remote(const VerifyArgs& args) {
    auto c = connect(args.server, args.server_flags);
    if (!c.ok()) {
        return fail(c.status());
    }
    client::ProgressPrinter printer(args.quiet);
    NamedPairs found;
    const auto start = Clock::now();
    auto summary =
        c.value()->verify_model(args.model, args.tolerance, [&](const client::VerifyEvent& e) {
            if (e.kind == client::VerifyEvent::Kind::progress) {
                printer.update(e.progress);
            } else {
                found.pairs.push_back(e.pair.pair);
                found.names.emplace_back(e.pair.name_a, e.pair.name_b);
            }
            return true;
        });
    printer.finish();
    if (!summary.ok()) {
        return fail(summary.status());
    }
    nlohmann::json doc = {{"server", args.server},
                          {"model", args.model},
                          {"tolerance", args.tolerance},
                          {"method", "static"}};
    doc["stats"] = verify_stats_json(summary->stats);
    doc["stats"]["server_seconds"] = summary->server_seconds;
    doc["stats"]["wall_seconds"] = seconds_since(start);
    doc["pairs"] = found.json();
    return emit_json(doc, args.output, verify_summary(doc));
}

int run_verify(const VerifyArgs& args) {
    if (!args.merge.empty()) {
        return run_verify_merge(args);
    }
    if (!args.tolerance_given) {
        return fail(invalid_argument("--tolerance is required (except with --merge)"));
    }
    if (!std::isfinite(args.tolerance) || args.tolerance < 0) {
        return fail(invalid_argument("--tolerance must be a finite distance >= 0"));
    }
    if (!args.server.empty()) {
        if (args.model.empty()) {
            return fail(
                invalid_argument("--server needs --model NAME (proxima models lists them)"));
        }
        if (args.brute_force || !args.cache_bytes.empty()) {
            return fail(invalid_argument(
                "--brute-force and --cache-bytes are for --store (the daemon's cache is its "
                "--cache-bytes)"));
        }
        return run_verify_remote(args);
    }
    std::uint64_t cache_bytes = massive::DEFAULT_CACHE_BYTES;
    if (!args.cache_bytes.empty()) {
        auto v = parse_size("--cache-bytes", args.cache_bytes, 1024);
        if (!v.ok()) {
            return fail(v.status());
        }
        cache_bytes = v.value();
    }
    if (!args.shard.empty()) {
        // I/N with 0 <= I < N.
        unsigned index = 0;
        unsigned count = 0;
        char tail = 0;
        if (std::sscanf(args.shard.c_str(), "%u/%u%c", &index, &count, &tail) != 2 || count == 0 ||
            index >= count || args.shard.find('-') != std::string::npos) {
            return fail(invalid_argument("--shard '" + args.shard +
                                         "': expected I/N with 0 <= I < N (e.g. 0/3)"));
        }
        if (args.brute_force) {
            return fail(
                invalid_argument("--shard splits the static verification, not --brute-force"));
        }
        return run_verify_shard(args, cache_bytes, index, count);
    }
    return run_verify_local(args, cache_bytes);
}

// --- review ------------------------------------------------------------------------------------

struct ReviewArgs {
    std::string store;
    std::string server;
    ServerFlags server_flags;
    std::string model;
    std::string room;
    std::string member;
    std::string avatar;
    std::string path;
    double tolerance = 0.0;
    bool no_nearest = false;
    std::string cache_bytes;
    JsonOutput output;
    bool quiet = false;
};

// The path file's poses (format at the top of this file).
StatusOr<std::vector<massive::Affine>> read_path(const std::string& file) {
    std::ifstream in(file);
    if (!in) {
        return not_found("path file " + file + " cannot be opened");
    }
    std::vector<massive::Affine> poses;
    std::string line;
    for (std::size_t number = 1; std::getline(in, line); ++number) {
        const auto first = line.find_first_not_of(" \t\r");
        if (first == std::string::npos || line[first] == '#') {
            continue;
        }
        std::replace(line.begin(), line.end(), ',', ' ');
        std::istringstream fields(line);
        std::vector<double> values;
        std::string field;
        while (fields >> field) {
            std::size_t used = 0;
            double v = 0;
            try {
                v = std::stod(field, &used);
            } catch (const std::exception&) {
                used = 0;
            }
            if (used != field.size() || !std::isfinite(v)) {
                return invalid_argument(file + ":" + std::to_string(number) + ": '" + field +
                                        "' is not a finite number");
            }
            values.push_back(v);
        }
        massive::Affine pose;
        if (values.size() == 12) {
            std::copy(values.begin(), values.end(), pose.m.begin());
        } else if (values.size() == 3) {
            pose.m[3] = values[0];
            pose.m[7] = values[1];
            pose.m[11] = values[2];
        } else {
            return invalid_argument(file + ":" + std::to_string(number) + ": expected 12 numbers " +
                                    "(a row-major 3x4 transform) or 3 (a translation x y z), got " +
                                    std::to_string(values.size()));
        }
        poses.push_back(pose);
    }
    if (poses.empty()) {
        return invalid_argument("path file " + file + " has no poses");
    }
    return poses;
}

nlohmann::json hit_json(const massive::AvatarHit& h, const std::string& name) {
    // The closest-pair shape, the avatar being the other side (it has no object index).
    return {{"object", h.object},
            {"name", name},
            {"triangle", h.object_triangle},
            {"point", client::point_json(h.object_point)},
            {"other_triangle", h.avatar_triangle},
            {"other_point", client::point_json(h.avatar_point)},
            {"distance", h.distance}};
}

// One pose's answer: the same shape in both modes.
nlohmann::json pose_json(std::uint64_t sequence, const massive::AvatarResult& r,
                         const std::vector<std::string>& collision_names,
                         const std::vector<std::string>& within_names,
                         const std::string& nearest_name, double round_trip_ms) {
    nlohmann::json collisions = nlohmann::json::array();
    for (std::size_t k = 0; k < r.collisions.size(); ++k) {
        collisions.push_back(hit_json(r.collisions[k], collision_names[k]));
    }
    nlohmann::json within = nlohmann::json::array();
    for (std::size_t k = 0; k < r.within.size(); ++k) {
        within.push_back(hit_json(r.within[k], within_names[k]));
    }
    return {{"sequence", sequence},
            {"collisions", collisions},
            {"within", within},
            {"nearest", r.nearest ? hit_json(*r.nearest, nearest_name) : nlohmann::json()},
            {"stats",
             {{"candidate_pieces", r.candidate_pieces},
              {"pieces_tested", r.pieces_tested},
              {"exact_tests", r.exact_tests},
              {"prefetch_hints", r.prefetch_hints},
              {"seconds", r.seconds},
              {"round_trip_ms", round_trip_ms}}}};
}

nlohmann::json latency_json(std::vector<double> ms) {
    if (ms.empty()) {
        return nullptr;
    }
    std::sort(ms.begin(), ms.end());
    // Nearest rank: the smallest value with at least q of the samples at or below it.
    auto rank = [&](double q) {
        const auto k = static_cast<std::size_t>(std::ceil(q * static_cast<double>(ms.size())));
        return ms[std::min(ms.size() - 1, k == 0 ? 0 : k - 1)];
    };
    double sum = 0;
    for (double v : ms) {
        sum += v;
    }
    return {{"p50", rank(0.50)},
            {"p99", rank(0.99)},
            {"max", ms.back()},
            {"mean", sum / static_cast<double>(ms.size())},
            {"pose_count", ms.size()}};
}

void report_progress(client::ProgressPrinter& printer, std::size_t done, std::size_t total) {
    printer.update({"reviewing", done, total, "poses"});
}

int run_review_local(const ReviewArgs& args, const TriangleMesh& avatar,
                     const std::vector<massive::Affine>& poses, std::uint64_t cache_bytes) {
    auto opened = massive::Store::open(args.store);
    if (!opened.ok()) {
        return fail(opened.status());
    }
    const std::shared_ptr<const massive::Store> store = opened.value();
    auto view = std::make_shared<massive::ModelView>(
        store, std::make_shared<massive::GeometryCache>(cache_bytes));
    auto tracker = massive::AvatarTracker::create(view, avatar);
    if (!tracker.ok()) {
        return fail(tracker.status());
    }
    massive::AvatarQueryOptions options;
    options.tolerance = args.tolerance;
    options.nearest = !args.no_nearest;
    client::ProgressPrinter printer(args.quiet);
    nlohmann::json out = nlohmann::json::array();
    std::vector<double> latencies;
    auto name = [&](std::uint32_t object) {
        auto n = view->object_name(object);
        return n.ok() ? n.value() : std::string();
    };
    for (std::size_t k = 0; k < poses.size(); ++k) {
        const auto start = Clock::now();
        auto r = tracker.value()->query(poses[k], options);
        const double ms = seconds_since(start) * 1e3;
        if (!r.ok()) {
            printer.finish();
            return fail(r.status());
        }
        std::vector<std::string> collision_names;
        std::vector<std::string> within_names;
        for (const auto& h : r->collisions) {
            collision_names.push_back(name(h.object));
        }
        for (const auto& h : r->within) {
            within_names.push_back(name(h.object));
        }
        latencies.push_back(ms);
        out.push_back(pose_json(k + 1, r.value(), collision_names, within_names,
                                r->nearest ? name(r->nearest->object) : std::string(), ms));
        report_progress(printer, k + 1, poses.size());
    }
    printer.finish();
    nlohmann::json doc = {{"store", args.store},
                          {"generation", store->summary().generation},
                          {"tolerance", args.tolerance},
                          {"nearest", !args.no_nearest},
                          {"poses", out},
                          {"latency_ms", latency_json(latencies)},
                          {"cache", cache_json(view->cache()->stats())}};
    return emit_json(doc, args.output, review_summary(doc));
}

// USER@HOST-PID: two reviewers (or two runs of one) never clash on the default name.
std::string default_member_name() {
    const char* user = std::getenv("USER");
    std::array<char, 256> host{};
    if (gethostname(host.data(), host.size() - 1) != 0) {
        host[0] = '\0';
    }
    return std::string(user != nullptr && *user != '\0' ? user : "proxima") + "@" +
           (host[0] != '\0' ? host.data() : "localhost") + "-" + std::to_string(getpid());
}

int run_review_remote(const ReviewArgs& args, const TriangleMesh& avatar,
                      const std::vector<massive::Affine>& poses) {
    auto c = connect(args.server, args.server_flags);
    if (!c.ok()) {
        return fail(c.status());
    }
    client::ReviewJoin join;
    join.room = args.room;
    join.model = args.model;
    // Worked out only here, not for every command line that is parsed.
    const std::string member = args.member.empty() ? default_member_name() : args.member;
    join.member = member;
    join.avatar = {"avatar", avatar};
    join.tolerance = args.tolerance;
    join.nearest = !args.no_nearest;
    auto session = c.value()->join_review(join);
    if (!session.ok()) {
        if (session.status().code() == StatusCode::failed_precondition &&
            session.status().message().find("already has a member named") != std::string::npos) {
            return fail(Status(
                session.status().code(),
                session.status().message() + "; join under another name with --member NAME"));
        }
        return fail(session.status());
    }
    auto& review = *session.value();
    const auto& joined = review.joined();
    if (!args.quiet) {
        std::fprintf(stderr, "joined room %s (model %s %s) as %s with %zu other member(s)\n",
                     joined.room.c_str(), joined.model.c_str(), joined.generation.c_str(),
                     member.c_str(), joined.members.size() - 1);
    }
    client::ProgressPrinter printer(args.quiet);
    nlohmann::json out = nlohmann::json::array();
    std::vector<double> latencies;
    std::uint64_t peer_updates = 0;
    std::uint64_t edits_seen = 0;
    auto other = [&](const client::ReviewEvent& e) {
        if (e.kind == client::ReviewEvent::Kind::peer) {
            ++peer_updates;
        } else if (e.kind == client::ReviewEvent::Kind::edit_applied) {
            ++edits_seen;
        }
    };
    // Lockstep (send a pose, wait for its answer), so each round trip is measured alone.
    for (std::size_t k = 0; k < poses.size(); ++k) {
        const auto start = Clock::now();
        if (Status s = review.send_pose(k + 1, poses[k]); !s.ok()) {
            printer.finish();
            return fail(s);
        }
        auto r = review.wait_result(k + 1, other);
        const double ms = seconds_since(start) * 1e3;
        if (!r.ok()) {
            printer.finish();
            return fail(r.status());
        }
        latencies.push_back(ms);
        auto pose =
            pose_json(k + 1, r->result, r->collision_names, r->within_names, r->nearest_name, ms);
        pose["stats"]["server_seconds"] = r->server_seconds;
        pose["model_version"] = r->model_version;
        out.push_back(std::move(pose));
        report_progress(printer, k + 1, poses.size());
    }
    printer.finish();
    if (Status s = review.finish(); !s.ok()) {
        return fail(s);
    }
    nlohmann::json doc = {{"server", args.server},
                          {"model", args.model},
                          {"generation", joined.generation},
                          {"room", args.room},
                          {"member", member},
                          {"tolerance", args.tolerance},
                          {"nearest", !args.no_nearest},
                          {"poses", out},
                          {"latency_ms", latency_json(latencies)},
                          {"peer_updates", peer_updates},
                          {"edits_seen", edits_seen}};
    return emit_json(doc, args.output, review_summary(doc));
}

int run_review(const ReviewArgs& args) {
    if (!std::isfinite(args.tolerance) || args.tolerance < 0) {
        return fail(invalid_argument("--tolerance must be a finite distance >= 0"));
    }
    auto avatar = read_mesh(args.avatar);
    if (!avatar.ok()) {
        return fail(avatar.status());
    }
    auto poses = read_path(args.path);
    if (!poses.ok()) {
        return fail(poses.status());
    }
    if (!args.server.empty()) {
        if (args.model.empty()) {
            return fail(
                invalid_argument("--server needs --model NAME (proxima models lists them)"));
        }
        if (!args.cache_bytes.empty()) {
            return fail(invalid_argument(
                "--cache-bytes is for --store (the daemon's cache is its --cache-bytes)"));
        }
        return run_review_remote(args, avatar.value(), poses.value());
    }
    std::uint64_t cache_bytes = massive::DEFAULT_CACHE_BYTES;
    if (!args.cache_bytes.empty()) {
        auto v = parse_size("--cache-bytes", args.cache_bytes, 1024);
        if (!v.ok()) {
            return fail(v.status());
        }
        cache_bytes = v.value();
    }
    return run_review_local(args, avatar.value(), poses.value(), cache_bytes);
}

// --- region ------------------------------------------------------------------------------------

struct RegionArgs {
    std::string server;
    ServerFlags server_flags;
    std::string model;
    RegionFlags region;
    std::vector<std::uint32_t> objects;
    bool float64 = false;
    std::string obj;
    JsonOutput output;
    bool quiet = false;
};

int run_region(const RegionArgs& args) {
    auto request = region_request(args.model, args.region);
    if (!request.ok()) {
        return fail(request.status());
    }
    request->objects = args.objects;
    request->float64 = args.float64;
    std::FILE* obj = nullptr;
    if (!args.obj.empty()) {
        obj = std::fopen(args.obj.c_str(), "w");
        if (obj == nullptr) {
            return fail(Status(StatusCode::unavailable, "cannot write " + args.obj));
        }
        std::fprintf(obj, "# proxima region: model %s%s%s\n", args.model.c_str(),
                     args.region.room.empty() ? "" : " room ", args.region.room.c_str());
    }
    auto c = connect(args.server, args.server_flags);
    if (!c.ok()) {
        if (obj != nullptr) {
            std::fclose(obj);
        }
        return fail(c.status());
    }
    client::ProgressPrinter printer(args.quiet);
    nlohmann::json pieces = nlohmann::json::array();
    unsigned long long next_vertex = 1;  // OBJ indices start at 1 and run over the whole file
    const auto start = Clock::now();
    auto summary = c.value()->fetch_region(*request, [&](const client::RegionEvent& e) {
        if (const auto* g = std::get_if<client::RegionProgress>(&e)) {
            printer.update({"fetching", g->triangles_sent, g->triangles_total, "triangles"});
            return true;
        }
        const auto* p = std::get_if<client::RegionPiece>(&e);
        if (p == nullptr) {
            return true;
        }
        pieces.push_back({{"object", p->object},
                          {"name", p->object_name},
                          {"distance", p->distance},
                          {"vertex_count", p->vertices.size()},
                          {"triangle_count", p->triangles.size()},
                          {"box", client::box_json(p->box)}});
        if (obj != nullptr) {
            // One OBJ object per piece; its triangles' ids in their object on a comment line
            // before its faces (in face order).
            std::fprintf(obj, "o %s\n# object %u distance %.17g\n# triangle_ids",
                         p->object_name.c_str(), p->object, p->distance);
            for (auto id : p->triangle_ids) {
                std::fprintf(obj, " %u", id);
            }
            std::fprintf(obj, "\n");
            for (const auto& v : p->vertices) {
                std::fprintf(obj, "v %.17g %.17g %.17g\n", v.x, v.y, v.z);
            }
            for (const auto& f : p->triangles) {
                std::fprintf(obj, "f %llu %llu %llu\n", next_vertex + f[0], next_vertex + f[1],
                             next_vertex + f[2]);
            }
            next_vertex += p->vertices.size();
        }
        return true;
    });
    printer.finish();
    if (obj != nullptr && std::fclose(obj) != 0 && summary.ok()) {
        return fail(Status(StatusCode::unavailable, "cannot write " + args.obj));
    }
    if (!summary.ok()) {
        return fail(summary.status());
    }
    nlohmann::json doc = {{"server", args.server},
                          {"model", args.model},
                          {"room", args.region.room},
                          {"center", args.region.center},
                          {"radius", args.region.radius},
                          {"max_triangles", args.region.max_triangles},
                          {"generation", summary->generation},
                          {"model_version", summary->model_version},
                          {"piece_count", summary->pieces},
                          {"triangle_count", summary->triangles},
                          {"truncated", summary->truncated},
                          {"pieces", pieces},
                          {"server_seconds", summary->server_seconds},
                          {"wall_seconds", seconds_since(start)}};
    if (!args.obj.empty()) {
        doc["obj"] = args.obj;
    }
    return emit_json(doc, args.output,
                     "region: " + std::to_string(summary->pieces) + " pieces, " +
                         std::to_string(summary->triangles) + " triangles");
}

}  // namespace

void add_massive_commands(CLI::App& app, int& exit_code) {
    auto models_args = std::make_shared<ModelsArgs>();
    auto* models = app.add_subcommand(
        "models", "List the massive models a proximad daemon serves, and its cache counters");
    models->add_option("--server", models_args->server, "The daemon's HOST:PORT")->required();
    add_server_flags(*models, models_args->server_flags);
    add_json_output(*models, models_args->output);
    models->callback([models_args, &exit_code] { exit_code = run_models(*models_args); });

    auto verify_args = std::make_shared<VerifyArgs>();
    auto* verify = app.add_subcommand(
        "verify",
        "Every object pair of a massive model within a tolerance (0: every collision), through a "
        "cache of bounded size; JSON on standard output or --out FILE, progress on standard "
        "error");
    auto* store_opt =
        verify->add_option("--store", verify_args->store, "Run in this process on the store in DIR")
            ->type_name("DIR");
    auto* server_opt = verify->add_option("--server", verify_args->server,
                                          "Run on the proximad daemon at HOST:PORT (with --model)");
    store_opt->excludes(server_opt);
    add_server_flags(*verify, verify_args->server_flags, server_opt);
    verify->add_option("--model", verify_args->model, "With --server: the model's name")
        ->needs(server_opt);
    auto* tolerance_opt =
        verify
            ->add_option("--tolerance", verify_args->tolerance,
                         "Report object pairs within this distance (0: touching or intersecting)")
            ->check(non_negative_number());
    verify
        ->add_option("--cache-bytes", verify_args->cache_bytes,
                     "With --store: the cache budget (default 160M)")
        ->check(size_text(1024))
        ->needs(store_opt);
    verify
        ->add_flag("--brute-force", verify_args->brute_force,
                   "With --store: every object pair with everything in memory (the reference)")
        ->needs(store_opt);
    verify
        ->add_option("--shard", verify_args->shard,
                     "With --store: run only shard I of N (the I-th of N work-balanced groups of "
                     "the model's localized subgraphs, I from 0) and write a shard output for "
                     "--merge")
        ->type_name("I/N")
        ->needs(store_opt);
    verify
        ->add_option("--merge", verify_args->merge,
                     "Combine the outputs of every shard of one run (--shard I/N, I = 0 .. "
                     "N-1) into exactly the single run's output")
        ->type_name("FILE...")
        ->excludes(store_opt)
        ->excludes(server_opt)
        ->excludes(tolerance_opt);
    verify->add_flag("--reproducible", verify_args->reproducible,
                     "Leave out the fields that vary from run to run (stats: plan_seconds, "
                     "seconds, wall_seconds, schedule_from_store, cache)");
    add_json_output(*verify, verify_args->output, true);
    verify->add_flag("--quiet", verify_args->quiet, "No progress on standard error");
    verify->callback([verify, verify_args, tolerance_opt, &exit_code] {
        verify_args->tolerance_given = tolerance_opt->count() > 0;
        if (verify_args->store.empty() && verify_args->server.empty() &&
            verify_args->merge.empty()) {
            exit_code = usage_error(
                *verify, "verify needs --store DIR or --server ADDR (or --merge FILE...)");
            return;
        }
        exit_code = run_verify(*verify_args);
    });

    auto review_args = std::make_shared<ReviewArgs>();
    auto* review = app.add_subcommand(
        "review",
        "Walk an avatar along a path of poses through a massive model: per pose the objects it "
        "touches, those within the tolerance and the nearest; latency percentiles");
    auto* review_store =
        review->add_option("--store", review_args->store, "Run in this process on the store in DIR")
            ->type_name("DIR");
    auto* review_server =
        review->add_option("--server", review_args->server,
                           "Join a review room on the proximad daemon at HOST:PORT (with --model)");
    review_store->excludes(review_server);
    add_server_flags(*review, review_args->server_flags, review_server);
    review->add_option("--model", review_args->model, "With --server: the model's name")
        ->needs(review_server);
    review->add_option("--room", review_args->room, "With --server: the room (default: review)")
        ->needs(review_server)
        ->default_str("review");
    review_args->room = "review";
    review
        ->add_option("--member", review_args->member,
                     "With --server: this member's name in the room (default: USER@HOST-PID, "
                     "unique per client)")
        ->needs(review_server);
    review->add_option("--avatar", review_args->avatar, "The avatar's mesh file (any format)")
        ->required()
        ->check(CLI::ExistingFile);
    review
        ->add_option("--path", review_args->path,
                     "Poses, one a line: 12 numbers (row-major 3x4 transform) or 3 (x y z)")
        ->required()
        ->check(CLI::ExistingFile);
    review
        ->add_option("--tolerance", review_args->tolerance,
                     "Report objects within this distance of the avatar")
        ->check(non_negative_number())
        ->capture_default_str();
    review->add_flag("--no-nearest", review_args->no_nearest,
                     "Do not look for the nearest object beyond the tolerance");
    review
        ->add_option("--cache-bytes", review_args->cache_bytes,
                     "With --store: the cache budget (default 160M)")
        ->check(size_text(1024))
        ->needs(review_store);
    add_json_output(*review, review_args->output, true);
    review->add_flag("--quiet", review_args->quiet, "No progress on standard error");
    review->callback([review, review_args, &exit_code] {
        if (review_args->store.empty() && review_args->server.empty()) {
            exit_code = usage_error(*review, "review needs --store DIR or --server ADDR");
            return;
        }
        exit_code = run_review(*review_args);
    });

    auto region_args = std::make_shared<RegionArgs>();
    auto* region = app.add_subcommand(
        "region",
        "The pieces of a served massive model near a point, nearest first (FetchRegion): JSON "
        "on standard output or --out FILE, the geometry with --obj FILE");
    region->add_option("--server", region_args->server, "The daemon's HOST:PORT")->required();
    add_server_flags(*region, region_args->server_flags);
    region->add_option("--model", region_args->model, "The model's name")->required();
    add_region_flags(*region, region_args->region);
    region->add_option("--objects", region_args->objects, "Only these object indices (I,J,...)")
        ->delimiter(',');
    region->add_flag("--float64", region_args->float64,
                     "Exact float64 coordinates (default: float32 on the wire)");
    region->add_option("--obj", region_args->obj,
                       "Write the pieces' geometry to this Wavefront OBJ file");
    add_json_output(*region, region_args->output, true);
    region->add_flag("--quiet", region_args->quiet, "No progress on standard error");
    region->callback([region_args, &exit_code] { exit_code = run_region(*region_args); });
}

}  // namespace proxima::cli
