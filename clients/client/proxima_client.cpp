#include "client/proxima_client.hpp"

#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <random>
#include <sstream>
#include <string_view>
#include <thread>
#include <unordered_map>
#include <utility>
#include <variant>

#include <grpcpp/grpcpp.h>

#include "client/decode.hpp"
#include "proxima/v1/proxima.grpc.pb.h"
#include "proxima/wire/buffers.hpp"
#include "proxima/wire/frames.hpp"
#include "proxima/wire/massive.hpp"
#include "proxima/wire/snapshot.hpp"
#include "proxima/wire/status.hpp"

namespace proxima::client {

namespace pb = ::proxima::v1;
using wire::from_grpc;

namespace {

// Upload chunks stay at or under 1 MiB so that each message is far below any sane server limit,
// and hold whole vertices / triangles so that each chunk is packed independently (no full copy
// of a large mesh in wire format).
constexpr std::size_t UPLOAD_CHUNK_BYTES = 1u << 20;

std::chrono::system_clock::time_point deadline_after(std::chrono::milliseconds ms) {
    return std::chrono::system_clock::now() + ms;
}

std::string milliseconds_text(std::chrono::milliseconds ms) {
    return std::to_string(ms.count()) + " ms";
}

// gRPC sends ASCII header values only (a newline would end the header): a token with anything
// else cannot work, and saying so beats a baffling INTERNAL from the transport.
Status check_token(const std::string& token, const std::string& source) {
    for (unsigned char c : token) {
        if (c < 0x20 || c > 0x7e) {
            return invalid_argument(source +
                                    " holds a character that cannot travel in an "
                                    "authorization header (printable ASCII only)");
        }
    }
    return {};
}

bool holds_pem(const std::string& text, const std::string& label_end) {
    const auto begin = text.find("-----BEGIN ");
    return begin != std::string::npos && text.find(label_end, begin) != std::string::npos;
}

Status check_tls(const TlsOptions& tls) {
    if (!tls.root_ca_pem.empty() && !holds_pem(tls.root_ca_pem, "CERTIFICATE-----")) {
        return invalid_argument("TLS root CA: no PEM certificate (-----BEGIN CERTIFICATE-----)");
    }
    if (tls.client_cert_pem.empty() != tls.client_key_pem.empty()) {
        return invalid_argument(
            tls.client_cert_pem.empty()
                ? "TLS: a client key without a client certificate (mutual TLS needs both)"
                : "TLS: a client certificate without its private key (mutual TLS needs both)");
    }
    if (!tls.client_cert_pem.empty() && !holds_pem(tls.client_cert_pem, "CERTIFICATE-----")) {
        return invalid_argument("TLS client certificate: no PEM certificate");
    }
    if (!tls.client_key_pem.empty() && !holds_pem(tls.client_key_pem, "PRIVATE KEY-----")) {
        return invalid_argument(
            "TLS client key: no PEM private key (-----BEGIN ... PRIVATE "
            "KEY-----)");
    }
    return {};
}

StatusOr<std::string> read_text_file(const std::string& path, const std::string& what) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
        return not_found(what + " '" + path + "' does not exist");
    }
    if (std::filesystem::is_directory(path, ec)) {
        return invalid_argument(what + " '" + path + "' is a directory, not a file");
    }
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        return Status(StatusCode::failed_precondition,
                      what + " '" + path + "' cannot be read: " + std::strerror(errno));
    }
    std::ostringstream text;
    text << in.rdbuf();
    if (in.bad()) {
        return Status(StatusCode::failed_precondition, what + " '" + path + "': read error");
    }
    return text.str();
}

// Names match the proto's methods so that retry reports read like the daemon's logs.
enum class Retry {
    idempotent,   // safe to repeat whatever happened: every UNAVAILABLE is retried
    unsent_only,  // repeats would change state: retried only when the request never went out
};

}  // namespace

namespace {

// from_grpc's form for codes the engine cannot name: internal, "gRPC NAME: message".
bool split_grpc_prefix(const Status& status, std::string* name, std::string* rest) {
    constexpr std::string_view PREFIX = "gRPC ";
    const auto& m = status.message();
    if (status.code() != StatusCode::internal || m.rfind(PREFIX, 0) != 0) {
        return false;
    }
    const auto colon = m.find(": ", PREFIX.size());
    if (colon == std::string::npos) {
        return false;
    }
    const auto candidate = m.substr(PREFIX.size(), colon - PREFIX.size());
    if (candidate.empty() ||
        candidate.find_first_not_of("ABCDEFGHIJKLMNOPQRSTUVWXYZ_") != std::string::npos) {
        return false;
    }
    *name = candidate;
    *rest = m.substr(colon + 2);
    return true;
}

}  // namespace

std::string grpc_code_name(const Status& status) {
    std::string name;
    std::string rest;
    if (split_grpc_prefix(status, &name, &rest)) {
        return name;
    }
    return status_code_name(status.code());
}

std::string describe_status(const Status& status) {
    std::string name;
    std::string rest;
    if (split_grpc_prefix(status, &name, &rest)) {
        return name + ": " + rest;
    }
    return status.to_string();
}

StatusOr<TlsOptions> load_tls_files(const std::string& root_ca_file,
                                    const std::string& client_cert_file,
                                    const std::string& client_key_file) {
    TlsOptions tls;
    struct Part {
        const std::string& path;
        std::string* out;
        const char* what;
    };
    for (const Part& part :
         {Part{root_ca_file, &tls.root_ca_pem, "TLS root CA file"},
          Part{client_cert_file, &tls.client_cert_pem, "TLS client certificate file"},
          Part{client_key_file, &tls.client_key_pem, "TLS client key file"}}) {
        if (part.path.empty()) {
            continue;
        }
        auto text = read_text_file(part.path, part.what);
        if (!text.ok()) {
            return text.status();
        }
        *part.out = std::move(text).value();
    }
    // The same checks as connect(), but naming the files.
    if (!root_ca_file.empty() && !holds_pem(tls.root_ca_pem, "CERTIFICATE-----")) {
        return invalid_argument("TLS root CA file '" + root_ca_file +
                                "' holds no PEM certificate (-----BEGIN CERTIFICATE-----)");
    }
    if (!client_cert_file.empty() && !holds_pem(tls.client_cert_pem, "CERTIFICATE-----")) {
        return invalid_argument("TLS client certificate file '" + client_cert_file +
                                "' holds no PEM certificate (-----BEGIN CERTIFICATE-----)");
    }
    if (!client_key_file.empty() && !holds_pem(tls.client_key_pem, "PRIVATE KEY-----")) {
        return invalid_argument("TLS client key file '" + client_key_file +
                                "' holds no PEM private key (-----BEGIN ... PRIVATE KEY-----)");
    }
    if (client_cert_file.empty() != client_key_file.empty()) {
        return invalid_argument(client_cert_file.empty()
                                    ? "a TLS client key file needs its certificate file too"
                                    : "a TLS client certificate file needs its key file too");
    }
    return tls;
}

StatusOr<std::string> read_token_file(const std::string& path, std::string* warning) {
    auto text = read_text_file(path, "token file");
    if (!text.ok()) {
        return text.status();
    }
    std::string line = text->substr(0, text->find('\n'));
    const auto first = line.find_first_not_of(" \t\r\f\v");
    if (first == std::string::npos) {
        return invalid_argument("token file '" + path + "': the first line is empty");
    }
    line = line.substr(first, line.find_last_not_of(" \t\r\f\v") - first + 1);
    if (auto st = check_token(line, "token file '" + path + "'"); !st.ok()) {
        return st;
    }
    struct stat info {};
    if (warning && ::stat(path.c_str(), &info) == 0 && (info.st_mode & S_IROTH) != 0) {
        char mode[8];
        std::snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(info.st_mode & 07777));
        *warning = "token file '" + path + "' is readable by every user (mode " + mode +
                   "); the token is a password: chmod 600 it";
    }
    return line;
}

namespace {

// 16 hex digits: a Client's own routing key when the caller names none.
std::string random_route_suffix(std::mt19937_64& rng) {
    static constexpr std::string_view DIGITS = "0123456789abcdef";
    std::string out;
    auto bits = rng();
    for (int i = 0; i < 16; ++i) {
        out += DIGITS[bits & 0xfU];
        bits >>= 4U;
    }
    return out;
}

}  // namespace

struct Client::Impl {
    std::string address;
    ConnectOptions options;
    std::shared_ptr<grpc::ChannelCredentials> credentials;
    grpc::ChannelArguments channel_args;
    // The channel is replaced when a connection attempt must be made from scratch (below);
    // calls take a reference under the lock, so one in flight keeps its channel alive.
    std::mutex channel_mu;
    std::shared_ptr<grpc::Channel> channel;
    std::shared_ptr<pb::Proximity::Stub> stub;
    std::mutex rng_mu;
    std::mt19937_64 rng{std::random_device{}()};
    // Whether the caller chose options.route (else it is this Client's random one).
    bool explicit_route = false;

    void new_channel() {
        auto fresh = grpc::CreateCustomChannel(address, credentials, channel_args);
        auto fresh_stub = std::shared_ptr<pb::Proximity::Stub>(pb::Proximity::NewStub(fresh));
        std::lock_guard lock(channel_mu);
        channel = std::move(fresh);
        stub = std::move(fresh_stub);
    }

    std::shared_ptr<pb::Proximity::Stub> stub_now() {
        std::lock_guard lock(channel_mu);
        return stub;
    }

    std::shared_ptr<grpc::Channel> channel_now() {
        std::lock_guard lock(channel_mu);
        return channel;
    }

    // Deadline (unary calls only: a stream lives as long as its caller wants) and the token.
    // `route`: the routing key for this call instead of options.route (empty: options.route).
    void prepare(grpc::ClientContext& context, bool unary = true,
                 const std::string& route = {}) const {
        if (unary && options.call_timeout.count() > 0) {
            context.set_deadline(deadline_after(options.call_timeout));
        }
        if (!options.token.empty()) {
            context.AddMetadata("authorization", "Bearer " + options.token);
        }
        const std::string& key = route.empty() ? options.route : route;
        if (!key.empty()) {
            context.AddMetadata(ROUTE_HEADER, key);
        }
    }

    // One connection attempt: ok once the channel is READY; unavailable when the attempt ended
    // in TRANSIENT_FAILURE (refused, reset, a failed TLS handshake) or at the deadline.
    // A channel in TRANSIENT_FAILURE stays there ("sticky") until it is READY, so a failed retry
    // of gRPC's own could not be seen on it, and its reconnect schedule is gRPC's: such a channel
    // is replaced by a fresh one (its own subchannel pool, see connect()), whose single attempt
    // goes IDLE -> CONNECTING -> READY or TRANSIENT_FAILURE where we can watch it.
    Status ensure_connected(std::chrono::milliseconds timeout) {
        auto current = channel_now();
        auto state = current->GetState(true);
        if (state == GRPC_CHANNEL_READY) {
            return {};
        }
        if (state == GRPC_CHANNEL_TRANSIENT_FAILURE || state == GRPC_CHANNEL_SHUTDOWN) {
            new_channel();
            current = channel_now();
            state = current->GetState(true);
        }
        const auto deadline = deadline_after(timeout);
        bool attempted = state == GRPC_CHANNEL_CONNECTING;
        for (;;) {
            if (state == GRPC_CHANNEL_READY) {
                return {};
            }
            if ((state == GRPC_CHANNEL_TRANSIENT_FAILURE && attempted) ||
                state == GRPC_CHANNEL_SHUTDOWN) {
                return {StatusCode::unavailable, unreachable("the connection attempt failed")};
            }
            if (!current->WaitForStateChange(state, deadline)) {
                return {StatusCode::unavailable,
                        unreachable("no connection within " + milliseconds_text(timeout))};
            }
            // Whatever we see next, the channel went through a connection attempt.
            attempted = true;
            state = current->GetState(true);
        }
    }

    std::string unreachable(const std::string& why) const {
        std::string out = "cannot reach proximad at " + address + ": " + why;
        if (options.tls) {
            out +=
                " (over TLS: does the daemon serve TLS, does its certificate chain to the root "
                "CA and name the host or the server-name override";
            out += options.tls->client_cert_pem.empty()
                       ? ", does it want a client certificate (mutual TLS)?)"
                       : ", does it accept this client's certificate?)";
        }
        return out;
    }

    std::chrono::milliseconds backoff(const RetryOptions& retry, int attempt) {
        double cap = static_cast<double>(retry.initial_backoff.count()) *
                     std::pow(std::max(retry.multiplier, 1.0), attempt - 1);
        cap = std::min(cap, static_cast<double>(retry.max_backoff.count()));
        cap = std::max(cap, 0.0);
        if (!retry.jitter) {
            return std::chrono::milliseconds(static_cast<std::int64_t>(cap));
        }
        std::lock_guard lock(rng_mu);
        std::uniform_real_distribution<double> draw(0.0, cap);
        return std::chrono::milliseconds(static_cast<std::int64_t>(draw(rng)));
    }

    // Runs `attempt` (which returns a Status) under `retry`: an UNAVAILABLE answer, or a
    // connection that cannot be made, waits a backoff and tries again. `sent` tells whether the
    // failed attempt got as far as issuing the call (connected first), for Retry::unsent_only.
    // `committed` (if given) is set by an attempt once the caller has seen part of its answer
    // (a streamed event): a repeat would show it twice, so from then on nothing is retried.
    template <class Attempt>
    Status with_retries(const RetryOptions& retry, const std::string& operation, Retry policy,
                        Attempt&& attempt, const bool* committed = nullptr) {
        const auto start = std::chrono::steady_clock::now();
        for (int n = 1;; ++n) {
            bool sent = false;
            Status status = ensure_connected(options.connect_timeout);
            if (status.ok()) {
                sent = true;
                status = attempt();
            }
            if (status.code() != StatusCode::unavailable ||
                (sent && policy == Retry::unsent_only) || (committed && *committed)) {
                return status;
            }
            if (n >= std::max(retry.max_attempts, 1)) {
                return give_up(status, n, start);
            }
            const auto delay = backoff(retry, n);
            const auto elapsed = std::chrono::steady_clock::now() - start;
            if (retry.max_total.count() > 0 && elapsed + delay > retry.max_total) {
                return give_up(status, n, start);
            }
            if (retry.on_retry) {
                retry.on_retry(RetryEvent{operation, n, status, delay});
            }
            std::this_thread::sleep_for(delay);
        }
    }

    Status give_up(const Status& last, int attempts,
                   std::chrono::steady_clock::time_point start) const {
        if (attempts <= 1) {
            return last;
        }
        const auto took = std::chrono::duration_cast<std::chrono::milliseconds>(
            std::chrono::steady_clock::now() - start);
        return {last.code(), last.message() + " (" + std::to_string(attempts) + " attempts in " +
                                 milliseconds_text(took) + ")"};
    }

    // A unary RPC: a fresh context per attempt (a context serves one call only). `route` as for
    // prepare().
    template <class Call>
    Status unary(const std::string& operation, Retry policy, Call&& call,
                 const std::string& route = {}) {
        return with_retries(options.retry, operation, policy, [&] {
            grpc::ClientContext context;
            prepare(context, true, route);
            return from_grpc(call(context));
        });
    }
};

struct FrameStream::Impl {
    // Keeps the channel the call runs on alive (Client replaces a failed channel with a new one
    // while streams on the old one may still be finishing). Declared first: destroyed last.
    std::shared_ptr<pb::Proximity::Stub> stub;
    bool float32 = false;
    // Sent on every frame: the existing scene's id, or empty for a stream-owned scene (whose id
    // the first result names; later frames need not repeat it).
    std::string scene_id;
    grpc::ClientContext context;
    std::unique_ptr<grpc::ClientReaderWriter<pb::Frame, pb::FrameResult>> stream;
    // Results read ahead while closing after a failed write: they were sent by the server before
    // it ended the stream, so receive() still hands them out, in order, before the final status.
    std::deque<pb::FrameResult> read_ahead;
    std::size_t in_flight = 0;
    bool writes_done = false;
    bool finished = false;
    Status final_status;

    // Reads what is left, then collects the status. Only after WritesDone, a failed write or a
    // failed read: Finish would otherwise wait for a server that waits for us.
    void close() {
        if (finished) {
            return;
        }
        pb::FrameResult result;
        while (stream->Read(&result)) {
            read_ahead.push_back(std::move(result));
            result.Clear();
        }
        final_status = from_grpc(stream->Finish());
        finished = true;
    }

    Status ended_status() const {
        if (!final_status.ok()) {
            return final_status;
        }
        return {StatusCode::failed_precondition, "the frame stream has ended"};
    }
};

namespace {
Status upload_once(Client::Impl* impl, const std::string& scene_id, const NamedMesh& mesh,
                   bool float32, pb::ObjectInfo* info_out);
}  // namespace

// --- Client ----------------------------------------------------------------------------------

Client::Client(std::unique_ptr<Impl> impl) : m_impl(std::move(impl)) {}
Client::~Client() = default;

StatusOr<std::unique_ptr<Client>> Client::connect(const std::string& address,
                                                  ConnectOptions options) {
    if (auto st = check_token(options.token, "the token"); !st.ok()) {
        return st;
    }
    grpc::ChannelArguments args;
    // Results of big scenes (self distances per triangle) outgrow gRPC's 4 MiB default; the
    // server's own limits bound what it accepts, so the client does not cap either direction.
    args.SetMaxReceiveMessageSize(-1);
    args.SetMaxSendMessageSize(-1);
    // gRPC's own reconnect schedule (1 s, growing to 120 s) would leave a restarted daemon
    // unseen for long where a channel reconnects by itself (after a READY connection dropped);
    // ours is the one that counts (ensure_connected), so gRPC's is kept within the same bounds.
    const auto initial = std::max<std::int64_t>(options.retry.initial_backoff.count(), 1);
    args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, static_cast<int>(initial));
    args.SetInt(GRPC_ARG_MIN_RECONNECT_BACKOFF_MS, static_cast<int>(initial));
    args.SetInt(
        GRPC_ARG_MAX_RECONNECT_BACKOFF_MS,
        static_cast<int>(std::max<std::int64_t>(options.retry.max_backoff.count(), initial)));
    std::shared_ptr<grpc::ChannelCredentials> credentials;
    if (options.tls) {
        if (auto st = check_tls(*options.tls); !st.ok()) {
            return st;
        }
        grpc::SslCredentialsOptions ssl;
        ssl.pem_root_certs = options.tls->root_ca_pem;
        ssl.pem_cert_chain = options.tls->client_cert_pem;
        ssl.pem_private_key = options.tls->client_key_pem;
        credentials = grpc::SslCredentials(ssl);
        if (!options.tls->server_name_override.empty()) {
            args.SetSslTargetNameOverride(options.tls->server_name_override);
        }
    } else {
        credentials = grpc::InsecureChannelCredentials();
    }
    // Each channel its own subchannels: a replacement channel (ensure_connected) must dial
    // afresh, not inherit a failed subchannel and its backoff from the process-wide pool.
    args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
    auto impl = std::make_unique<Impl>();
    impl->address = address;
    impl->options = std::move(options);
    impl->explicit_route = !impl->options.route.empty();
    if (!impl->explicit_route) {
        // Every call of this Client reaches the same daemon behind a load balancer.
        impl->options.route = "client-" + random_route_suffix(impl->rng);
    }
    impl->credentials = std::move(credentials);
    impl->channel_args = args;
    impl->new_channel();
    // Connecting is always safe to repeat.
    if (auto st = impl->with_retries(impl->options.retry, "connect", Retry::idempotent,
                                     [] { return Status(); });
        !st.ok()) {
        return st;
    }
    return std::unique_ptr<Client>(new Client(std::move(impl)));
}

StatusOr<RemoteServerInfo> Client::server_info() {
    pb::ServerInfo info;
    if (auto st = m_impl->unary("GetServerInfo", Retry::idempotent,
                                [&](grpc::ClientContext& context) {
                                    return m_impl->stub_now()->GetServerInfo(
                                        &context, pb::GetServerInfoRequest(), &info);
                                });
        !st.ok()) {
        return st;
    }
    return detail::decode_server_info(info);
}

StatusOr<RemoteScene> Client::create_scene(const std::string& name,
                                           const std::vector<NamedMesh>& objects) {
    const bool float32 = m_impl->options.float32_vertices;
    const std::size_t budget = m_impl->options.inline_mesh_bytes;
    // Results list objects in creation order and uploads append, so only a leading run of
    // objects can travel inline: the first one too big for the budget and everything after it
    // are uploaded, in order.
    pb::CreateSceneRequest request;
    request.set_name(name);
    std::size_t inline_count = 0;
    std::size_t used = 0;
    for (; inline_count < objects.size(); ++inline_count) {
        const auto bytes = wire::encoded_mesh_bytes(objects[inline_count], float32);
        if (used + bytes > budget) {
            break;
        }
        used += bytes;
        wire::encode_mesh(objects[inline_count], float32, request.add_objects());
    }
    // Not idempotent: a repeat after a lost answer would leave a second scene behind.
    pb::SceneInfo info;
    if (auto st = m_impl->unary("CreateScene", Retry::unsent_only,
                                [&](grpc::ClientContext& context) {
                                    return m_impl->stub_now()->CreateScene(&context, request,
                                                                           &info);
                                });
        !st.ok()) {
        return st;
    }
    auto scene = detail::decode_scene(info);
    for (std::size_t i = inline_count; i < objects.size(); ++i) {
        auto object = upload_object(scene.scene_id, objects[i]);
        if (!object.ok()) {
            // A half-built scene is of no use to the caller and would hold the daemon's memory.
            (void)delete_scene(scene.scene_id);
            return object.status();
        }
        scene.triangle_count += object->triangle_count;
        scene.objects.push_back(std::move(object).value());
    }
    return scene;
}

StatusOr<RemoteScene> Client::describe_scene(const std::string& scene_id) {
    pb::DescribeSceneRequest request;
    request.set_scene_id(scene_id);
    pb::SceneInfo info;
    if (auto st = m_impl->unary("DescribeScene", Retry::idempotent,
                                [&](grpc::ClientContext& context) {
                                    return m_impl->stub_now()->DescribeScene(&context, request,
                                                                             &info);
                                });
        !st.ok()) {
        return st;
    }
    return detail::decode_scene(info);
}

Status Client::delete_scene(const std::string& scene_id) {
    pb::DeleteSceneRequest request;
    request.set_scene_id(scene_id);
    pb::DeleteSceneResponse response;
    // Repeating a delete cannot harm. A repeat that finds no scene means an earlier attempt (whose
    // answer was lost) or a daemon restart removed it: the caller's wish holds, so it is ok; only
    // a first attempt's NOT_FOUND (a wrong id) is reported.
    int attempts = 0;
    Status st = m_impl->unary("DeleteScene", Retry::idempotent, [&](grpc::ClientContext& context) {
        ++attempts;
        return m_impl->stub_now()->DeleteScene(&context, request, &response);
    });
    if (st.code() == StatusCode::not_found && attempts > 1) {
        return {};
    }
    return st;
}

StatusOr<RemoteObject> Client::upload_object(const std::string& scene_id, const NamedMesh& mesh) {
    const auto& vertices = mesh.mesh.vertices;
    const auto& triangles = mesh.mesh.triangles;
    constexpr auto MAX_COUNT = std::numeric_limits<std::uint32_t>::max();
    if (vertices.size() > MAX_COUNT || triangles.size() > MAX_COUNT) {
        return invalid_argument("object '" + mesh.name + "': " + std::to_string(vertices.size()) +
                                " vertices and " + std::to_string(triangles.size()) +
                                " triangles exceed the API's 32-bit counts");
    }
    const bool float32 = m_impl->options.float32_vertices;
    pb::ObjectInfo info;
    // Not idempotent (an upload appends): retried only when it never went out.
    Status status = m_impl->with_retries(
        m_impl->options.retry, "UploadObject", Retry::unsent_only,
        [&] { return upload_once(m_impl.get(), scene_id, mesh, float32, &info); });
    if (!status.ok()) {
        return status;
    }
    return detail::decode_object(info);
}

namespace {

Status upload_once(Client::Impl* impl, const std::string& scene_id, const NamedMesh& mesh,
                   bool float32, pb::ObjectInfo* info_out) {
    const auto& vertices = mesh.mesh.vertices;
    const auto& triangles = mesh.mesh.triangles;
    grpc::ClientContext context;
    impl->prepare(context);
    pb::ObjectInfo& info = *info_out;
    // The call uses its channel until Finish: hold it (the client may replace its channel).
    const auto stub = impl->stub_now();
    auto writer = stub->UploadObject(&context, &info);

    // A failed write means the server has ended the call: stop sending, Finish says why.
    bool open = true;
    auto write = [&](const pb::UploadChunk& chunk) { open = open && writer->Write(chunk); };

    pb::UploadChunk chunk;
    auto* header = chunk.mutable_header();
    header->set_scene_id(scene_id);
    header->set_name(mesh.name);
    header->set_type(wire::scalar_type(float32));
    header->set_vertex_count(static_cast<std::uint32_t>(vertices.size()));
    header->set_triangle_count(static_cast<std::uint32_t>(triangles.size()));
    write(chunk);

    const std::size_t stride = float32 ? wire::FLOAT32_VERTEX_BYTES : wire::FLOAT64_VERTEX_BYTES;
    const std::size_t vertices_per_chunk = UPLOAD_CHUNK_BYTES / stride;
    for (std::size_t first = 0; open && first < vertices.size(); first += vertices_per_chunk) {
        const auto count = std::min(vertices_per_chunk, vertices.size() - first);
        chunk.set_vertex_bytes(
            wire::pack_vertices(std::span<const Vec3>(vertices).subspan(first, count), float32));
        write(chunk);
    }
    const std::size_t triangles_per_chunk = UPLOAD_CHUNK_BYTES / wire::TRIANGLE_BYTES;
    for (std::size_t first = 0; open && first < triangles.size(); first += triangles_per_chunk) {
        const auto count = std::min(triangles_per_chunk, triangles.size() - first);
        chunk.set_index_bytes(wire::pack_triangles(
            std::span<const TriangleIndices>(triangles).subspan(first, count)));
        write(chunk);
    }
    if (open) {
        writer->WritesDone();
    }
    return from_grpc(writer->Finish());
}

}  // namespace

StatusOr<FrameResponse> Client::query(const std::string& scene_id, const FrameRequest& frame) {
    pb::Frame request;
    wire::encode_frame(frame, scene_id, m_impl->options.float32_vertices, &request);
    // Positions are absolute, so a frame that only moves vertices and asks questions leaves the
    // same scene when applied twice. Additions, removals and topology changes would not, and a
    // CCD frame interpolates from the positions before it, which a lost first attempt moved.
    const auto& u = frame.update;
    const bool repeatable =
        u.additions.empty() && u.removals.empty() && u.replacements.empty() && !frame.ccd;
    pb::FrameResult result;
    if (auto st = m_impl->unary("Query", repeatable ? Retry::idempotent : Retry::unsent_only,
                                [&](grpc::ClientContext& context) {
                                    return m_impl->stub_now()->Query(&context, request, &result);
                                });
        !st.ok()) {
        return st;
    }
    return detail::decode_frame_response(result);
}

namespace {

// One Snapshot call, for a scene's or a model region's request. `route` as for Impl::prepare.
StatusOr<render::Snapshot> snapshot_call(Client::Impl* impl, const pb::SnapshotRequest& message,
                                         const std::string& route = {}) {
    pb::SnapshotResponse response;
    // Snapshots change nothing: safe to repeat.
    if (auto st = impl->unary(
            "Snapshot", Retry::idempotent,
            [&](grpc::ClientContext& context) {
                return impl->stub_now()->Snapshot(&context, message, &response);
            },
            route);
        !st.ok()) {
        return st;
    }
    return wire::decode_snapshot(response);
}

}  // namespace

StatusOr<render::Snapshot> Client::snapshot(const std::string& scene_id,
                                            const render::SnapshotRequest& request) {
    pb::SnapshotRequest message;
    wire::encode_snapshot_request(scene_id, request, &message);
    return snapshot_call(m_impl.get(), message);
}

StatusOr<render::Snapshot> Client::snapshot_region(const massive::RegionRequest& region,
                                                   const render::SnapshotRequest& request) {
    pb::SnapshotRequest message;
    wire::encode_model_snapshot_request(region, request, &message);
    // A room's view lives on the daemon its members meet on: the room's name is the route (as for
    // fetch_region and join_review), unless the caller chose one.
    return snapshot_call(
        m_impl.get(), message,
        m_impl->explicit_route || region.room.empty() ? std::string() : region.room);
}

StatusOr<std::unique_ptr<FrameStream>> Client::open_stream(const std::string& scene_id) {
    auto impl = std::make_unique<FrameStream::Impl>();
    impl->float32 = m_impl->options.float32_vertices;
    impl->scene_id = scene_id;
    // Waiting for a connection (with the retry policy) is safe: nothing is sent yet. Streams are
    // not retried once open (frames change the scene; ResilientScene is the way to survive a
    // daemon going away).
    if (auto st = m_impl->with_retries(m_impl->options.retry, "StreamFrames", Retry::unsent_only,
                                       [] { return Status(); });
        !st.ok()) {
        return st;
    }
    // No deadline: a stream lives as long as the simulation. The call starts lazily; a daemon
    // that refuses it (unknown scene, too many streams) answers on the first receive().
    m_impl->prepare(impl->context, false);
    impl->stub = m_impl->stub_now();
    impl->stream = impl->stub->StreamFrames(&impl->context);
    if (!impl->stream) {
        return Status(StatusCode::internal, "could not start a frame stream");
    }
    return std::make_unique<FrameStream>(std::move(impl));
}

// --- FrameStream -----------------------------------------------------------------------------

FrameStream::FrameStream(std::unique_ptr<Impl> impl) : m_impl(std::move(impl)) {}

FrameStream::~FrameStream() {
    if (m_impl && !m_impl->finished) {
        // Cancelling first makes Finish return at once instead of waiting for the server to
        // answer frames nobody will read.
        m_impl->context.TryCancel();
        m_impl->final_status = from_grpc(m_impl->stream->Finish());
        m_impl->finished = true;
    }
}

Status FrameStream::send(const FrameRequest& frame) {
    auto& s = *m_impl;
    if (s.finished) {
        return s.ended_status();
    }
    if (s.writes_done) {
        return {StatusCode::failed_precondition, "send() after finish()"};
    }
    pb::Frame message;
    wire::encode_frame(frame, s.scene_id, s.float32, &message);
    if (!s.stream->Write(message)) {
        // The server ended the stream (a rejected frame, shutdown, cancellation): its status is
        // the useful answer, not "write failed".
        s.close();
        return s.final_status.ok()
                   ? Status(StatusCode::unavailable, "the server closed the frame stream")
                   : s.final_status;
    }
    ++s.in_flight;
    return {};
}

StatusOr<FrameResponse> FrameStream::receive() {
    auto& s = *m_impl;
    pb::FrameResult result;
    if (!s.read_ahead.empty()) {
        result = std::move(s.read_ahead.front());
        s.read_ahead.pop_front();
    } else if (s.finished) {
        return s.ended_status();
    } else if (s.in_flight == 0) {
        // Reading now would block forever: the server answers frames, it never speaks first.
        return Status(StatusCode::failed_precondition, "receive() with no frame in flight");
    } else if (!s.stream->Read(&result)) {
        s.close();
        return s.final_status.ok()
                   ? Status(StatusCode::internal,
                            "the server ended the frame stream without answering a frame")
                   : s.final_status;
    }
    if (s.in_flight > 0) {
        --s.in_flight;
    }
    return detail::decode_frame_response(result);
}

Status FrameStream::finish() {
    auto& s = *m_impl;
    if (!s.finished) {
        if (!s.writes_done) {
            s.stream->WritesDone();
            s.writes_done = true;
        }
        s.close();
    }
    // Results nobody asked for are dropped: finish() is the end of the conversation.
    s.read_ahead.clear();
    s.in_flight = 0;
    return s.final_status;
}

void FrameStream::cancel() {
    m_impl->context.TryCancel();
}

// --- Massive models ----------------------------------------------------------------------------

StatusOr<RemoteModelList> Client::list_models() {
    pb::ListModelsResponse response;
    if (auto st = m_impl->unary("ListModels", Retry::idempotent,
                                [&](grpc::ClientContext& context) {
                                    return m_impl->stub_now()->ListModels(
                                        &context, pb::ListModelsRequest(), &response);
                                });
        !st.ok()) {
        return st;
    }
    return detail::decode_model_list(response);
}

StatusOr<RemoteVerifySummary> Client::verify_model(
    const std::string& model, double tolerance,
    const std::function<bool(const VerifyEvent&)>& on_event, std::chrono::milliseconds timeout) {
    pb::VerifyModelRequest request;
    request.set_model(model);
    request.set_tolerance(tolerance);
    std::optional<RemoteVerifySummary> summary;
    bool stopped = false;
    // Verification only reads, so a call that failed before the caller saw any event is repeated;
    // after one, a repeat would hand out the same events again.
    bool delivered = false;
    Status status = m_impl->with_retries(
        m_impl->options.retry, "VerifyModel", Retry::idempotent,
        [&] {
            grpc::ClientContext context;
            m_impl->prepare(context, false);
            if (timeout.count() > 0) {
                context.set_deadline(deadline_after(timeout));
            }
            const auto stub = m_impl->stub_now();  // held until Finish, like the channel
            auto reader = stub->VerifyModel(&context, request);
            pb::VerifyModelEvent event;
            while (reader->Read(&event)) {
                if (stopped) {
                    continue;  // cancelled: drain what is in flight until the call ends
                }
                VerifyEvent out;
                switch (event.event_case()) {
                    case pb::VerifyModelEvent::kProgress:
                        out.kind = VerifyEvent::Kind::progress;
                        out.progress = wire::decode_progress(event.progress());
                        break;
                    case pb::VerifyModelEvent::kPair:
                        out.kind = VerifyEvent::Kind::pair;
                        out.pair = detail::decode_object_pair(event.pair());
                        break;
                    case pb::VerifyModelEvent::kSummary:
                        summary = detail::decode_verify_summary(event.summary());
                        continue;
                    default:
                        continue;
                }
                delivered = true;
                if (on_event && !on_event(out)) {
                    stopped = true;
                    context.TryCancel();
                }
            }
            return from_grpc(reader->Finish());
        },
        &delivered);
    if (stopped) {
        return Status(StatusCode::cancelled, "verification cancelled by the caller");
    }
    if (!status.ok()) {
        return status;
    }
    if (!summary) {
        return Status(StatusCode::internal, "the server ended VerifyModel without a summary");
    }
    return *summary;
}

StatusOr<RegionSummary> Client::fetch_region(
    const RegionRequest& region, const std::function<bool(const RegionEvent&)>& on_event,
    std::chrono::milliseconds timeout) {
    pb::FetchRegionRequest request;
    wire::encode_region_request(region, &request);
    std::optional<RegionSummary> summary;
    bool stopped = false;
    Status malformed;
    // A region fetch only reads, so a call that failed before the caller saw any event is
    // repeated; after one, a repeat would hand out the same pieces again.
    bool delivered = false;
    Status status = m_impl->with_retries(
        m_impl->options.retry, "FetchRegion", Retry::idempotent,
        [&] {
            grpc::ClientContext context;
            // A room's view lives on the daemon its members meet on: the room's name is the
            // route (as for join_review), unless the caller chose one.
            m_impl->prepare(
                context, false,
                m_impl->explicit_route || region.room.empty() ? std::string() : region.room);
            if (timeout.count() > 0) {
                context.set_deadline(deadline_after(timeout));
            }
            const auto stub = m_impl->stub_now();  // held until Finish, like the channel
            auto reader = stub->FetchRegion(&context, request);
            pb::RegionEvent event;
            while (reader->Read(&event)) {
                if (stopped) {
                    continue;  // cancelled: drain what is in flight until the call ends
                }
                auto decoded = wire::decode_region_event(event);
                if (!decoded.ok()) {
                    malformed = decoded.status();
                    stopped = true;
                    context.TryCancel();
                    continue;
                }
                if (auto* s = std::get_if<RegionSummary>(&decoded.value())) {
                    summary = std::move(*s);
                    continue;
                }
                delivered = true;
                if (on_event && !on_event(decoded.value())) {
                    stopped = true;
                    context.TryCancel();
                }
            }
            return from_grpc(reader->Finish());
        },
        &delivered);
    if (!malformed.ok()) {
        return malformed;
    }
    if (stopped) {
        return Status(StatusCode::cancelled, "region fetch cancelled by the caller");
    }
    if (!status.ok()) {
        return status;
    }
    if (!summary) {
        return Status(StatusCode::internal, "the server ended FetchRegion without a summary");
    }
    return *summary;
}

// A reader thread moves events from the stream into `events`: at most MAX_QUEUED ordered events
// (past that it waits for next(), so the daemon's flow control and bounds apply rather than this
// queue growing) and at most one update per peer (a newer one replaces it, as in the daemon's
// outbox: the reader keeps reading, so a member's own answers never queue behind peer updates).
// Writes happen on the caller's thread under `write_mu`, which the reader also takes for Finish
// (gRPC wants no write in progress while Finish runs).
struct ReviewSession::Impl {
    static constexpr std::size_t MAX_QUEUED = 64;

    // Keeps the call's channel alive (see FrameStream::Impl). Declared first: destroyed last.
    std::shared_ptr<pb::Proximity::Stub> stub;
    bool float32 = false;
    grpc::ClientContext context;
    std::unique_ptr<grpc::ClientReaderWriter<pb::ReviewRequest, pb::ReviewEvent>> stream;
    ReviewJoined joined;

    std::mutex write_mu;
    bool writes_done = false;  // guarded by write_mu

    std::mutex mu;
    std::condition_variable changed;
    std::deque<StatusOr<ReviewEvent>> events;  // guarded by mu
    // guarded by mu: how many of `events` are not peer updates (only those count against
    // MAX_QUEUED: peer updates coalesce, at most one per peer)
    std::size_t ordered = 0;
    bool ended = false;    // guarded by mu: Finish has returned
    bool discard = false;  // guarded by mu: drop events (finishing)
    // guarded by mu: wait_result is waiting for a result; other events need not wake it (with
    // many room members most events are peer updates, and waking the caller for each one cost
    // more than the rest of the client: it takes them all, in order, when the result comes)
    bool result_only = false;
    Status final_status;  // guarded by mu
    std::thread reader;

    // Queues one event the reader decoded (mu held).
    void take_locked(std::unique_lock<std::mutex>& lock, StatusOr<ReviewEvent> decoded) {
        if (decoded.ok() && decoded->kind == ReviewEvent::Kind::peer) {
            // As the daemon's outbox does: a peer's update not yet taken is replaced by the
            // newer one, at the end. So the reader never stops for peer updates, and the
            // member's own answers never wait behind a backlog of them in the transport.
            if (!discard) {
                const auto stale = std::find_if(events.begin(), events.end(), [&](auto& e) {
                    return e.ok() && e->kind == ReviewEvent::Kind::peer &&
                           e->peer.member == decoded->peer.member;
                });
                if (stale != events.end()) {
                    events.erase(stale);
                }
                events.push_back(std::move(decoded));
                if (!result_only) {
                    changed.notify_all();
                }
            }
            return;
        }
        changed.wait(lock, [&] { return discard || ordered < MAX_QUEUED; });
        if (!discard) {
            const bool wake = !result_only || !decoded.ok() ||
                              decoded->kind == ReviewEvent::Kind::result ||
                              ordered + 1 >= MAX_QUEUED;
            events.push_back(std::move(decoded));
            ++ordered;
            if (wake) {
                changed.notify_all();
            }
        }
    }

    void read_loop() {
        pb::ReviewEvent event;
        while (stream->Read(&event)) {
            // A `peers` message holds several updates: each is taken as its own peer event.
            auto decoded = detail::decode_review_events(event);
            std::unique_lock lock(mu);
            if (!decoded.ok()) {
                take_locked(lock, decoded.status());
                continue;
            }
            for (auto& e : *decoded) {
                take_locked(lock, std::move(e));
            }
        }
        Status status;
        {
            std::lock_guard writes(write_mu);
            status = from_grpc(stream->Finish());
            writes_done = true;  // no write after Finish
        }
        std::lock_guard lock(mu);
        ended = true;
        final_status = status;
        changed.notify_all();
    }

    // A failed write means the daemon ended the call: the reader collects its status, which
    // is the answer here once known (and always from next()).
    Status write(const pb::ReviewRequest& request) {
        {
            std::lock_guard writes(write_mu);
            if (!writes_done) {
                if (stream->Write(request)) {
                    return {};
                }
                writes_done = true;
            }
        }
        std::lock_guard lock(mu);
        if (ended && !final_status.ok()) {
            return final_status;
        }
        return {StatusCode::failed_precondition,
                ended ? "the review stream has ended"
                      : "the review stream is ending (next() returns its final status)"};
    }

    // The oldest event (events not empty; mu held).
    StatusOr<ReviewEvent> pop_locked() {
        auto event = std::move(events.front());
        events.pop_front();
        if (!(event.ok() && event->kind == ReviewEvent::Kind::peer)) {
            --ordered;
        }
        changed.notify_all();  // the reader may wait for room in the queue
        return event;
    }

    void stop_reader() {
        if (reader.joinable()) {
            reader.join();
        }
    }
};

StatusOr<std::unique_ptr<ReviewSession>> Client::join_review(const ReviewJoin& join,
                                                             std::chrono::milliseconds timeout) {
    auto impl = std::make_unique<ReviewSession::Impl>();
    impl->float32 = m_impl->options.float32_vertices;
    // A join adds a member to a room: only the wait for a connection is retried.
    if (auto st = m_impl->with_retries(m_impl->options.retry, "Review", Retry::unsent_only,
                                       [] { return Status(); });
        !st.ok()) {
        return st;
    }
    // A review room's members must meet on one daemon: the room's name is their route,
    // unless the caller chose one.
    m_impl->prepare(impl->context, false,
                    m_impl->explicit_route || join.room.empty() ? std::string() : join.room);
    impl->stub = m_impl->stub_now();
    impl->stream = impl->stub->Review(&impl->context);
    if (!impl->stream) {
        return Status(StatusCode::internal, "could not start a review stream");
    }
    pb::ReviewRequest request;
    wire::encode_review_join(join, impl->float32, &request);
    auto* raw = impl.get();
    impl->reader = std::thread([raw] { raw->read_loop(); });
    auto session = std::make_unique<ReviewSession>(std::move(impl));
    if (Status s = raw->write(request); !s.ok()) {
        return s;
    }
    auto first = session->next(timeout);
    if (!first.ok()) {
        return first.status();
    }
    if (first->kind != ReviewEvent::Kind::joined) {
        return Status(StatusCode::internal, "the server answered join with another event");
    }
    raw->joined = std::move(first->joined);
    return session;
}

ReviewSession::ReviewSession(std::unique_ptr<Impl> impl) : m_impl(std::move(impl)) {}

ReviewSession::~ReviewSession() {
    if (!m_impl) {
        return;
    }
    {
        std::lock_guard lock(m_impl->mu);
        m_impl->discard = true;
        m_impl->changed.notify_all();
        if (!m_impl->ended) {
            m_impl->context.TryCancel();
        }
    }
    m_impl->stop_reader();
}

const ReviewJoined& ReviewSession::joined() const {
    return m_impl->joined;
}

Status ReviewSession::send_pose(std::uint64_t sequence, const massive::Affine& pose) {
    pb::ReviewRequest request;
    wire::encode_review_pose({sequence, pose}, &request);
    return m_impl->write(request);
}

Status ReviewSession::move_object(std::uint64_t sequence, std::uint32_t object,
                                  const massive::Affine& transform) {
    massive::ReviewEditRequest edit;
    edit.sequence = sequence;
    edit.what = massive::EditKind::move;
    edit.object = object;
    edit.transform = transform;
    pb::ReviewRequest request;
    wire::encode_review_edit(edit, m_impl->float32, &request);
    return m_impl->write(request);
}

Status ReviewSession::add_object(std::uint64_t sequence, const NamedMesh& object) {
    massive::ReviewEditRequest edit;
    edit.sequence = sequence;
    edit.what = massive::EditKind::add;
    edit.added = object;
    pb::ReviewRequest request;
    wire::encode_review_edit(edit, m_impl->float32, &request);
    return m_impl->write(request);
}

Status ReviewSession::delete_object(std::uint64_t sequence, std::uint32_t object) {
    massive::ReviewEditRequest edit;
    edit.sequence = sequence;
    edit.what = massive::EditKind::remove;
    edit.object = object;
    pb::ReviewRequest request;
    wire::encode_review_edit(edit, m_impl->float32, &request);
    return m_impl->write(request);
}

StatusOr<ReviewEvent> ReviewSession::next(std::chrono::milliseconds timeout) {
    auto& s = *m_impl;
    std::unique_lock lock(s.mu);
    if (!s.changed.wait_for(lock, timeout, [&] { return !s.events.empty() || s.ended; })) {
        return Status(StatusCode::deadline_exceeded,
                      "no review event within " + std::to_string(timeout.count()) + " ms");
    }
    if (!s.events.empty()) {
        return s.pop_locked();
    }
    return s.final_status.ok()
               ? Status(StatusCode::failed_precondition, "the review stream has ended")
               : s.final_status;
}

StatusOr<ReviewPoseResult> ReviewSession::wait_result(
    std::uint64_t sequence, const std::function<void(const ReviewEvent&)>& other,
    std::chrono::milliseconds timeout) {
    // next()'s loop, except that the reader wakes this thread only for a result, an error, the
    // end or a full queue (Impl::result_only), and each wake-up takes every queued event.
    auto& s = *m_impl;
    const auto until = std::chrono::steady_clock::now() + timeout;
    std::unique_lock lock(s.mu);
    s.result_only = true;
    for (;;) {
        if (!s.changed.wait_until(lock, until, [&] { return !s.events.empty() || s.ended; })) {
            s.result_only = false;
            return Status(StatusCode::deadline_exceeded,
                          "no review event within " + std::to_string(timeout.count()) + " ms");
        }
        if (s.events.empty()) {
            s.result_only = false;
            return s.final_status.ok()
                       ? Status(StatusCode::failed_precondition, "the review stream has ended")
                       : s.final_status;
        }
        auto event = s.pop_locked();
        if (!event.ok()) {
            s.result_only = false;
            return event.status();
        }
        if (event->kind == ReviewEvent::Kind::result && event->result.sequence == sequence) {
            s.result_only = false;
            return std::move(event->result);
        }
        if (other) {
            lock.unlock();
            other(event.value());
            lock.lock();
        }
    }
}

Status ReviewSession::finish() {
    auto& s = *m_impl;
    {
        std::lock_guard writes(s.write_mu);
        if (!s.writes_done) {
            s.stream->WritesDone();
            s.writes_done = true;
        }
    }
    {
        std::lock_guard lock(s.mu);
        s.discard = true;
        s.events.clear();
        s.ordered = 0;
        s.changed.notify_all();
    }
    s.stop_reader();
    std::lock_guard lock(s.mu);
    return s.final_status;
}

void ReviewSession::cancel() {
    m_impl->context.TryCancel();
}

// --- ResilientScene --------------------------------------------------------------------------

namespace {

// Whether a frame stream's failure means "the daemon went away": UNAVAILABLE (a direct connection
// broke), CANCELLED that this client did not ask for, or UNKNOWN without any gRPC status (the
// HTTP/2 stream ended with no grpc-status: gRPC reports "No status received" or "Stream
// removed"). A ResilientScene's stream has no deadline, and the session cancels it only when it
// ends (after which nothing recovers), so any CANCELLED it sees comes from between: behind HAProxy
// a killed backend's stream ends with "Received RST_STREAM with error code 8" (CANCELLED) or
// without a status (UNKNOWN), not UNAVAILABLE (docs/deploy.md). A daemon's own UNKNOWN always
// carries its status, so it is not taken for one.
bool daemon_gone(const Status& status) {
    switch (status.code()) {
        case StatusCode::unavailable:
        case StatusCode::cancelled:
            return true;
        default: {
            // UNKNOWN reaches the engine's codes as internal, "gRPC UNKNOWN: message" (from_grpc).
            std::string name;
            std::string rest;
            return split_grpc_prefix(status, &name, &rest) && name == "UNKNOWN" &&
                   (rest == "No status received" || rest == "Stream removed");
        }
    }
}

// The same failure as UNAVAILABLE, so the recovery's retry policy treats it as one.
Status as_unavailable(const Status& status) {
    if (!daemon_gone(status) || status.code() == StatusCode::unavailable) {
        return status;
    }
    return {StatusCode::unavailable,
            "the stream ended on the way, not by this client or the daemon: " + status.message()};
}

}  // namespace

struct ResilientScene::Impl {
    // One object of the session's copy of the scene, in result order.
    struct Tracked {
        ObjectId session = 0;
        NamedMesh mesh;
    };
    // A frame sent and not yet answered, in the caller's (session) ids.
    struct Pending {
        FrameRequest frame;
        bool resent = false;  // already re-sent on a re-created scene
    };

    Client* client = nullptr;
    ResilientSceneOptions options;
    std::string name;
    std::string scene_id;
    std::unique_ptr<FrameStream> stream;
    std::vector<Tracked> objects;
    // Session <-> daemon ids. Identity until a re-created scene numbers objects differently.
    std::unordered_map<ObjectId, ObjectId> to_daemon;
    std::unordered_map<ObjectId, ObjectId> to_session;
    bool remapped = false;
    ObjectId next_session = 1;
    std::deque<Pending> pending;
    // Answers taken from a failed stream during recovery (the old daemon sent them before it
    // went away), or the errors of frames lost with the session; handed out before anything new.
    std::deque<StatusOr<FrameResponse>> ready;
    std::uint64_t recreations = 0;
    bool mark_next = false;  // the next answer from the new stream is flagged recreated_scene
    bool ended = false;
    Status final_status;

    void learn(ObjectId daemon_id, ObjectId session_id) {
        to_daemon[session_id] = daemon_id;
        to_session[daemon_id] = session_id;
        next_session = std::max(next_session, session_id + 1);
    }

    void forget(ObjectId session_id) {
        auto it = to_daemon.find(session_id);
        if (it != to_daemon.end()) {
            to_session.erase(it->second);
            to_daemon.erase(it);
        }
    }

    // A daemon id the session has not seen: before any remapping the daemon's own ids serve (so
    // a session that never lost its daemon shows exactly the daemon's ids); after, fresh ones.
    ObjectId adopt(ObjectId daemon_id) {
        const ObjectId session_id = remapped ? next_session : daemon_id;
        learn(daemon_id, session_id);
        return session_id;
    }

    StatusOr<ObjectId> daemon_id(ObjectId session_id) const {
        auto it = to_daemon.find(session_id);
        if (it != to_daemon.end()) {
            return it->second;
        }
        if (!remapped) {
            return session_id;  // the daemon judges ids it does not know (NOT_FOUND)
        }
        return not_found("object " + std::to_string(session_id) +
                         " is not in the session's scene (as of the last answered frame)");
    }

    StatusOr<FrameRequest> to_wire(const FrameRequest& frame) const {
        FrameRequest out = frame;
        for (auto& id : out.update.removals) {
            auto d = daemon_id(id);
            if (!d.ok()) {
                return d.status();
            }
            id = d.value();
        }
        for (auto& r : out.update.replacements) {
            auto d = daemon_id(r.object);
            if (!d.ok()) {
                return d.status();
            }
            r.object = d.value();
        }
        for (auto& p : out.update.positions) {
            auto d = daemon_id(p.object);
            if (!d.ok()) {
                return d.status();
            }
            p.object = d.value();
        }
        return out;
    }

    // The answer to the oldest pending frame: new ids learnt, the session's copy brought to the
    // state after the frame (the engine's order: removals, replacements, positions, additions),
    // ids translated, and the copy checked against the daemon's object list.
    StatusOr<FrameResponse> accept(FrameResponse response) {
        const FrameRequest frame = std::move(pending.front().frame);
        pending.pop_front();
        const auto& u = frame.update;
        if (response.added_ids.size() != u.additions.size() ||
            response.fragment_ids.size() != u.replacements.size()) {
            return Status(StatusCode::internal,
                          "the daemon's answer to frame " + std::to_string(frame.frame) +
                              " lists ids for other changes than the frame made");
        }
        for (std::size_t i = 0; i < u.replacements.size(); ++i) {
            if (response.fragment_ids[i].size() != u.replacements[i].fragments.size()) {
                return Status(StatusCode::internal, "the daemon's answer to frame " +
                                                        std::to_string(frame.frame) +
                                                        " has the wrong number of fragment ids");
            }
        }
        auto index_of = [&](ObjectId session_id) -> std::ptrdiff_t {
            for (std::size_t i = 0; i < objects.size(); ++i) {
                if (objects[i].session == session_id) {
                    return static_cast<std::ptrdiff_t>(i);
                }
            }
            return -1;
        };
        // Removals and replacements name objects in session ids (the caller's).
        for (auto id : u.removals) {
            if (auto i = index_of(id); i >= 0) {
                objects.erase(objects.begin() + i);
            }
            forget(id);
        }
        for (std::size_t r = 0; r < u.replacements.size(); ++r) {
            const auto& rep = u.replacements[r];
            auto i = index_of(rep.object);
            forget(rep.object);
            std::vector<Tracked> fragments;
            for (std::size_t f = 0; f < rep.fragments.size(); ++f) {
                const ObjectId s = adopt(response.fragment_ids[r][f]);
                response.fragment_ids[r][f] = s;
                fragments.push_back({s, rep.fragments[f]});
            }
            if (i >= 0) {
                objects.erase(objects.begin() + i);
                objects.insert(objects.begin() + i, fragments.begin(), fragments.end());
            }
        }
        for (const auto& p : u.positions) {
            if (auto i = index_of(p.object); i >= 0) {
                objects[static_cast<std::size_t>(i)].mesh.mesh.vertices = p.vertices;
            }
        }
        for (std::size_t a = 0; a < u.additions.size(); ++a) {
            const ObjectId s = adopt(response.added_ids[a]);
            response.added_ids[a] = s;
            objects.push_back({s, u.additions[a]});
        }
        bool same = response.object_ids.size() == objects.size();
        for (std::size_t i = 0; same && i < objects.size(); ++i) {
            auto it = to_session.find(response.object_ids[i]);
            same = it != to_session.end() && it->second == objects[i].session;
            if (same) {
                response.object_ids[i] = it->second;
            }
        }
        if (!same) {
            return Status(StatusCode::internal,
                          "after frame " + std::to_string(frame.frame) +
                              " the daemon's scene and the session's copy differ");
        }
        response.scene_id = scene_id;
        if (mark_next) {
            response.recreated_scene = true;
            mark_next = false;
        }
        return response;
    }

    void end(const Status& status) {
        ended = true;
        final_status = status;
        if (stream) {
            stream->cancel();
            (void)stream->finish();
        }
        // Every frame still in flight gets this outcome, in order: none vanishes.
        while (!pending.empty()) {
            pending.pop_front();
            ready.push_back(status);
        }
    }

    std::vector<NamedMesh> meshes() const {
        std::vector<NamedMesh> out;
        out.reserve(objects.size());
        for (const auto& o : objects) {
            out.push_back(o.mesh);
        }
        return out;
    }

    // After `cause` (unavailable) on the stream: keep what the old stream still holds, then
    // reconnect with backoff, re-create the scene from the session's copy, re-send the frames in
    // flight (once each). Ends the session when that cannot be done.
    void recover(const Status& cause) {
        // Answers the old daemon sent before it went away are still good (and in order).
        while (!pending.empty()) {
            auto r = stream->receive();
            if (!r.ok()) {
                break;
            }
            ready.push_back(accept(std::move(r).value()));
        }
        (void)stream->finish();
        stream.reset();
        for (const auto& p : pending) {
            if (p.resent) {
                end(Status(StatusCode::unavailable,
                           "the daemon went away again before answering frame " +
                               std::to_string(p.frame.frame) +
                               ", already re-sent on a re-created scene: " + cause.message()));
                return;
            }
        }
        const std::string old_scene = scene_id;
        auto& c = *client->m_impl;
        bool ids_remapped = false;
        Status status = c.with_retries(options.recovery, "recover scene", Retry::idempotent, [&] {
            // The old scene goes first: if the daemon survived (a dropped connection), it may
            // hold frames we never saw answered; a fresh scene from our copy is the state the
            // caller saw. NOT_FOUND (a restarted daemon) is the usual answer. (After a failed
            // attempt, `scene_id` is that attempt's scene, which goes the same way.)
            {
                grpc::ClientContext context;
                c.prepare(context);
                pb::DeleteSceneRequest request;
                request.set_scene_id(scene_id);
                pb::DeleteSceneResponse response;
                auto st = from_grpc(c.stub_now()->DeleteScene(&context, request, &response));
                if (st.code() == StatusCode::unavailable) {
                    return st;
                }
            }
            auto created = client->create_scene(name, meshes());
            if (!created.ok()) {
                return created.status();
            }
            if (created->objects.size() != objects.size()) {
                return Status(StatusCode::internal, "the re-created scene has " +
                                                        std::to_string(created->objects.size()) +
                                                        " objects, the session's copy " +
                                                        std::to_string(objects.size()));
            }
            scene_id = created->scene_id;
            // The new daemon numbers objects its own way: check and remap.
            bool identity = true;
            ObjectId highest = 0;
            for (std::size_t i = 0; i < objects.size(); ++i) {
                identity = identity && created->objects[i].id == objects[i].session;
                highest = std::max(highest, created->objects[i].id);
            }
            // Identity also needs the daemon's next ids to be unused by the session (ids of
            // objects removed earlier must not come back).
            if (!identity || highest + 1 < next_session) {
                remapped = true;
                ids_remapped = true;
            }
            to_daemon.clear();
            to_session.clear();
            for (std::size_t i = 0; i < objects.size(); ++i) {
                learn(created->objects[i].id, objects[i].session);
            }
            auto opened = client->open_stream(scene_id);
            if (!opened.ok()) {
                return opened.status();
            }
            stream = std::move(opened).value();
            for (auto& p : pending) {
                auto wire = to_wire(p.frame);
                if (!wire.ok()) {
                    return wire.status();
                }
                if (auto st = stream->send(wire.value()); !st.ok()) {
                    return as_unavailable(st);
                }
            }
            return Status();
        });
        if (!status.ok()) {
            end(status.code() == StatusCode::unavailable
                    ? Status(StatusCode::unavailable,
                             "could not re-create the scene after the daemon went away (" +
                                 cause.message() + "): " + status.message())
                    : status);
            return;
        }
        for (auto& p : pending) {
            p.resent = true;
        }
        ++recreations;
        mark_next = !pending.empty();
        if (options.on_recreated) {
            options.on_recreated(SceneRecreation{old_scene, scene_id, recreations, pending.size(),
                                                 cause, ids_remapped});
        }
    }
};

StatusOr<std::unique_ptr<ResilientScene>> ResilientScene::create(
    Client& client, const std::string& name, const std::vector<NamedMesh>& objects,
    ResilientSceneOptions options) {
    auto created = client.create_scene(name, objects);
    if (!created.ok()) {
        return created.status();
    }
    auto impl = std::make_unique<Impl>();
    impl->client = &client;
    impl->options = std::move(options);
    impl->name = name;
    impl->scene_id = created->scene_id;
    for (std::size_t i = 0; i < objects.size(); ++i) {
        impl->objects.push_back({created->objects[i].id, objects[i]});
        impl->learn(created->objects[i].id, created->objects[i].id);
    }
    auto stream = client.open_stream(impl->scene_id);
    if (!stream.ok()) {
        (void)client.delete_scene(impl->scene_id);
        return stream.status();
    }
    impl->stream = std::move(stream).value();
    return std::make_unique<ResilientScene>(std::move(impl));
}

ResilientScene::ResilientScene(std::unique_ptr<Impl> impl) : m_impl(std::move(impl)) {}

ResilientScene::~ResilientScene() {
    if (!m_impl) {
        return;
    }
    if (m_impl->stream) {
        m_impl->stream->cancel();
        (void)m_impl->stream->finish();
    }
    if (!m_impl->scene_id.empty()) {
        // One attempt: a destructor must not sleep through a backoff schedule.
        auto& c = *m_impl->client->m_impl;
        grpc::ClientContext context;
        c.prepare(context);
        if (c.options.call_timeout.count() == 0) {
            context.set_deadline(deadline_after(c.options.connect_timeout));
        }
        pb::DeleteSceneRequest request;
        request.set_scene_id(m_impl->scene_id);
        pb::DeleteSceneResponse response;
        (void)c.stub_now()->DeleteScene(&context, request, &response);
    }
}

const std::string& ResilientScene::scene_id() const {
    return m_impl->scene_id;
}

std::vector<ObjectId> ResilientScene::object_ids() const {
    std::vector<ObjectId> out;
    out.reserve(m_impl->objects.size());
    for (const auto& o : m_impl->objects) {
        out.push_back(o.session);
    }
    return out;
}

std::uint64_t ResilientScene::recreations() const {
    return m_impl->recreations;
}

Status ResilientScene::send(const FrameRequest& frame) {
    auto& s = *m_impl;
    if (s.ended) {
        return s.final_status.ok()
                   ? Status(StatusCode::failed_precondition, "the resilient scene has ended")
                   : s.final_status;
    }
    auto wire = s.to_wire(frame);
    if (!wire.ok()) {
        return wire.status();
    }
    // From here the frame is the session's: whatever happens, receive() gives its outcome.
    s.pending.push_back({frame, false});
    Status sent = s.stream->send(wire.value());
    if (sent.ok()) {
        return {};
    }
    if (daemon_gone(sent)) {
        s.recover(
            as_unavailable(sent));  // re-sends this frame too, or ends the session with its outcome
        return {};
    }
    // The daemon ended the stream for another reason (an earlier frame rejected, a quota):
    // its answers up to the failure stay readable, then each frame in flight gets the status.
    while (!s.pending.empty()) {
        auto r = s.stream->receive();
        if (!r.ok()) {
            break;
        }
        s.ready.push_back(s.accept(std::move(r).value()));
    }
    s.end(sent);
    return {};
}

StatusOr<FrameResponse> ResilientScene::receive() {
    auto& s = *m_impl;
    for (;;) {
        if (!s.ready.empty()) {
            auto r = std::move(s.ready.front());
            s.ready.pop_front();
            return r;
        }
        if (s.ended) {
            return s.final_status.ok()
                       ? Status(StatusCode::failed_precondition, "the resilient scene has ended")
                       : s.final_status;
        }
        if (s.pending.empty()) {
            return Status(StatusCode::failed_precondition, "receive() with no frame in flight");
        }
        auto r = s.stream->receive();
        if (r.ok()) {
            return s.accept(std::move(r).value());
        }
        if (daemon_gone(r.status())) {
            s.recover(as_unavailable(r.status()));
            continue;
        }
        // A rejected frame (or any other error) ends the stream: this frame gets the status,
        // later ones too (the daemon answered none of them).
        s.pending.pop_front();
        s.ready.push_front(r.status());
        s.end(r.status());
    }
}

StatusOr<FrameResponse> ResilientScene::step(const FrameRequest& frame) {
    if (auto st = send(frame); !st.ok()) {
        return st;
    }
    return receive();
}

Status ResilientScene::finish() {
    auto& s = *m_impl;
    Status status;
    if (s.stream) {
        status = s.stream->finish();
        s.stream.reset();
    }
    s.pending.clear();
    s.ready.clear();
    if (!s.ended) {
        s.ended = true;
        s.final_status = status;
    }
    if (!s.scene_id.empty()) {
        Status deleted = s.client->delete_scene(s.scene_id);
        s.scene_id.clear();
        if (status.ok()) {
            status = deleted;
        }
    }
    return status;
}

}  // namespace proxima::client
