#pragma once
// Subcommands that live in their own files. Each adds itself to the app; when it is the one
// the user named, its callback runs it during parsing and stores the exit status in `exit_code`.

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "cli/args.hpp"
#include "client/proxima_client.hpp"
#include "common/local_scene.hpp"
#include "proxima/io/size_text.hpp"

namespace proxima::cli {

// proxima ccd-queries: the public CCD benchmark format (clients/cli/ccd_queries_command.cpp).
void add_ccd_queries_command(CLI::App& app, int& exit_code);
// proxima ccd: continuous collisions between two frames of mesh files
// (clients/cli/ccd_command.cpp).
void add_ccd_command(CLI::App& app, int& exit_code);
// Two frames of one scene as loaded (clients/cli/ccd_command.cpp): the objects of the t0 file
// (the scene at t = 0) and the vertices of the same objects in the t1 file. Both files must give
// the same objects with the same triangles (invalid_argument naming the difference otherwise);
// `weld` as in client::load_objects.
struct FramePair {
    std::vector<client::InputObject> objects;  // at t = 0
    std::vector<std::vector<Vec3>> positions_t1;
};
StatusOr<FramePair> load_frame_pair(const std::string& t0_file, const std::string& t1_file,
                                    bool split_components, WeldMode weld);
// proxima import and proxima store-info: the on-disk model store
// (clients/cli/import_command.cpp).
void add_import_command(CLI::App& app, int& exit_code);
// proxima generate plant|building: deterministic test models as files
// (clients/cli/generate_command.cpp).
void add_generate_command(CLI::App& app, int& exit_code);
// proxima play: a recorded sequence through the engine or a daemon
// (clients/cli/play_command.cpp).
void add_play_command(CLI::App& app, int& exit_code);
// proxima models, verify and review: massive models on a daemon or in a local store
// (clients/cli/massive_command.cpp).
void add_massive_commands(CLI::App& app, int& exit_code);
// proxima load: the load-test harness (clients/cli/load_command.cpp).
void add_load_command(CLI::App& app, int& exit_code);

// proxima snapshot: an offscreen PNG of mesh files, locally or on a daemon
// (clients/cli/snapshot_command.cpp).
void add_snapshot_command(CLI::App& app, int& exit_code);

// --weld (merge identical positions in every file) as a WeldMode; without it only triangle soups
// are welded (commands that read mesh files: distance, ccd).
inline WeldMode weld_mode(bool weld) {
    return weld ? WeldMode::always : WeldMode::triangle_soups;
}

// Prints "proxima: error: CODE: message" on standard error and returns exit status 1
// (clients/cli/cli_util.cpp). CODE is the gRPC name, also for codes the engine has no name for
// ("UNAUTHENTICATED: ...", not "INTERNAL: gRPC UNAUTHENTICATED: ...").
int fail(const Status& status);

// How every subcommand that talks to a daemon authenticates and secures the connection
// (clients/cli/server_flags.cpp): --token-file FILE (else the environment's PROXIMA_TOKEN),
// --tls-ca FILE, --tls-cert FILE, --tls-key FILE, --tls-server-name NAME.
struct ServerFlags {
    std::string token_file;
    std::string tls_ca;
    std::string tls_cert;
    std::string tls_key;
    std::string tls_server_name;
};
// Adds the flags to `cmd`; with `server` set they need it (they mean nothing locally).
void add_server_flags(CLI::App& cmd, ServerFlags& flags, CLI::Option* server = nullptr);
// --local (in this process, the default) and --server HOST:PORT (on a daemon), which exclude
// each other, then the server flags needing --server: for the commands that run either way, with
// their own help texts. Returns --server, for the options that need it.
CLI::Option* add_local_or_server(CLI::App& cmd, bool& local, std::string& server,
                                 ServerFlags& flags, const std::string& local_help,
                                 const std::string& server_help);
// ConnectOptions from the flags: the token (from the file, else PROXIMA_TOKEN; a token file
// readable by every user is a warning on standard error) and TLS when any --tls-* flag is given.
// Errors name the flag's file.
StatusOr<client::ConnectOptions> connect_options(const ServerFlags& flags,
                                                 client::ConnectOptions base = {});
// connect_options, then Client::connect.
StatusOr<std::unique_ptr<client::Client>> connect_server(const std::string& address,
                                                         const ServerFlags& flags,
                                                         client::ConnectOptions base = {});
// The region of a served massive model that `proxima region` fetches and `proxima snapshot
// --model` draws (clients/cli/server_flags.cpp): --center X,Y,Z, --radius, --room and
// --max-triangles.
struct RegionFlags {
    std::vector<double> center{0.0, 0.0, 0.0};
    double radius = 0.0;
    std::string room;
    std::uint64_t max_triangles = 0;
};
// Adds the flags to `cmd`; with `model` set they need it and their help says so.
void add_region_flags(CLI::App& cmd, RegionFlags& flags, CLI::Option* model = nullptr);
// The request for `model`'s region from the flags (no `objects`, float32 vertices);
// invalid_argument when --center is not three numbers.
StatusOr<client::RegionRequest> region_request(const std::string& model, const RegionFlags& flags);
// One frame on the daemon in a scene of its own (clients/cli/remote.cpp): creates the scene with
// `objects` in input order (so result indices mean what they mean locally), lets `fill` complete
// the frame (it sees the scene's object ids), sends it with the Query RPC, then deletes the
// scene; a failed delete is a warning on standard error, the answer stands.
StatusOr<client::FrameResponse> query_in_temporary_scene(
    client::Client& c, const std::string& scene_name,
    const std::vector<client::InputObject>& objects,
    const std::function<void(client::FrameRequest&, const client::RemoteScene&)>& fill);

}  // namespace proxima::cli
