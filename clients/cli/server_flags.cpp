// The flags every --server subcommand shares: who the client is (a bearer token) and how the
// connection is secured (TLS, optionally mutual); and the region of a served massive model that
// the model commands select. Declared in commands.hpp.

#include <cctype>
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

CLI::Option* add_local_or_server(CLI::App& cmd, bool& local, std::string& server,
                                 ServerFlags& flags, const std::string& local_help,
                                 const std::string& server_help) {
    auto* local_flag = cmd.add_flag("--local", local, local_help);
    auto* server_opt = cmd.add_option("--server", server, server_help);
    server_opt->excludes(local_flag);
    add_server_flags(cmd, flags, server_opt);
    return server_opt;
}

void add_region_flags(CLI::App& cmd, RegionFlags& flags, CLI::Option* model) {
    // With `model`: "With --model: " before the help, which then starts in lower case.
    auto help = [model](std::string text) {
        if (model) {
            text[0] = static_cast<char>(std::tolower(static_cast<unsigned char>(text[0])));
            text = "With --model: " + text;
        }
        return text;
    };
    auto needs_model = [model](CLI::Option* option) {
        if (model) {
            option->needs(model);
        }
    };
    needs_model(cmd.add_option("--center", flags.center, help("The point X,Y,Z (default 0,0,0)"))
                    ->delimiter(',')
                    ->expected(3));
    needs_model(cmd.add_option("--radius", flags.radius,
                               help("Pieces whose boxes come within this distance (0: every "
                                    "piece)"))
                    ->check(non_negative_number())
                    ->capture_default_str());
    needs_model(
        cmd.add_option("--room", flags.room, help("A review room's edited view of the model")));
    needs_model(cmd.add_option("--max-triangles", flags.max_triangles,
                               help("Stop after the nearest pieces up to this many triangles (0: "
                                    "no limit)"))
                    ->capture_default_str());
}

StatusOr<client::RegionRequest> region_request(const std::string& model, const RegionFlags& flags) {
    if (flags.center.size() != 3) {
        return invalid_argument("--center is three numbers X,Y,Z");
    }
    client::RegionRequest request;
    request.model = model;
    request.center = {flags.center[0], flags.center[1], flags.center[2]};
    request.radius = flags.radius;
    request.room = flags.room;
    request.max_triangles = flags.max_triangles;
    return request;
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
