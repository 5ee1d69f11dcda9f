// proxima_bench: per-frame cost of the N-body proximity query on the five procedural scenes (seed
// 000 Table 1) and on the real frame pairs of ../shared/data/frames, with FCL 0.7 computing the
// object-level separation on the same geometry in the same run. Every object's separation
// distance is cross-checked against FCL's.
//
//   proxima_bench [--frames N] [--reps N] [--per-frame] [--quick] [--threads N]
//                 [--markdown FILE] [--data DIR] [--scenes a,b,...]
//
// Procedural scenes: frame 0 loads the objects (and builds every hierarchy); frames 1..N-1 each
// apply the scene's update and run separation + self with the BVH culler. Medians exclude frame 0.
// Real frames: t0 is loaded and queried once (the build); then each repetition applies the other
// frame's positions and runs the separation query, then a self query on the same positions.

#include <sched.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include <fcl/broadphase/broadphase_dynamic_AABB_tree.h>
#include <fcl/geometry/bvh/BVH_model.h>
#include <fcl/narrowphase/collision_object.h>
#include <fcl/narrowphase/distance.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>
#include <Eigen/Dense>

#include "proxima/distance/primitives.hpp"
#include "proxima/io/mesh_io.hpp"
#include "proxima/mesh/mesh.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scenes/procedural.hpp"

#include "bench_util.hpp"

#ifndef PROXIMA_DATA_DIR
#define PROXIMA_DATA_DIR ""
#endif

namespace {

using namespace proxima;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

std::string ms(double seconds) {
    return bench::fixed(1e3 * seconds, seconds < 0.01 ? 3 : 2);
}
std::string count(double v) {
    if (!std::isfinite(v)) {
        return "-";
    }
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.0f", v);
    return buf;
}
std::string sci(double v) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.3g", v);
    return buf;
}

// ---------------------------------------------------------------------------------------------
// Tables: printed aligned on stdout and, with --markdown, as Markdown.

struct Table {
    std::string title;
    std::vector<std::string> header;
    std::vector<std::vector<std::string>> rows;
    std::vector<std::string> notes;

    void print(std::ostream& out) const {
        std::vector<std::size_t> width(header.size(), 0);
        for (std::size_t c = 0; c < header.size(); ++c) {
            width[c] = header[c].size();
            for (const auto& r : rows) {
                width[c] = std::max(width[c], r[c].size());
            }
        }
        out << "\n" << title << "\n";
        auto line = [&](const std::vector<std::string>& cells) {
            for (std::size_t c = 0; c < cells.size(); ++c) {
                out << (c == 0 ? "" : "  ");
                if (c == 0) {
                    out << cells[c] << std::string(width[c] - cells[c].size(), ' ');
                } else {
                    out << std::string(width[c] - cells[c].size(), ' ') << cells[c];
                }
            }
            out << "\n";
        };
        line(header);
        for (const auto& r : rows) {
            line(r);
        }
        for (const auto& n : notes) {
            out << "  " << n << "\n";
        }
    }

    void markdown(std::ostream& out) const {
        out << "\n### " << title << "\n\n|";
        for (const auto& h : header) {
            out << " " << h << " |";
        }
        out << "\n|";
        for (std::size_t c = 0; c < header.size(); ++c) {
            out << (c == 0 ? "---|" : "---:|");
        }
        out << "\n";
        for (const auto& r : rows) {
            out << "|";
            for (const auto& cell : r) {
                out << " " << cell << " |";
            }
            out << "\n";
        }
        if (!notes.empty()) {
            out << "\n";
            for (const auto& n : notes) {
                out << n << "\n";
            }
        }
    }
};

// ---------------------------------------------------------------------------------------------
// FCL peer: object-level separation as BASELINES.md describes it. One AABB BVHModel per object
// (built once per topology), a dynamic AABB tree manager over the objects; moving = replacing the
// model's vertices with a bottom-up refit; the query = for every object, the distance to its
// closest other object through the manager's distance callback, exact (rel_err = abs_err = 0).

using FclModel = fcl::BVHModel<fcl::AABBd>;

struct NearestOther {
    const fcl::CollisionObjectd* self = nullptr;
    fcl::DistanceRequestd request{true /*nearest points*/, true, 0.0 /*rel_err*/, 0.0 /*abs_err*/};
    // Reused across the pairs of one query object, as FCL's DefaultDistanceFunction does: the
    // best distance so far prunes the next pair's traversal.
    fcl::DistanceResultd result;
};

bool nearest_other_callback(fcl::CollisionObjectd* o1, fcl::CollisionObjectd* o2, void* data,
                            double& dist) {
    auto* d = static_cast<NearestOther*>(data);
    if (o1 == o2) {
        return false;  // the query object is in the manager too
    }
    fcl::distance(o1, o2, d->request, d->result);
    dist = d->result.min_distance;
    return dist <= 0.0;  // touching: nothing can be closer
}

std::vector<fcl::Vector3d> to_fcl(const std::vector<Vec3>& vertices) {
    std::vector<fcl::Vector3d> out;
    out.reserve(vertices.size());
    for (const auto& v : vertices) {
        out.emplace_back(v.x, v.y, v.z);
    }
    return out;
}

class FclPeer {
  public:
    // Brings FCL up to date with the scene and returns the seconds it took. Objects with the same
    // id and topology as before are moved (vertex replacement + bottom-up refit); new or changed
    // ones are built, and then the manager is rebuilt.
    double sync(const Scene& scene) {
        const auto t0 = Clock::now();
        bool same = m_entries.size() == scene.size();
        for (std::size_t i = 0; same && i < scene.size(); ++i) {
            same = m_entries[i].id == scene[i].id &&
                   m_entries[i].topology_version == scene[i].topology_version;
        }
        if (same) {
            for (std::size_t i = 0; i < scene.size(); ++i) {
                move(m_entries[i], scene[i]);
            }
            m_manager->update();
        } else {
            std::unordered_map<ObjectId, Entry> old;
            for (auto& e : m_entries) {
                old.emplace(e.id, std::move(e));
            }
            m_entries.clear();
            for (const auto& obj : scene.objects()) {
                auto it = old.find(obj.id);
                if (it != old.end() && it->second.topology_version == obj.topology_version) {
                    move(it->second, obj);
                    m_entries.push_back(std::move(it->second));
                } else {
                    m_entries.push_back(build(obj));
                }
            }
            m_manager = std::make_unique<fcl::DynamicAABBTreeCollisionManagerd>();
            std::vector<fcl::CollisionObjectd*> objects;
            for (auto& e : m_entries) {
                objects.push_back(e.object.get());
            }
            m_manager->registerObjects(objects);
            m_manager->setup();
        }
        return seconds_since(t0);
    }

    // Distance from every object to its closest other object (+inf when alone).
    std::vector<double> query() const {
        std::vector<double> out;
        out.reserve(m_entries.size());
        for (const auto& e : m_entries) {
            NearestOther data;
            data.self = e.object.get();
            if (m_entries.size() > 1) {
                m_manager->distance(e.object.get(), &data, nearest_other_callback);
            }
            const double d = data.result.min_distance;
            out.push_back(m_entries.size() > 1 && d < std::numeric_limits<double>::max()
                              ? d
                              : std::numeric_limits<double>::infinity());
        }
        return out;
    }

  private:
    struct Entry {
        ObjectId id = 0;
        std::uint64_t topology_version = 0;
        std::shared_ptr<FclModel> model;
        std::unique_ptr<fcl::CollisionObjectd> object;
    };

    static Entry build(const SceneObject& obj) {
        Entry e;
        e.id = obj.id;
        e.topology_version = obj.topology_version;
        e.model = std::make_shared<FclModel>();
        std::vector<fcl::Triangle> tris;
        tris.reserve(obj.triangle_count());
        for (const auto& t : obj.topology->triangles()) {
            tris.emplace_back(t[0], t[1], t[2]);
        }
        e.model->beginModel(static_cast<int>(tris.size()), static_cast<int>(obj.vertices.size()));
        e.model->addSubModel(to_fcl(obj.vertices), tris);
        e.model->endModel();
        e.model->computeLocalAABB();
        e.object = std::make_unique<fcl::CollisionObjectd>(e.model);
        return e;
    }

    static void move(Entry& e, const SceneObject& obj) {
        e.model->beginReplaceModel();
        e.model->replaceSubModel(to_fcl(obj.vertices));
        e.model->endReplaceModel(true /*refit*/, true /*bottom-up*/);
        // endReplaceModel refits the BVH but not the model's local box, which is what the
        // collision object's (and so the manager's) box is computed from: without this the
        // broad phase culls with last frame's boxes and misses the closest object.
        e.model->computeLocalAABB();
        e.object->computeAABB();
    }

    std::vector<Entry> m_entries;
    std::unique_ptr<fcl::DynamicAABBTreeCollisionManagerd> m_manager;
};

// Our per-object separation against FCL's: equal within 1e-9 relative + 1e-12 absolute.
struct Mismatch {
    std::size_t object = 0;
    double ours = 0;
    double fcl = 0;
};

std::vector<Mismatch> cross_check(const QueryResult& ours, const std::vector<double>& fcl) {
    std::vector<Mismatch> out;
    for (std::size_t i = 0; i < fcl.size(); ++i) {
        const double a = i < ours.separation.size() ? ours.separation[i].distance
                                                    : std::numeric_limits<double>::quiet_NaN();
        const double b = fcl[i];
        const bool both_inf = std::isinf(a) && std::isinf(b);
        if (!both_inf && !(std::abs(a - b) <= 1e-9 * std::max(std::abs(a), std::abs(b)) + 1e-12)) {
            out.push_back({i, a, b});
        }
    }
    return out;
}

void report_mismatches(const std::string& where, const Scene& scene,
                       const std::vector<Mismatch>& mismatches, std::vector<std::string>& log) {
    for (std::size_t m = 0; m < mismatches.size() && m < 5; ++m) {
        const auto& x = mismatches[m];
        char buf[512];
        std::snprintf(
            buf, sizeof buf, "MISMATCH %s: object %zu ('%s'): ours %.17g, FCL %.17g (diff %.3g)",
            where.c_str(), x.object, scene[x.object].name.c_str(), x.ours, x.fcl, x.ours - x.fcl);
        std::cerr << buf << "\n";
        log.emplace_back(buf);
    }
    if (mismatches.size() > 5) {
        log.push_back("MISMATCH " + where + ": ... " + std::to_string(mismatches.size() - 5) +
                      " more");
    }
}

// ---------------------------------------------------------------------------------------------

struct Options {
    std::size_t frames = 16;
    std::size_t reps = 5;
    bool per_frame = false;
    bool quick = false;
    int threads = 0;
    std::string markdown;
    std::string data = PROXIMA_DATA_DIR;
    std::vector<std::string> scenes;  // empty: all
    std::string command_line;
    std::size_t stream = 0;                     // --stream N: only the per-frame stream spread
    CullerKind culler = CullerKind::automatic;  // of the stream
};

bool wanted(const Options& opt, const std::string& name) {
    return opt.scenes.empty() ||
           std::find(opt.scenes.begin(), opt.scenes.end(), name) != opt.scenes.end();
}

int usage(const char* argv0, int code) {
    std::fprintf(code == 0 ? stdout : stderr,
                 "usage: %s [--frames N] [--reps N] [--per-frame] [--quick] [--threads N]\n"
                 "          [--markdown FILE] [--data DIR] [--scenes a,b,...]\n"
                 "  --frames N     frames per procedural scene (default 16; frame 0 is the build)\n"
                 "  --reps N       timed repetitions per real frame pair (default 5)\n"
                 "  --per-frame    also print every frame of the procedural scenes\n"
                 "  --quick        smoke run: 2 frames, 2 reps, armadillo-rollers, cloth-funnel\n"
                 "  --threads N    cap TBB's parallelism (default: all cores)\n"
                 "  --markdown F   also write the tables as Markdown to F\n"
                 "  --data DIR     folder holding frames/<scene>/ (default: %s)\n"
                 "  --scenes LIST  only these scenes (procedural or real names)\n"
                 "  --stream N     instead: stream N frames per scene with the demo's query\n"
                 "                 (separation + self + collisions) and print each stream's\n"
                 "                 per-frame median, p99 and max; scenes: procedural names or\n"
                 "                 real/<frames scene> (t0, t1, t0, ...), default\n"
                 "                 cloth-ball,real/armadillo-rollers,real/cloth-funnel\n"
                 "  --culler NAME  the stream's culler (default auto)\n",
                 argv0, PROXIMA_DATA_DIR);
    return code;
}

struct Machine {
    int cpus = 0;
    std::string model;
    std::string date;
    int threads = 0;
};

// The 1-minute load average: other work on the machine shows up in every timing.
std::string load_average() {
    std::ifstream in("/proc/loadavg");
    std::string one;
    in >> one;
    return one.empty() ? "?" : one;
}

Machine machine() {
    Machine m;
    cpu_set_t set;
    CPU_ZERO(&set);
    m.cpus = sched_getaffinity(0, sizeof set, &set) == 0 ? CPU_COUNT(&set) : 0;
    m.model = bench::cpu_model();
    const std::time_t now = std::time(nullptr);
    char buf[64];
    std::strftime(buf, sizeof buf, "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
    m.date = buf;
    // --threads caps TBB through global_control, which the arena's concurrency does not show.
    m.threads = std::min<int>(tbb::this_task_arena::max_concurrency(),
                              static_cast<int>(tbb::global_control::active_value(
                                  tbb::global_control::max_allowed_parallelism)));
    return m;
}

// Single-thread cost of one exact triangle-triangle distance test, on pairs of nearby
// non-adjacent triangles of the skirt (folded cloth): what an exact test costs on this machine,
// to tell culling overhead from exact work in the tables.
double exact_test_seconds() {
    const auto ps = scenes::skirt(2);
    const TriangleMesh& cloth = ps.initial.front().mesh;
    const auto n = static_cast<std::uint32_t>(cloth.triangles.size());
    std::mt19937_64 gen(7);
    std::vector<std::pair<Triangle, Triangle>> pairs;
    auto corners = [&](std::uint32_t t) {
        const auto& tri = cloth.triangles[t];
        return Triangle{cloth.vertices[tri[0]], cloth.vertices[tri[1]], cloth.vertices[tri[2]]};
    };
    while (pairs.size() < 100000) {
        const auto t = static_cast<std::uint32_t>(gen() % n);
        const auto u = static_cast<std::uint32_t>((t + 2 + gen() % 400) % n);
        if (!share_vertex(cloth.triangles[t], cloth.triangles[u])) {
            pairs.emplace_back(corners(t), corners(u));
        }
    }
    double best = std::numeric_limits<double>::infinity();
    volatile double sink = 0;
    for (int round = 0; round < 3; ++round) {
        const auto t0 = Clock::now();
        double sum = 0;
        for (const auto& [a, b] : pairs) {
            sum += triangle_triangle(a, b).squared_distance;
        }
        sink = sink + sum;
        best = std::min(best, seconds_since(t0) / static_cast<double>(pairs.size()));
    }
    return best;
}

// ---------------------------------------------------------------------------------------------
// Procedural scenes.

struct FrameRow {
    double gen = 0, update = 0, prepare = 0, broad = 0, separation = 0, self = 0, total = 0;
    double exact = 0, brute = 0;
    double fcl_move = 0, fcl_query = 0;
    std::size_t objects = 0, triangles = 0, mismatches = 0;
};

struct Goal {
    const char* scene;
    double frame_ms;
};
constexpr Goal PROCEDURAL_GOALS[] = {
    {"skirt", 26}, {"cloth-ball", 35}, {"bowl", 4}, {"ramps", 55}, {"breaking", 6}};

double procedural_goal(const std::string& name) {
    for (const auto& g : PROCEDURAL_GOALS) {
        if (name == g.scene) {
            return g.frame_ms;
        }
    }
    return std::nan("");
}

struct ProceduralSummary {
    std::string name;
    std::vector<FrameRow> frames;
};

ProceduralSummary run_procedural(const std::string& name, const Options& opt,
                                 std::vector<std::string>& log) {
    ProceduralSummary summary;
    summary.name = name;
    const auto ps = scenes::by_name(name, opt.frames);
    ProximityEngine engine;
    FclPeer fcl;
    QueryRequest request;
    request.separation = true;
    request.self = true;
    request.culler = CullerKind::bvh;
    for (std::size_t k = 0; k < ps.frame_count; ++k) {
        FrameRow row;
        auto t0 = Clock::now();
        if (k == 0) {
            for (const auto& m : ps.initial) {
                auto id = engine.scene().add_object(m);
                if (!id.ok()) {
                    std::cerr << name << ": " << id.status().to_string() << "\n";
                    std::exit(1);
                }
            }
        } else {
            auto update = ps.step(k, engine.scene());
            row.gen = seconds_since(t0);
            t0 = Clock::now();
            auto applied = engine.scene().apply(std::move(update));
            if (!applied.ok()) {
                std::cerr << name << " frame " << k << ": " << applied.status().to_string() << "\n";
                std::exit(1);
            }
        }
        row.update = seconds_since(t0);
        auto result = engine.query(request);
        if (!result.ok()) {
            std::cerr << name << " frame " << k << ": " << result.status().to_string() << "\n";
            std::exit(1);
        }
        const auto& st = result->stats;
        row.prepare = st.prepare_seconds;
        row.broad = st.broad_phase_seconds;
        row.separation = st.separation_seconds;
        row.self = st.self_seconds;
        row.total = st.total_seconds;
        row.exact = static_cast<double>(st.exact_tests);
        row.brute = static_cast<double>(st.brute_force_tests);
        row.objects = engine.scene().size();
        row.triangles = engine.scene().triangle_count();

        row.fcl_move = fcl.sync(engine.scene());
        t0 = Clock::now();
        const auto fcl_distances = fcl.query();
        row.fcl_query = seconds_since(t0);
        const auto mismatches = cross_check(result.value(), fcl_distances);
        row.mismatches = mismatches.size();
        report_mismatches(name + " frame " + std::to_string(k), engine.scene(), mismatches, log);
        summary.frames.push_back(row);
    }
    return summary;
}

double median_of(const std::vector<FrameRow>& rows, double FrameRow::*field) {
    std::vector<double> v;
    for (std::size_t k = 1; k < rows.size(); ++k) {
        v.push_back(rows[k].*field);
    }
    return bench::median(v);
}

std::vector<double> frame_totals(const std::vector<FrameRow>& rows, bool separation_only) {
    std::vector<double> v;
    for (std::size_t k = 1; k < rows.size(); ++k) {
        const auto& r = rows[k];
        v.push_back(separation_only ? r.update + r.prepare + r.broad + r.separation
                                    : r.update + r.total);
    }
    return v;
}

// ---------------------------------------------------------------------------------------------
// Real frame pairs.

struct RealGoal {
    const char* scene;
    const char* label;
    double separation_ms;  // BASELINES.md: 3x faster than FCL's best correct per-frame time
    double self_ms;        // issue #14: >= 4x faster self distance per frame (NaN: no goal)
};
const RealGoal REAL_SCENES[] = {
    {"armadillo-rollers", "armadillo-rollers", 1.6, 15},
    {"cloth-ball", "cloth-ball", 10, 100},
    {"cloth-funnel", "cloth-funnel", 6, 10},
    {"n-body-simulation", "n-body", 67, 25},
    {"rod-twist", "rod-twist", 108, 30},
};

struct RealSummary {
    std::string name;
    std::size_t objects = 0, triangles = 0;
    double fcl_build = 0, our_build = 0;
    std::vector<double> fcl_move, fcl_query, update, prepare, broad, separation, separation_exact;
    std::vector<double> self, self_exact;            // warm: seeded by the previous frame's answer
    std::vector<double> self_cold, self_cold_exact;  // the same frame again, coherence forgotten
    // The same frame again right after the warm query, seeded by that very answer: what a warm
    // frame would cost if its seeds were already every triangle's closest triangle.
    std::vector<double> self_ideal, self_ideal_exact;
    std::size_t self_differences = 0;  // triangles whose warm, ideal-seed or cold answers differ
    // Per step, the share of triangles whose closest triangle is the previous frame's (the
    // warm seed was already the answer): how coherent the frame pair is.
    std::vector<double> self_kept;
    std::vector<double> self_floor, self_pairs;  // item 7: answer pairs x one exact test
    // One step's motion against the self distances it must resolve (motion_against_distances).
    double move_median = 0, move_max = 0, distance_median = 0, skin_pairs = 0;
    double rigid_median = 0, rigid_max = 0, rigid_skin_pairs = 0;
    double separation_goal = 0, self_goal = 0;
    std::size_t mismatches = 0, checks = 0;
    std::string skipped;
};

struct FramePair {
    std::vector<TriangleMesh> t0;       // objects at t0
    std::vector<std::vector<Vec3>> t1;  // the same objects' vertices at t1
};

// Reads both frames without welding: indexed PLY files already share their vertices, and welding
// each frame on its own could merge coincident vertices in one frame and not in the other. The
// t1 positions are taken through t0's component split, so objects correspond exactly.
StatusOr<FramePair> load_pair(const std::string& a, const std::string& b) {
    MeshReadOptions raw;
    raw.weld = WeldMode::never;
    auto m0 = read_mesh(a, raw);
    if (!m0.ok()) {
        return m0.status();
    }
    auto m1 = read_mesh(b, raw);
    if (!m1.ok()) {
        return m1.status();
    }
    if (m0->triangles != m1->triangles || m0->vertices.size() != m1->vertices.size()) {
        return invalid_argument("'" + a + "' and '" + b + "' do not share their connectivity");
    }
    auto split = split_components(m0.value());
    FramePair pair;
    for (std::size_t c = 0; c < split.meshes.size(); ++c) {
        std::vector<Vec3> v1;
        v1.reserve(split.vertex_ids[c].size());
        for (auto id : split.vertex_ids[c]) {
            v1.push_back(m1->vertices[id]);
        }
        pair.t1.push_back(std::move(v1));
        pair.t0.push_back(std::move(split.meshes[c]));
    }
    return pair;
}

// The frame pair of a real scene: the two .ply files in <data>/frames/<scene>, in name order.
StatusOr<FramePair> load_scene_pair(const std::string& data, const std::string& scene) {
    namespace fs = std::filesystem;
    const fs::path dir = fs::path(data) / "frames" / scene;
    std::vector<std::string> files;
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(dir, ec)) {
        if (entry.path().extension() == ".ply") {
            files.push_back(entry.path().string());
        }
    }
    std::sort(files.begin(), files.end());
    if (ec || files.size() != 2) {
        return not_found("no frame pair in " + dir.string());
    }
    return load_pair(files[0], files[1]);
}

// Each vertex's distance from where the rigid motion that best fits the object's step (least
// squares, Kabsch: the SVD of the 3x3 covariance) puts it: the object's own deformation.
std::vector<double> rigid_residuals(const std::vector<Vec3>& from, const std::vector<Vec3>& to) {
    const auto n = static_cast<double>(from.size());
    Eigen::Vector3d c0 = Eigen::Vector3d::Zero();
    Eigen::Vector3d c1 = Eigen::Vector3d::Zero();
    auto e = [](const Vec3& v) { return Eigen::Vector3d(v.x, v.y, v.z); };
    for (std::size_t v = 0; v < from.size(); ++v) {
        c0 += e(from[v]) / n;
        c1 += e(to[v]) / n;
    }
    Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
    for (std::size_t v = 0; v < from.size(); ++v) {
        h += (e(from[v]) - c0) * (e(to[v]) - c1).transpose();
    }
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d v = svd.matrixV();
    if ((v * svd.matrixU().transpose()).determinant() < 0) {
        v.col(2) *= -1.0;  // a rotation, not a reflection
    }
    const Eigen::Matrix3d r = v * svd.matrixU().transpose();
    std::vector<double> out(from.size());
    for (std::size_t k = 0; k < from.size(); ++k) {
        out[k] = (e(to[k]) - (r * (e(from[k]) - c0) + c1)).norm();
    }
    return out;
}

// How far the frame pair's vertices move in one step against the self distances at t0, for a
// neighbour list kept across frames (a Verlet list): at t0 it would hold, for each triangle t,
// every non-adjacent triangle within best(t) + skin, and it stays valid at t1 while the skin
// covers both triangles' moves: skin = 2 x the object's largest vertex move, or, with the
// object's best-fitting rigid motion subtracted (self distances do not change under it), 2 x its
// largest rigid residual. `skin_pairs` and `rigid_skin_pairs` are those lists' lengths per
// triangle, counted by brute force (exact distances) for up to 200 evenly spaced triangles of each
// object (`best` from `answers`, t0's self answer).
void motion_against_distances(const FramePair& pair,
                              const std::vector<std::vector<SelfDistance>>& answers,
                              RealSummary& s) {
    std::vector<double> moves;
    std::vector<double> residuals;
    std::vector<double> distances;
    double listed = 0;
    double rigid_listed = 0;
    std::size_t sampled = 0;
    for (std::size_t o = 0; o < pair.t0.size() && o < answers.size(); ++o) {
        const TriangleMesh& mesh = pair.t0[o];
        double largest = 0;
        for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
            moves.push_back(norm(pair.t1[o][v] - mesh.vertices[v]));
            largest = std::max(largest, moves.back());
        }
        s.move_max = std::max(s.move_max, largest);
        const auto residual = rigid_residuals(mesh.vertices, pair.t1[o]);
        const double rigid_largest = *std::max_element(residual.begin(), residual.end());
        s.rigid_max = std::max(s.rigid_max, rigid_largest);
        residuals.insert(residuals.end(), residual.begin(), residual.end());
        for (const auto& a : answers[o]) {
            if (a.closest != NO_OBJECT) {
                distances.push_back(a.distance);
            }
        }
        const auto& tris = mesh.triangles;
        auto corners = [&](std::size_t t) {
            return Triangle{mesh.vertices[tris[t][0]], mesh.vertices[tris[t][1]],
                            mesh.vertices[tris[t][2]]};
        };
        const std::size_t n = tris.size();
        const std::size_t samples = std::min<std::size_t>(n, 200);
        for (std::size_t k = 0; k < samples; ++k) {
            const std::size_t t = k * n / samples;
            if (answers[o][t].closest == NO_OBJECT) {
                continue;
            }
            const double reach = answers[o][t].distance + 2.0 * largest;
            const double rigid_reach = answers[o][t].distance + 2.0 * rigid_largest;
            const Triangle x = corners(t);
            for (std::size_t u = 0; u < n; ++u) {
                bool adjacent = false;
                for (const auto i : tris[t]) {
                    for (const auto j : tris[u]) {
                        adjacent = adjacent || i == j;
                    }
                }
                if (adjacent) {
                    continue;
                }
                const double d_sq = triangle_triangle(x, corners(u)).squared_distance;
                listed += d_sq < reach * reach ? 1 : 0;
                rigid_listed += d_sq < rigid_reach * rigid_reach ? 1 : 0;
            }
            ++sampled;
        }
    }
    s.move_median = bench::median(moves);
    s.distance_median = bench::median(distances);
    s.skin_pairs = sampled == 0 ? 0.0 : listed / static_cast<double>(sampled);
    s.rigid_median = bench::median(residuals);
    s.rigid_skin_pairs = sampled == 0 ? 0.0 : rigid_listed / static_cast<double>(sampled);
}

RealSummary run_real(const RealGoal& goal, const Options& opt, std::vector<std::string>& log) {
    RealSummary s;
    s.name = goal.label;
    s.separation_goal = goal.separation_ms;
    s.self_goal = goal.self_ms;
    auto pair = load_scene_pair(opt.data, goal.scene);
    if (!pair.ok()) {
        s.skipped = pair.status().message();
        return s;
    }

    // The t0 objects into an engine (false: one was refused, s.skipped says why).
    auto add_objects = [&](ProximityEngine& e) {
        for (std::size_t c = 0; c < pair->t0.size(); ++c) {
            auto id = e.scene().add_object(
                {goal.label + std::string(".") + std::to_string(c), pair->t0[c]});
            if (!id.ok()) {
                s.skipped = id.status().to_string();
                return false;
            }
        }
        return true;
    };
    ProximityEngine engine;
    const auto load_start = Clock::now();
    if (!add_objects(engine)) {
        return s;
    }
    const double load = seconds_since(load_start);
    s.objects = engine.scene().size();
    s.triangles = engine.scene().triangle_count();
    // The cold queries run on an engine of their own with the same objects and positions: the
    // stream's engine keeps what a real stream keeps between frames (the last answer and, for a
    // rigidly moving object, its candidate list), so its warm frames are a stream's.
    ProximityEngine cold_engine;
    if (!add_objects(cold_engine)) {
        return s;
    }
    QueryRequest separation;
    separation.separation = true;
    separation.culler = CullerKind::bvh;
    QueryRequest self;
    self.separation = false;
    self.self = true;
    self.culler = CullerKind::bvh;

    FclPeer fcl;
    s.fcl_build = fcl.sync(engine.scene());
    auto first = engine.query(separation);
    if (!first.ok()) {
        s.skipped = first.status().to_string();
        return s;
    }
    s.our_build = load + first->stats.total_seconds;
    auto check = [&](const QueryResult& r, const std::string& when) {
        const auto mism = cross_check(r, fcl.query());
        s.mismatches += mism.size();
        ++s.checks;
        report_mismatches(s.name + " " + when, engine.scene(), mism, log);
    };
    check(first.value(), "t0 (build)");
    // The t0 self answer, untimed: the first timed step is then a warm one-frame step.
    auto primed = engine.query(self);
    if (!primed.ok()) {
        s.skipped = primed.status().to_string();
        return s;
    }
    // The answer the next warm query is seeded with (the engine remembers the last answer).
    std::vector<std::vector<SelfDistance>> previous = std::move(primed->self);
    motion_against_distances(pair.value(), previous, s);

    for (std::size_t rep = 0; rep < opt.reps; ++rep) {
        // Alternate t1, t0, t1, ...: every repetition is a real one-frame step.
        const bool to_t1 = rep % 2 == 0;
        SceneUpdate update;
        SceneUpdate cold_update;
        for (std::size_t i = 0; i < engine.scene().size(); ++i) {
            update.positions.push_back(
                {engine.scene()[i].id, to_t1 ? pair->t1[i] : pair->t0[i].vertices});
            cold_update.positions.push_back(
                {cold_engine.scene()[i].id, to_t1 ? pair->t1[i] : pair->t0[i].vertices});
        }
        if (auto applied = cold_engine.scene().apply(std::move(cold_update)); !applied.ok()) {
            s.skipped = applied.status().to_string();
            return s;
        }
        auto t0 = Clock::now();
        auto applied = engine.scene().apply(std::move(update));
        s.update.push_back(seconds_since(t0));
        if (!applied.ok()) {
            s.skipped = applied.status().to_string();
            return s;
        }
        auto r = engine.query(separation);
        if (!r.ok()) {
            s.skipped = r.status().to_string();
            return s;
        }
        s.prepare.push_back(r->stats.prepare_seconds);
        s.broad.push_back(r->stats.broad_phase_seconds);
        s.separation.push_back(r->stats.separation_seconds);
        s.separation_exact.push_back(static_cast<double>(r->stats.exact_tests));

        s.fcl_move.push_back(fcl.sync(engine.scene()));
        t0 = Clock::now();
        const auto d = fcl.query();
        s.fcl_query.push_back(seconds_since(t0));
        const auto mism = cross_check(r.value(), d);
        s.mismatches += mism.size();
        ++s.checks;
        report_mismatches(s.name + (to_t1 ? " t1" : " t0") + " rep " + std::to_string(rep),
                          engine.scene(), mism, log);

        // Records one self query's time and exact tests (false: it failed, s.skipped says why).
        auto record = [&](const StatusOr<QueryResult>& r, std::vector<double>& seconds,
                          std::vector<double>& exact) {
            if (!r.ok()) {
                s.skipped = r.status().to_string();
                return false;
            }
            seconds.push_back(r->stats.self_seconds);
            exact.push_back(static_cast<double>(r->stats.exact_tests));
            return true;
        };
        const auto sr = engine.query(self);
        if (!record(sr, s.self, s.self_exact)) {
            return s;
        }
        // Floor (issue #14 item 7): the exact tests the answer itself needs, one per reported
        // pair (a pair two triangles report for each other counted once), timed here on one
        // thread by running exactly those tests again.
        {
            std::size_t pairs = 0;
            double sink = 0;
            const auto f0 = Clock::now();
            for (std::size_t o = 0; o < sr->self.size(); ++o) {
                const SceneObject& obj = engine.scene()[o];
                const auto& tris = obj.topology->triangles();
                auto corners = [&](std::size_t t) {
                    return Triangle{obj.vertices[tris[t][0]], obj.vertices[tris[t][1]],
                                    obj.vertices[tris[t][2]]};
                };
                for (std::size_t t = 0; t < sr->self[o].size(); ++t) {
                    const auto c = sr->self[o][t].closest;
                    if (c == NO_OBJECT || (static_cast<std::size_t>(c) < t &&
                                           sr->self[o][static_cast<std::size_t>(c)].closest ==
                                               static_cast<std::int64_t>(t))) {
                        continue;
                    }
                    sink += triangle_triangle(corners(t), corners(static_cast<std::size_t>(c)))
                                .squared_distance;
                    ++pairs;
                }
            }
            s.self_floor.push_back(seconds_since(f0));
            s.self_pairs.push_back(static_cast<double>(pairs));
            if (sink < 0) {
                std::printf("%g\n", sink);  // keeps the tests from being optimised away
            }
        }
        // Ideal seeds: the same geometry again, seeded by its own answer (the warm query's).
        const auto ir = engine.query(self);
        if (!record(ir, s.self_ideal, s.self_ideal_exact)) {
            return s;
        }
        // Cold: the same geometry without the previous frame's answer (item 5: warm vs cold).
        cold_engine.forget_coherence();
        const auto cr = cold_engine.query(self);
        if (!record(cr, s.self_cold, s.self_cold_exact)) {
            return s;
        }
        std::size_t kept = 0;
        std::size_t total = 0;
        for (std::size_t o = 0; o < sr->self.size() && o < previous.size(); ++o) {
            for (std::size_t t = 0; t < sr->self[o].size() && t < previous[o].size(); ++t) {
                kept += sr->self[o][t].closest == previous[o][t].closest ? 1 : 0;
                ++total;
            }
        }
        s.self_kept.push_back(total == 0 ? 0.0 : static_cast<double>(kept) / total);
        previous = cr->self;
        for (std::size_t o = 0; o < sr->self.size(); ++o) {
            for (std::size_t t = 0; t < sr->self[o].size(); ++t) {
                const auto& w = sr->self[o][t];
                const auto& c = cr->self[o][t];
                const auto& i = ir->self[o][t];
                if (w.closest != c.closest || w.distance != c.distance || w.closest != i.closest ||
                    w.distance != i.distance) {
                    ++s.self_differences;
                }
            }
        }
    }
    return s;
}

// ---- Per-frame stream spread (issue #14, "no spikes"): one engine, N lockstep frames with the
// demo's query (separation + self + collisions), each frame = apply the update + query. What a
// client sees is the spread of these times: p99 and max against the median.
struct StreamSummary {
    std::string name;
    std::size_t triangles = 0;
    std::vector<double> frame;  // seconds, frames 1..N-1 (frame 0 builds)
    double build = 0;
    std::map<std::string, std::size_t> cullers;  // culler -> frames it ran (1..N-1)
    std::uint64_t voronoi_frames = 0;            // frames 1..N-1 that ran Stage II (dvd samples)
    std::string skipped;
};

double percentile_of(std::vector<double> v, double q) {
    if (v.empty()) {
        return std::nan("");
    }
    std::sort(v.begin(), v.end());
    const auto rank = static_cast<std::size_t>(std::ceil(q * static_cast<double>(v.size())));
    return v[std::max<std::size_t>(rank, 1) - 1];  // nearest rank
}

StreamSummary run_stream(const std::string& name, const Options& opt) {
    StreamSummary s;
    s.name = name;
    QueryRequest request;
    request.separation = true;
    request.self = true;
    request.collisions = true;
    request.culler = opt.culler;
    ProximityEngine engine;
    // Frame k's update (k >= 1); frame 0 adds the objects.
    std::function<StatusOr<SceneUpdate>(std::size_t)> step;
    std::optional<scenes::ProceduralScene> procedural;
    std::optional<FramePair> pair;
    if (name.rfind("real/", 0) == 0) {
        auto loaded = load_scene_pair(opt.data, name.substr(5));
        if (!loaded.ok()) {
            s.skipped = loaded.status().message();
            return s;
        }
        pair = std::move(loaded).value();
        for (std::size_t c = 0; c < pair->t0.size(); ++c) {
            if (auto id = engine.scene().add_object({name + "." + std::to_string(c), pair->t0[c]});
                !id.ok()) {
                s.skipped = id.status().to_string();
                return s;
            }
        }
        step = [&](std::size_t k) -> StatusOr<SceneUpdate> {
            SceneUpdate u;
            for (std::size_t i = 0; i < engine.scene().size(); ++i) {
                u.positions.push_back(
                    {engine.scene()[i].id, k % 2 == 1 ? pair->t1[i] : pair->t0[i].vertices});
            }
            return u;
        };
    } else {
        procedural = scenes::by_name(name, opt.stream);
        if (procedural->name.empty()) {
            s.skipped = "unknown scene";
            return s;
        }
        SceneUpdate first;
        first.additions = procedural->initial;
        if (auto r = engine.scene().apply(std::move(first)); !r.ok()) {
            s.skipped = r.status().to_string();
            return s;
        }
        step = [&](std::size_t k) -> StatusOr<SceneUpdate> {
            return procedural->step(k, engine.scene());
        };
    }
    for (std::size_t k = 0; k < opt.stream; ++k) {
        double update = 0;
        if (k > 0) {
            auto u = step(k);
            if (!u.ok()) {
                s.skipped = u.status().to_string();
                return s;
            }
            const auto t0 = Clock::now();
            auto applied = engine.scene().apply(std::move(u).value());
            update = seconds_since(t0);
            if (!applied.ok()) {
                s.skipped = applied.status().to_string();
                return s;
            }
        }
        auto r = engine.query(request);
        if (!r.ok()) {
            s.skipped = r.status().to_string();
            return s;
        }
        const double frame = update + r->stats.total_seconds;
        if (k == 0) {
            s.build = frame;
            continue;
        }
        s.frame.push_back(frame);
        ++s.cullers[r->stats.culler];
        s.voronoi_frames += r->stats.dvd_samples > 0 ? 1 : 0;
    }
    s.triangles = engine.scene().triangle_count();
    return s;
}

int run_streams(const Options& opt) {
    std::vector<std::string> names = opt.scenes;
    if (names.empty()) {
        names = {"cloth-ball", "real/armadillo-rollers", "real/cloth-funnel"};
    }
    Table t;
    t.title = "Per-frame stream: separation + self + collisions, culler " +
              std::string(culler_name(opt.culler)) + ", frames 1.." +
              std::to_string(opt.stream - 1) + " (ms)";
    t.header = {"scene",
                "triangles",
                "build (frame 0)",
                "median",
                "p99",
                "max",
                "p99 / median",
                "max / median",
                "cullers (frames)",
                "frames with Voronoi stage"};
    std::uint64_t unasked_voronoi = 0;
    for (const auto& name : names) {
        std::fprintf(stderr, "stream %s: %zu frames...\n", name.c_str(), opt.stream);
        const auto s = run_stream(name, opt);
        if (!s.skipped.empty()) {
            std::printf("skipping stream '%s': %s\n", name.c_str(), s.skipped.c_str());
            continue;
        }
        const double med = bench::median(s.frame);
        const double p99 = percentile_of(s.frame, 0.99);
        const double mx = *std::max_element(s.frame.begin(), s.frame.end());
        std::string used;
        for (const auto& [c, n] : s.cullers) {
            used += (used.empty() ? "" : ", ") + c + " " + std::to_string(n);
        }
        t.rows.push_back({s.name, std::to_string(s.triangles), ms(s.build), ms(med), ms(p99),
                          ms(mx), bench::fixed(p99 / med, 2), bench::fixed(mx / med, 2), used,
                          std::to_string(s.voronoi_frames)});
        if (opt.culler == CullerKind::automatic) {
            unasked_voronoi += s.voronoi_frames;
        }
    }
    t.notes = {
        "frame = Scene::apply of the frame's update + ProximityEngine::query; p99 by "
        "nearest rank; real/<scene> alternates the pair's t1, t0, t1, ..."};
    t.print(std::cout);
    if (!opt.markdown.empty()) {
        std::ofstream md(opt.markdown);
        md << "Command: `" << opt.command_line << "`\n";
        t.markdown(md);
    }
    // Nothing in these streams asks for a Voronoi culler, so `auto` must never run one (issue #14:
    // no exploration on a client's frame).
    if (unasked_voronoi > 0) {
        std::printf("FAILED: culler auto ran a Voronoi stage on %llu frames nobody asked for\n",
                    static_cast<unsigned long long>(unasked_voronoi));
        return 3;
    }
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    Options opt;
    for (int i = 0; i < argc; ++i) {
        opt.command_line += (i == 0 ? "" : " ") + std::string(argv[i]);
    }
    bool frames_given = false;
    bool reps_given = false;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto value = [&]() -> std::string {
            if (i + 1 >= argc) {
                std::fprintf(stderr, "%s needs a value\n", a.c_str());
                std::exit(usage(argv[0], 2));
            }
            return argv[++i];
        };
        auto number = [&]() -> long {
            const std::string v = value();
            char* end = nullptr;
            const long n = std::strtol(v.c_str(), &end, 10);
            if (end == v.c_str() || *end != '\0' || n < 1) {
                std::fprintf(stderr, "%s: expected a positive integer, got '%s'\n", a.c_str(),
                             v.c_str());
                std::exit(2);
            }
            return n;
        };
        if (a == "--frames") {
            opt.frames = static_cast<std::size_t>(number());
            frames_given = true;
        } else if (a == "--reps") {
            opt.reps = static_cast<std::size_t>(number());
            reps_given = true;
        } else if (a == "--per-frame") {
            opt.per_frame = true;
        } else if (a == "--quick") {
            opt.quick = true;
        } else if (a == "--threads") {
            opt.threads = static_cast<int>(number());
        } else if (a == "--markdown") {
            opt.markdown = value();
        } else if (a == "--data") {
            opt.data = value();
        } else if (a == "--scenes") {
            std::stringstream list(value());
            for (std::string name; std::getline(list, name, ',');) {
                if (!name.empty()) {
                    opt.scenes.push_back(name);
                }
            }
        } else if (a == "--stream") {
            opt.stream = static_cast<std::size_t>(number());
        } else if (a == "--culler") {
            auto c = parse_culler(value());
            if (!c.ok()) {
                std::fprintf(stderr, "--culler: %s\n", c.status().to_string().c_str());
                return 2;
            }
            opt.culler = c.value();
        } else if (a == "--help" || a == "-h") {
            return usage(argv[0], 0);
        } else {
            std::fprintf(stderr, "unknown argument '%s'\n", a.c_str());
            return usage(argv[0], 2);
        }
    }
    if (opt.quick) {
        if (!frames_given) {
            opt.frames = 2;
        }
        if (!reps_given) {
            opt.reps = 2;
        }
    }
    if (opt.frames < 2) {
        std::fprintf(stderr, "--frames must be at least 2 (frame 0 is the build)\n");
        return 2;
    }
    std::optional<tbb::global_control> cap;
    if (opt.threads > 0) {
        cap.emplace(tbb::global_control::max_allowed_parallelism,
                    static_cast<std::size_t>(opt.threads));
    }

    const Machine host = machine();
    std::printf("proxima_bench: %s\n", opt.command_line.c_str());
    std::printf("machine: %d CPUs (nproc), %s; TBB threads: %d; %s\n", host.cpus,
                host.model.c_str(), host.threads, host.date.c_str());
    if (opt.stream > 0) {
        if (opt.stream < 3) {
            std::fprintf(stderr, "--stream must be at least 3 (frame 0 is the build)\n");
            return 2;
        }
        std::printf("1-minute load average %s at the start\n", load_average().c_str());
        const int rc = run_streams(opt);
        std::printf("1-minute load average %s at the end\n", load_average().c_str());
        return rc;
    }
    const std::string load_start = load_average();
    const double exact_test = exact_test_seconds();
    std::printf("one exact triangle-triangle distance test: %.0f ns (single thread)\n",
                1e9 * exact_test);

    std::vector<Table> tables;
    std::vector<std::string> log;
    const auto wall = Clock::now();

    // ---- Procedural scenes: separation + self (inter + intra), BVH culler.
    std::vector<ProceduralSummary> procedural;
    for (const char* name : {"skirt", "cloth-ball", "bowl", "ramps", "breaking"}) {
        if (!wanted(opt, name)) {
            continue;
        }
        std::fprintf(stderr, "procedural %s: %zu frames...\n", name, opt.frames);
        procedural.push_back(run_procedural(name, opt, log));
    }
    if (!procedural.empty()) {
        Table t;
        t.title =
            "Procedural scenes: separation + self (inter + intra) per frame, BVH culler, "
            "median of frames 1.." +
            std::to_string(opt.frames - 1) + " (ms)";
        t.header = {"scene",       "objects",
                    "triangles",   "update",
                    "prepare",     "broad",
                    "separation",  "self",
                    "query",       "frame",
                    "goal",        "met",
                    "exact tests", "brute-force tests",
                    "culled"};
        for (const auto& p : procedural) {
            const auto& last = p.frames.back();
            const double frame = bench::median(frame_totals(p.frames, false));
            const double goal = procedural_goal(p.name);
            const double exact = median_of(p.frames, &FrameRow::exact);
            const double brute = median_of(p.frames, &FrameRow::brute);
            t.rows.push_back({p.name, std::to_string(last.objects), std::to_string(last.triangles),
                              ms(median_of(p.frames, &FrameRow::update)),
                              ms(median_of(p.frames, &FrameRow::prepare)),
                              ms(median_of(p.frames, &FrameRow::broad)),
                              ms(median_of(p.frames, &FrameRow::separation)),
                              ms(median_of(p.frames, &FrameRow::self)),
                              ms(median_of(p.frames, &FrameRow::total)), ms(frame),
                              bench::fixed(goal, 0), 1e3 * frame <= goal ? "yes" : "no",
                              count(exact), sci(brute),
                              bench::fixed(brute / std::max(exact, 1.0), 0) + "x"});
        }
        t.notes = {
            "update = applying the frame's SceneUpdate (validation, boxes; generating "
            "it is not counted); query = ProximityEngine::query total (prepare + broad + "
            "separation + self); frame = update + query, compared with the goal.",
            "objects and triangles at the last frame (breaking: after the break)."};
        tables.push_back(t);

        Table f;
        f.title = "Procedural scenes: object-level separation vs FCL 0.7 (same frames, median, ms)";
        f.header = {"scene",      "objects",   "FCL move",
                    "FCL query",  "FCL total", "ours (update+prepare+broad+separation)",
                    "FCL / ours", "mismatches"};
        for (const auto& p : procedural) {
            const double fcl_total = bench::median([&] {
                std::vector<double> v;
                for (std::size_t k = 1; k < p.frames.size(); ++k) {
                    v.push_back(p.frames[k].fcl_move + p.frames[k].fcl_query);
                }
                return v;
            }());
            const double ours = bench::median(frame_totals(p.frames, true));
            std::size_t mism = 0;
            for (const auto& r : p.frames) {
                mism += r.mismatches;
            }
            f.rows.push_back({p.name, std::to_string(p.frames.back().objects),
                              ms(median_of(p.frames, &FrameRow::fcl_move)),
                              ms(median_of(p.frames, &FrameRow::fcl_query)), ms(fcl_total),
                              ms(ours), bench::fixed(fcl_total / ours, 1) + "x",
                              std::to_string(mism)});
        }
        f.notes = {
            "mismatches: objects whose separation distance differs from FCL's by more "
            "than 1e-9 relative + 1e-12, over all frames including frame 0."};
        tables.push_back(f);

        if (opt.per_frame) {
            for (const auto& p : procedural) {
                Table pf;
                pf.title = p.name + ": every frame (ms)";
                pf.header = {"frame",
                             "objects",
                             "gen",
                             "update",
                             "prepare",
                             "broad",
                             "separation",
                             "self",
                             "query",
                             "exact tests",
                             "brute-force tests",
                             "FCL move",
                             "FCL query",
                             "mismatches"};
                for (std::size_t k = 0; k < p.frames.size(); ++k) {
                    const auto& r = p.frames[k];
                    pf.rows.push_back({std::to_string(k), std::to_string(r.objects), ms(r.gen),
                                       ms(r.update), ms(r.prepare), ms(r.broad), ms(r.separation),
                                       ms(r.self), ms(r.total), count(r.exact), sci(r.brute),
                                       ms(r.fcl_move), ms(r.fcl_query),
                                       std::to_string(r.mismatches)});
                }
                pf.notes = {
                    "frame 0 loads the scene: its update is adding the objects, its "
                    "prepare builds every hierarchy, its FCL move builds FCL's models."};
                tables.push_back(pf);
            }
        }
    }

    // ---- Real frame pairs: object-level separation vs FCL, and self distance.
    std::vector<RealSummary> real;
    for (const auto& g : REAL_SCENES) {
        const std::string label = g.label;
        if (opt.quick && label != "armadillo-rollers" && label != "cloth-funnel") {
            continue;
        }
        if (!wanted(opt, label) && !wanted(opt, g.scene)) {
            continue;
        }
        std::fprintf(stderr, "real %s: %zu reps...\n", g.label, opt.reps);
        real.push_back(run_real(g, opt, log));
        if (!real.back().skipped.empty()) {
            std::printf("skipping real frames '%s': %s\n", g.label, real.back().skipped.c_str());
        }
    }
    bool any_real = false;
    for (const auto& r : real) {
        any_real = any_real || r.skipped.empty();
    }
    if (any_real) {
        Table t;
        t.title = "Real frames: object-level separation per frame vs FCL 0.7, median of " +
                  std::to_string(opt.reps) + " steps (ms)";
        t.header = {"scene",    "objects",     "triangles",  "FCL build",  "our build",
                    "FCL move", "FCL query",   "FCL total",  "update",     "prepare",
                    "broad",    "separation",  "ours total", "FCL / ours", "goal",
                    "met",      "exact tests", "mismatches"};
        Table self;
        self.title =
            "Real frames: self distance (every triangle's closest non-adjacent triangle) "
            "per frame, median of " +
            std::to_string(opt.reps) + " steps (ms)";
        self.header = {"scene",      "triangles",         "warm self",    "warm exact tests",
                       "cold self",  "cold exact tests",  "cold / warm",  "answer pairs",
                       "floor",      "warm / floor",      "goal",         "met (warm)",
                       "ideal self", "ideal exact tests", "partner kept", "warm != cold"};
        for (const auto& r : real) {
            if (!r.skipped.empty()) {
                continue;
            }
            std::vector<double> fcl_total;
            std::vector<double> ours;
            for (std::size_t i = 0; i < r.update.size(); ++i) {
                fcl_total.push_back(r.fcl_move[i] + r.fcl_query[i]);
                ours.push_back(r.update[i] + r.prepare[i] + r.broad[i] + r.separation[i]);
            }
            const double f = bench::median(fcl_total);
            const double o = bench::median(ours);
            const bool met = 1e3 * o <= r.separation_goal && f / o >= 3.0;
            t.rows.push_back({r.name, std::to_string(r.objects), std::to_string(r.triangles),
                              ms(r.fcl_build), ms(r.our_build), ms(bench::median(r.fcl_move)),
                              ms(bench::median(r.fcl_query)), ms(f), ms(bench::median(r.update)),
                              ms(bench::median(r.prepare)), ms(bench::median(r.broad)),
                              ms(bench::median(r.separation)), ms(o), bench::fixed(f / o, 1) + "x",
                              bench::fixed(r.separation_goal, 1), met ? "yes" : "no",
                              count(bench::median(r.separation_exact)),
                              std::to_string(r.mismatches) + " / " + std::to_string(r.checks)});
            const double sm = bench::median(r.self);
            const double cm = bench::median(r.self_cold);
            const bool has_goal = !std::isnan(r.self_goal);
            self.rows.push_back(
                {r.name, std::to_string(r.triangles), ms(sm), count(bench::median(r.self_exact)),
                 ms(cm), count(bench::median(r.self_cold_exact)), bench::fixed(cm / sm, 2) + "x",
                 count(bench::median(r.self_pairs)), ms(bench::median(r.self_floor)),
                 bench::fixed(sm / bench::median(r.self_floor), 1) + "x",
                 has_goal ? bench::fixed(r.self_goal, 0) : "-",
                 has_goal ? (1e3 * sm <= r.self_goal ? "yes" : "no") : "-",
                 ms(bench::median(r.self_ideal)), count(bench::median(r.self_ideal_exact)),
                 bench::fixed(100.0 * bench::median(r.self_kept), 1) + "%",
                 std::to_string(r.self_differences)});
        }
        t.notes = {
            "build: FCL = building every model and the manager; ours = adding the objects "
            "(validation, connectivity) + the first separation query, which builds every "
            "hierarchy.",
            "ours total = update (apply positions) + prepare (refit) + broad + separation; "
            "goal (ms) from BASELINES.md, met = within the goal and >= 3x faster than FCL.",
            "exact tests: triangle pairs the separation query tested exactly; mismatches: "
            "objects differing from FCL / queries checked (each query checks every "
            "object)."};
        self.notes = {
            "warm = a one-frame step seeded by the previous frame's answer (each triangle's "
            "closest triangle, tested again at the new positions, or for a rigidly moving "
            "object its candidate list); cold = the same geometry on a second engine after "
            "ProximityEngine::forget_coherence (2-ring seeds only).",
            "warm != cold: triangles whose closest triangle or distance differ between the warm, "
            "ideal and cold answers over all steps (must be 0).",
            "floor (issue #14 item 7): the exact tests the answer itself needs, one per "
            "reported pair (answer pairs; a pair two triangles report for each other counts "
            "once) x one test's time, measured by running those tests again on one thread; "
            "the query itself runs on all threads.",
            "FCL has no self-distance query; brute force costs about 48 ns per "
            "non-adjacent pair (BASELINES.md)."};
        // Second and fourth, in statements of their own: a fifth joined literal in the list
        // above trips clang-tidy's missing-comma heuristic.
        self.notes.insert(self.notes.begin() + 1,
                          "ideal = the same geometry once more right after the warm query, "
                          "seeded by that very answer: a warm frame whose seeds are already "
                          "every triangle's closest triangle, i.e. what better seeding alone "
                          "could save (an object that moves rigidly answers both from its "
                          "candidate list instead).");
        self.notes.insert(self.notes.begin() + 3,
                          "partner kept: triangles whose closest triangle is the previous "
                          "frame's, i.e. whose warm seed was already the answer (ideal seeds: "
                          "all of them).");
        Table motion;
        motion.title =
            "Real frames: one step's vertex motion against the self distances at t0 (what a "
            "neighbour list with a skin, kept across frames, would hold)";
        motion.header = {"scene",
                         "vertex move median",
                         "vertex move max",
                         "rigid residual median",
                         "rigid residual max",
                         "self distance median",
                         "pairs within best + 2 max move",
                         "pairs within best + 2 max residual",
                         "answer pairs / triangle"};
        for (const auto& r : real) {
            if (!r.skipped.empty()) {
                continue;
            }
            auto sci = [](double x) {
                char buf[32];
                std::snprintf(buf, sizeof buf, "%.3g", x);
                return std::string(buf);
            };
            motion.rows.push_back(
                {r.name, sci(r.move_median), sci(r.move_max), sci(r.rigid_median), sci(r.rigid_max),
                 sci(r.distance_median), bench::fixed(r.skin_pairs, 1),
                 bench::fixed(r.rigid_skin_pairs, 1),
                 bench::fixed(bench::median(r.self_pairs) / static_cast<double>(r.triangles), 2)});
        }
        motion.notes = {
            "move: |x(t1) - x(t0)| per vertex; self distance: every triangle's closest "
            "non-adjacent distance at t0 (the scene's objects pooled).",
            "rigid residual: each vertex's distance from where the object's best-fitting rigid "
            "motion (least squares) puts it at t1, i.e. the object's own deformation.",
            "pairs within best + 2 max move (residual): per triangle (up to 200 evenly spaced "
            "triangles per object, exact distances, brute force), the non-adjacent triangles a "
            "list built at t0 with a skin of twice the object's largest vertex move (rigid "
            "residual) would hold: what each triangle would test every frame instead of the "
            "traversal."};
        tables.push_back(t);
        tables.push_back(self);
        tables.push_back(motion);
    } else if (!real.empty()) {
        std::printf("real frames: none found under %s/frames (use --data DIR); skipped\n",
                    opt.data.c_str());
    }

    for (const auto& t : tables) {
        t.print(std::cout);
    }
    std::size_t mismatch_total = 0;
    for (const auto& line : log) {
        mismatch_total += line.rfind("MISMATCH", 0) == 0 ? 1 : 0;
        std::cout << line << "\n";
    }
    const double wall_seconds = seconds_since(wall);
    const std::string load_end = load_average();
    std::printf("\nwall time: %.1f s; 1-minute load average %s at the start, %s at the end\n",
                wall_seconds, load_start.c_str(), load_end.c_str());

    if (!opt.markdown.empty()) {
        std::ofstream md(opt.markdown);
        md << "Command: `" << opt.command_line << "`\n\n"
           << "Machine: " << host.cpus << " CPUs (nproc), " << host.model << "; TBB threads "
           << host.threads << "; " << host.date << ".\n\n"
           << "One exact triangle-triangle distance test: " << bench::fixed(1e9 * exact_test, 0)
           << " ns (single thread, nearby pairs of the skirt).\n\n"
           << "Wall time " << bench::fixed(wall_seconds, 1) << " s; 1-minute load average "
           << load_start << " at the start, " << load_end << " at the end.\n";
        for (const auto& t : tables) {
            t.markdown(md);
        }
        if (!log.empty()) {
            md << "\n```\n";
            for (const auto& line : log) {
                md << line << "\n";
            }
            md << "```\n";
        }
        if (!md) {
            std::fprintf(stderr, "cannot write %s\n", opt.markdown.c_str());
            return 1;
        }
    }
    // A mismatch with FCL is a failure of the smoke test.
    return mismatch_total == 0 ? 0 : 3;
}
