// proxima-bullet (clients/examples/bullet, issue #19) against a daemon started here: a short
// cloth-sphere run whose every frame the example also runs through the in-process engine
// (--check: the daemon's answers must be bit-identical), then, independently of the service, a
// brute-force CCD over the states the simulation kept (--record): every vertex-face and edge-edge
// pair of the soft body against itself (non-adjacent) and against the obstacle, tested with the
// engine's elementary tests between each pair of consecutive states, must be contact-free: the
// CCD-limited step never let two primitives pass through (or touch) each other.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "integration/daemon_process.hpp"
#include "proxima/ccd/elementary.hpp"
#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/mesh/mesh.hpp"
#include "support/sanitized.hpp"

namespace proxima {
namespace {

using nlohmann::json;

struct TempDir {
    std::filesystem::path path;
    TempDir() {
        std::string t = (std::filesystem::temp_directory_path() / "proxima-bullet-XXXXXX").string();
        path = mkdtemp(t.data()) != nullptr ? t : std::string();
    }
    ~TempDir() {
        std::error_code ec;
        std::filesystem::remove_all(path, ec);
    }
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;
};

// Runs a command line; its exit status (-1 when it did not exit).
int run(const std::string& command) {
    const int status = std::system(command.c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

json load(const std::filesystem::path& file) {
    std::ifstream in(file);
    return json::parse(in);
}

// One object of the recording: its topology, edges and positions per kept state.
struct Recorded {
    bool soft = false;
    std::vector<TriangleIndices> triangles;
    std::vector<std::array<std::uint32_t, 2>> edges;
    std::vector<std::vector<Vec3>> states;  // soft: one per state; static: one
    std::size_t vertex_count = 0;
    const std::vector<Vec3>& at(std::size_t state) const { return states[soft ? state : 0]; }
};

// Swept box of points moving linearly (the segment of each point lies in the box of its ends),
// widened by more than the elementary tests' tolerance.
struct Box {
    Vec3 lo{1e300, 1e300, 1e300};
    Vec3 hi{-1e300, -1e300, -1e300};
    void add(const Vec3& p) {
        lo = cwise_min(lo, p);
        hi = cwise_max(hi, p);
    }
    void widen(double by) {
        lo = lo - Vec3{by, by, by};
        hi = hi + Vec3{by, by, by};
    }
    bool overlaps(const Box& o) const {
        return lo.x <= o.hi.x && o.lo.x <= hi.x && lo.y <= o.hi.y && o.lo.y <= hi.y &&
               lo.z <= o.hi.z && o.lo.z <= hi.z;
    }
};

struct Counts {
    std::uint64_t pairs = 0;
    std::uint64_t elementary = 0;
    std::uint64_t hits = 0;
    std::string first_hit;
};

// Every vf and ee pair of objects a and b (a == b: non-adjacent pairs of one object) between
// states k-1 and k, each pair whose swept boxes meet tested with the elementary test.
void brute_force(const Recorded& a, const Recorded& b, bool same, std::size_t k, Counts& counts) {
    const auto& a0 = a.at(k - 1);
    const auto& a1 = a.at(k);
    const auto& b0 = b.at(k - 1);
    const auto& b1 = b.at(k);
    // The elementary tests report contact within their tolerance (1e-6): boxes apart by more
    // than that (with room for rounding) hold no pair they would report.
    const double widen = 2e-6;
    auto vertex_box = [&](const std::vector<Vec3>& p0, const std::vector<Vec3>& p1,
                          std::uint32_t v) {
        Box box;
        box.add(p0[v]);
        box.add(p1[v]);
        box.widen(widen);
        return box;
    };
    auto tri_box = [&](const std::vector<Vec3>& p0, const std::vector<Vec3>& p1,
                       const TriangleIndices& t) {
        Box box;
        for (auto v : t) {
            box.add(p0[v]);
            box.add(p1[v]);
        }
        box.widen(widen);
        return box;
    };
    auto edge_box = [&](const std::vector<Vec3>& p0, const std::vector<Vec3>& p1,
                        const std::array<std::uint32_t, 2>& e) {
        Box box;
        for (auto v : e) {
            box.add(p0[v]);
            box.add(p1[v]);
        }
        box.widen(widen);
        return box;
    };
    auto test = [&](ccd::CcdKind kind, const ccd::CcdPoints& points, const std::string& what) {
        ++counts.elementary;
        if (ccd::elementary_prefilter_rejects(kind, points)) {
            return;
        }
        const auto r = ccd::elementary(kind, points);
        if (r.hit) {
            if (counts.hits++ == 0) {
                counts.first_hit = what + " between states " + std::to_string(k - 1) + " and " +
                                   std::to_string(k) + " (toi " + std::to_string(r.toi) + ")";
            }
        }
    };
    // Vertex-face, both directions (within one object: one loop covers both roles).
    auto vf = [&](const Recorded& p, const std::vector<Vec3>& p0, const std::vector<Vec3>& p1,
                  const Recorded& q, const std::vector<Vec3>& q0, const std::vector<Vec3>& q1) {
        std::vector<Box> tboxes;
        for (const auto& t : q.triangles) {
            tboxes.push_back(tri_box(q0, q1, t));
        }
        std::vector<bool> used(p.vertex_count, false);
        for (const auto& t : p.triangles) {
            for (auto v : t) {
                used[v] = true;
            }
        }
        for (std::uint32_t v = 0; v < p.vertex_count; ++v) {
            if (!used[v]) {
                continue;
            }
            const Box vb = vertex_box(p0, p1, v);
            for (std::size_t f = 0; f < q.triangles.size(); ++f) {
                const auto& t = q.triangles[f];
                if (same && (t[0] == v || t[1] == v || t[2] == v)) {
                    continue;
                }
                ++counts.pairs;
                if (!vb.overlaps(tboxes[f])) {
                    continue;
                }
                test(ccd::CcdKind::vertex_face,
                     {p0[v], q0[t[0]], q0[t[1]], q0[t[2]], p1[v], q1[t[0]], q1[t[1]], q1[t[2]]},
                     "vertex " + std::to_string(v) + " / triangle " + std::to_string(f));
            }
        }
    };
    vf(a, a0, a1, b, b0, b1);
    if (!same) {
        vf(b, b0, b1, a, a0, a1);
    }
    std::vector<Box> eboxes;
    for (const auto& e : b.edges) {
        eboxes.push_back(edge_box(b0, b1, e));
    }
    for (std::size_t i = 0; i < a.edges.size(); ++i) {
        const auto& e = a.edges[i];
        const Box ea = edge_box(a0, a1, e);
        for (std::size_t j = same ? i + 1 : 0; j < b.edges.size(); ++j) {
            const auto& f = b.edges[j];
            if (same && (e[0] == f[0] || e[0] == f[1] || e[1] == f[0] || e[1] == f[1])) {
                continue;
            }
            ++counts.pairs;
            if (!ea.overlaps(eboxes[j])) {
                continue;
            }
            test(ccd::CcdKind::edge_edge,
                 {a0[e[0]], a0[e[1]], b0[f[0]], b0[f[1]], a1[e[0]], a1[e[1]], b1[f[0]], b1[f[1]]},
                 "edge " + std::to_string(i) + " / edge " + std::to_string(j));
        }
    }
}

// Every pair of the recording's soft body with itself and with the obstacle, between every two
// consecutive kept states.
Counts brute_force_recording(const std::filesystem::path& record_file, std::size_t steps) {
    const json record = load(record_file);
    std::vector<Recorded> objects;
    for (const auto& o : record["objects"]) {
        Recorded r;
        r.soft = o["soft"].get<bool>();
        for (const auto& t : o["triangles"]) {
            r.triangles.push_back(
                {t[0].get<std::uint32_t>(), t[1].get<std::uint32_t>(), t[2].get<std::uint32_t>()});
        }
        if (!r.soft) {
            std::vector<Vec3> v;
            for (const auto& p : o["vertices"]) {
                v.push_back({p[0].get<double>(), p[1].get<double>(), p[2].get<double>()});
            }
            r.vertex_count = v.size();
            r.states.push_back(std::move(v));
        }
        objects.push_back(std::move(r));
    }
    const auto& states = record["states"];
    EXPECT_EQ(states.size(), steps + 1);
    for (const auto& state : states) {
        std::size_t soft = 0;
        for (auto& o : objects) {
            if (!o.soft) {
                continue;
            }
            const auto& flat = state["positions"][soft++];
            std::vector<Vec3> v;
            for (std::size_t i = 0; i + 2 < flat.size(); i += 3) {
                v.push_back(
                    {flat[i].get<double>(), flat[i + 1].get<double>(), flat[i + 2].get<double>()});
            }
            o.vertex_count = v.size();
            o.states.push_back(std::move(v));
        }
    }
    for (auto& o : objects) {
        o.edges = ccd::mesh_edges(MeshTopology(o.triangles, o.vertex_count));
    }
    Counts counts;
    if (objects.empty() || !objects[0].soft) {
        ADD_FAILURE() << "the recording should hold a soft body first";
        return counts;
    }
    // Every object pair that can move: soft with itself, soft with soft, soft with obstacle.
    for (std::size_t k = 1; k < states.size(); ++k) {
        for (std::size_t i = 0; i < objects.size(); ++i) {
            for (std::size_t j = i; j < objects.size(); ++j) {
                if (objects[i].soft || objects[j].soft) {
                    brute_force(objects[i], objects[j], i == j, k, counts);
                }
            }
        }
    }
    return counts;
}

// Runs `scene` for `steps` against a daemon started here with --check and --record; checks the log
// and the brute force over the kept states; returns the log's summary.
json run_and_check(const std::string& scene, std::size_t steps, const std::string& extra) {
    json summary = json::object();
    Counts counts;
    test::DaemonProcess daemon({"--log-level", "warn"});
    EXPECT_TRUE(daemon.ok()) << daemon.error();
    TempDir dir;
    EXPECT_FALSE(dir.path.empty());
    if (!daemon.ok() || dir.path.empty()) {
        return summary;
    }
    const auto log_file = dir.path / "log.json";
    const auto record_file = dir.path / "record.json";
    const std::string command = std::string(PROXIMA_BULLET_PATH) + " --server " + daemon.address() +
                                " --scene " + scene + " --steps " + std::to_string(steps) + " " +
                                extra + " --check --quiet --json " + log_file.string() +
                                " --record " + record_file.string();
    EXPECT_EQ(run(command), 0) << command;
    if (!std::filesystem::exists(log_file) || !std::filesystem::exists(record_file)) {
        ADD_FAILURE() << "no log or recording from " << command;
        return summary;
    }
    const json log = load(log_file);
    summary = log["summary"];
    EXPECT_EQ(log["steps"].size(), steps);
    EXPECT_EQ(summary["step_count"], steps);
    // Every frame (at least one per step) ran in-process too, with bit-identical answers.
    EXPECT_GE(summary["check"]["frame_count"].get<std::uint64_t>(), steps);
    EXPECT_EQ(summary["check"]["mismatch_count"], 0) << summary["check"].dump();
    for (const auto& s : log["steps"]) {
        EXPECT_TRUE(s["bullet_ms"].is_number());
        EXPECT_GT(s["round_trip_ms"].get<double>(), 0.0);
        EXPECT_GE(s["frame_count"].get<int>(), 1);
        // A contact found by the first CCD of a step is always followed by a limiting frame.
        if (s["ccd"]["pair_count"].get<std::uint64_t>() > 0) {
            EXPECT_GT(s["frame_count"].get<int>(), 1) << s.dump();
        }
    }
    counts = brute_force_recording(record_file, steps);
    EXPECT_GT(counts.elementary, 0u);
    EXPECT_EQ(counts.hits, 0u) << scene << ": " << counts.first_hit << " (" << counts.hits
                               << " contacts over " << counts.pairs << " pairs)";
    std::printf(
        "%s: %zu steps, %llu limited; brute force: %llu primitive pairs, %llu elementary "
        "tests, %llu contacts\n",
        scene.c_str(), steps,
        static_cast<unsigned long long>(summary["limited_step_count"].get<std::uint64_t>()),
        static_cast<unsigned long long>(counts.pairs),
        static_cast<unsigned long long>(counts.elementary),
        static_cast<unsigned long long>(counts.hits));
    return summary;
}

TEST(BulletExample, ClothSphereAnswersLikeTheEngineAndNothingPassesThrough) {
    // Under a sanitizer (TSan: 5-15x, on one CPU) a shorter run keeps the test within its timeout.
    const auto r = run_and_check("cloth-sphere", test::SANITIZED ? 80 : 200, "--resolution 12");
    // The scene exercises what the client is for: Bullet lets cloth nodes sink into the sphere
    // and the service's CCD limits those steps.
    EXPECT_GT(r["limited_step_count"].get<std::uint64_t>(), 0u);
    EXPECT_GT(r["ccd_contacts_bullet_missed"].get<std::uint64_t>(), 0u);
}

// --max-freeze 0: every limited step takes the fallback, a rewind of every node to half the
// earliest time of impact.
TEST(BulletExample, RewindFallbackAnswersLikeTheEngineAndNothingPassesThrough) {
    const auto r = run_and_check("cloth-sphere", 80, "--resolution 12 --max-freeze 0");
    EXPECT_GT(r["rewind_count"].get<std::uint64_t>(), 0u);
    EXPECT_EQ(r["rewind_count"], r["limited_step_count"]);
}

TEST(BulletExample, BallBowlAnswersLikeTheEngineAndNothingPassesThrough) {
    const auto r = run_and_check("ball-bowl", 150, "--resolution 20");
    // The ball squeezes into the seams between the bowl's boxes where Bullet lets nodes in.
    EXPECT_GT(r["limited_step_count"].get<std::uint64_t>(), 0u);
}

TEST(BulletExample, RopesAnswerLikeTheEngineAndNothingPassesThrough) {
    const auto r = run_and_check("ropes", 120, "--resolution 16");
    // The ropes fold over themselves (Bullet has no self-collision here): CCD limits those steps.
    EXPECT_GT(r["limited_step_count"].get<std::uint64_t>(), 0u);
}

// The brute force has teeth: without the step limiting (--no-limit: Bullet's own response only)
// the same scene lets cloth nodes through the sphere's mesh, and the brute force finds them, as
// many steps as the client's CCD reported.
TEST(BulletExample, WithoutLimitingTheBruteForceFindsWhatBulletMissed) {
    test::DaemonProcess daemon({"--log-level", "warn"});
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    TempDir dir;
    ASSERT_FALSE(dir.path.empty());
    const auto log_file = dir.path / "log.json";
    const auto record_file = dir.path / "record.json";
    const std::size_t steps = 60;
    const std::string command = std::string(PROXIMA_BULLET_PATH) + " --server " + daemon.address() +
                                " --scene cloth-sphere --steps " + std::to_string(steps) +
                                " --resolution 12 --no-limit --quiet " + "--json " +
                                log_file.string() + " --record " + record_file.string();
    ASSERT_EQ(run(command), 0) << command;
    const json log = load(log_file);
    ASSERT_GT(log["summary"]["ccd_contacts_bullet_missed"].get<std::uint64_t>(), 0u);
    std::uint64_t ccd_contacts = 0;
    for (const auto& s : log["steps"]) {
        ASSERT_EQ(s["frame_count"], 1);  // nothing limited, nothing pushed
        ccd_contacts += s["ccd"]["pair_count"].get<std::uint64_t>();
    }
    const Counts counts = brute_force_recording(record_file, steps);
    // The same elementary tests on the same points: the daemon's CCD and the brute force agree.
    EXPECT_EQ(counts.hits, ccd_contacts);
}

// --pushout-only: no step limiting, so Bullet's cloth sinks into the sphere's mesh, and the
// penetration vectors push nodes back out after the step (one more frame on those steps).
TEST(BulletExample, PushOutOnlyFollowsPenetrationsWithACorrectionFrame) {
    test::DaemonProcess daemon({"--log-level", "warn"});
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    TempDir dir;
    ASSERT_FALSE(dir.path.empty());
    const auto log_file = dir.path / "log.json";
    const std::size_t steps = 80;
    const std::string command = std::string(PROXIMA_BULLET_PATH) + " --server " + daemon.address() +
                                " --scene cloth-sphere --steps " + std::to_string(steps) +
                                " --resolution 12 --pushout-only --check --quiet --json " +
                                log_file.string();
    ASSERT_EQ(run(command), 0) << command;
    const json log = load(log_file);
    const auto& summary = log["summary"];
    EXPECT_EQ(log["response"], "pushout");
    EXPECT_EQ(summary["check"]["mismatch_count"], 0) << summary["check"].dump();
    EXPECT_EQ(summary["limited_step_count"], 0);
    std::uint64_t pushed_steps = 0;
    for (const auto& s : log["steps"]) {
        const bool pushed = s["pushed_node_count"].get<std::uint64_t>() > 0;
        pushed_steps += pushed ? 1 : 0;
        EXPECT_EQ(s["frame_count"], pushed ? 2 : 1) << s.dump();
        EXPECT_EQ(s["freeze_rounds"], 0);
    }
    EXPECT_GT(pushed_steps, 0u);
    EXPECT_EQ(summary["pushout_count"], pushed_steps);
}

// --snapshots: PNGs of the daemon's scene through its Snapshot call, at step 0, every
// --snapshot-every steps and the last, named in the JSON log, of the asked size, one camera for
// all (so the first and last images differ only because the cloth moved).
TEST(BulletExample, SnapshotsAreSavedThroughTheDaemonsSnapshotCall) {
    test::DaemonProcess daemon({"--log-level", "warn"});
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    TempDir dir;
    ASSERT_FALSE(dir.path.empty());
    const auto log_file = dir.path / "log.json";
    const auto shots = dir.path / "shots";
    const std::string command = std::string(PROXIMA_BULLET_PATH) + " --server " + daemon.address() +
                                " --scene cloth-sphere --steps 25 --resolution 12 --quiet" +
                                " --snapshots " + shots.string() +
                                " --snapshot-every 10 --snapshot-width 160 --snapshot-height 120" +
                                " --json " + log_file.string();
    ASSERT_EQ(run(command), 0) << command;
    const json log = load(log_file);
    EXPECT_EQ(log["summary"]["snapshots"]["count"], 4);
    std::vector<std::string> named;
    for (const auto& s : log["steps"]) {
        if (s.contains("snapshot")) {
            named.push_back(std::filesystem::path(s["snapshot"].get<std::string>()).filename());
        }
    }
    EXPECT_EQ(named, (std::vector<std::string>{"cloth-sphere-000010.png", "cloth-sphere-000020.png",
                                               "cloth-sphere-000025.png"}));
    std::vector<std::string> bytes;
    for (const char* name : {"cloth-sphere-000000.png", "cloth-sphere-000010.png",
                             "cloth-sphere-000020.png", "cloth-sphere-000025.png"}) {
        std::ifstream in(shots / name, std::ios::binary);
        ASSERT_TRUE(in) << name;
        std::string png((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        // The PNG signature, then IHDR: big-endian width and height at bytes 16 and 20.
        ASSERT_GT(png.size(), 24u) << name;
        EXPECT_EQ(png.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8)) << name;
        auto be32 = [&](std::size_t at) {
            std::uint32_t v = 0;
            for (std::size_t i = 0; i < 4; ++i) {
                v = (v << 8U) | static_cast<unsigned char>(png[at + i]);
            }
            return v;
        };
        EXPECT_EQ(be32(16), 160u) << name;
        EXPECT_EQ(be32(20), 120u) << name;
        bytes.push_back(std::move(png));
    }
    EXPECT_NE(bytes.front(), bytes.back());
}

// Standard error and exit status of a command line (standard output dropped).
std::pair<int, std::string> run_capturing_stderr(const std::string& command) {
    std::string err;
    FILE* p = popen((command + " 2>&1 >/dev/null").c_str(), "r");
    if (p == nullptr) {
        return {-1, err};
    }
    std::array<char, 512> buf{};
    while (std::fgets(buf.data(), static_cast<int>(buf.size()), p) != nullptr) {
        err += buf.data();
    }
    const int status = pclose(p);
    return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, err};
}

TEST(BulletExample, UsageErrorsExitTwoWithOneLineAndTheHelpHint) {
    const std::string bin = PROXIMA_BULLET_PATH;
    for (const std::string args : {" --server 127.0.0.1:1 --scene teapot",
                                   " --scene cloth-sphere",  // --server is required
                                   " --server 127.0.0.1:1 --steps 0",
                                   " --server 127.0.0.1:1 --snapshots d --snapshot-every 0"}) {
        const auto [code, err] = run_capturing_stderr(bin + args);
        EXPECT_EQ(code, 2) << args;
        EXPECT_EQ(err.rfind("proxima-bullet: error: ", 0), 0u) << err;
        EXPECT_NE(err.find("\nRun 'proxima-bullet --help'\n"), std::string::npos) << err;
        EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 2) << err;
    }
}

}  // namespace
}  // namespace proxima
