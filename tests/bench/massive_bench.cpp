// proxima_massive_bench: the massive-model path of seed 001 on a generated plant.
//  - Fig. 8: triangles loaded from disk per triangle of the model, for cache budgets M, during
//    static verification (each M in a fresh process, so the peak RSS is that run's);
//  - static verification throughput (model triangles per second, piece pairs per second);
//  - Fig. 10: a ~4K-triangle avatar along a path through the plant, per-pose latency p50 / p99
//    (cold cache at the start, prefetch along the velocity);
//  - process RSS against M.
// The store is imported once (pieces at most min(M) / 10) and reused by later runs.
//
//   proxima_massive_bench --store /tmp/plant15m --plant 15M --cache-mb 30,80,160,400,800
//   proxima_massive_bench --quick            (CI smoke: a 200K-triangle plant, two budgets)

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <numeric>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.hpp"
#include "proxima/massive/avatar.hpp"
#include "proxima/massive/generator.hpp"
#include "proxima/massive/verify.hpp"

namespace fs = std::filesystem;
using namespace proxima;
using namespace proxima::massive;

namespace {

struct Args {
    std::string store;
    std::uint64_t plant = 15'000'000;
    std::vector<double> cache_mb{30, 80, 160, 400, 800};
    double tolerance = 0.0;
    int poses = 2000;
    double avatar_mb = 160;
    double nearest_max = INFINITY;  // avatar: nearest object within this distance
    bool quick = false;
    // Internal: run one measurement and print one line.
    std::string child;
    double child_mb = 0;
};

std::uint64_t parse_count(const std::string& s) {
    double v = std::stod(s);
    const char c = s.empty() ? 0 : s.back();
    if (c == 'K' || c == 'k')
        v *= 1e3;
    if (c == 'M' || c == 'm')
        v *= 1e6;
    if (c == 'G' || c == 'g')
        v *= 1e9;
    return static_cast<std::uint64_t>(v);
}

std::uint64_t proc_status_kb(const char* key) {
    std::ifstream f("/proc/self/status");
    std::string line;
    while (std::getline(f, line)) {
        if (line.rfind(key, 0) == 0) {
            return std::stoull(line.substr(std::strlen(key) + 1));
        }
    }
    return 0;
}

double thread_cpu_ms() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

TriangleMesh sphere(double r, int n) {
    TriangleMesh m;
    m.vertices.push_back({0, 0, r});
    for (int i = 1; i < n; ++i) {
        const double th = M_PI * i / n;
        for (int j = 0; j < 2 * n; ++j) {
            const double ph = M_PI * j / n;
            m.vertices.push_back({r * std::sin(th) * std::cos(ph), r * std::sin(th) * std::sin(ph),
                                  r * std::cos(th)});
        }
    }
    m.vertices.push_back({0, 0, -r});
    auto ring = [&](int i, int j) { return std::uint32_t(1 + (i - 1) * 2 * n + (j % (2 * n))); };
    const auto bottom = std::uint32_t(m.vertices.size() - 1);
    for (int j = 0; j < 2 * n; ++j) {
        m.triangles.push_back({0, ring(1, j), ring(1, j + 1)});
        for (int i = 1; i + 1 < n; ++i) {
            m.triangles.push_back({ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)});
            m.triangles.push_back({ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)});
        }
        m.triangles.push_back({ring(n - 1, j), bottom, ring(n - 1, j + 1)});
    }
    return m;
}

int ensure_store(const Args& a) {
    if (Store::open(a.store).ok()) {
        return 0;
    }
    const double min_mb = *std::min_element(a.cache_mb.begin(), a.cache_mb.end());
    StoreOptions options;
    options.max_piece_bytes = static_cast<std::uint64_t>(min_mb * (1 << 20)) / SPLIT_FRACTION;
    options.source = "plant " + std::to_string(a.plant) + " seed 1";
    std::fprintf(stderr, "importing a %llu-triangle plant into %s (pieces <= %.1f MB)\n",
                 static_cast<unsigned long long>(a.plant), a.store.c_str(),
                 options.max_piece_bytes / 1048576.0);
    const auto t0 = std::chrono::steady_clock::now();
    auto writer = StoreWriter::create(a.store, options);
    if (!writer.ok()) {
        std::fprintf(stderr, "error: %s\n", writer.status().to_string().c_str());
        return 1;
    }
    std::uint64_t last = 0;
    PlantOptions plant;
    plant.triangles = a.plant;
    auto g = generate_plant(
        plant, [&](ModelObject&& o) { return (*writer)->add(std::move(o)); },
        [&](const Progress& p) {
            if (p.total > 0 && p.done * 20 / p.total != last) {
                last = p.done * 20 / p.total;
                std::fprintf(stderr, "  %s %3llu%%\n", p.step.c_str(),
                             static_cast<unsigned long long>(p.done * 100 / p.total));
            }
        });
    if (!g.ok()) {
        std::fprintf(stderr, "error: %s\n", g.status().to_string().c_str());
        return 1;
    }
    auto s = (*writer)->commit();
    if (!s.ok()) {
        std::fprintf(stderr, "error: %s\n", s.status().to_string().c_str());
        return 1;
    }
    std::fprintf(stderr, "imported %llu objects, %llu pieces, %llu triangles, %.0f MB in %.1f s\n",
                 static_cast<unsigned long long>(s->objects),
                 static_cast<unsigned long long>(s->pieces),
                 static_cast<unsigned long long>(s->triangles), s->bytes / 1e6,
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    return 0;
}

// One static verification at budget M in this process: one line of key=value.
int child_verify(const Args& a) {
    auto store = Store::open(a.store);
    if (!store.ok()) {
        std::fprintf(stderr, "error: %s\n", store.status().to_string().c_str());
        return 1;
    }
    const auto budget = static_cast<std::uint64_t>(a.child_mb * (1 << 20));
    GeometryCache cache(budget);
    VerifyOptions options;
    options.tolerance = a.tolerance;
    auto stats = verify_static(*store, cache, options, {});
    if (!stats.ok()) {
        std::fprintf(stderr, "error: %s\n", stats.status().to_string().c_str());
        return 1;
    }
    std::printf(
        "reload=%.4f loaded_per_triangle=%.4f pairs=%llu edges=%llu subgraphs=%llu seconds=%.3f "
        "plan_seconds=%.3f peak_cache_mb=%.1f rss_peak_mb=%.1f waits=%llu "
        "blocked_seconds=%.3f exact_tests=%llu\n",
        double(stats->cache.triangles_loaded) / double(stats->edge_triangles),
        double(stats->cache.triangles_loaded) / double(stats->model_triangles),
        static_cast<unsigned long long>(stats->pairs_found),
        static_cast<unsigned long long>(stats->edges),
        static_cast<unsigned long long>(stats->subgraphs), stats->seconds, stats->plan_seconds,
        stats->cache.peak_bytes / 1048576.0, proc_status_kb("VmHWM:") / 1024.0,
        static_cast<unsigned long long>(stats->cache.waits + stats->cache.misses),
        stats->cache.blocked_seconds, static_cast<unsigned long long>(stats->exact_tests));
    return 0;
}

// The avatar along a path at budget M, cold cache: one line of key=value.
int child_avatar(const Args& a) {
    auto store = Store::open(a.store);
    if (!store.ok()) {
        std::fprintf(stderr, "error: %s\n", store.status().to_string().c_str());
        return 1;
    }
    const auto budget = static_cast<std::uint64_t>(a.child_mb * (1 << 20));
    auto cache = std::make_shared<GeometryCache>(budget);
    auto view = std::make_shared<ModelView>(*store, cache);
    const TriangleMesh avatar = sphere(0.5, 46);  // 4,140 triangles
    auto tracker = AvatarTracker::create(view, avatar, 7);
    if (!tracker.ok()) {
        return 1;
    }
    Aabb box;
    for (const auto& o : (*store)->objects()) {
        box.extend(o.box);
    }
    // A walk along x through the middle of the plant at pipe-rack height, 5 cm per pose (3 m/s
    // at 60 poses per second), weaving in y so it crosses pipe runs and frames.
    std::vector<double> ms;
    std::vector<double> cpu_ms;  // the query thread's own CPU time: what a quiet machine would see
    std::uint64_t collisions = 0;
    std::uint64_t within = 0;
    const Vec3 e = box.extent();
    const double z = box.lo.z + 0.35 * e.z;
    const auto start = std::chrono::steady_clock::now();
    for (int k = 0; k < a.poses; ++k) {
        const double x = box.lo.x + 0.05 * e.x + 0.05 * k;
        const double y = box.lo.y + 0.5 * e.y + 0.15 * e.y * std::sin(0.01 * k);
        Affine pose;
        pose.m = {1, 0, 0, x, 0, 1, 0, y, 0, 0, 1, z};
        // Poses at 60 Hz (a user walking at 3 m/s): the prefetch thread works between poses, as
        // it would in a review session; latency is measured per pose.
        std::this_thread::sleep_until(start + std::chrono::microseconds(16667) * k);
        const auto t0 = std::chrono::steady_clock::now();
        const double c0 = thread_cpu_ms();
        AvatarQueryOptions q;
        q.tolerance = a.tolerance > 0 ? a.tolerance : 0.05;
        q.nearest = a.nearest_max >= 0.0;  // < 0: collisions and tolerance only (seed Fig. 10)
        q.nearest_max_distance = std::max(0.0, a.nearest_max);
        auto r = (*tracker)->query(pose, q);
        cpu_ms.push_back(thread_cpu_ms() - c0);
        ms.push_back(
            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                .count());
        if (!r.ok()) {
            std::fprintf(stderr, "error: %s\n", r.status().to_string().c_str());
            return 1;
        }
        collisions += r->collisions.size();
        within += r->within.size();
        if (std::getenv("PROXIMA_BENCH_TRACE") != nullptr && ms.back() > 2.0) {
            const auto cs = cache->stats();
            std::fprintf(
                stderr,
                "pose %d: %.2f ms (cpu %.2f), %llu candidates, %llu pieces tested, %llu exact "
                "tests, nearest %.3f, cache waits+misses %llu\n",
                k, ms.back(), cpu_ms.back(), static_cast<unsigned long long>(r->candidate_pieces),
                static_cast<unsigned long long>(r->pieces_tested),
                static_cast<unsigned long long>(r->exact_tests),
                r->nearest ? r->nearest->distance : -1.0,
                static_cast<unsigned long long>(cs.waits + cs.misses));
        }
    }
    std::sort(cpu_ms.begin(), cpu_ms.end());
    const double cpu_p50 = cpu_ms[cpu_ms.size() / 2];
    const double cpu_p99 = cpu_ms[std::min(cpu_ms.size() - 1, cpu_ms.size() * 99 / 100)];
    std::vector<double> sorted = ms;
    std::sort(sorted.begin(), sorted.end());
    auto pct = [&](double q) {
        return sorted[std::min(sorted.size() - 1, static_cast<std::size_t>(q * sorted.size()))];
    };
    const auto s = cache->stats();
    std::printf(
        "poses=%d p50_ms=%.3f p99_ms=%.3f max_ms=%.3f mean_ms=%.3f cpu_p50_ms=%.3f "
        "cpu_p99_ms=%.3f collisions=%llu "
        "within=%llu loads=%llu prefetch_loads=%llu waits=%llu peak_cache_mb=%.1f "
        "rss_peak_mb=%.1f\n",
        a.poses, pct(0.5), pct(0.99), sorted.back(),
        std::accumulate(ms.begin(), ms.end(), 0.0) / ms.size(), cpu_p50, cpu_p99,
        static_cast<unsigned long long>(collisions), static_cast<unsigned long long>(within),
        static_cast<unsigned long long>(s.loads), static_cast<unsigned long long>(s.prefetch_loads),
        static_cast<unsigned long long>(s.waits + s.misses), s.peak_bytes / 1048576.0,
        proc_status_kb("VmHWM:") / 1024.0);
    return 0;
}

std::string run_child(const std::string& self, const Args& a, const std::string& what, double mb,
                      double nearest_max = INFINITY) {
    std::ostringstream cmd;
    cmd << '"' << self << "\" --child " << what << " --child-mb " << mb << " --store \"" << a.store
        << "\" --tolerance " << a.tolerance << " --poses " << a.poses;
    if (!std::isinf(nearest_max)) {
        cmd << " --nearest-max " << nearest_max;
    }
    FILE* p = popen(cmd.str().c_str(), "r");
    std::string out;
    char buf[4096];
    while (p != nullptr && std::fgets(buf, sizeof(buf), p) != nullptr) {
        out += buf;
    }
    const int rc = p != nullptr ? pclose(p) : -1;
    if (rc != 0) {
        std::fprintf(stderr, "child %s at %.0f MB failed\n", what.c_str(), mb);
        std::exit(1);
    }
    return out;
}

double field(const std::string& line, const std::string& key) {
    const auto at = line.find(key + "=");
    return at == std::string::npos ? NAN : std::stod(line.substr(at + key.size() + 1));
}

}  // namespace

int main(int argc, char** argv) {
    Args a;
    for (int i = 1; i < argc; ++i) {
        const std::string k = argv[i];
        auto next = [&]() -> std::string {
            if (i + 1 >= argc) {
                std::fprintf(stderr, "%s needs a value\n", k.c_str());
                std::exit(2);
            }
            return argv[++i];
        };
        if (k == "--store") {
            a.store = next();
        } else if (k == "--plant") {
            a.plant = parse_count(next());
        } else if (k == "--cache-mb") {
            a.cache_mb.clear();
            std::stringstream ss(next());
            std::string item;
            while (std::getline(ss, item, ',')) {
                a.cache_mb.push_back(std::stod(item));
            }
        } else if (k == "--tolerance") {
            a.tolerance = std::stod(next());
        } else if (k == "--poses") {
            a.poses = std::stoi(next());
        } else if (k == "--nearest-max") {
            a.nearest_max = std::stod(next());
        } else if (k == "--avatar-mb") {
            a.avatar_mb = std::stod(next());
        } else if (k == "--quick") {
            a.quick = true;
        } else if (k == "--child") {
            a.child = next();
        } else if (k == "--child-mb") {
            a.child_mb = std::stod(next());
        } else {
            std::fprintf(stderr, "unknown argument %s\n", k.c_str());
            return 2;
        }
    }
    if (a.child == "verify") {
        return child_verify(a);
    }
    if (a.child == "avatar") {
        return child_avatar(a);
    }
    if (a.quick) {
        a.plant = 200'000;
        a.cache_mb = {4, 16};
        a.avatar_mb = 16;
        a.poses = 100;
    }
    bool temporary = false;
    if (a.store.empty()) {
        a.store =
            (fs::temp_directory_path() / ("proxima-massive-bench-" + std::to_string(getpid())))
                .string();
        temporary = true;
    }
    if (ensure_store(a) != 0) {
        return 1;
    }
    auto store = Store::open(a.store);
    if (!store.ok()) {
        std::fprintf(stderr, "error: %s\n", store.status().to_string().c_str());
        return 1;
    }
    const auto& sum = (*store)->summary();
    std::uint64_t model_bytes = 0;
    for (const auto& p : (*store)->pieces()) {
        model_bytes += p.weight();
    }
    const std::string self = fs::read_symlink("/proc/self/exe").string();
    std::printf("# proxima_massive_bench on %s (%u cores), load %s\n", bench::cpu_model().c_str(),
                std::thread::hardware_concurrency(), bench::load_average().c_str());
    std::printf(
        "# store %s: %llu objects, %llu pieces, %llu triangles, %.0f MB on disk, "
        "%.0f MB if all resident; tolerance %g\n",
        a.store.c_str(), static_cast<unsigned long long>(sum.objects),
        static_cast<unsigned long long>(sum.pieces), static_cast<unsigned long long>(sum.triangles),
        sum.bytes / 1e6, model_bytes / 1048576.0, a.tolerance);
    std::printf("\n## static verification per cache budget M (fresh process each)\n");
    std::printf("%8s %10s %8s %8s %9s %9s %10s %12s %10s %10s %9s\n", "M_MB", "loads/tri", "reload",
                "pairs", "edges", "seconds", "plan_s", "Mtri/s", "cache_pk", "rss_pk_MB", "rss-M");
    for (double mb : a.cache_mb) {
        const std::string line = run_child(self, a, "verify", mb);
        const double secs = field(line, "seconds");
        std::printf("%8.0f %10.3f %8.3f %8.0f %9.0f %9.2f %10.2f %12.2f %10.1f %10.1f %9.1f\n", mb,
                    field(line, "loaded_per_triangle"), field(line, "reload"), field(line, "pairs"),
                    field(line, "edges"), secs, field(line, "plan_seconds"),
                    sum.triangles / 1e6 / secs, field(line, "peak_cache_mb"),
                    field(line, "rss_peak_mb"), field(line, "rss_peak_mb") - mb);
        std::fflush(stdout);
    }
    std::printf(
        "\n## avatar (4,140 triangles) along a %d-pose path, M = %.0f MB, cold cache; "
        "per pose: collisions, objects within 5 cm, nearest object\n",
        a.poses, a.avatar_mb);
    const std::pair<double, const char*> modes[] = {
        {-1.0, "collisions + within 5 cm (seed Fig. 10)"},
        {1.0, "+ nearest object within 1 m"},
        {double(INFINITY), "+ nearest object at any distance"}};
    for (const auto& [nearest_max, label] : modes) {
        std::printf("%s: %s", label,
                    run_child(self, a, "avatar", a.avatar_mb, nearest_max).c_str());
        std::fflush(stdout);
    }
    if (temporary) {
        fs::remove_all(a.store);
    }
    return 0;
}
