// proxima import: mesh files, directories of them, scene files or a generated plant into an
// on-disk model store (engine/include/proxima/massive/store.hpp), with progress on standard
// error and a JSON summary on standard output. proxima store-info: what a store holds, and with
// --verify whether every chunk still matches its checksum.

#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli/commands.hpp"
#include "common/json_output.hpp"
#include "common/progress.hpp"
#include "proxima/massive/generator.hpp"
#include "proxima/massive/store.hpp"

namespace proxima::cli {

namespace {

nlohmann::json summary_json(const massive::StoreSummary& s) {
    return {{"store", s.path},
            {"generation", s.generation},
            {"object_count", s.objects},
            {"piece_count", s.pieces},
            {"split_object_count", s.split_objects},
            {"triangle_count", s.triangles},
            {"vertex_count", s.vertices},
            {"chunk_count", s.chunks},
            {"bytes", s.bytes}};
}

struct ImportArgs {
    std::string store;
    std::string max_piece_bytes;
    std::string cache_bytes;
    std::string chunk_bytes;
    std::string plant;
    std::uint64_t seed = 1;
    bool quiet = false;
    JsonOutput output;
    std::vector<std::string> inputs;
};

StatusOr<massive::StoreSummary> import_plant(const ImportArgs& args,
                                             const massive::StoreOptions& options,
                                             client::ProgressPrinter& printer) {
    auto triangles = parse_size("--plant", args.plant, 1024);
    if (!triangles.ok()) {
        return triangles.status();
    }
    massive::PlantOptions plant;
    plant.triangles = triangles.value();
    plant.seed = args.seed;
    auto writer = massive::StoreWriter::create(args.store, options);
    if (!writer.ok()) {
        return writer.status();
    }
    // Objects go straight from the generator into the writer: the model is never held whole.
    auto generated = massive::generate_plant(
        plant, [&](massive::ModelObject&& object) { return writer.value()->add(object); },
        printer.callback());
    if (!generated.ok()) {
        return generated.status();
    }
    return writer.value()->commit(printer.callback());
}

int run_import(const ImportArgs& args) {
    massive::StoreOptions options;
    if (!args.max_piece_bytes.empty()) {
        auto v = parse_size("--max-piece-bytes", args.max_piece_bytes, 1024);
        if (!v.ok()) {
            return fail(v.status());
        }
        options.max_piece_bytes = v.value();
    } else if (!args.cache_bytes.empty()) {
        auto v = parse_size("--cache-bytes", args.cache_bytes, 1024);
        if (!v.ok()) {
            return fail(v.status());
        }
        options.max_piece_bytes = v.value() / massive::SPLIT_FRACTION;
    }
    if (!args.chunk_bytes.empty()) {
        auto v = parse_size("--chunk-bytes", args.chunk_bytes, 1024);
        if (!v.ok()) {
            return fail(v.status());
        }
        options.chunk_bytes = v.value();
    }
    if (args.plant.empty() == args.inputs.empty()) {
        return fail(invalid_argument(args.plant.empty()
                                         ? "nothing to import: give input files or --plant"
                                         : "--plant generates the model: give no input files"));
    }
    if (args.plant.empty()) {
        options.source = "import of";
        for (const auto& input : args.inputs) {
            options.source += ' ';
            options.source += input;
        }
    } else {
        auto triangles = parse_size("--plant", args.plant, 1024);
        if (!triangles.ok()) {
            return fail(triangles.status());
        }
        options.source = "plant " + std::to_string(triangles.value()) + " triangles seed " +
                         std::to_string(args.seed);
    }
    // Importing over an existing store replaces it (a new generation; the old one is kept until
    // the next import): say so, since a daemon serving the directory switches to it.
    std::string replaced;
    if (auto existing = massive::Store::open(args.store); existing.ok()) {
        const auto& old = existing.value()->summary();
        replaced = old.generation;
        std::fprintf(stderr,
                     "proxima: replacing generation %s of %s (%llu objects, %llu triangles); a "
                     "proximad serving it switches to the new one at its next rescan\n",
                     old.generation.c_str(), args.store.c_str(),
                     static_cast<unsigned long long>(old.objects),
                     static_cast<unsigned long long>(old.triangles));
    }
    const auto start = std::chrono::steady_clock::now();
    client::ProgressPrinter printer(args.quiet);
    auto summary = args.plant.empty()
                       ? massive::import_files(args.inputs, args.store, options, printer.callback())
                       : import_plant(args, options, printer);
    printer.finish();
    if (!summary.ok()) {
        return fail(summary.status());
    }
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    auto doc = summary_json(summary.value());
    doc["max_piece_bytes"] = options.max_piece_bytes;
    doc["chunk_bytes"] = options.chunk_bytes;
    doc["source"] = options.source;
    if (!replaced.empty()) {
        doc["replaced_generation"] = replaced;
    }
    doc["seconds"] = seconds;
    doc["triangles_per_second"] =
        seconds > 0 ? static_cast<double>(summary->triangles) / seconds : 0.0;
    doc["bytes_per_second"] = seconds > 0 ? static_cast<double>(summary->bytes) / seconds : 0.0;
    return emit_json(doc, args.output,
                     "import: " + std::to_string(summary->triangles) + " triangles into " +
                         args.store + " (" + summary->generation + ")");
}

struct InfoArgs {
    std::string store;
    bool verify = false;
    bool objects = false;
    bool quiet = false;
    JsonOutput output;
};

int run_store_info(const InfoArgs& args) {
    auto opened = massive::Store::open(args.store);
    if (!opened.ok()) {
        return fail(opened.status());
    }
    const auto& store = *opened.value();
    auto doc = summary_json(store.summary());
    std::uint64_t largest = 0;
    for (const auto& p : store.pieces()) {
        largest = std::max(largest, p.weight());
    }
    doc["largest_piece_weight"] = largest;
    if (args.objects) {
        auto objects = nlohmann::json::array();
        for (const auto& o : store.objects()) {
            objects.push_back({{"name", o.name},
                               {"box", client::box_json(o.box)},
                               {"vertex_count", o.vertex_count},
                               {"triangle_count", o.triangle_count},
                               {"first_piece", o.first_piece},
                               {"piece_count", o.piece_count}});
        }
        doc["objects"] = std::move(objects);
    }
    if (args.verify) {
        const auto start = std::chrono::steady_clock::now();
        client::ProgressPrinter printer(args.quiet);
        const Status verified = store.verify(printer.callback());
        printer.finish();
        if (!verified.ok()) {
            return fail(verified);
        }
        doc["verified"] = true;
        doc["verify_seconds"] =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }
    return emit_json(doc, args.output,
                     "store-info: " + args.store + " (" + store.summary().generation + ")");
}

}  // namespace

void add_import_command(CLI::App& app, int& exit_code) {
    auto args = std::make_shared<ImportArgs>();
    auto* cmd = app.add_subcommand(
        "import",
        "Import mesh files, directories, scene files (*.json, proxima-scene/1) or a generated "
        "plant into a model store");
    cmd->add_option("--store", args->store, "The store directory (created if absent)")->required();
    auto* max_piece =
        cmd->add_option("--max-piece-bytes", args->max_piece_bytes,
                        "Split objects into pieces of at most this cache weight (default 16M)");
    max_piece->check(size_text(1024));
    cmd->add_option("--cache-bytes", args->cache_bytes,
                    "The runtime cache size M: pieces are at most M/10")
        ->check(size_text(1024))
        ->excludes(max_piece);
    cmd->add_option("--chunk-bytes", args->chunk_bytes, "Checksummed chunk size")
        ->check(size_text(1024))
        ->default_str(std::to_string(massive::StoreOptions{}.chunk_bytes));
    auto* plant = cmd->add_option("--plant", args->plant,
                                  "Generate a plant of about this many triangles (K, M, G: "
                                  "powers of 1024) instead of reading files")
                      ->check(size_text(1024));
    cmd->add_option("--seed", args->seed, "Seed of the generated plant")
        ->check(whole_number(0, UINT64_MAX))
        ->capture_default_str()
        ->needs(plant);
    cmd->add_flag("--quiet", args->quiet, "No progress on standard error");
    add_json_output(*cmd, args->output, true);
    cmd->add_option("inputs", args->inputs, "Mesh files, directories or scene files");
    cmd->callback([args, &exit_code] { exit_code = run_import(*args); });

    auto info_args = std::make_shared<InfoArgs>();
    auto* info = app.add_subcommand("store-info", "Summarise a model store (JSON)");
    info->add_option("--store", info_args->store, "The store directory")->required();
    info->add_flag("--verify", info_args->verify,
                   "Read every chunk and check its checksum (exit 1 if one is corrupt)");
    info->add_flag("--objects", info_args->objects, "List the objects");
    info->add_flag("--quiet", info_args->quiet, "No progress on standard error");
    add_json_output(*info, info_args->output, true);
    info->callback([info_args, &exit_code] { exit_code = run_store_info(*info_args); });
}

}  // namespace proxima::cli
