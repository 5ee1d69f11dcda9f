#include "cli/args.hpp"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <string>

#include "proxima/io/size_text.hpp"

namespace proxima::cli {

namespace {

std::string shown(const std::string& text) {
    return "'" + (text.size() > 40 ? text.substr(0, 40) + "..." : text) + "'";
}

std::string format_bound(double v) {
    std::ostringstream out;
    out << v;
    return out.str();
}

}  // namespace

CLI::Validator finite_number(double lo, bool strict) {
    const std::string bound = (strict ? "> " : ">= ") + format_bound(lo);
    return {[lo, strict, bound](std::string& text) -> std::string {
                double v = 0.0;
                const char* end = text.data() + text.size();
                const char* begin = text.data();
                if (!text.empty() && text.front() == '+') {
                    ++begin;
                }
                const auto parsed = std::from_chars(begin, end, v);
                if (text.empty() || parsed.ptr != end || parsed.ec != std::errc()) {
                    return "expected a number, got " + shown(text);
                }
                if (!std::isfinite(v)) {
                    return "must be a finite number, got " + shown(text);
                }
                if (strict ? !(v > lo) : !(v >= lo)) {
                    return "must be " + bound + ", got " + shown(text);
                }
                return {};
            },
            "NUMBER " + bound, "finite_number"};
}

CLI::Validator whole_number(std::uint64_t lo, std::uint64_t hi) {
    const std::string range = std::to_string(lo) + " to " + std::to_string(hi);
    return {
        [lo, hi, range](std::string& text) -> std::string {
            std::uint64_t v = 0;
            const char* end = text.data() + text.size();
            const auto parsed = std::from_chars(text.data(), end, v);
            if (text.empty() || parsed.ptr != end || parsed.ec != std::errc() || v < lo || v > hi) {
                return "expected a whole number from " + range + ", got " + shown(text);
            }
            return {};
        },
        "INTEGER " + range, "whole_number"};
}

CLI::Validator size_text(std::uint64_t base, bool allow_zero) {
    return {[base, allow_zero](std::string& text) -> std::string {
                if (allow_zero && text == "0") {
                    return {};
                }
                auto v = parse_size("", text, base);
                if (!v.ok()) {
                    return "expected a positive number with an optional K, M, G or T suffix "
                           "(powers of " +
                           std::to_string(base) + "), e.g. 160M; got " + shown(text);
                }
                text = std::to_string(v.value());  // kept by transform(), not by check()
                return {};
            },
            base == 1024 ? "SIZE (K/M/G/T = 1024^n)" : "SIZE (K/M/G/T = 1000^n)", "size_text"};
}

namespace {

// "proxima generate plant": the command's path from the top.
std::string command_path(const CLI::App& command) {
    std::string path = command.get_name();
    for (const CLI::App* up = command.get_parent(); up != nullptr; up = up->get_parent()) {
        path = up->get_name() + " " + path;
    }
    return path;
}

std::string top_name(const CLI::App& command) {
    const CLI::App* top = &command;
    while (top->get_parent() != nullptr) {
        top = top->get_parent();
    }
    return top->get_name();
}

}  // namespace

void add_json_output(CLI::App& cmd, JsonOutput& output, bool always) {
    cmd.add_flag("--json", output.json,
                 always ? "Print the JSON result on standard output (the default)"
                        : "Print the result as one JSON object on standard output");
    cmd.add_option("--out", output.out,
                   "Write the JSON result to FILE instead (a one-line summary on standard error)")
        ->type_name("FILE");
}

int emit_json(const nlohmann::json& doc, const JsonOutput& output, const std::string& summary) {
    const std::string text = doc.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
    if (output.out.empty()) {
        std::fwrite(text.data(), 1, text.size(), stdout);
        std::fputc('\n', stdout);
        return 0;
    }
    std::FILE* file = std::fopen(output.out.c_str(), "wb");
    const bool ok = file != nullptr &&
                    std::fwrite(text.data(), 1, text.size(), file) == text.size() &&
                    std::fputc('\n', file) != EOF;
    if (file == nullptr || std::fclose(file) != 0 || !ok) {
        std::fprintf(stderr, "proxima: error: cannot write '%s'\n", output.out.c_str());
        return 1;
    }
    std::fprintf(stderr, "%s; JSON in %s\n", summary.c_str(), output.out.c_str());
    return 0;
}

int usage_error(const CLI::App& command, const std::string& message) {
    std::fprintf(stderr, "%s: error: %s\nRun '%s --help' for the options.\n",
                 top_name(command).c_str(), message.c_str(), command_path(command).c_str());
    return EXIT_USAGE;
}

int parse_command_line(CLI::App& app, int argc, char** argv) {
    try {
        app.parse(argc, argv);
        return -1;
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForAllHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        // The deepest subcommand the parse reached names the --help to read.
        const CLI::App* at = &app;
        while (!at->get_subcommands().empty()) {
            at = at->get_subcommands().front();
        }
        return usage_error(*at, e.what());
    }
}

}  // namespace proxima::cli
