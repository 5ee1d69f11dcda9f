// proxima_stream_bench: what the frame stream costs on loopback, apart from the geometry work.
//   1. Round-trip overhead per frame: one deforming sheet of 15K or 150K vertices, lockstep
//      frames that only update positions (no query), float32 and float64 buffers; overhead =
//      client round trip - the server's own time (decode, validate, apply, encode). In the same
//      run, interleaved frame by frame, the gRPC floor: a bare bidi stream to a generic echo
//      server (this program with --echo-server, another process like the daemon) carrying the
//      same bytes (the serialized Frame): `echo` answers with the same bytes, `ack` with an
//      empty message (the daemon's answer to such a frame is a few dozen bytes).
//   2. Throughput: 1, 8 and 32 concurrent streams, each its own scene (the 'bowl' scene,
//      separation query), lockstep frames for a fixed time; total frames per second.
// Starts its own proximad on 127.0.0.1:0. `--quick` is the CI smoke run.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include <sys/wait.h>
#include <unistd.h>

#include <grpcpp/generic/async_generic_service.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>

#include "client/proxima_client.hpp"
#include "proxima/scenes/procedural.hpp"
#include "proxima/v1/proxima.pb.h"
#include "proxima/wire/frames.hpp"

namespace {

using namespace proxima;
using Clock = std::chrono::steady_clock;

// A child process (proximad, or this program as the echo server) that prints "listening on
// HOST:PORT" as its first line; SIGTERM at the end.
struct Daemon {
    pid_t pid = -1;
    std::string address;
    explicit Daemon(const char* proximad, const char* echo_self = nullptr) {
        int out[2];
        if (pipe(out) != 0) {
            std::perror("pipe");
            std::exit(1);
        }
        pid = fork();
        if (pid == 0) {
            dup2(out[1], STDOUT_FILENO);
            close(out[0]);
            close(out[1]);
            if (echo_self != nullptr) {
                execl(echo_self, echo_self, "--echo-server", static_cast<char*>(nullptr));
            } else {
                execl(proximad, proximad, "--listen", "127.0.0.1:0", "--log-level", "warn",
                      static_cast<char*>(nullptr));
            }
            std::perror("exec");
            _exit(127);
        }
        close(out[1]);
        std::string line;
        char c;
        while (read(out[0], &c, 1) == 1 && c != '\n') {
            line += c;
        }
        close(out[0]);
        const std::string prefix = "listening on ";
        if (line.rfind(prefix, 0) != 0) {
            std::fprintf(stderr, "%s did not start (first line: '%s')\n",
                         echo_self != nullptr ? "the echo server" : "proximad", line.c_str());
            std::exit(1);
        }
        address = line.substr(prefix.size());
    }
    ~Daemon() {
        if (pid > 0) {
            kill(pid, SIGTERM);
            int status = 0;
            waitpid(pid, &status, 0);
        }
    }
};

// --- The gRPC floor: a generic echo server and its lockstep client ----------------------------

constexpr const char* ECHO_METHOD = "/bench.Echo/Echo";  // answers with the same bytes
constexpr const char* ACK_METHOD = "/bench.Echo/Ack";    // answers with an empty message

class EchoReactor : public grpc::ServerGenericBidiReactor {
  public:
    explicit EchoReactor(bool ack) : m_ack(ack) { StartRead(&m_in); }
    void OnReadDone(bool ok) override {
        if (!ok) {
            Finish(grpc::Status::OK);
            return;
        }
        if (m_ack) {
            grpc::Slice empty("", 0);
            m_out = grpc::ByteBuffer(&empty, 1);
        } else {
            m_out = m_in;
        }
        StartWrite(&m_out);
    }
    void OnWriteDone(bool ok) override {
        if (!ok) {
            Finish(grpc::Status(grpc::StatusCode::UNAVAILABLE, "write failed"));
            return;
        }
        StartRead(&m_in);
    }
    void OnDone() override { delete this; }

  private:
    bool m_ack;
    grpc::ByteBuffer m_in;
    grpc::ByteBuffer m_out;
};

class EchoService : public grpc::CallbackGenericService {
    grpc::ServerGenericBidiReactor* CreateReactor(
        grpc::GenericCallbackServerContext* context) override {
        return new EchoReactor(context->method() == ACK_METHOD);
    }
};

int run_echo_server() {
    EchoService service;
    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
    builder.SetMaxReceiveMessageSize(-1);
    builder.SetMaxSendMessageSize(-1);
    builder.RegisterCallbackGenericService(&service);
    auto server = builder.BuildAndStart();
    if (!server || port == 0) {
        std::fprintf(stderr, "echo server: cannot listen\n");
        return 1;
    }
    std::printf("listening on 127.0.0.1:%d\n", port);
    std::fflush(stdout);
    server->Wait();  // until SIGTERM ends the process
    return 0;
}

// One lockstep bidi stream to the echo server (completion-queue API, no thread of its own).
class EchoClient {
  public:
    EchoClient(const std::shared_ptr<grpc::Channel>& channel, const char* method)
        : m_stub(channel) {
        m_call = m_stub.PrepareCall(&m_context, method, &m_cq);
        m_call->StartCall(tag(1));
        check(wait(), "start");
    }
    ~EchoClient() {
        m_call->WritesDone(tag(4));
        (void)wait();
        grpc::Status status;
        m_call->Finish(&status, tag(5));
        (void)wait();
        m_cq.Shutdown();
        void* t = nullptr;
        bool ok = false;
        while (m_cq.Next(&t, &ok)) {
        }
    }
    EchoClient(const EchoClient&) = delete;
    EchoClient& operator=(const EchoClient&) = delete;

    // Milliseconds from writing `payload` to having read the answer.
    double round_trip(const grpc::ByteBuffer& payload) {
        const auto t0 = Clock::now();
        m_call->Write(payload, tag(2));
        check(wait(), "write");
        m_call->Read(&m_in, tag(3));
        check(wait(), "read");
        return std::chrono::duration<double>(Clock::now() - t0).count() * 1e3;
    }

  private:
    static void* tag(std::intptr_t n) { return reinterpret_cast<void*>(n); }
    bool wait() {
        void* t = nullptr;
        bool ok = false;
        return m_cq.Next(&t, &ok) && ok;
    }
    static void check(bool ok, const char* what) {
        if (!ok) {
            std::fprintf(stderr, "echo stream: %s failed\n", what);
            std::exit(1);
        }
    }
    grpc::GenericStub m_stub;
    grpc::CompletionQueue m_cq;
    grpc::ClientContext m_context;
    std::unique_ptr<grpc::GenericClientAsyncReaderWriter> m_call;
    grpc::ByteBuffer m_in;
};

std::shared_ptr<grpc::Channel> echo_channel(const std::string& address) {
    grpc::ChannelArguments args;
    args.SetMaxReceiveMessageSize(-1);
    args.SetMaxSendMessageSize(-1);
    return grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args);
}

TriangleMesh sheet(int nx, int ny) {
    TriangleMesh m;
    for (int j = 0; j < ny; ++j) {
        for (int i = 0; i < nx; ++i) {
            m.vertices.push_back({i * 0.01, j * 0.01, 0.0});
        }
    }
    for (int j = 0; j + 1 < ny; ++j) {
        for (int i = 0; i + 1 < nx; ++i) {
            const auto a = static_cast<std::uint32_t>(j * nx + i);
            m.triangles.push_back({a, a + 1, a + static_cast<std::uint32_t>(nx) + 1});
            m.triangles.push_back(
                {a, a + static_cast<std::uint32_t>(nx) + 1, a + static_cast<std::uint32_t>(nx)});
        }
    }
    return m;
}

double percentile(std::vector<double> v, double p) {
    if (v.empty()) {
        return 0;
    }
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, static_cast<std::size_t>(p * (v.size() - 1) + 0.5))];
}

// One overhead case's figures (milliseconds), a row of the table.
struct Row {
    std::size_t vertices = 0;
    bool f32 = false;
    std::size_t frame_bytes = 0;
    double rtt50 = 0, server50 = 0, over50 = 0, over99 = 0, echo50 = 0, ack50 = 0;
};

void print_header() {
    std::printf(
        "| vertices | buffer | frame bytes | round trip p50 | server p50 | overhead p50 | "
        "overhead p99 | echo p50 | ack p50 | overhead / echo | overhead / ack |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|---|---|\n");
}

void print_row(const Row& r) {
    std::printf("| %zu | %s | %zu | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %.2fx | %.2fx |\n",
                r.vertices, r.f32 ? "float32" : "float64", r.frame_bytes, r.rtt50, r.server50,
                r.over50, r.over99, r.echo50, r.ack50, r.over50 / r.echo50, r.over50 / r.ack50);
    std::fflush(stdout);
}

double median(std::vector<double> v) {
    return percentile(std::move(v), 0.5);
}

// Each column's median over the repeats (the ratios: of the medians).
Row median_row(const std::vector<Row>& rows) {
    Row out = rows.front();
    auto column = [&](double Row::*field) {
        std::vector<double> v;
        for (const auto& r : rows) {
            v.push_back(r.*field);
        }
        return median(std::move(v));
    };
    out.rtt50 = column(&Row::rtt50);
    out.server50 = column(&Row::server50);
    out.over50 = column(&Row::over50);
    out.over99 = column(&Row::over99);
    out.echo50 = column(&Row::echo50);
    out.ack50 = column(&Row::ack50);
    return out;
}

Row overhead(const std::string& address, const std::string& echo_address, int nx, int ny, bool f32,
             int frames) {
    client::ConnectOptions opts;
    opts.float32_vertices = f32;
    opts.inline_mesh_bytes = 64u << 20;
    auto c = client::Client::connect(address, opts);
    if (!c.ok()) {
        std::fprintf(stderr, "connect: %s\n", c.status().to_string().c_str());
        std::exit(1);
    }
    auto mesh = sheet(nx, ny);
    auto scene = c.value()->create_scene("overhead", {{"sheet", mesh}});
    if (!scene.ok()) {
        std::fprintf(stderr, "create: %s\n", scene.status().to_string().c_str());
        std::exit(1);
    }
    const ObjectId id = scene->objects.at(0).id;
    auto stream = c.value()->open_stream(scene->scene_id);
    if (!stream.ok()) {
        std::fprintf(stderr, "stream: %s\n", stream.status().to_string().c_str());
        std::exit(1);
    }
    auto channel = echo_channel(echo_address);
    EchoClient echo(channel, ECHO_METHOD);
    EchoClient ack(channel, ACK_METHOD);
    std::vector<double> rtt, over, server, echo_ms, ack_ms;
    std::size_t frame_bytes = 0;
    for (int k = 0; k < frames; ++k) {
        client::FrameRequest f;
        f.frame = static_cast<std::uint64_t>(k);
        f.queries.separation = false;
        auto v = mesh.vertices;
        for (auto& p : v) {
            p.z = 0.001 * std::sin(0.1 * k + p.x);
        }
        f.update.positions.push_back({id, std::move(v)});
        // The floor's payload: the same frame as the client library puts it on the wire.
        proxima::v1::Frame message;
        wire::encode_frame(f, scene->scene_id, f32, &message);
        const std::string bytes = message.SerializeAsString();
        frame_bytes = bytes.size();
        grpc::Slice slice(bytes);
        const grpc::ByteBuffer payload(&slice, 1);
        // Building the frame is the simulator's work, not the stream's: start the clock here.
        const auto t0 = Clock::now();
        if (Status s = stream.value()->send(f); !s.ok()) {
            std::fprintf(stderr, "send: %s\n", s.to_string().c_str());
            std::exit(1);
        }
        auto r = stream.value()->receive();
        const double dt = std::chrono::duration<double>(Clock::now() - t0).count();
        if (!r.ok()) {
            std::fprintf(stderr, "receive: %s\n", r.status().to_string().c_str());
            std::exit(1);
        }
        const double e = echo.round_trip(payload);
        const double a = ack.round_trip(payload);
        if (k >= 3) {  // warm-up frames excluded
            rtt.push_back(dt * 1e3);
            server.push_back(r->server_seconds * 1e3);
            over.push_back((dt - r->server_seconds) * 1e3);
            echo_ms.push_back(e);
            ack_ms.push_back(a);
        }
    }
    (void)stream.value()->finish();
    (void)c.value()->delete_scene(scene->scene_id);
    Row row;
    row.vertices = mesh.vertices.size();
    row.f32 = f32;
    row.frame_bytes = frame_bytes;
    row.rtt50 = percentile(rtt, 0.5);
    row.server50 = percentile(server, 0.5);
    row.over50 = percentile(over, 0.5);
    row.over99 = percentile(over, 0.99);
    row.echo50 = percentile(echo_ms, 0.5);
    row.ack50 = percentile(ack_ms, 0.5);
    return row;
}

void throughput(const std::string& address, int streams, double seconds) {
    std::atomic<std::uint64_t> frames{0};
    std::atomic<bool> failed{false};
    std::vector<std::thread> threads;
    std::vector<std::vector<double>> latency(static_cast<std::size_t>(streams));
    const auto stop = Clock::now() + std::chrono::duration<double>(seconds);
    for (int s = 0; s < streams; ++s) {
        threads.emplace_back([&, s] {
            auto c = client::Client::connect(address);
            if (!c.ok()) {
                failed = true;
                return;
            }
            auto sc = scenes::bowl(100000);
            auto remote = c.value()->create_scene("bowl", sc.initial);
            if (!remote.ok()) {
                failed = true;
                return;
            }
            Scene mirror;
            SceneUpdate first;
            first.additions = sc.initial;
            (void)mirror.apply(first);
            auto stream = c.value()->open_stream(remote->scene_id);
            if (!stream.ok()) {
                failed = true;
                return;
            }
            for (std::size_t k = 1; Clock::now() < stop; ++k) {
                SceneUpdate local = sc.step(k, mirror);
                client::FrameRequest f;
                f.frame = k;
                f.queries.separation = true;
                f.update = local;
                // The bowl scene keeps its topology: local and remote ids correspond by position.
                for (auto& p : f.update.positions) {
                    p.object =
                        remote->objects[static_cast<std::size_t>(mirror.index_of(p.object))].id;
                }
                (void)mirror.apply(std::move(local));
                const auto t0 = Clock::now();
                if (!stream.value()->send(f).ok()) {
                    failed = true;
                    return;
                }
                auto r = stream.value()->receive();
                if (!r.ok()) {
                    failed = true;
                    return;
                }
                latency[static_cast<std::size_t>(s)].push_back(
                    std::chrono::duration<double>(Clock::now() - t0).count() * 1e3);
                ++frames;
            }
            (void)stream.value()->finish();
            (void)c.value()->delete_scene(remote->scene_id);
        });
    }
    for (auto& t : threads) {
        t.join();
    }
    if (failed) {
        std::fprintf(stderr, "a stream failed\n");
        std::exit(1);
    }
    std::vector<double> all;
    for (auto& l : latency) {
        all.insert(all.end(), l.begin(), l.end());
    }
    std::printf("| %d | %.1f | %.2f | %.2f |\n", streams, frames.load() / seconds,
                percentile(all, 0.5), percentile(all, 0.99));
}

void usage(const char* argv0) {
    std::fprintf(stderr,
                 "usage: %s [--quick] [--overhead-only] [--only VERTICES:float32|float64]\n"
                 "          [--frames N] [--repeat N] [--proximad PATH]\n"
                 "  --quick          the CI smoke run (few frames, short throughput runs)\n"
                 "  --overhead-only  skip the concurrent-streams part\n"
                 "  --only V:T       only the overhead case of V vertices (15000 or 150000) and\n"
                 "                   buffer T, e.g. 15000:float32\n"
                 "  --frames N       frames per 15K case (default 200; 150K cases: 30%%)\n"
                 "  --repeat N       the overhead table N times, then each case's medians over\n"
                 "                   the repeats (the machine is shared: compare medians)\n"
                 "  --proximad PATH  the daemon to start (default: this build's)\n",
                 argv0);
}

}  // namespace

int main(int argc, char** argv) {
    bool quick = false;
    bool overhead_only = false;
    std::string only;
    int frames_arg = 0;
    int repeat = 1;
    const char* proximad = PROXIMAD_PATH;
    for (int i = 1; i < argc; ++i) {
        const bool has_value = i + 1 < argc;
        if (std::strcmp(argv[i], "--quick") == 0) {
            quick = true;
        } else if (std::strcmp(argv[i], "--echo-server") == 0) {
            return run_echo_server();
        } else if (std::strcmp(argv[i], "--overhead-only") == 0) {
            overhead_only = true;
        } else if (std::strcmp(argv[i], "--only") == 0 && has_value) {
            only = argv[++i];
        } else if (std::strcmp(argv[i], "--frames") == 0 && has_value) {
            frames_arg = std::atoi(argv[++i]);
        } else if (std::strcmp(argv[i], "--repeat") == 0 && has_value) {
            repeat = std::atoi(argv[++i]);
        } else if (std::strcmp(argv[i], "--proximad") == 0 && has_value) {
            proximad = argv[++i];
        } else if (std::strcmp(argv[i], "--help") == 0 || std::strcmp(argv[i], "-h") == 0) {
            usage(argv[0]);
            return 0;
        } else {
            usage(argv[0]);
            return 2;
        }
    }
    if (repeat < 1 || frames_arg < 0 || (frames_arg > 0 && frames_arg < 10)) {
        std::fprintf(stderr, "--repeat must be >= 1 and --frames >= 10\n");
        return 2;
    }
    Daemon daemon(proximad);
    Daemon echo(proximad, "/proc/self/exe");
    std::printf("proximad (%s) at %s, echo server at %s; %u hardware threads\n\n", proximad,
                daemon.address.c_str(), echo.address.c_str(), std::thread::hardware_concurrency());
    std::printf(
        "Round trip per frame, positions only, lockstep (ms; overhead = round trip - server "
        "time; echo and ack: the same serialized frame over a bare gRPC stream, answered with "
        "the same bytes or with an empty message, interleaved with the daemon's frames)\n\n");
    const int frames = frames_arg > 0 ? frames_arg : (quick ? 8 : 200);
    const int large_frames = frames_arg > 0 ? std::max(10, frames_arg * 3 / 10) : (quick ? 5 : 60);
    struct Case {
        int nx, ny;
        bool f32;
        std::vector<Row> rows;
    };
    std::vector<Case> cases;
    for (bool f32 : {true, false}) {
        for (auto [nx, ny] : {std::pair{150, 100}, std::pair{500, 300}}) {
            const std::string name = std::to_string(nx * ny) + (f32 ? ":float32" : ":float64");
            if (only.empty() || only == name) {
                cases.push_back({nx, ny, f32, {}});
            }
        }
    }
    if (cases.empty()) {
        std::fprintf(stderr, "--only %s matches no case (15000 or 150000, float32 or float64)\n",
                     only.c_str());
        return 2;
    }
    for (int r = 0; r < repeat; ++r) {
        if (repeat > 1) {
            std::printf("Repeat %d of %d\n\n", r + 1, repeat);
        }
        print_header();
        for (auto& c : cases) {
            c.rows.push_back(overhead(daemon.address, echo.address, c.nx, c.ny, c.f32,
                                      c.nx * c.ny > 20000 ? large_frames : frames));
            print_row(c.rows.back());
        }
        std::printf("\n");
    }
    if (repeat > 1) {
        std::printf("Medians over the %d repeats (each column's median on its own)\n\n", repeat);
        print_header();
        for (auto& c : cases) {
            print_row(median_row(c.rows));
        }
        std::printf("\n");
    }
    if (overhead_only) {
        return 0;
    }
    std::printf(
        "Concurrent streams, scene 'bowl' (11 objects, 4.5K triangles), separation per "
        "frame, lockstep\n\n");
    std::printf("| streams | frames/s (all streams) | latency p50 ms | latency p99 ms |\n");
    std::printf("|---|---|---|---|\n");
    for (int s : {1, 8, 32}) {
        throughput(daemon.address, s, quick ? 0.5 : 5.0);
    }
    return 0;
}
