// proxima_dvd_bench: the discrete-Voronoi culler (seed 000 §4-5.2, Figs. 13-14) on the five
// procedural scenes and the real frame pairs of ../shared/data/frames:
//   - DVD (kernel) time and Stage II time vs grid resolution,
//   - exact tests vs resolution,
//   - exact tests with Voronoi culling vs BVH culling,
//   - total time per frame per backend (cpu; gpu when a headless EGL context starts).
// Every configuration runs on the same scene state each frame, in one engine, and its answers are
// checked against the BVH culler's (separation and self distances, collision and tolerance pairs).
//
//   proxima_dvd_bench [--quick] [--frames N] [--cells f1,f2,...] [--queries LIST] [--no-gpu]
//                     [--csv FILE] [--json FILE] [--data DIR] [--scenes a,b,...]
//
// --csv and --json write the same rows (one per scene, query and culler configuration); the JSON
// document adds the facts the table header prints (device, CPU model, load, frames) and is what
// docs/plots/plot_all.py draws.
//
// --scenes names procedural scenes (skirt, cloth-ball, bowl, ramps, breaking) and real frame pairs
// as real:<dir> (real:cloth-ball, real:n-body-simulation, real:armadillo-rollers,
// real:cloth-funnel, real:rod-twist).
//
// --cells: cell sizes as multiples of the scene's median edge length ("auto" = the culler's own
// choice); --queries: "nbody" (separation + self), "contact" (collisions + tolerance of 0.05
// median edge), or both (default). Medians over frames 1..N-1 (frame 0 builds everything).

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "proxima/culling/dvd.hpp"
#include "proxima/gpu/egl_backend.hpp"
#include "proxima/io/mesh_io.hpp"
#include "proxima/mesh/mesh.hpp"
#include "proxima/query/query.hpp"
#include "proxima/scenes/procedural.hpp"

#include <nlohmann/json.hpp>

#include "bench_util.hpp"

#ifndef PROXIMA_DATA_DIR
#define PROXIMA_DATA_DIR ""
#endif

namespace {

using namespace proxima;

struct Options {
    bool quick = false;
    std::size_t frames = 6;
    std::vector<std::string> cells{"auto", "0.25", "0.5", "1", "2", "4"};
    bool nbody = true;
    bool contact = true;
    bool gpu = true;
    std::string csv;
    std::string json;
    std::string data = PROXIMA_DATA_DIR;
    std::vector<std::string> scenes;
};

std::vector<std::string> split(const std::string& s) {
    std::vector<std::string> out;
    std::stringstream ss(s);
    std::string item;
    while (std::getline(ss, item, ',')) {
        if (!item.empty()) {
            out.push_back(item);
        }
    }
    return out;
}

struct Config {
    CullerKind culler;
    std::string cell;  // "auto" or a factor of the median edge
    std::string label() const {
        return std::string(culler_name(culler)) + (culler == CullerKind::bvh ? "" : " @" + cell);
    }
};

// Per (scene, query, config): per-frame measurements.
struct Series {
    std::string scene;
    std::string query;
    Config config;
    std::size_t triangles = 0;
    double median_edge = 0;
    std::vector<double> total, stage2, dvd, exact, samples, cell, culled, brute;
    std::size_t mismatches = 0;
};

// Median edge length (the Voronoi culler's grid scale).
double median_edge(const Scene& scene) {
    std::vector<double> lengths;
    for (const auto& o : scene.objects()) {
        for (std::uint32_t t = 0; t < o.triangle_count(); ++t) {
            const auto& i = o.triangle(t);
            for (int c = 0; c < 3; ++c) {
                lengths.push_back(norm(o.vertices[i[(c + 1) % 3]] - o.vertices[i[c]]));
            }
        }
    }
    if (lengths.empty()) {
        return 1.0;
    }
    auto mid = lengths.begin() + static_cast<std::ptrdiff_t>(lengths.size() / 2);
    std::nth_element(lengths.begin(), mid, lengths.end());
    return *mid;
}

bool same(double a, double b) {
    if (std::isinf(a) || std::isinf(b)) {
        return a == b;
    }
    return std::abs(a - b) <= 1e-12 * std::max(1.0, std::max(std::abs(a), std::abs(b)));
}

// Differences between two answers (0 when equal).
std::size_t compare(const QueryResult& x, const QueryResult& ref) {
    std::size_t bad = 0;
    for (std::size_t i = 0; i < x.separation.size() && i < ref.separation.size(); ++i) {
        bad += !same(x.separation[i].distance, ref.separation[i].distance);
    }
    for (std::size_t i = 0; i < x.self.size() && i < ref.self.size(); ++i) {
        for (std::size_t t = 0; t < x.self[i].size(); ++t) {
            bad += !same(x.self[i][t].distance, ref.self[i][t].distance);
        }
    }
    auto pairs_differ = [](const std::vector<FeaturePair>& a, const std::vector<FeaturePair>& b) {
        if (a.size() != b.size()) {
            return true;
        }
        for (std::size_t k = 0; k < a.size(); ++k) {
            if (a[k] < b[k] || b[k] < a[k]) {
                return true;
            }
        }
        return false;
    };
    bad += pairs_differ(x.collisions, ref.collisions);
    bad += pairs_differ(x.tolerance, ref.tolerance);
    return bad;
}

class Runner {
  public:
    Runner(const Options& opt, std::shared_ptr<dvd::Backend> gpu) : m_opt(opt), m_gpu(gpu) {
        m_configs.push_back({CullerKind::bvh, ""});
        std::vector<CullerKind> kinds{CullerKind::voronoi_cpu};
        if (gpu) {
            kinds.push_back(CullerKind::voronoi_gpu);
        }
        for (auto k : kinds) {
            for (const auto& c : opt.cells) {
                m_configs.push_back({k, c});
            }
        }
    }

    // Runs every configuration on the engine's current scene state; frame 0 is not recorded.
    void frame(const std::string& scene, ProximityEngine& engine, std::size_t k) {
        const double edge = median_edge(engine.scene());
        std::vector<std::pair<std::string, QueryRequest>> requests;
        if (m_opt.nbody) {
            QueryRequest r;
            r.separation = true;
            r.self = true;
            requests.emplace_back("nbody", r);
        }
        if (m_opt.contact) {
            QueryRequest r;
            r.separation = false;
            r.collisions = true;
            r.tolerance = 0.05 * edge;
            requests.emplace_back("contact", r);
        }
        for (auto& [qname, req] : requests) {
            std::optional<QueryResult> reference;
            for (const auto& cfg : m_configs) {
                QueryRequest r = req;
                r.culler = cfg.culler;
                if (cfg.culler != CullerKind::bvh && cfg.cell != "auto") {
                    r.voronoi_cell = std::stod(cfg.cell) * edge;
                }
                auto result = engine.query(r);
                if (!result.ok()) {
                    std::cerr << scene << " " << qname << " " << cfg.label() << ": "
                              << result.status().to_string() << "\n";
                    std::exit(1);
                }
                Series& s = series(scene, qname, cfg);
                s.triangles = engine.scene().triangle_count();
                s.median_edge = edge;
                if (!reference) {
                    reference = std::move(result.value());
                    if (k == 0) {
                        continue;
                    }
                    record(s, reference->stats);
                    continue;
                }
                s.mismatches += compare(result.value(), *reference);
                if (k > 0) {
                    record(s, result->stats);
                }
            }
        }
    }

    const std::vector<Series>& all() const { return m_series; }

  private:
    static void record(Series& s, const QueryStats& st) {
        s.total.push_back(st.total_seconds);
        s.stage2.push_back(st.voronoi_seconds);
        s.dvd.push_back(st.dvd_seconds);
        s.exact.push_back(static_cast<double>(st.exact_tests));
        s.samples.push_back(static_cast<double>(st.dvd_samples));
        s.cell.push_back(st.dvd_cell);
        s.culled.push_back(static_cast<double>(st.voronoi_culled));
        s.brute.push_back(static_cast<double>(st.brute_force_tests));
    }
    Series& series(const std::string& scene, const std::string& query, const Config& cfg) {
        for (auto& s : m_series) {
            if (s.scene == scene && s.query == query && s.config.culler == cfg.culler &&
                s.config.cell == cfg.cell) {
                return s;
            }
        }
        Series fresh;
        fresh.scene = scene;
        fresh.query = query;
        fresh.config = cfg;
        m_series.push_back(std::move(fresh));
        return m_series.back();
    }

    const Options& m_opt;
    std::shared_ptr<dvd::Backend> m_gpu;
    std::vector<Config> m_configs;
    std::vector<Series> m_series;
};

void run_procedural(const std::string& name, const Options& opt, Runner& runner,
                    const std::shared_ptr<dvd::Backend>& gpu) {
    const auto ps = scenes::by_name(name, opt.frames);
    if (ps.name.empty()) {
        std::cerr << "unknown scene " << name << "\n";
        std::exit(2);
    }
    ProximityEngine engine;
    engine.set_gpu_backend(gpu);
    for (std::size_t k = 0; k < ps.frame_count; ++k) {
        if (k == 0) {
            for (const auto& m : ps.initial) {
                if (!engine.scene().add_object(m).ok()) {
                    std::exit(1);
                }
            }
        } else {
            auto applied = engine.scene().apply(ps.step(k, engine.scene()));
            if (!applied.ok()) {
                std::cerr << applied.status().to_string() << "\n";
                std::exit(1);
            }
        }
        std::fprintf(stderr, "  %s frame %zu\n", name.c_str(), k);
        runner.frame(name, engine, k);
    }
}

// Real frame pair: t0 (build), then alternately t1, t0, ... for frames 1..N-1.
bool run_real(const std::string& dir_name, const Options& opt, Runner& runner,
              const std::shared_ptr<dvd::Backend>& gpu) {
    namespace fs = std::filesystem;
    const fs::path dir = fs::path(opt.data) / "frames" / dir_name;
    std::vector<std::string> files;
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(dir, ec)) {
        if (entry.path().extension() == ".ply") {
            files.push_back(entry.path().string());
        }
    }
    std::sort(files.begin(), files.end());
    if (ec || files.size() != 2) {
        std::cerr << "skipping " << dir_name << ": no frame pair in " << dir << "\n";
        return false;
    }
    MeshReadOptions raw;
    raw.weld = WeldMode::never;
    auto m0 = read_mesh(files[0], raw);
    auto m1 = read_mesh(files[1], raw);
    if (!m0.ok() || !m1.ok() || m0->triangles != m1->triangles) {
        std::cerr << "skipping " << dir_name << ": cannot read the pair\n";
        return false;
    }
    auto parts = split_components(m0.value());
    std::vector<std::vector<Vec3>> t1(parts.meshes.size());
    for (std::size_t c = 0; c < parts.meshes.size(); ++c) {
        for (auto id : parts.vertex_ids[c]) {
            t1[c].push_back(m1->vertices[id]);
        }
    }
    ProximityEngine engine;
    engine.set_gpu_backend(gpu);
    for (std::size_t c = 0; c < parts.meshes.size(); ++c) {
        if (!engine.scene()
                 .add_object({dir_name + "." + std::to_string(c), parts.meshes[c]})
                 .ok()) {
            return false;
        }
    }
    for (std::size_t k = 0; k < opt.frames; ++k) {
        if (k > 0) {
            SceneUpdate update;
            for (std::size_t i = 0; i < engine.scene().size(); ++i) {
                update.positions.push_back(
                    {engine.scene()[i].id, k % 2 == 1 ? t1[i] : parts.meshes[i].vertices});
            }
            if (!engine.scene().apply(std::move(update)).ok()) {
                return false;
            }
        }
        std::fprintf(stderr, "  %s frame %zu\n", dir_name.c_str(), k);
        runner.frame(dir_name, engine, k);
    }
    return true;
}

// A finite number, or null (a median over no frames, a BVH row's cell).
nlohmann::json number(double v) {
    return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json();
}

// The --csv rows as one JSON document, with the machine facts: what docs/plots/plot_all.py reads.
void write_json(const Options& opt, const Runner& runner, const std::string& device) {
    nlohmann::json cells = nlohmann::json::array();
    for (const auto& c : opt.cells) {
        cells.push_back(c);
    }
    nlohmann::json rows = nlohmann::json::array();
    double bvh = 0;
    for (const auto& s : runner.all()) {
        const bool is_bvh = s.config.culler == CullerKind::bvh;
        if (is_bvh) {
            bvh = bench::median(s.exact);
        }
        rows.push_back({{"scene", s.scene},
                        {"triangles", s.triangles},
                        {"query", s.query},
                        {"culler", culler_name(s.config.culler)},
                        {"cell_factor", is_bvh ? nlohmann::json() : nlohmann::json(s.config.cell)},
                        {"cell", is_bvh ? nlohmann::json() : number(bench::median(s.cell))},
                        {"median_edge", number(s.median_edge)},
                        {"samples", number(bench::median(s.samples))},
                        {"dvd_ms", number(1e3 * bench::median(s.dvd))},
                        {"stage2_ms", number(1e3 * bench::median(s.stage2))},
                        {"total_ms", number(1e3 * bench::median(s.total))},
                        {"exact_tests", number(bench::median(s.exact))},
                        {"bvh_exact_tests", number(bvh)},
                        {"brute_force_tests", number(bench::median(s.brute))},
                        {"voronoi_culled", number(bench::median(s.culled))},
                        {"mismatches", s.mismatches}});
    }
    const nlohmann::json doc = {{"tool", "proxima_dvd_bench"},
                                {"device", device},
                                {"cpu", bench::cpu_model()},
                                {"load_average", bench::load_average()},
                                {"frames", opt.frames},
                                {"cells", cells},
                                {"rows", rows}};
    std::ofstream out(opt.json);
    out << doc.dump(2) << "\n";
    if (!out) {
        std::cerr << "could not write " << opt.json << "\n";
        std::exit(1);
    }
    std::cerr << "wrote " << opt.json << "\n";
}

void print(const Options& opt, const Runner& runner, const std::string& device) {
    std::ostream& out = std::cout;
    out << "\n# proxima_dvd_bench (" << device << ")\n\n";
    out << "Medians over frames 1.." << opt.frames - 1
        << "; times in ms; cell as a multiple of the median edge (auto: the culler's choice); "
           "exact = exact triangle tests; vs bvh = BVH exact tests / these.\n\n";
    out << "| scene | query | culler | cell | samples | DVD ms | stage II ms | total ms | exact | "
           "vs bvh | culled | mismatches |\n";
    out << "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    double bvh_exact = 0;
    for (const auto& s : runner.all()) {
        const double exact = bench::median(s.exact);
        if (s.config.culler == CullerKind::bvh) {
            bvh_exact = exact;
        }
        out << "| " << s.scene << " (" << s.triangles << " tris) | " << s.query << " | "
            << culler_name(s.config.culler) << " | "
            << (s.config.culler == CullerKind::bvh
                    ? "-"
                    : s.config.cell + " (" + bench::fixed(bench::median(s.cell), 5) + ")")
            << " | " << bench::fixed(bench::median(s.samples), 0) << " | "
            << bench::fixed(1e3 * bench::median(s.dvd)) << " | "
            << bench::fixed(1e3 * bench::median(s.stage2)) << " | "
            << bench::fixed(1e3 * bench::median(s.total)) << " | " << bench::fixed(exact, 0)
            << " | " << bench::fixed(exact > 0 ? bvh_exact / exact : NAN, 2) << " | "
            << bench::fixed(bench::median(s.culled), 0) << " | " << s.mismatches << " |\n";
    }
    if (!opt.csv.empty()) {
        std::ofstream csv(opt.csv);
        csv << "scene,triangles,query,culler,cell_factor,cell,median_edge,samples,dvd_ms,stage2_ms,"
               "total_ms,exact_tests,bvh_exact_tests,brute_force_tests,voronoi_culled,mismatches,"
               "device\n";
        double bvh = 0;
        for (const auto& s : runner.all()) {
            if (s.config.culler == CullerKind::bvh) {
                bvh = bench::median(s.exact);
            }
            csv << s.scene << "," << s.triangles << "," << s.query << ","
                << culler_name(s.config.culler) << ","
                << (s.config.culler == CullerKind::bvh ? "" : s.config.cell) << ","
                << bench::median(s.cell) << "," << s.median_edge << "," << bench::median(s.samples)
                << "," << 1e3 * bench::median(s.dvd) << "," << 1e3 * bench::median(s.stage2) << ","
                << 1e3 * bench::median(s.total) << "," << bench::median(s.exact) << "," << bvh
                << "," << bench::median(s.brute) << "," << bench::median(s.culled) << ","
                << s.mismatches << ",\"" << device << "\"\n";
        }
        std::cerr << "wrote " << opt.csv << "\n";
    }
    if (!opt.json.empty()) {
        write_json(opt, runner, device);
    }
}

}  // namespace

int main(int argc, char** argv) {
    Options opt;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto value = [&]() -> std::string {
            if (i + 1 >= argc) {
                std::cerr << a << " needs a value\n";
                std::exit(2);
            }
            return argv[++i];
        };
        if (a == "--quick") {
            opt.quick = true;
        } else if (a == "--frames") {
            opt.frames = std::max<std::size_t>(2, std::stoul(value()));
        } else if (a == "--cells") {
            opt.cells = split(value());
        } else if (a == "--queries") {
            const auto q = split(value());
            opt.nbody = std::find(q.begin(), q.end(), "nbody") != q.end();
            opt.contact = std::find(q.begin(), q.end(), "contact") != q.end();
        } else if (a == "--no-gpu") {
            opt.gpu = false;
        } else if (a == "--csv") {
            opt.csv = value();
        } else if (a == "--json") {
            opt.json = value();
        } else if (a == "--data") {
            opt.data = value();
        } else if (a == "--scenes") {
            opt.scenes = split(value());
        } else {
            std::cerr
                << "usage: proxima_dvd_bench [--quick] [--frames N] [--cells f1,f2,...] "
                   "[--queries nbody,contact] [--no-gpu] [--csv FILE] [--json FILE] [--data DIR] "
                   "[--scenes a,b,...]\n";
            return a == "--help" ? 0 : 2;
        }
    }
    std::vector<std::string> procedural{"skirt", "cloth-ball", "bowl", "ramps", "breaking"};
    std::vector<std::string> real{"cloth-ball", "n-body-simulation", "armadillo-rollers",
                                  "cloth-funnel", "rod-twist"};
    if (opt.quick) {
        opt.frames = 2;
        // Smoke run (CI, 2 cores, GPU on llvmpipe): two small procedural scenes, automatic
        // cell only; the real frames are 18K-146K triangles, too slow for llvmpipe here.
        opt.cells = {"auto"};
        procedural = {"bowl", "breaking"};
        real = {};
    }
    std::shared_ptr<dvd::Backend> gpu;
    std::string device = "cpu";
    if (opt.gpu) {
        auto g = gpu::make_egl_backend();
        if (g.ok()) {
            gpu = g.value();
            device = "cpu + " + gpu->name();
        } else {
            std::cerr << "no GPU backend: " << g.status().to_string() << "\n";
        }
    }
    Runner runner(opt, gpu);
    for (const auto& name : procedural) {
        if (!opt.scenes.empty() &&
            std::find(opt.scenes.begin(), opt.scenes.end(), name) == opt.scenes.end()) {
            continue;
        }
        std::fprintf(stderr, "procedural %s\n", name.c_str());
        run_procedural(name, opt, runner, gpu);
    }
    for (const auto& name : real) {
        if (!opt.scenes.empty() &&
            std::find(opt.scenes.begin(), opt.scenes.end(), "real:" + name) == opt.scenes.end()) {
            continue;
        }
        std::fprintf(stderr, "real %s\n", name.c_str());
        run_real(name, opt, runner, gpu);
    }
    print(opt, runner, device);
    std::size_t bad = 0;
    for (const auto& s : runner.all()) {
        bad += s.mismatches;
    }
    if (bad != 0) {
        std::cerr << bad << " answers differ from the BVH culler's\n";
        return 1;
    }
    return 0;
}
