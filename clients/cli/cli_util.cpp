// Helpers shared by the subcommands in clients/cli (declared in commands.hpp).

#include <cstdio>

#include "cli/commands.hpp"

namespace proxima::cli {

int fail(const Status& status) {
    std::fprintf(stderr, "proxima: error: %s\n", client::describe_status(status).c_str());
    return 1;
}

}  // namespace proxima::cli
