#pragma once
// Subcommands that live in their own files. Each adds itself to the app; when it is the one
// the user named, its callback runs it during parsing and stores the exit status in `exit_code`.

#include <CLI/CLI.hpp>

namespace proxima::cli {

// proxima ccd-queries: the public CCD benchmark format (clients/cli/ccd_queries_command.cpp).
void add_ccd_queries_command(CLI::App& app, int& exit_code);
// proxima ccd: continuous collisions between two frames of mesh files
// (clients/cli/ccd_command.cpp).
void add_ccd_command(CLI::App& app, int& exit_code);

}  // namespace proxima::cli
