// proxima_ccd_frames_bench: full-frame continuous collision detection (proxima/ccd/frame_ccd.hpp)
// on the five real frame pairs of ../shared/data/frames: each file holds the whole scene as one
// mesh, split into objects by connected components (the same split at t0 and t1); every vertex
// moves linearly from t0 to t1.
//
//   proxima_ccd_frames_bench [--reps N] [--threads N] [--min-distance D] [--quick] [--data DIR]
//                            [--scenes a,b,...] [--no-prefilter] [--check]
//
// Reports per scene: objects, triangles, object pairs whose swept boxes meet, candidate triangle
// pairs, pairs the prefilter rejected, elementary tests (and what brute force would test),
// contacts (vf / ee, capped), the earliest time of impact, and the median broad / narrow / total
// seconds over the repetitions. --check runs each scene once more with the prefilter off and
// compares the pairs, times of impact and capped flags (listing the first differences).
// No peer: no library packaged in Debian 12 does continuous collision detection of deformable
// meshes with times of impact (FCL's CCD is for rigid motions of whole objects, Bullet's for convex
// shapes); the public Tight-Inclusion / scalable CCD codes are not packaged.

#include <sched.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/io/mesh_io.hpp"
#include "proxima/mesh/mesh.hpp"
#include "proxima/scene.hpp"

#include "bench_util.hpp"

namespace {

using namespace proxima;

struct FramePair {
    std::string name;
    std::string t0;
    std::string t1;
};

const std::vector<FramePair>& frame_pairs() {
    static const std::vector<FramePair> pairs{
        {"armadillo-rollers", "armadillo-rollers/326.ply", "armadillo-rollers/327.ply"},
        {"cloth-ball", "cloth-ball/cloth_ball92.ply", "cloth-ball/cloth_ball93.ply"},
        {"cloth-funnel", "cloth-funnel/227.ply", "cloth-funnel/228.ply"},
        {"n-body-simulation", "n-body-simulation/balls16_18.ply",
         "n-body-simulation/balls16_19.ply"},
        {"rod-twist", "rod-twist/3036.ply", "rod-twist/3037.ply"},
    };
    return pairs;
}

struct Options {
    int reps = 3;
    int threads = 0;
    double min_distance = 0.0;
    std::string data = PROXIMA_DATA_DIR;
    std::vector<std::string> scenes;
    bool prefilter = true;
    bool check = false;
};

int usage(const char* argv0, int code) {
    std::fprintf(code == 0 ? stdout : stderr,
                 "usage: %s [--reps N] [--threads N] [--min-distance D] [--quick] [--data DIR] "
                 "[--scenes a,b,...] [--no-prefilter] [--check]\n"
                 "  --reps N          repetitions per scene, median reported (default 3)\n"
                 "  --threads N       cap TBB's threads (default: all)\n"
                 "  --min-distance D  report contact within this distance (default 0)\n"
                 "  --quick           smoke run: 1 repetition, armadillo-rollers and cloth-funnel\n"
                 "  --data DIR        folder holding frames/<scene>/ (default: %s)\n"
                 "  --scenes LIST     only these scenes\n"
                 "  --no-prefilter    skip the prefilter (every swept-box candidate is tested)\n"
                 "  --check           also run once without the prefilter and compare the pairs\n"
                 "                    and times of impact (exit 1 on a difference)\n",
                 argv0, PROXIMA_DATA_DIR);
    return code;
}

// Both frames read without welding (the simulation's connectivity), split by the components of t0.
StatusOr<std::pair<Scene, std::vector<std::vector<Vec3>>>> load(const std::string& dir,
                                                                const FramePair& fp) {
    MeshReadOptions raw;
    raw.weld = WeldMode::never;
    auto m0 = read_mesh(dir + "/frames/" + fp.t0, raw);
    if (!m0.ok()) {
        return m0.status();
    }
    auto m1 = read_mesh(dir + "/frames/" + fp.t1, raw);
    if (!m1.ok()) {
        return m1.status();
    }
    if (m0->triangles != m1->triangles || m0->vertices.size() != m1->vertices.size()) {
        return invalid_argument(fp.name + ": the two frames do not share their topology");
    }
    auto split = split_components(m0.value());
    Scene scene;
    std::vector<std::vector<Vec3>> p1;
    for (std::size_t c = 0; c < split.meshes.size(); ++c) {
        auto id = scene.add_object({fp.name + "#" + std::to_string(c), split.meshes[c]});
        if (!id.ok()) {
            return id.status();
        }
        std::vector<Vec3> v;
        v.reserve(split.vertex_ids[c].size());
        for (auto i : split.vertex_ids[c]) {
            v.push_back(m1->vertices[i]);
        }
        p1.push_back(std::move(v));
    }
    return std::make_pair(std::move(scene), std::move(p1));
}

}  // namespace

int main(int argc, char** argv) {
    Options opt;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto value = [&]() -> std::string {
            if (i + 1 >= argc) {
                std::exit(usage(argv[0], 2));
            }
            return argv[++i];
        };
        try {
            if (a == "--reps") {
                opt.reps = std::max(1, std::stoi(value()));
            } else if (a == "--threads") {
                opt.threads = std::max(1, std::stoi(value()));
            } else if (a == "--min-distance") {
                opt.min_distance = std::stod(value());
            } else if (a == "--quick") {
                opt.reps = 1;
                opt.scenes = {"armadillo-rollers", "cloth-funnel"};
            } else if (a == "--data") {
                opt.data = value();
            } else if (a == "--scenes") {
                std::stringstream ss(value());
                opt.scenes.clear();
                for (std::string s; std::getline(ss, s, ',');) {
                    opt.scenes.push_back(s);
                }
            } else if (a == "--no-prefilter") {
                opt.prefilter = false;
            } else if (a == "--check") {
                opt.check = true;
            } else if (a == "--help" || a == "-h") {
                return usage(argv[0], 0);
            } else {
                return usage(argv[0], 2);
            }
        } catch (const std::exception&) {
            return usage(argv[0], 2);
        }
    }
    std::unique_ptr<tbb::global_control> cap;
    if (opt.threads > 0) {
        cap = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                    opt.threads);
    }
    const int threads = std::min<int>(tbb::this_task_arena::max_concurrency(),
                                      static_cast<int>(tbb::global_control::active_value(
                                          tbb::global_control::max_allowed_parallelism)));
    cpu_set_t set;
    CPU_ZERO(&set);
    const int cpus = sched_getaffinity(0, sizeof set, &set) == 0 ? CPU_COUNT(&set) : 0;
    std::printf("proxima_ccd_frames_bench: full-frame CCD (vf + ee, within and between objects)\n");
    std::printf("machine: %d CPUs (nproc), %s; TBB threads: %d; load average %s\n", cpus,
                bench::cpu_model().c_str(), threads, bench::load_average().c_str());
    std::printf("min_distance %g, tolerance %g, %d repetition(s), median seconds\n",
                opt.min_distance, ccd::ElementaryOptions{}.tolerance, opt.reps);
    std::printf(
        "peer: none (no Debian 12 package does CCD of deformable meshes with times of impact)\n");
    if (!std::filesystem::is_directory(opt.data + "/frames")) {
        std::fprintf(stderr, "proxima_ccd_frames_bench: no frames/ folder under '%s'\n",
                     opt.data.c_str());
        return 1;
    }
    std::printf("prefilter: %s\n", opt.prefilter ? "on" : "off (--no-prefilter)");
    std::printf("%-18s %7s %9s %8s %11s %11s %11s %14s %8s %7s %7s %10s %8s %8s %8s\n", "scene",
                "objects", "triangles", "obj-pairs", "tri-pairs", "prefiltered", "elem-tests",
                "brute-force", "contacts", "vf", "capped", "earliest", "broad-s", "narrow-s",
                "total-s");
    int status = 0;
    for (const auto& fp : frame_pairs()) {
        if (!opt.scenes.empty() &&
            std::find(opt.scenes.begin(), opt.scenes.end(), fp.name) == opt.scenes.end()) {
            continue;
        }
        auto loaded = load(opt.data, fp);
        if (!loaded.ok()) {
            std::fprintf(stderr, "%s: %s\n", fp.name.c_str(), loaded.status().to_string().c_str());
            status = 1;
            continue;
        }
        const auto& [scene, p1] = loaded.value();
        ccd::CcdRequest request;
        request.elementary.min_distance = opt.min_distance;
        request.prefilter = opt.prefilter;
        std::vector<double> broad;
        std::vector<double> narrow;
        std::vector<double> total;
        ccd::CcdResult last;
        for (int r = 0; r < opt.reps; ++r) {
            auto result = ccd::continuous_collisions(scene, p1, request);
            if (!result.ok()) {
                std::fprintf(stderr, "%s: %s\n", fp.name.c_str(),
                             result.status().to_string().c_str());
                status = 1;
                break;
            }
            broad.push_back(result->stats.broad_phase_seconds);
            narrow.push_back(result->stats.narrow_phase_seconds);
            total.push_back(result->stats.total_seconds);
            last = std::move(result).value();
        }
        if (total.empty()) {
            continue;
        }
        std::size_t vf = 0;
        for (const auto& p : last.pairs) {
            vf += p.kind == ccd::CcdKind::vertex_face ? 1 : 0;
        }
        char earliest[32] = "-";
        if (last.earliest) {
            std::snprintf(earliest, sizeof earliest, "%.6g", last.pairs[*last.earliest].toi);
        }
        const auto& st = last.stats;
        std::printf(
            "%-18s %7zu %9zu %8llu %11llu %11llu %11llu %14llu %8zu %7zu %7llu %10s %8.3f %8.3f "
            "%8.3f\n",
            fp.name.c_str(), scene.size(), scene.triangle_count(),
            static_cast<unsigned long long>(st.object_pairs_tested),
            static_cast<unsigned long long>(st.candidate_pairs),
            static_cast<unsigned long long>(st.prefilter_rejects),
            static_cast<unsigned long long>(st.elementary_tests),
            static_cast<unsigned long long>(st.brute_force_tests), last.pairs.size(), vf,
            static_cast<unsigned long long>(st.capped_tests), earliest, bench::median(broad),
            bench::median(narrow), bench::median(total));
        // A digest of the result (pairs, times of impact, capped flags), to compare builds.
        std::uint64_t digest = 1469598103934665603ull;
        auto mix = [&digest](std::uint64_t x) {
            for (int b = 0; b < 8; ++b) {
                digest = (digest ^ ((x >> (8 * b)) & 0xff)) * 1099511628211ull;
            }
        };
        for (const auto& p : last.pairs) {
            std::uint64_t toi_bits = 0;
            std::memcpy(&toi_bits, &p.toi, sizeof toi_bits);
            mix(static_cast<std::uint64_t>(p.kind));
            mix(p.object);
            mix(p.primitive);
            mix(p.other);
            mix(p.other_primitive);
            mix(toi_bits);
            mix(p.capped ? 1 : 0);
        }
        std::printf("  result digest %016llx\n", static_cast<unsigned long long>(digest));
        std::fflush(stdout);
        if (opt.check) {
            ccd::CcdRequest other = request;
            other.prefilter = !request.prefilter;
            auto ref = ccd::continuous_collisions(scene, p1, other);
            if (!ref.ok()) {
                std::fprintf(stderr, "%s: %s\n", fp.name.c_str(), ref.status().to_string().c_str());
                status = 1;
                continue;
            }
            auto same = [](const ccd::CcdPair& x, const ccd::CcdPair& y) {
                return x.kind == y.kind && x.object == y.object && x.primitive == y.primitive &&
                       x.other == y.other && x.other_primitive == y.other_primitive &&
                       x.toi == y.toi && x.capped == y.capped;
            };
            const bool equal =
                ref->pairs.size() == last.pairs.size() &&
                std::equal(last.pairs.begin(), last.pairs.end(), ref->pairs.begin(), same);
            std::printf("  check: %zu pairs with the prefilter %s, %zu without: %s\n",
                        last.pairs.size(), request.prefilter ? "on" : "off", ref->pairs.size(),
                        equal ? "identical (pairs, tois, capped)" : "DIFFERENT");
            if (!equal) {
                status = 1;
                // The first few differences (a pair only one run reports, or a different toi).
                auto key = [](const ccd::CcdPair& x) {
                    return std::tuple(x.kind, x.object, x.primitive, x.other, x.other_primitive);
                };
                const auto& with = request.prefilter ? last.pairs : ref->pairs;
                const auto& without = request.prefilter ? ref->pairs : last.pairs;
                std::size_t i = 0;
                std::size_t j = 0;
                int shown = 0;
                while ((i < with.size() || j < without.size()) && shown < 10) {
                    const bool take_i =
                        j == without.size() || (i < with.size() && key(with[i]) < key(without[j]));
                    const bool take_j =
                        i == with.size() || (j < without.size() && key(without[j]) < key(with[i]));
                    const ccd::CcdPair& x = take_j ? without[j] : with[i];
                    if (take_i || take_j || !same(with[i], without[j])) {
                        std::printf("    %s %u:%u - %u:%u  with filter: %s  without: %s\n",
                                    ccd::ccd_kind_name(x.kind), x.object, x.primitive, x.other,
                                    x.other_primitive,
                                    take_j ? "-"
                                           : (std::to_string(with[i].toi) +
                                              (with[i].capped ? " capped" : ""))
                                                 .c_str(),
                                    take_i ? "-"
                                           : (std::to_string(without[j].toi) +
                                              (without[j].capped ? " capped" : ""))
                                                 .c_str());
                        ++shown;
                    }
                    i += take_j ? 0 : 1;
                    j += take_i ? 0 : 1;
                }
            }
        }
    }
    return status;
}
