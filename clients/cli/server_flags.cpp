// The flags every --server subcommand shares: who the client is (a bearer token) and how the
// connection is secured (TLS, optionally mutual). Declared in commands.hpp.

#include <cstdio>
#include <cstdlib>

#include <grpc/support/log.h>

#include "cli/commands.hpp"

namespace proxima::cli {

void add_server_flags(CLI::App& cmd, ServerFlags& flags, CLI::Option* server) {
    auto needs_server = [server](CLI::Option* option) {
        if (server) {
            option->needs(server);
        }
    };
    needs_server(cmd.add_option("--token-file", flags.token_file,
                                "With --server: a file whose first line is the bearer token "
                                "(default: the environment's PROXIMA_TOKEN)"));
    needs_server(cmd.add_option("--tls-ca", flags.tls_ca,
                                "With --server: connect over TLS, verifying the daemon's "
                                "certificate with this PEM root CA"));
    needs_server(cmd.add_option("--tls-cert", flags.tls_cert,
                                "With --server: mutual TLS, this client's PEM certificate"));
    needs_server(cmd.add_option("--tls-key", flags.tls_key,
                                "With --server: mutual TLS, this client's PEM private key"));
    needs_server(cmd.add_option("--tls-server-name", flags.tls_server_name,
                                "With --server: the name the daemon's certificate must hold "
                                "instead of the address's host (TLS)"));
}

StatusOr<client::ConnectOptions> connect_options(const ServerFlags& flags,
                                                 client::ConnectOptions base) {
    if (!flags.token_file.empty()) {
        std::string warning;
        auto token = client::read_token_file(flags.token_file, &warning);
        if (!token.ok()) {
            return Status(token.status().code(), "--token-file: " + token.status().message());
        }
        if (!warning.empty()) {
            std::fprintf(stderr, "proxima: warning: %s\n", warning.c_str());
        }
        base.token = std::move(token).value();
    } else if (const char* env = std::getenv("PROXIMA_TOKEN"); env != nullptr && *env != '\0') {
        // Trimmed like a token file's line: a trailing newline from `$(cat file)` is harmless.
        std::string token = env;
        const auto first = token.find_first_not_of(" \t\r\n");
        const auto last = token.find_last_not_of(" \t\r\n");
        base.token = first == std::string::npos ? "" : token.substr(first, last - first + 1);
    }
    if (!flags.tls_ca.empty() || !flags.tls_cert.empty() || !flags.tls_key.empty() ||
        !flags.tls_server_name.empty()) {
        auto tls = client::load_tls_files(flags.tls_ca, flags.tls_cert, flags.tls_key);
        if (!tls.ok()) {
            return tls.status();
        }
        tls->server_name_override = flags.tls_server_name;
        base.tls = std::move(tls).value();
    }
    return base;
}

namespace {

void drop_grpc_log(gpr_log_func_args*) {}

}  // namespace

StatusOr<std::unique_ptr<client::Client>> connect_server(const std::string& address,
                                                         const ServerFlags& flags,
                                                         client::ConnectOptions base) {
    // gRPC logs each failed connection attempt itself (a TLS handshake error per retry): the
    // command's own one-line error says what failed. GRPC_VERBOSITY in the environment keeps
    // gRPC's lines, for debugging the transport.
    if (std::getenv("GRPC_VERBOSITY") == nullptr) {
        gpr_set_log_function(drop_grpc_log);
    }
    auto options = connect_options(flags, std::move(base));
    if (!options.ok()) {
        return options.status();
    }
    return client::Client::connect(address, std::move(options).value());
}

}  // namespace proxima::cli
