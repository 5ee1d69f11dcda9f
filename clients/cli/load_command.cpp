// proxima load: the load-test harness (issue #16). Drives one or more proximad with a mix of
// clients for a bounded time and number of calls, then stops by itself and reports per call kind
// the figures of a ghz JSON report (count, total, average, fastest, slowest, rps, histogram,
// latencyDistribution, statusCodeDistribution, errorDistribution), a one-screen text summary,
// optionally a PNG plot drawn by gnuplot, and the daemons' Prometheus samples over the run.
//
//   proxima load --server ADDR [--server ADDR ...] [--duration 30s] [--warmup 2s]
//                [--clients sim=N,frames=N,review=N,verify=N] [--scene S[,S...]]
//                [--queries Q[,Q...]] [--tolerance D] [--rate FPS] [--episode-frames N]
//                [--frames DIR ...] [--sequence DIR ...] [--model NAME] [--edit-every N]
//                [--metrics URL ...]
//                [--max-calls N] [--plot FILE.png] [--json | --out FILE] [--quiet]
//
// Client kinds (docs/load.md):
//   sim     streams a built-in seed scene over StreamFrames in episodes of --episode-frames
//           frames (the first frame creates the stream-owned scene: call kind sim_scene; the
//           others move vertices, or change topology: sim_frame), asking the --queries.
//   frames  a real frame pair (--frames DIR, e.g. ../shared/data/frames): CreateScene with t0
//           (pair_scene), then frames moving every vertex to t1, back to t0, ... (pair_frame).
//   review  joins a review room on a served massive model with a box avatar and walks it along a
//           generated loop through the model (review_join, review_pose); with --edit-every N,
//           every other reviewer moves an object every N-th step (review_edit: until the room's
//           edit_applied comes back).
//   verify  static verification of the whole model (VerifyModel), one call after the other.
//   play    a recorded sequence (--sequence DIR: numbered mesh files, an MD2 model, a sequence
//           with topology changes from `proxima generate sequence`), played through the daemon
//           as `proxima play --server` plays it (the same player: CreateScene with the first
//           frame, play_scene; one stream, every frame a diff of the previous one, play_frame),
//           then again from the start.
// --rate FPS paces each sim, frames and review client (open loop: a call's latency runs from the
// moment it was due, so a slow daemon is not hidden by the client waiting for it); 0 is closed
// loop. Paced clients start at evenly spread phases of the period, so the daemon sees an evenly
// spaced aggregate rate (as ghz's --rps), not every client's call at the same instant.

#include <netdb.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cctype>
#include <charconv>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <numbers>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli/commands.hpp"
#include "cli/id_map.hpp"
#include "client/proxima_client.hpp"
#include "common/player.hpp"
#include "common/progress.hpp"
#include "common/sequence.hpp"
#include "proxima/scenes/procedural.hpp"

namespace proxima::cli {

namespace {

using Clock = std::chrono::steady_clock;

constexpr std::size_t MAX_CLIENTS = 256;
constexpr std::size_t MAX_ERROR_MESSAGES = 100;  // distinct messages in errorDistribution

// --- Arguments ---------------------------------------------------------------------------------

struct LoadArgs {
    std::vector<std::string> servers;
    ServerFlags server_flags;
    std::string duration = "30s";
    std::string warmup = "2s";
    std::string clients = "sim=4";
    std::string scenes = "all";
    std::string queries = "separation";
    double tolerance = 0.01;
    double rate = 0.0;
    std::size_t episode_frames = 32;
    std::string model;
    std::size_t edit_every = 10;
    std::vector<std::string> frame_dirs;
    std::vector<std::string> sequence_dirs;
    std::vector<std::string> metrics;
    std::uint64_t max_calls = 1000000;
    std::string plot;
    JsonOutput output;
    bool quiet = false;
};

// "30s", "500ms", "2m", "1h", or a plain number of seconds; > 0 unless `allow_zero`.
std::optional<double> parse_duration(const std::string& text, bool allow_zero) {
    double v = 0;
    const char* begin = text.data();
    const char* end = text.data() + text.size();
    const auto parsed = std::from_chars(begin, end, v);
    if (text.empty() || parsed.ec != std::errc() || !std::isfinite(v) || v < 0) {
        return std::nullopt;
    }
    const std::string unit(parsed.ptr, end);
    double scale = 0;
    if (unit.empty() || unit == "s") {
        scale = 1;
    } else if (unit == "ms") {
        scale = 1e-3;
    } else if (unit == "m" || unit == "min") {
        scale = 60;
    } else if (unit == "h") {
        scale = 3600;
    } else {
        return std::nullopt;
    }
    if (v == 0 && !allow_zero) {
        return std::nullopt;
    }
    return v * scale;
}

CLI::Validator duration_text(bool allow_zero) {
    return {[allow_zero](std::string& text) -> std::string {
                if (!parse_duration(text, allow_zero)) {
                    return std::string("expected a duration") + (allow_zero ? "" : " > 0") +
                           " such as 30s, 500ms, 2m or 1h, got '" + text + "'";
                }
                return {};
            },
            "DURATION (30s, 500ms, 2m)", "duration_text"};
}

std::vector<std::string> split_list(const std::string& text) {
    std::vector<std::string> out;
    std::stringstream in(text);
    for (std::string item; std::getline(in, item, ',');) {
        out.push_back(item);
    }
    return out;
}

struct ClientMix {
    std::size_t sim = 0;
    std::size_t frames = 0;
    std::size_t review = 0;
    std::size_t verify = 0;
    std::size_t play = 0;
    std::size_t total() const { return sim + frames + review + verify + play; }
};

// "sim=8,review=4": the clients of each kind; the message for a bad one.
std::variant<ClientMix, std::string> parse_clients(const std::string& text) {
    ClientMix mix;
    for (const auto& item : split_list(text)) {
        const auto eq = item.find('=');
        const std::string kind = item.substr(0, eq);
        std::size_t count = 0;
        if (eq == std::string::npos) {
            return "--clients: expected KIND=COUNT items separated by commas (e.g. "
                   "sim=8,review=4), got '" +
                   item + "'";
        }
        const std::string number = item.substr(eq + 1);
        const auto parsed = std::from_chars(number.data(), number.data() + number.size(), count);
        if (number.empty() || parsed.ec != std::errc() ||
            parsed.ptr != number.data() + number.size() || count > MAX_CLIENTS) {
            return "--clients: '" + item + "': the count must be a whole number from 0 to " +
                   std::to_string(MAX_CLIENTS);
        }
        if (kind == "sim") {
            mix.sim = count;
        } else if (kind == "frames") {
            mix.frames = count;
        } else if (kind == "review") {
            mix.review = count;
        } else if (kind == "verify") {
            mix.verify = count;
        } else if (kind == "play") {
            mix.play = count;
        } else {
            return "--clients: unknown client kind '" + kind +
                   "' (expected sim, frames, review, verify or play)";
        }
    }
    if (mix.total() == 0) {
        return "--clients: no clients (e.g. --clients sim=8,review=4)";
    }
    if (mix.total() > MAX_CLIENTS) {
        return "--clients: " + std::to_string(mix.total()) + " clients; at most " +
               std::to_string(MAX_CLIENTS);
    }
    return mix;
}

struct QueryMix {
    QueryRequest request;
    bool ccd = false;
    std::vector<std::string> names;
};

std::variant<QueryMix, std::string> parse_queries(const std::string& text, double tolerance) {
    QueryMix mix;
    mix.request.separation = false;
    for (const auto& q : split_list(text)) {
        if (q == "separation") {
            mix.request.separation = true;
        } else if (q == "self") {
            mix.request.self = true;
        } else if (q == "collisions") {
            mix.request.collisions = true;
        } else if (q == "tolerance") {
            mix.request.tolerance = tolerance;
        } else if (q == "ccd") {
            mix.ccd = true;
        } else {
            return "--queries: unknown query '" + q +
                   "' (expected separation, self, collisions, tolerance or ccd)";
        }
        mix.names.push_back(q);
    }
    if (mix.names.empty()) {
        return std::string("--queries: no query named");
    }
    return mix;
}

// --- Metrics endpoint --------------------------------------------------------------------------

struct MetricsTarget {
    std::string host;
    std::string port;
    std::string path = "/metrics";
    std::string shown;  // as given
};

std::string host_of(const std::string& address) {
    const auto colon = address.rfind(':');
    std::string host = colon == std::string::npos ? address : address.substr(0, colon);
    if (host.size() >= 2 && host.front() == '[' && host.back() == ']') {
        host = host.substr(1, host.size() - 2);
    }
    return host;
}

bool loopback(const std::string& host) {
    return host == "localhost" || host == "::1" || host.rfind("127.", 0) == 0;
}

// "http://HOST:PORT/metrics" or "HOST:PORT" (path /metrics). Only loopback hosts and the hosts of
// the --server addresses: the harness reads nothing the operator did not name.
std::variant<MetricsTarget, std::string> parse_metrics(const std::string& text,
                                                       const std::vector<std::string>& servers) {
    MetricsTarget t;
    t.shown = text;
    std::string rest = text;
    if (rest.rfind("http://", 0) == 0) {
        rest = rest.substr(7);
    } else if (rest.find("://") != std::string::npos) {
        return "--metrics '" + text + "': only http:// is supported";
    }
    if (const auto slash = rest.find('/'); slash != std::string::npos) {
        t.path = rest.substr(slash);
        rest = rest.substr(0, slash);
    }
    const auto colon = rest.rfind(':');
    if (colon == std::string::npos || colon + 1 == rest.size()) {
        return "--metrics '" + text + "': expected http://HOST:PORT/metrics or HOST:PORT";
    }
    t.host = host_of(rest);
    t.port = rest.substr(colon + 1);
    bool allowed = loopback(t.host);
    for (const auto& s : servers) {
        allowed = allowed || host_of(s) == t.host;
    }
    if (!allowed) {
        return "--metrics '" + text +
               "': the host must be a loopback address or the host of a --server";
    }
    return t;
}

// GET over a plain socket with 2 s timeouts; the body, or the reason it failed.
StatusOr<std::string> http_get(const MetricsTarget& t) {
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* found = nullptr;
    if (getaddrinfo(t.host.c_str(), t.port.c_str(), &hints, &found) != 0 || found == nullptr) {
        return Status(StatusCode::unavailable,
                      "metrics endpoint " + t.shown + ": cannot resolve " + t.host);
    }
    const int fd = socket(found->ai_family, found->ai_socktype, found->ai_protocol);
    timeval timeout{2, 0};
    bool connected = false;
    if (fd >= 0) {
        setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof(timeout));
        setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &timeout, sizeof(timeout));
        connected = connect(fd, found->ai_addr, found->ai_addrlen) == 0;
    }
    freeaddrinfo(found);
    if (!connected) {
        if (fd >= 0) {
            close(fd);
        }
        return Status(StatusCode::unavailable, "metrics endpoint " + t.shown + ": cannot connect");
    }
    const std::string request = "GET " + t.path + " HTTP/1.1\r\nHost: " + t.host + ":" + t.port +
                                "\r\nConnection: close\r\n\r\n";
    if (write(fd, request.data(), request.size()) != static_cast<ssize_t>(request.size())) {
        close(fd);
        return Status(StatusCode::unavailable,
                      "metrics endpoint " + t.shown + ": cannot send the request");
    }
    std::string response;
    std::array<char, 8192> buffer{};
    for (ssize_t n = 0; (n = read(fd, buffer.data(), buffer.size())) > 0;) {
        response.append(buffer.data(), static_cast<std::size_t>(n));
        if (response.size() > (64u << 20)) {
            break;
        }
    }
    close(fd);
    const auto body = response.find("\r\n\r\n");
    if (response.rfind("HTTP/1.", 0) != 0 || body == std::string::npos ||
        response.find(" 200 ") > response.find("\r\n")) {
        return Status(StatusCode::unavailable,
                      "metrics endpoint " + t.shown + ": no HTTP 200 answer");
    }
    return response.substr(body + 4);
}

// The sum of every series of `name` (all label sets); none when the family is absent.
std::optional<double> metric_sum(const std::string& text, const std::string& name) {
    std::optional<double> sum;
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);) {
        if (line.empty() || line[0] == '#' || line.rfind(name, 0) != 0 ||
            (line.size() > name.size() && line[name.size()] != '{' && line[name.size()] != ' ')) {
            continue;
        }
        const auto space = line.rfind(' ');
        double v = 0;
        const char* begin = line.data() + space + 1;
        if (space != std::string::npos &&
            std::from_chars(begin, line.data() + line.size(), v).ec == std::errc()) {
            sum = sum.value_or(0) + v;
        }
    }
    return sum;
}

// The metrics each sample keeps, report name -> Prometheus name.
const std::array<std::pair<const char*, const char*>, 9> SAMPLED = {{
    {"rss_bytes", "process_resident_memory_bytes"},
    {"cpu_seconds", "process_cpu_seconds_total"},
    {"cache_resident_bytes", "proxima_cache_resident_bytes"},
    {"cache_hits", "proxima_cache_hits_total"},
    {"cache_misses", "proxima_cache_misses_total"},
    {"cache_loads", "proxima_cache_loads_total"},
    {"cache_evictions", "proxima_cache_evictions_total"},
    {"live_streams", "proxima_live_streams"},
    {"frames", "proxima_frames_total"},
}};

struct MetricsSample {
    double t = 0;  // seconds since the run began
    std::size_t target = 0;
    std::array<std::optional<double>, SAMPLED.size()> values;
};

// This process's CPU time so far (user + system, every thread), seconds.
double own_cpu_seconds() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    auto seconds = [](const timeval& t) {
        return static_cast<double>(t.tv_sec) + static_cast<double>(t.tv_usec) * 1e-6;
    };
    return seconds(u.ru_utime) + seconds(u.ru_stime);
}

// --- Recording ---------------------------------------------------------------------------------

enum Kind : int {
    sim_scene,
    sim_frame,
    pair_scene,
    pair_frame,
    review_join,
    review_pose,
    review_edit,
    verify_model,
    play_scene,
    play_frame
};
constexpr int KIND_COUNT = 10;
const std::array<const char*, KIND_COUNT> KIND_NAMES = {
    "sim_scene",   "sim_frame",   "pair_scene",   "pair_frame", "review_join",
    "review_pose", "review_edit", "verify_model", "play_scene", "play_frame"};

struct Call {
    double start = 0;          // seconds since the run began (when the call was due)
    std::int64_t latency = 0;  // nanoseconds
    std::int64_t server = -1;  // nanoseconds the daemon reports it spent (-1: not reported)
    int kind = 0;
    std::string code;     // "OK" or the gRPC code name
    std::string message;  // describe_status of a failure
};

struct Shared {
    const LoadArgs* args = nullptr;
    QueryMix queries;
    std::vector<std::string> scenes;
    client::ConnectOptions options;
    Clock::time_point start;
    Clock::time_point end;
    std::size_t per_client_cap = 0;
    std::atomic<bool> stop{false};
    std::mutex mu;
    std::condition_variable cv;
    std::array<std::atomic<std::uint64_t>, KIND_COUNT> counts{};
    std::atomic<std::uint64_t> errors{0};
    std::size_t running = 0;  // client threads not yet returned (guarded by mu)
    // The streams in flight, cancelled when the run ends and they do not finish in time.
    std::mutex cancel_mu;
    std::map<const void*, std::function<void()>> cancels;

    // Sleeps until `t`; false when the run is stopping.
    bool sleep_until(Clock::time_point t) {
        std::unique_lock lock(mu);
        return !cv.wait_until(lock, t, [this] { return stop.load(); });
    }
    double since_start(Clock::time_point t) const {
        return std::chrono::duration<double>(t - start).count();
    }
};

// While alive, the run's end may cancel the stream (TryCancel, safe from another thread).
class CancelHook {
  public:
    CancelHook(Shared& shared, std::function<void()> cancel) : m_shared(shared) {
        std::lock_guard lock(m_shared.cancel_mu);
        m_shared.cancels[this] = std::move(cancel);
    }
    ~CancelHook() {
        std::lock_guard lock(m_shared.cancel_mu);
        m_shared.cancels.erase(this);
    }
    CancelHook(const CancelHook&) = delete;
    CancelHook& operator=(const CancelHook&) = delete;

  private:
    Shared& m_shared;
};

class Recorder {
  public:
    explicit Recorder(Shared& shared) : m_shared(shared) {}
    // Records a call due at `due` that ended now; false once the client has made its share. A
    // call the end of the run cancelled is not a figure.
    // `server_seconds`: the daemon's own time for the call where it reports one (< 0: none).
    bool record(int kind, Clock::time_point due, const Status& status,
                double server_seconds = -1.0) {
        if (m_shared.stop.load() && status.code() == StatusCode::cancelled) {
            return false;
        }
        const auto now = Clock::now();
        Call c;
        c.start = m_shared.since_start(due);
        c.latency = std::chrono::duration_cast<std::chrono::nanoseconds>(now - due).count();
        if (server_seconds >= 0.0) {
            c.server = static_cast<std::int64_t>(server_seconds * 1e9);
        }
        c.kind = kind;
        if (status.ok()) {
            c.code = "OK";
        } else {
            c.code = client::grpc_code_name(status);
            c.message = client::describe_status(status);
            m_shared.errors.fetch_add(1, std::memory_order_relaxed);
        }
        m_shared.counts[static_cast<std::size_t>(kind)].fetch_add(1, std::memory_order_relaxed);
        calls.push_back(std::move(c));
        return calls.size() < m_shared.per_client_cap;
    }
    bool running() const { return !m_shared.stop.load() && calls.size() < m_shared.per_client_cap; }
    // The client's calls: its own thread's until the thread is joined.
    std::vector<Call> calls;

  private:
    Shared& m_shared;
};

// Paces a client: closed loop (rate 0) returns now; open loop the next due time, waiting for it.
// Calls at `rate` per second from now + phase / rate (phase in [0, 1)): the run gives each paced
// client its own phase, so N clients at rate r send an evenly spaced N * r calls per second (as
// ghz's --rps does), not N calls at once every 1/r seconds.
class Pacer {
  public:
    Pacer(Shared& shared, double rate, double phase)
        : m_shared(shared),
          m_rate(rate),
          m_t0(Clock::now() + (rate > 0 ? std::chrono::duration_cast<Clock::duration>(
                                              std::chrono::duration<double>(phase / rate))
                                        : Clock::duration::zero())) {}
    std::optional<Clock::time_point> next() {
        if (m_rate <= 0) {
            return m_shared.stop.load() ? std::nullopt : std::optional(Clock::now());
        }
        const auto due =
            m_t0 + std::chrono::duration_cast<Clock::duration>(
                       std::chrono::duration<double>(static_cast<double>(m_n++) / m_rate));
        if (!m_shared.sleep_until(due)) {
            return std::nullopt;
        }
        return due;
    }

  private:
    Shared& m_shared;
    double m_rate;
    Clock::time_point m_t0;
    std::uint64_t m_n = 0;
};

// After a failed call: a short pause before the client starts over (no busy loop on a daemon
// that refuses everything).
void back_off(Shared& shared) {
    shared.sleep_until(Clock::now() + std::chrono::milliseconds(200));
}

// --- Clients -----------------------------------------------------------------------------------

StatusOr<std::unique_ptr<client::Client>> connect_client(Shared& shared,
                                                         const std::string& server) {
    return client::Client::connect(server, shared.options);
}

void run_sim(Shared& shared, Recorder& rec, const std::string& server, std::size_t index,
             double phase) {
    auto c = connect_client(shared, server);
    while (!c.ok() && rec.running()) {
        rec.record(sim_scene, Clock::now(), c.status());
        back_off(shared);
        c = connect_client(shared, server);
    }
    if (!c.ok()) {
        return;
    }
    const auto& scene_name = shared.scenes[index % shared.scenes.size()];
    Pacer pacer(shared, shared.args->rate, phase);
    while (rec.running()) {
        auto scene = scenes::by_name(scene_name, shared.args->episode_frames);
        auto opened = c.value()->open_stream("");
        if (!opened.ok()) {
            rec.record(sim_scene, Clock::now(), opened.status());
            back_off(shared);
            continue;
        }
        auto& stream = *opened.value();
        const CancelHook hook(shared, [&stream] { stream.cancel(); });
        Scene mirror;
        IdMap ids;
        bool broken = false;
        for (std::size_t k = 0; k < scene.frame_count && rec.running() && !broken; ++k) {
            SceneUpdate local = k == 0 ? SceneUpdate{} : scene.step(k, mirror);
            if (k == 0) {
                local.additions = scene.initial;
            }
            client::FrameRequest frame;
            frame.frame = k;
            frame.queries = shared.queries.request;
            // CCD needs a frame that only moves vertices.
            frame.ccd = shared.queries.ccd && k > 0 && local.additions.empty() &&
                        local.removals.empty() && local.replacements.empty();
            auto translated = ids.translate(local);
            auto applied = translated.ok() ? mirror.apply(local)
                                           : StatusOr<SceneUpdateResult>(translated.status());
            if (!applied.ok()) {
                rec.record(k == 0 ? sim_scene : sim_frame, Clock::now(), applied.status());
                broken = true;
                break;
            }
            frame.update = std::move(translated).value();
            const auto due = pacer.next();
            if (!due) {
                break;
            }
            Status status = stream.send(frame);
            StatusOr<client::FrameResponse> response = status;
            if (status.ok()) {
                response = stream.receive();
                status = response.status();
            }
            if (status.ok()) {
                status = ids.update(local, applied.value(), response.value());
            }
            rec.record(k == 0 ? sim_scene : sim_frame, *due, status);
            broken = !status.ok();
        }
        if (broken) {
            stream.cancel();
            back_off(shared);
        } else {
            (void)stream.finish();
        }
    }
}

// --- Real frame pairs --------------------------------------------------------------------------

struct LoadedPair {
    std::string name;  // the directory
    FramePair frames;
};

bool mesh_file(const std::filesystem::path& p) {
    std::string name = p.filename().string();
    if (name.size() > 3 && name.substr(name.size() - 3) == ".gz") {
        name = name.substr(0, name.size() - 3);
    }
    const auto dot = name.rfind('.');
    if (dot == std::string::npos) {
        return false;
    }
    std::string ext = name.substr(dot + 1);
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
    return ext == "ply" || ext == "off" || ext == "obj" || ext == "stl" || ext == "gltf" ||
           ext == "glb";
}

// The mesh files directly in `dir`, by name.
std::vector<std::filesystem::path> meshes_in(const std::filesystem::path& dir) {
    std::vector<std::filesystem::path> out;
    std::error_code ec;
    for (const auto& e : std::filesystem::directory_iterator(dir, ec)) {
        if (e.is_regular_file() && mesh_file(e.path())) {
            out.push_back(e.path());
        }
    }
    std::sort(out.begin(), out.end());
    return out;
}

// --frames DIR: a directory with two mesh files (t0 and t1, in name order), or one whose
// subdirectories are such pairs (../shared/data/frames). Each file is one scene, split into its
// connected components.
StatusOr<std::vector<LoadedPair>> load_pairs(const std::vector<std::string>& dirs) {
    std::vector<LoadedPair> out;
    for (const auto& d : dirs) {
        std::error_code ec;
        if (!std::filesystem::is_directory(d, ec)) {
            return not_found("--frames " + d + ": not a directory");
        }
        std::vector<std::filesystem::path> pair_dirs;
        if (meshes_in(d).size() == 2) {
            pair_dirs.emplace_back(d);
        } else {
            for (const auto& e : std::filesystem::directory_iterator(d, ec)) {
                if (e.is_directory() && meshes_in(e.path()).size() == 2) {
                    pair_dirs.push_back(e.path());
                }
            }
            std::sort(pair_dirs.begin(), pair_dirs.end());
        }
        if (pair_dirs.empty()) {
            return invalid_argument("--frames " + d +
                                    ": neither two mesh files (t0, t1) nor subdirectories "
                                    "holding two each");
        }
        for (const auto& p : pair_dirs) {
            const auto files = meshes_in(p);
            auto frames = load_frame_pair(files[0].string(), files[1].string(), true,
                                          WeldMode::triangle_soups);
            if (!frames.ok()) {
                return frames.status();
            }
            out.push_back({p.string(), std::move(frames).value()});
        }
    }
    return out;
}

// One scene of a real frame pair (CreateScene with the t0 objects: pair_scene), then frames over
// one stream moving every vertex to t1, back to t0, and so on (pair_frame), with the --queries.
void run_pair(Shared& shared, Recorder& rec, const std::string& server, const LoadedPair& pair,
              double phase) {
    auto c = connect_client(shared, server);
    while (!c.ok() && rec.running()) {
        rec.record(pair_scene, Clock::now(), c.status());
        back_off(shared);
        c = connect_client(shared, server);
    }
    if (!c.ok()) {
        return;
    }
    std::vector<NamedMesh> meshes;
    for (const auto& o : pair.frames.objects) {
        meshes.push_back(o.mesh);
    }
    Pacer pacer(shared, shared.args->rate, phase);
    while (rec.running()) {
        const auto created_at = Clock::now();
        auto scene = c.value()->create_scene("proxima load", meshes);
        rec.record(pair_scene, created_at, scene.status());
        if (!scene.ok()) {
            back_off(shared);
            continue;
        }
        auto opened = c.value()->open_stream(scene->scene_id);
        Status status = opened.status();
        std::optional<CancelHook> hook;
        if (opened.ok()) {
            client::FrameStream* stream = opened.value().get();
            hook.emplace(shared, [stream] { stream->cancel(); });
        }
        for (std::uint64_t k = 1; status.ok() && rec.running(); ++k) {
            client::FrameRequest frame;
            frame.frame = k;
            frame.queries = shared.queries.request;
            frame.ccd = shared.queries.ccd;
            for (std::size_t i = 0; i < meshes.size(); ++i) {
                frame.update.positions.push_back(
                    {scene->objects[i].id,
                     k % 2 == 1 ? pair.frames.positions_t1[i] : meshes[i].mesh.vertices});
            }
            const auto due = pacer.next();
            if (!due) {
                break;
            }
            status = opened.value()->send(frame);
            if (status.ok()) {
                status = opened.value()->receive().status();
            }
            rec.record(pair_frame, *due, status);
        }
        if (opened.ok()) {
            if (status.ok()) {
                (void)opened.value()->finish();
            } else {
                opened.value()->cancel();
            }
        } else {
            rec.record(pair_frame, Clock::now(), status);
        }
        (void)c.value()->delete_scene(scene->scene_id);
        if (!status.ok()) {
            back_off(shared);
        }
    }
}

// --- Recorded sequences --------------------------------------------------------------------------

// One recorded sequence played through the daemon by the player of `proxima play --server`, over
// and over: the scene's creation is a play_scene call (the player's setup time), each frame a
// play_frame call (its latency from the moment it was due: the player's send-to-answer time plus
// how late --rate pacing sent it). A frame the player rejects (an answer that does not fit the
// frame's objects) is an error like a failed call.
void run_play(Shared& shared, Recorder& rec, const std::string& server,
              const client::Sequence& sequence) {
    auto c = connect_client(shared, server);
    while (!c.ok() && rec.running()) {
        rec.record(play_scene, Clock::now(), c.status());
        back_off(shared);
        c = connect_client(shared, server);
    }
    if (!c.ok()) {
        return;
    }
    client::PlayOptions options;
    options.queries = shared.queries.request;
    options.ccd = shared.queries.ccd;
    options.fps = shared.args->rate;
    options.keep_results = false;
    const Status run_over(StatusCode::cancelled, "the load run is over");
    options.on_setup = [&](double setup_ms) {
        const auto due = Clock::now() - std::chrono::duration_cast<Clock::duration>(
                                            std::chrono::duration<double, std::milli>(setup_ms));
        return rec.record(play_scene, due, {}) ? Status{} : run_over;
    };
    options.on_frame = [&](const client::PlayedFrame& f) {
        const auto due =
            Clock::now() - std::chrono::duration_cast<Clock::duration>(
                               std::chrono::duration<double, std::milli>(f.latency_ms + f.late_ms));
        return rec.record(play_frame, due, {}) ? Status{} : run_over;
    };
    while (rec.running()) {
        const auto started = Clock::now();
        auto report = client::play_remote(*c.value(), sequence, options);
        if (!report.ok() && !(report.status().code() == StatusCode::cancelled &&
                              report.status().message() == run_over.message())) {
            rec.record(play_frame, started, report.status());
            back_off(shared);
        }
    }
}

// A closed box of half-size h around the origin (the reviewers' avatar).
NamedMesh box_avatar(double h) {
    NamedMesh box;
    box.name = "load-avatar";
    for (int k = 0; k < 8; ++k) {
        box.mesh.vertices.push_back(
            {(k & 1) != 0 ? h : -h, (k & 2) != 0 ? h : -h, (k & 4) != 0 ? h : -h});
    }
    box.mesh.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                          {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
    return box;
}

struct ModelInfo {
    std::string name;
    Aabb box;
    std::uint64_t objects = 0;
};

// Reviewer `index` of `count`: a loop around the model's centre at its own height and phase.
massive::Affine review_pose_at(const ModelInfo& model, std::size_t index, std::size_t count,
                               std::uint64_t step) {
    const Vec3 lo = model.box.lo;
    const Vec3 hi = model.box.hi;
    const double phase = 2.0 * std::numbers::pi * static_cast<double>(index) /
                         static_cast<double>(std::max<std::size_t>(count, 1));
    const double angle = phase + 2.0 * std::numbers::pi * static_cast<double>(step % 400) / 400.0;
    const double height = 0.25 + 0.5 * std::fmod(0.618 * static_cast<double>(index), 1.0);
    massive::Affine pose;
    pose.m[3] = 0.5 * (lo.x + hi.x) + 0.35 * (hi.x - lo.x) * std::cos(angle);
    pose.m[7] = 0.5 * (lo.y + hi.y) + 0.35 * (hi.y - lo.y) * std::sin(angle);
    pose.m[11] = lo.z + height * (hi.z - lo.z);
    return pose;
}

void run_review(Shared& shared, Recorder& rec, const std::string& server, const ModelInfo& model,
                std::size_t index, std::size_t count, double phase) {
    const auto wait = std::chrono::seconds(10);
    auto c = connect_client(shared, server);
    while (!c.ok() && rec.running()) {
        rec.record(review_join, Clock::now(), c.status());
        back_off(shared);
        c = connect_client(shared, server);
    }
    if (!c.ok()) {
        return;
    }
    const Vec3 extent = model.box.hi - model.box.lo;
    client::ReviewJoin join;
    join.room = "load-" + std::to_string(getpid());
    join.model = model.name;
    join.member = "load-" + std::to_string(getpid()) + "-review-" + std::to_string(index);
    join.avatar = box_avatar(0.01 * std::max({extent.x, extent.y, extent.z, 1e-9}));
    join.tolerance = shared.args->tolerance;
    join.nearest = true;
    const bool editor = shared.args->edit_every > 0 && index % 2 == 1 && model.objects > 0;
    Pacer pacer(shared, shared.args->rate, phase);
    std::uint64_t step = 0;
    std::uint64_t edits = 0;
    while (rec.running()) {
        const auto joined_at = Clock::now();
        auto session = c.value()->join_review(join, wait);
        rec.record(review_join, joined_at, session.status());
        if (!session.ok()) {
            back_off(shared);
            continue;
        }
        auto& review = *session.value();
        const CancelHook hook(shared, [&review] { review.cancel(); });
        std::uint64_t sequence = 0;
        Status status;
        while (status.ok() && rec.running()) {
            const auto due = pacer.next();
            if (!due) {
                break;
            }
            ++sequence;
            ++step;
            if (editor && step % shared.args->edit_every == 0) {
                // Moves an object away and back on alternate edits: the room's model stays near
                // the stored one.
                massive::Affine move;
                if (edits % 2 == 0) {
                    move.m[3] = 0.001 * extent.x;
                }
                const auto object =
                    static_cast<std::uint32_t>((index * 7919 + edits / 2) % model.objects);
                ++edits;
                status = review.move_object(sequence, object, move);
                while (status.ok()) {
                    auto event = review.next(wait);
                    if (!event.ok()) {
                        status = event.status();
                    } else if (event->kind == client::ReviewEvent::Kind::edit_applied &&
                               event->edit.member == join.member &&
                               event->edit.sequence == sequence) {
                        break;
                    }
                }
                rec.record(review_edit, *due, status);
                continue;
            }
            status = review.send_pose(sequence, review_pose_at(model, index, count, step));
            double server_seconds = -1.0;
            if (status.ok()) {
                auto result = review.wait_result(sequence, {}, wait);
                status = result.status();
                if (result.ok()) {
                    server_seconds = result->server_seconds;
                }
            }
            rec.record(review_pose, *due, status, server_seconds);
        }
        if (!status.ok()) {
            review.cancel();
            back_off(shared);
        } else {
            (void)review.finish();
        }
    }
}

void run_verify(Shared& shared, Recorder& rec, const std::string& server, const ModelInfo& model) {
    auto c = connect_client(shared, server);
    while (!c.ok() && rec.running()) {
        rec.record(verify_model, Clock::now(), c.status());
        back_off(shared);
        c = connect_client(shared, server);
    }
    while (c.ok() && rec.running()) {
        const auto start = Clock::now();
        // A deadline at the end of the run's grace: a whole-model verification that sends no
        // event for a while still ends with the run.
        const auto deadline = std::chrono::duration_cast<std::chrono::milliseconds>(
            shared.end - start + std::chrono::seconds(2));
        auto summary = c.value()->verify_model(
            model.name, shared.args->tolerance,
            [&](const client::VerifyEvent&) { return !shared.stop.load(); },
            std::max(deadline, std::chrono::milliseconds(1)));
        if (!summary.ok() && shared.stop.load()) {
            break;  // cut short by the end of the run: not a figure
        }
        rec.record(verify_model, start, summary.status());
        if (!summary.ok()) {
            back_off(shared);
        }
    }
}

// Samples every endpoint at the start, once a second, and once more at the end.
void run_metrics(Shared& shared, const std::vector<MetricsTarget>& targets,
                 std::vector<MetricsSample>& samples, std::uint64_t& failures) {
    bool last = false;
    for (std::uint64_t n = 1; !last; ++n) {
        last = !shared.sleep_until(shared.start + std::chrono::seconds(n - 1));
        for (std::size_t i = 0; i < targets.size(); ++i) {
            MetricsSample s;
            s.t = shared.since_start(Clock::now());
            s.target = i;
            auto text = http_get(targets[i]);
            if (!text.ok()) {
                ++failures;
                continue;
            }
            for (std::size_t k = 0; k < SAMPLED.size(); ++k) {
                s.values[k] = metric_sum(text.value(), SAMPLED[k].second);
            }
            samples.push_back(s);
        }
    }
}

// --- Report ------------------------------------------------------------------------------------

// Nearest rank: the smallest latency with at least q of them at or below it.
std::int64_t rank(const std::vector<std::int64_t>& sorted, double q) {
    const auto k = static_cast<std::size_t>(std::ceil(q * static_cast<double>(sorted.size())));
    return sorted[std::min(sorted.size() - 1, k == 0 ? 0 : k - 1)];
}

// p50, p90, p99, p99.9 and max of sorted, non-empty nanoseconds.
nlohmann::json percentiles_json(const std::vector<std::int64_t>& sorted) {
    return {{"p50", rank(sorted, 0.50)},
            {"p90", rank(sorted, 0.90)},
            {"p99", rank(sorted, 0.99)},
            {"p99.9", rank(sorted, 0.999)},
            {"max", sorted.back()}};
}

// ghz's report fields (runner.Report) for these calls over `seconds` of measured time.
nlohmann::json ghz_json(const std::vector<const Call*>& calls, double seconds) {
    std::vector<std::int64_t> latencies;
    latencies.reserve(calls.size());
    std::map<std::string, std::uint64_t> codes;
    std::map<std::string, std::uint64_t> errors;
    for (const auto* c : calls) {
        latencies.push_back(c->latency);
        ++codes[c->code];
        if (!c->message.empty()) {
            if (errors.size() < MAX_ERROR_MESSAGES || errors.count(c->message) != 0) {
                ++errors[c->message];
            } else {
                ++errors["(other messages)"];
            }
        }
    }
    std::sort(latencies.begin(), latencies.end());
    const auto n = latencies.size();
    nlohmann::json j = {{"count", n},
                        {"total", static_cast<std::int64_t>(seconds * 1e9)},
                        {"rps", seconds > 0 ? static_cast<double>(n) / seconds : 0.0},
                        {"statusCodeDistribution", codes},
                        {"errorDistribution", errors}};
    if (n == 0) {
        j["average"] = 0;
        j["fastest"] = 0;
        j["slowest"] = 0;
        j["histogram"] = nlohmann::json::array();
        j["latencyDistribution"] = nlohmann::json::array();
        j["percentiles"] = nullptr;
        return j;
    }
    long double sum = 0;
    for (auto v : latencies) {
        sum += static_cast<long double>(v);
    }
    const std::int64_t fastest = latencies.front();
    const std::int64_t slowest = latencies.back();
    j["average"] = static_cast<std::int64_t>(sum / static_cast<long double>(n));
    j["fastest"] = fastest;
    j["slowest"] = slowest;
    // ghz's histogram: 10 equal steps from the fastest to the slowest, each bucket counting the
    // latencies up to its mark (seconds), the last mark the slowest.
    constexpr int BUCKETS = 10;
    std::array<double, BUCKETS + 1> marks{};
    std::array<std::uint64_t, BUCKETS + 1> counts{};
    const double width = static_cast<double>(slowest - fastest) / BUCKETS;
    for (int i = 0; i < BUCKETS; ++i) {
        marks[static_cast<std::size_t>(i)] = static_cast<double>(fastest) + width * i;
    }
    marks[BUCKETS] = static_cast<double>(slowest);
    std::size_t b = 0;
    for (auto v : latencies) {
        while (static_cast<double>(v) > marks[b] && b < BUCKETS) {
            ++b;
        }
        ++counts[b];
    }
    nlohmann::json histogram = nlohmann::json::array();
    for (std::size_t i = 0; i <= BUCKETS; ++i) {
        histogram.push_back(
            {{"mark", marks[i] * 1e-9},
             {"count", counts[i]},
             {"frequency", static_cast<double>(counts[i]) / static_cast<double>(n)}});
    }
    j["histogram"] = histogram;
    nlohmann::json distribution = nlohmann::json::array();
    for (int p : {10, 25, 50, 75, 90, 95, 99}) {
        distribution.push_back({{"percentage", p}, {"latency", rank(latencies, p / 100.0)}});
    }
    j["latencyDistribution"] = distribution;
    j["percentiles"] = percentiles_json(latencies);
    // Not in ghz: the daemon's own time for the calls that report it (review poses), so a
    // reader can tell service time from queueing and transport.
    std::vector<std::int64_t> server;
    for (const auto* c : calls) {
        if (c->server >= 0) {
            server.push_back(c->server);
        }
    }
    if (!server.empty()) {
        std::sort(server.begin(), server.end());
        j["serverPercentiles"] = percentiles_json(server);
    }
    return j;
}

// Per second of the run (warm-up included, for the plot): calls ended, errors and percentiles.
nlohmann::json timeline_json(const std::vector<const Call*>& calls, double duration) {
    // Calls that end after the run's last second (the tail of those in flight) count in it.
    const auto seconds = std::max<std::size_t>(1, static_cast<std::size_t>(std::ceil(duration)));
    std::vector<std::vector<std::int64_t>> per(seconds);
    std::vector<std::uint64_t> errors(seconds, 0);
    std::vector<std::array<std::uint64_t, KIND_COUNT>> kinds(seconds);
    for (auto& k : kinds) {
        k.fill(0);
    }
    for (const auto* c : calls) {
        const double end = c->start + static_cast<double>(c->latency) * 1e-9;
        const auto s = std::min(seconds - 1, static_cast<std::size_t>(std::max(0.0, end)));
        per[s].push_back(c->latency);
        errors[s] += c->code != "OK" ? 1 : 0;
        ++kinds[s][static_cast<std::size_t>(c->kind)];
    }
    nlohmann::json out = nlohmann::json::array();
    for (std::size_t s = 0; s < seconds; ++s) {
        auto& v = per[s];
        std::sort(v.begin(), v.end());
        nlohmann::json by_kind = nlohmann::json::object();
        for (int k = 0; k < KIND_COUNT; ++k) {
            if (kinds[s][static_cast<std::size_t>(k)] > 0) {
                by_kind[KIND_NAMES[static_cast<std::size_t>(k)]] =
                    kinds[s][static_cast<std::size_t>(k)];
            }
        }
        out.push_back({{"second", s},
                       {"count", v.size()},
                       {"error_count", errors[s]},
                       {"kinds", by_kind},
                       {"p50", v.empty() ? nlohmann::json() : nlohmann::json(rank(v, 0.5))},
                       {"p90", v.empty() ? nlohmann::json() : nlohmann::json(rank(v, 0.9))},
                       {"p99", v.empty() ? nlohmann::json() : nlohmann::json(rank(v, 0.99))},
                       {"max", v.empty() ? nlohmann::json() : nlohmann::json(v.back())}});
    }
    return out;
}

nlohmann::json metrics_json(const std::vector<MetricsTarget>& targets,
                            const std::vector<MetricsSample>& samples, std::uint64_t failures,
                            double warmup) {
    nlohmann::json endpoints = nlohmann::json::array();
    for (std::size_t i = 0; i < targets.size(); ++i) {
        // Over the measured window: the first sample at or after the warm-up and the last one.
        const MetricsSample* first = nullptr;
        const MetricsSample* last = nullptr;
        double rss_max = -1;
        nlohmann::json list = nlohmann::json::array();
        for (const auto& s : samples) {
            if (s.target != i) {
                continue;
            }
            nlohmann::json j = {{"t", s.t}};
            for (std::size_t k = 0; k < SAMPLED.size(); ++k) {
                j[SAMPLED[k].first] = s.values[k] ? nlohmann::json(*s.values[k]) : nlohmann::json();
            }
            list.push_back(j);
            if (s.t >= warmup - 0.5 && first == nullptr) {
                first = &s;
            }
            last = &s;
            if (s.values[0]) {
                rss_max = std::max(rss_max, *s.values[0]);
            }
        }
        auto delta = [&](std::size_t k) -> nlohmann::json {
            if (first == nullptr || last == nullptr || !first->values[k] || !last->values[k]) {
                return nullptr;
            }
            return *last->values[k] - *first->values[k];
        };
        nlohmann::json summary = {
            {"rss_bytes_max", rss_max >= 0 ? nlohmann::json(rss_max) : nlohmann::json()},
            {"cpu_seconds", delta(1)},
            {"cache_hits", delta(3)},
            {"cache_misses", delta(4)},
            {"cache_loads", delta(5)},
            {"cache_evictions", delta(6)}};
        if (first != nullptr && last != nullptr && last->t > first->t && first->values[1] &&
            last->values[1]) {
            summary["cpu_cores"] = (*last->values[1] - *first->values[1]) / (last->t - first->t);
        } else {
            summary["cpu_cores"] = nullptr;
        }
        endpoints.push_back({{"url", targets[i].shown}, {"summary", summary}, {"samples", list}});
    }
    return {{"endpoints", endpoints}, {"failed_scrape_count", failures}};
}

std::string ms_text(const nlohmann::json& ns) {
    if (!ns.is_number()) {
        return "-";
    }
    char buf[32];
    std::snprintf(buf, sizeof(buf), "%.2f", ns.get<double>() * 1e-6);
    return buf;
}

std::string clients_text(const nlohmann::json& doc) {
    std::string out;
    for (const char* kind : {"sim", "frames", "review", "verify", "play"}) {
        if (doc["clients"].value(kind, 0) > 0) {
            out += (out.empty() ? "" : ",") + std::string(kind) + "=" +
                   std::to_string(doc["clients"][kind].get<int>());
        }
    }
    return out;
}

std::string servers_text(const nlohmann::json& doc) {
    std::string out;
    for (const auto& s : doc["servers"]) {
        out += (out.empty() ? "" : " ") + s.get<std::string>();
    }
    return out;
}

std::string number_text(const nlohmann::json& v, const char* format) {
    if (!v.is_number()) {
        return "-";
    }
    char buf[48];
    std::snprintf(buf, sizeof(buf), format, v.get<double>());
    return buf;
}

void print_summary(const nlohmann::json& doc) {
    std::printf("load: %s s measured (%s s of warm-up excluded), clients %s against %s\n",
                number_text(doc["measured_seconds"], "%.1f").c_str(),
                number_text(doc["warmup_seconds"], "%.1f").c_str(), clients_text(doc).c_str(),
                servers_text(doc).c_str());
    std::printf("%-13s %9s %9s %9s %9s %9s %9s %9s %9s %7s\n", "kind", "count", "rate/s", "mean-ms",
                "p50-ms", "p90-ms", "p99-ms", "p99.9-ms", "max-ms", "errors");
    auto row = [](const std::string& name, const nlohmann::json& k) {
        const auto& p = k["percentiles"];
        std::uint64_t ok = k["statusCodeDistribution"].value("OK", std::uint64_t{0});
        std::printf("%-13s %9llu %9.1f %9s %9s %9s %9s %9s %9s %7llu\n", name.c_str(),
                    static_cast<unsigned long long>(k["count"].get<std::uint64_t>()),
                    k["rps"].get<double>(), ms_text(k["average"]).c_str(),
                    ms_text(p.is_null() ? nlohmann::json() : p["p50"]).c_str(),
                    ms_text(p.is_null() ? nlohmann::json() : p["p90"]).c_str(),
                    ms_text(p.is_null() ? nlohmann::json() : p["p99"]).c_str(),
                    ms_text(p.is_null() ? nlohmann::json() : p["p99.9"]).c_str(),
                    ms_text(k["slowest"]).c_str(),
                    static_cast<unsigned long long>(k["count"].get<std::uint64_t>() - ok));
    };
    for (const auto& [name, k] : doc["kinds"].items()) {
        row(name, k);
    }
    row("all", doc);
    for (const auto& [name, k] : doc["kinds"].items()) {
        if (k.contains("serverPercentiles")) {
            const auto& p = k["serverPercentiles"];
            std::printf("%s: the daemon's own time p50 %s p90 %s p99 %s p99.9 %s max %s ms\n",
                        name.c_str(), ms_text(p["p50"]).c_str(), ms_text(p["p90"]).c_str(),
                        ms_text(p["p99"]).c_str(), ms_text(p["p99.9"]).c_str(),
                        ms_text(p["max"]).c_str());
        }
    }
    if (!doc["errorDistribution"].empty()) {
        std::printf("errors:\n");
        int shown = 0;
        for (const auto& [message, count] : doc["errorDistribution"].items()) {
            if (++shown > 5) {
                std::printf("  ... (%zu distinct messages)\n", doc["errorDistribution"].size());
                break;
            }
            std::printf("  %6llu  %s\n",
                        static_cast<unsigned long long>(count.get<std::uint64_t>()),
                        message.c_str());
        }
    }
    for (const auto& e : doc["metrics"]["endpoints"]) {
        const auto& s = e["summary"];
        const std::string rss =
            s["rss_bytes_max"].is_number()
                ? client::format_amount(s["rss_bytes_max"].get<double>(), "bytes")
                : "-";
        std::printf("daemon %s: RSS max %s, CPU %s s (%s cores), cache hits %s, misses %s\n",
                    e["url"].get<std::string>().c_str(), rss.c_str(),
                    number_text(s["cpu_seconds"], "%.2f").c_str(),
                    number_text(s["cpu_cores"], "%.2f").c_str(),
                    number_text(s["cache_hits"], "%.0f").c_str(),
                    number_text(s["cache_misses"], "%.0f").c_str());
    }
    const auto& h = doc["harness"];
    std::printf("harness: %s threads, CPU %s s (%s cores), RSS max %s\n",
                std::to_string(h["threads"].get<std::uint64_t>()).c_str(),
                number_text(h["cpu_seconds"], "%.2f").c_str(),
                number_text(h["cpu_cores"], "%.2f").c_str(),
                client::format_amount(h["rss_bytes_max"].get<double>(), "bytes").c_str());
}

// --- Plot --------------------------------------------------------------------------------------

std::string find_gnuplot() {
    const char* path = std::getenv("PATH");
    std::stringstream dirs(path != nullptr ? path : "/usr/bin:/bin");
    for (std::string dir; std::getline(dirs, dir, ':');) {
        const auto candidate = std::filesystem::path(dir) / "gnuplot";
        if (!dir.empty() && access(candidate.c_str(), X_OK) == 0) {
            return candidate.string();
        }
    }
    return {};
}

std::string shell_quote(const std::string& s) {
    std::string out = "'";
    for (char ch : s) {
        out += ch == '\'' ? std::string("'\\''") : std::string(1, ch);
    }
    return out + "'";
}

std::string gnuplot_string(const std::string& s) {
    std::string out = "\"";
    for (char ch : s) {
        if (ch == '"' || ch == '\\') {
            out += '\\';
        }
        out += ch;
    }
    return out + "\"";
}

// Three panels: latency over time (p50, p90, p99 bands and the max, ms, log scale), throughput
// (calls and errors per second) and the daemons' RSS and CPU.
Status write_plot(const nlohmann::json& doc, const std::string& png, const std::string& gnuplot) {
    const auto dir =
        std::filesystem::temp_directory_path() / ("proxima-load-" + std::to_string(getpid()));
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);
    const auto calls_file = dir / "calls.dat";
    const auto metrics_file = dir / "metrics.dat";
    const auto script_file = dir / "plot.gp";
    {
        std::ofstream out(calls_file);
        for (const auto& s : doc["timeline"]) {
            if (s["count"].get<std::uint64_t>() == 0) {
                continue;
            }
            out << static_cast<double>(s["second"].get<std::uint64_t>()) + 0.5 << ' ' << s["count"]
                << ' ' << s["error_count"];
            for (const char* p : {"p50", "p90", "p99", "max"}) {
                out << ' ' << s[p].get<double>() * 1e-6;
            }
            for (const char* k : KIND_NAMES) {
                out << ' ' << s["kinds"].value(k, std::uint64_t{0});
            }
            out << '\n';
        }
    }
    bool have_metrics = false;
    {
        std::ofstream out(metrics_file);
        for (const auto& e : doc["metrics"]["endpoints"]) {
            double last_t = -1;
            double last_cpu = 0;
            for (const auto& s : e["samples"]) {
                if (!s["rss_bytes"].is_number() || !s["cpu_seconds"].is_number()) {
                    continue;
                }
                const double t = s["t"].get<double>();
                const double cpu = s["cpu_seconds"].get<double>();
                if (last_t >= 0 && t > last_t) {
                    out << t << ' ' << s["rss_bytes"].get<double>() / (1024.0 * 1024.0) << ' '
                        << 100.0 * (cpu - last_cpu) / (t - last_t) << '\n';
                    have_metrics = true;
                }
                last_t = t;
                last_cpu = cpu;
            }
            out << "\n\n";
        }
    }
    {
        std::ofstream out(script_file);
        const double warmup = doc["warmup_seconds"].get<double>();
        out << "set terminal pngcairo size 1100," << (have_metrics ? 900 : 640)
            << " font 'sans,9' noenhanced\nset output " << gnuplot_string(png) << "\n"
            << "set multiplot layout " << (have_metrics ? 3 : 2) << ",1 title "
            << gnuplot_string("proxima load: " + clients_text(doc) + " against " +
                              servers_text(doc))
            << "\nset grid\nset key outside right top\nset xlabel 'seconds'\nset xrange [0:"
            << doc["duration_seconds"].get<double>() << "]\nset lmargin 10\nset rmargin 28\n"
            << "set arrow from " << warmup << ", graph 0 to " << warmup
            << ", graph 1 nohead dt 2 lc rgb 'gray'\n"
            << "set ylabel 'latency (ms)'\nset logscale y\nset title 'latency per second "
               "(all calls; dashed line: end of warm-up)'\n"
            << "plot " << gnuplot_string(calls_file.string())
            << " using 1:4:5 with filledcurves lc rgb '#a6cee3' title 'p50-p90', '' using "
               "1:5:6 with filledcurves lc rgb '#fdbf6f' title 'p90-p99', '' using 1:4 with "
               "lines lw 2 lc rgb '#1f78b4' title 'p50', '' using 1:7 with points pt 7 ps 0.5 "
               "lc rgb '#e31a1c' title 'max'\n"
            << "unset logscale y\nset ylabel 'calls/s'\nset title 'throughput'\n"
            << "plot " << gnuplot_string(calls_file.string())
            << " using 1:2 with linespoints lw 2 lc rgb 'black' title 'all calls', '' using 1:3 "
               "with impulses lw 3 lc rgb 'red' title 'errors'";
        for (std::size_t k = 0; k < KIND_NAMES.size(); ++k) {
            if (doc["kinds"].contains(KIND_NAMES[k])) {
                out << ", '' using 1:" << 8 + k << " with linespoints title '" << KIND_NAMES[k]
                    << "'";
            }
        }
        out << "\n";
        if (have_metrics) {
            out << "set ylabel 'RSS (MiB)'\nset y2label 'CPU (% of a core)'\nset y2tics\n"
                << "set title 'daemon (Prometheus samples)'\n"
                << "plot " << gnuplot_string(metrics_file.string())
                << " using 1:2 with linespoints title 'RSS', '' using 1:3 axes x1y2 with "
                   "linespoints title 'CPU'\n";
        }
        out << "unset multiplot\n";
    }
    const std::string command = shell_quote(gnuplot) + " " + shell_quote(script_file.string()) +
                                " 2>" + shell_quote((dir / "gnuplot.log").string());
    const int rc = std::system(command.c_str());
    std::string log;
    {
        std::ifstream in(dir / "gnuplot.log");
        std::getline(in, log, '\0');
    }
    std::filesystem::remove_all(dir, ec);
    if (rc != 0 || !std::filesystem::exists(png)) {
        return Status(StatusCode::internal,
                      "gnuplot could not draw " + png + (log.empty() ? "" : ": " + log));
    }
    return {};
}

// --- The run -----------------------------------------------------------------------------------

std::string utc_now_text() {
    const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    std::tm utc{};
    gmtime_r(&now, &utc);
    std::array<char, 32> text{};
    std::strftime(text.data(), text.size(), "%Y-%m-%dT%H:%M:%SZ", &utc);
    return text.data();
}

int run_load(const CLI::App& command, const LoadArgs& args) {
    const auto duration = parse_duration(args.duration, false);
    const auto warmup = parse_duration(args.warmup, true);
    if (!duration || !warmup) {
        return usage_error(command, "--duration and --warmup take durations such as 30s");
    }
    if (*warmup >= *duration) {
        return usage_error(command, "--warmup (" + args.warmup +
                                        ") must be shorter than --duration (" + args.duration +
                                        ")");
    }
    auto mix = parse_clients(args.clients);
    if (const auto* message = std::get_if<std::string>(&mix)) {
        return usage_error(command, *message);
    }
    const ClientMix clients = std::get<ClientMix>(mix);
    auto queries = parse_queries(args.queries, args.tolerance);
    if (const auto* message = std::get_if<std::string>(&queries)) {
        return usage_error(command, *message);
    }
    std::vector<std::string> scene_names = split_list(args.scenes);
    if (args.scenes == "all") {
        scene_names = {"skirt", "cloth-ball", "bowl", "ramps", "breaking"};
    }
    for (const auto& s : scene_names) {
        if (scenes::by_name(s, 2).name.empty()) {
            return usage_error(command, "--scene: unknown scene '" + s +
                                            "' (expected all, or skirt, cloth-ball, bowl, "
                                            "ramps, breaking separated by commas)");
        }
    }
    std::vector<MetricsTarget> targets;
    for (const auto& m : args.metrics) {
        auto t = parse_metrics(m, args.servers);
        if (const auto* message = std::get_if<std::string>(&t)) {
            return usage_error(command, *message);
        }
        targets.push_back(std::get<MetricsTarget>(t));
    }
    if (clients.frames > 0 && args.frame_dirs.empty()) {
        return usage_error(command,
                           "frames clients need --frames DIR (two frames of a simulation, e.g. "
                           "../shared/data/frames/cloth-ball)");
    }
    if (clients.play > 0 && args.sequence_dirs.empty()) {
        return usage_error(command,
                           "play clients need --sequence DIR (a folder of numbered mesh files, an "
                           "MD2 model, or `proxima generate sequence` output)");
    }
    std::vector<client::Sequence> sequences;
    for (const auto& dir : clients.play > 0 ? args.sequence_dirs : std::vector<std::string>{}) {
        // Each file's connected components are its objects, as for the frames clients (and as
        // `proxima play --split-components` reads it).
        client::SequenceOptions read;
        read.split_components = true;
        auto loaded = client::load_sequence(dir, read);
        if (!loaded.ok()) {
            return fail(loaded.status());
        }
        sequences.push_back(std::move(loaded).value());
    }
    std::vector<LoadedPair> pairs;
    if (clients.frames > 0) {
        auto loaded = load_pairs(args.frame_dirs);
        if (!loaded.ok()) {
            return fail(loaded.status());
        }
        pairs = std::move(loaded).value();
    }
    std::string gnuplot;
    if (!args.plot.empty()) {
        gnuplot = find_gnuplot();
        if (gnuplot.empty()) {
            return fail(failed_precondition(
                "--plot needs gnuplot on PATH (Debian: apt-get install gnuplot-nox)"));
        }
    }

    auto shared = std::make_unique<Shared>();
    shared->args = &args;
    shared->queries = std::get<QueryMix>(queries);
    shared->scenes = scene_names;
    auto options = connect_options(args.server_flags);
    if (!options.ok()) {
        return fail(options.status());
    }
    shared->options = std::move(options).value();
    shared->per_client_cap =
        std::max<std::uint64_t>(1, args.max_calls / std::max<std::size_t>(1, clients.total()));

    // Before any load: every daemon answers, serves the model the review and verify clients
    // need, and every metrics endpoint reads.
    std::vector<ModelInfo> models(args.servers.size());
    for (std::size_t i = 0; i < args.servers.size(); ++i) {
        auto c = connect_server(args.servers[i], args.server_flags);
        if (!c.ok()) {
            return fail(c.status());
        }
        if (auto info = c.value()->server_info(); !info.ok()) {
            return fail(info.status());
        }
        if (clients.review + clients.verify == 0) {
            continue;
        }
        auto list = c.value()->list_models();
        if (!list.ok()) {
            return fail(list.status());
        }
        const client::RemoteModel* chosen = nullptr;
        for (const auto& m : list->models) {
            if (chosen == nullptr && (args.model.empty() || m.name == args.model)) {
                chosen = &m;
            }
        }
        if (chosen == nullptr) {
            return fail(failed_precondition(
                "the daemon at " + args.servers[i] +
                (args.model.empty() ? std::string(" serves no massive model")
                                    : " does not serve the model '" + args.model + "'") +
                "; review and verify clients need one (proximad --models DIR; proxima models "
                "lists them)"));
        }
        models[i] = {chosen->name, chosen->box, chosen->objects};
    }
    for (const auto& t : targets) {
        if (auto got = http_get(t); !got.ok()) {
            return fail(got.status());
        }
    }

    std::vector<std::unique_ptr<Recorder>> recorders;
    std::vector<std::thread> threads;
    std::vector<MetricsSample> samples;
    std::uint64_t scrape_failures = 0;
    const std::string date = utc_now_text();
    shared->start = Clock::now();
    shared->end = shared->start + std::chrono::duration_cast<Clock::duration>(
                                      std::chrono::duration<double>(*duration));
    Shared& sh = *shared;
    threads.emplace_back([&sh, &targets, &samples, &scrape_failures] {
        run_metrics(sh, targets, samples, scrape_failures);
    });
    std::size_t next = 0;
    auto spawn = [&](auto body) {
        recorders.push_back(std::make_unique<Recorder>(sh));
        Recorder* rec = recorders.back().get();
        // Paced clients start at evenly spread phases of the --rate period (Pacer).
        const double phase = static_cast<double>(next) /
                             static_cast<double>(std::max<std::size_t>(1, clients.total()));
        const std::size_t server = next++ % args.servers.size();
        {
            std::lock_guard lock(sh.mu);
            ++sh.running;
        }
        threads.emplace_back([body, rec, server, phase, &sh] {
            body(*rec, server, phase);
            {
                std::lock_guard lock(sh.mu);
                --sh.running;
            }
            sh.cv.notify_all();
        });
    };
    for (std::size_t i = 0; i < clients.sim; ++i) {
        spawn([&sh, &args, i](Recorder& rec, std::size_t server, double phase) {
            run_sim(sh, rec, args.servers[server], i, phase);
        });
    }
    for (std::size_t i = 0; i < clients.frames; ++i) {
        spawn([&sh, &args, &pairs, i](Recorder& rec, std::size_t server, double phase) {
            run_pair(sh, rec, args.servers[server], pairs[i % pairs.size()], phase);
        });
    }
    for (std::size_t i = 0; i < clients.review; ++i) {
        const std::size_t count = clients.review;
        spawn([&sh, &args, &models, i, count](Recorder& rec, std::size_t server, double phase) {
            run_review(sh, rec, args.servers[server], models[server], i, count, phase);
        });
    }
    for (std::size_t i = 0; i < clients.verify; ++i) {
        spawn([&sh, &args, &models](Recorder& rec, std::size_t server, double /*phase*/) {
            run_verify(sh, rec, args.servers[server], models[server]);
        });
    }
    for (std::size_t i = 0; i < clients.play; ++i) {
        spawn([&sh, &args, &sequences, i](Recorder& rec, std::size_t server, double /*phase*/) {
            run_play(sh, rec, args.servers[server], sequences[i % sequences.size()]);
        });
    }

    // A progress line once a second until the end (or every client reached its share of calls).
    const bool tty = isatty(fileno(stderr)) != 0;
    std::array<std::uint64_t, KIND_COUNT> before{};
    bool ended_by_count = false;
    // The harness's own CPU over the measured part: from the first tick at or after the warm-up.
    std::optional<std::pair<Clock::time_point, double>> cpu_from;
    if (*warmup <= 0) {
        cpu_from.emplace(sh.start, own_cpu_seconds());
    }
    for (int second = 1;; ++second) {
        const auto tick = std::min(sh.end, sh.start + std::chrono::seconds(second));
        bool all_done = false;
        {
            // Clients return once they made their share of the calls (--max-calls).
            std::unique_lock lock(sh.mu);
            all_done = sh.cv.wait_until(lock, tick, [&sh] { return sh.running == 0; });
        }
        if (!args.quiet) {
            std::string line = "load " + std::to_string(second) + "/" +
                               std::to_string(static_cast<int>(std::ceil(*duration))) + " s" +
                               (sh.since_start(tick) <= *warmup + 1e-6 ? " (warm-up)" : "") + ":";
            for (int k = 0; k < KIND_COUNT; ++k) {
                const auto n = sh.counts[static_cast<std::size_t>(k)].load();
                if (n > 0) {
                    line += " " + std::string(KIND_NAMES[static_cast<std::size_t>(k)]) + " " +
                            std::to_string(n) + " (" +
                            std::to_string(n - before[static_cast<std::size_t>(k)]) + "/s)";
                }
                before[static_cast<std::size_t>(k)] = n;
            }
            line += ", " + std::to_string(sh.errors.load()) + " errors";
            std::fprintf(stderr, tty ? "\r%s\033[K" : "%s\n", line.c_str());
            std::fflush(stderr);
        }
        if (!cpu_from && sh.since_start(tick) >= *warmup - 1e-6) {
            cpu_from.emplace(tick, own_cpu_seconds());
        }
        if (tick >= sh.end || all_done) {
            ended_by_count = all_done;
            break;
        }
    }
    const auto cpu_to = std::make_pair(Clock::now(), own_cpu_seconds());
    {
        std::lock_guard lock(sh.mu);
        sh.stop = true;
    }
    sh.cv.notify_all();
    // Calls in flight get a moment to finish (and count); then their streams are cancelled.
    {
        std::unique_lock lock(sh.mu);
        sh.cv.wait_for(lock, std::chrono::seconds(2), [&sh] { return sh.running == 0; });
    }
    {
        std::lock_guard lock(sh.cancel_mu);
        for (const auto& [hook, cancel] : sh.cancels) {
            cancel();
        }
    }
    for (auto& t : threads) {
        t.join();
    }
    if (!args.quiet && tty) {
        std::fprintf(stderr, "\n");
    }
    const double ran = sh.since_start(Clock::now());

    // The figures: calls due after the warm-up.
    std::vector<const Call*> all;
    std::vector<const Call*> measured;
    std::array<std::vector<const Call*>, KIND_COUNT> by_kind;
    for (const auto& r : recorders) {
        for (const auto& c : r->calls) {
            all.push_back(&c);
            if (c.start >= *warmup) {
                measured.push_back(&c);
                by_kind[static_cast<std::size_t>(c.kind)].push_back(&c);
            }
        }
    }
    const double window = std::max(1e-9, std::min(ran, *duration) - *warmup);
    nlohmann::json doc = ghz_json(measured, window);
    nlohmann::json kinds = nlohmann::json::object();
    for (int k = 0; k < KIND_COUNT; ++k) {
        if (!by_kind[static_cast<std::size_t>(k)].empty()) {
            kinds[KIND_NAMES[static_cast<std::size_t>(k)]] =
                ghz_json(by_kind[static_cast<std::size_t>(k)], window);
        }
    }
    // ghz's run description: when it began (RFC 3339, UTC) and why it ended ("timeout": the
    // duration; "normal": every client made its share of --max-calls).
    doc["date"] = date;
    doc["endReason"] = ended_by_count ? "normal" : "timeout";
    doc["servers"] = args.servers;
    doc["duration_seconds"] = *duration;
    doc["warmup_seconds"] = *warmup;
    doc["measured_seconds"] = window;
    doc["warmup_count"] = all.size() - measured.size();
    doc["clients"] = {{"sim", clients.sim},
                      {"frames", clients.frames},
                      {"review", clients.review},
                      {"verify", clients.verify},
                      {"play", clients.play}};
    nlohmann::json pair_names = nlohmann::json::array();
    for (const auto& p : pairs) {
        pair_names.push_back(p.name);
    }
    doc["frame_pairs"] = pair_names;
    nlohmann::json sequence_names = nlohmann::json::array();
    for (const auto& q : sequences) {
        sequence_names.push_back(q.dir);
    }
    doc["sequences"] = sequence_names;
    doc["sim_scenes"] = scene_names;
    doc["sim_queries"] = sh.queries.names;
    doc["tolerance"] = args.tolerance;
    doc["rate"] = args.rate;
    nlohmann::json model_names = nlohmann::json::array();
    if (clients.review + clients.verify > 0) {
        for (const auto& m : models) {
            model_names.push_back(m.name);
        }
    }
    doc["models"] = model_names;
    doc["kinds"] = kinds;
    doc["timeline"] = timeline_json(all, *duration);
    doc["metrics"] = metrics_json(targets, samples, scrape_failures, *warmup);
    {
        // The harness's share of the machine: CPU seconds per second of the measured part (a
        // run that ended before the warm-up did has none).
        nlohmann::json harness = {
            {"threads", clients.total() + 1}, {"cpu_seconds", nullptr}, {"cpu_cores", nullptr}};
        if (cpu_from) {
            const double cpu = cpu_to.second - cpu_from->second;
            const double wall =
                std::chrono::duration<double>(cpu_to.first - cpu_from->first).count();
            harness["cpu_seconds"] = cpu;
            harness["cpu_cores"] = wall > 0 ? nlohmann::json(cpu / wall) : nlohmann::json(nullptr);
        }
        rusage u{};
        getrusage(RUSAGE_SELF, &u);
        harness["rss_bytes_max"] = static_cast<std::uint64_t>(u.ru_maxrss) * 1024U;
        doc["harness"] = harness;
    }

    if (!args.plot.empty()) {
        if (Status s = write_plot(doc, args.plot, gnuplot); !s.ok()) {
            return fail(s);
        }
    }
    if (args.output.wanted()) {
        const auto count = doc["count"].get<std::uint64_t>();
        const auto ok = doc["statusCodeDistribution"].value("OK", std::uint64_t{0});
        char rate[32];
        std::snprintf(rate, sizeof(rate), "%.1f", doc["rps"].get<double>());
        return emit_json(doc, args.output,
                         "load: " + std::to_string(count) + " calls (" + rate + "/s), " +
                             std::to_string(count - ok) + " errors");
    }
    print_summary(doc);
    if (!args.plot.empty()) {
        std::printf("plot: %s\n", args.plot.c_str());
    }
    return 0;
}

}  // namespace

void add_load_command(CLI::App& app, int& exit_code) {
    auto args = std::make_shared<LoadArgs>();
    auto* load = app.add_subcommand(
        "load",
        "Load-test proximad daemons with simulator (seed scenes, real frame pairs), review and "
        "verify clients for a bounded time; per call kind the figures of a ghz report (JSON), a "
        "text summary, a PNG plot");
    auto* server = load->add_option("--server", args->servers,
                                    "A daemon's HOST:PORT (repeat for several; clients are "
                                    "spread over them)")
                       ->required();
    add_server_flags(*load, args->server_flags, server);
    load->add_option("--duration", args->duration, "How long the run lasts, warm-up included")
        ->check(duration_text(false))
        ->capture_default_str();
    load->add_option("--warmup", args->warmup,
                     "Calls due in this first part of the run are not in the figures")
        ->check(duration_text(true))
        ->capture_default_str();
    load->add_option("--clients", args->clients,
                     "Clients of each kind: sim=N,frames=N,review=N,verify=N,play=N (at most 256 "
                     "in all)")
        ->capture_default_str();
    load->add_option("--scene", args->scenes,
                     "Sim clients' seed scenes, one per client in turn: all, or skirt, "
                     "cloth-ball, bowl, ramps, breaking separated by commas")
        ->capture_default_str();
    load->add_option("--queries", args->queries,
                     "Sim clients' queries per frame: separation, self, collisions, tolerance, "
                     "ccd, separated by commas")
        ->capture_default_str();
    load->add_option("--tolerance", args->tolerance,
                     "The tolerance query's distance, and the review and verify tolerance")
        ->check(non_negative_number())
        ->capture_default_str();
    load->add_option(
            "--rate", args->rate,
            "Calls per second of each sim, frames, review and play client (open loop); 0: as "
            "fast as answered (closed loop)")
        ->check(non_negative_number())
        ->capture_default_str();
    load->add_option("--episode-frames", args->episode_frames,
                     "Frames per sim stream before it starts over on a new scene")
        ->check(whole_number(2, 100000))
        ->capture_default_str();
    load->add_option("--frames", args->frame_dirs,
                     "Frames clients' real frame pairs: a directory with two mesh files (t0, t1), "
                     "or a directory of such directories (../shared/data/frames); repeatable")
        ->type_name("DIR");
    load->add_option("--sequence", args->sequence_dirs,
                     "Play clients' recorded sequences, one per client in turn: a folder of "
                     "numbered mesh files, an MD2 model, or `proxima generate sequence` output "
                     "(as `proxima play` takes them); repeatable")
        ->type_name("DIR");
    load->add_option("--model", args->model,
                     "Review and verify clients' model (default: the first one served)");
    load->add_option("--edit-every", args->edit_every,
                     "Every other reviewer moves an object every N-th step (0: no edits)")
        ->check(whole_number(0, 1000000))
        ->capture_default_str();
    load->add_option("--metrics", args->metrics,
                     "A daemon's Prometheus endpoint (proximad --metrics-listen), "
                     "http://HOST:PORT/metrics or HOST:PORT, sampled once a second; loopback or "
                     "a --server's host only (repeatable)");
    load->add_option("--max-calls", args->max_calls,
                     "Stop once the clients made this many calls in all")
        ->check(whole_number(1, 1000000000))
        ->capture_default_str();
    load->add_option("--plot", args->plot,
                     "Draw latency over time with percentile bands, throughput and the "
                     "daemon's RSS and CPU into FILE.png (gnuplot)")
        ->type_name("FILE.png");
    add_json_output(*load, args->output);
    load->add_flag("--quiet", args->quiet, "No progress line on standard error");
    load->callback([load, args, &exit_code] { exit_code = run_load(*load, *args); });
}

}  // namespace proxima::cli
