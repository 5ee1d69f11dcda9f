#include "cli/commands.hpp"

namespace proxima::cli {

void add_ccd_queries_command(CLI::App& /*app*/, int& /*exit_code*/) {}

}  // namespace proxima::cli
