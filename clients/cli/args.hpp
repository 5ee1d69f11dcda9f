#pragma once
// The command line's one argument layer (clients/cli/args.cpp): checks for numeric parameters
// with messages in the project's words, byte sizes, and what a parse error does (one line, a
// pointer to the subcommand's --help, exit status 2).

#include <cstdint>
#include <string>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

namespace proxima::cli {

// Exit statuses (README "Exit status"): 0 success, 1 bad input or a failed operation (a bad mesh,
// an unreachable daemon, an error status), 2 a usage error (an unknown option, a missing or
// malformed argument, a value out of range).
inline constexpr int EXIT_USAGE = 2;

// A finite number (not nan or inf) of at least `lo`, or above it when `strict`.
CLI::Validator finite_number(double lo, bool strict);
inline CLI::Validator non_negative_number() {
    return finite_number(0.0, false);
}
inline CLI::Validator positive_number() {
    return finite_number(0.0, true);
}
// A whole number (digits only) from `lo` to `hi`.
CLI::Validator whole_number(std::uint64_t lo, std::uint64_t hi);
// A size as proxima::parse_size reads it (K, M, G, T powers of `base`: 1024 for every size the
// programs take, bytes and triangle counts alike), checked when the command line is parsed. As a
// transform() it also rewrites the text to the whole number, for options parsed into an integer.
// `allow_zero`: "0" is a value too (--inline-mesh-bytes 0: upload every object).
CLI::Validator size_text(std::uint64_t base, bool allow_zero = false);

// Parses the command line. Returns -1 when the command should run; otherwise the exit status:
// 0 after --help or --version, EXIT_USAGE after a usage error, which is printed as
// "proxima: error: MESSAGE" and a line naming the failing subcommand's --help.
int parse_command_line(CLI::App& app, int argc, char** argv);

// One output convention for every command that prints one JSON document: --json prints it on
// standard output (one line), --out FILE writes it to FILE instead and prints a one-line summary
// on standard error.
struct JsonOutput {
    bool json = false;
    std::string out;
    bool wanted() const { return json || !out.empty(); }
};
// Adds --json and --out FILE to `cmd`. `always`: the command prints nothing but JSON (--json is
// accepted for the convention's sake).
void add_json_output(CLI::App& cmd, JsonOutput& output, bool always = false);
// Prints or writes `doc` as JsonOutput says; `summary` is the stderr line after writing a file.
// Returns the exit status: 0, or 1 when the file cannot be written.
int emit_json(const nlohmann::json& doc, const JsonOutput& output, const std::string& summary);

// A usage error found after parsing (options that must come together): prints it as
// parse_command_line does, naming `command`'s --help, and returns EXIT_USAGE.
int usage_error(const CLI::App& command, const std::string& message);

}  // namespace proxima::cli
