#include "common/sequence.hpp"

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <system_error>
#include <unordered_map>

#include <nlohmann/json.hpp>

#include "proxima/io/md2.hpp"
#include "proxima/mesh/mesh.hpp"

namespace proxima::client {

namespace {

namespace fs = std::filesystem;

bool is_digit(char c) {
    return std::isdigit(static_cast<unsigned char>(c)) != 0;
}

std::string lower(std::string s) {
    std::transform(s.begin(), s.end(), s.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return s;
}

bool ends_with(const std::string& s, const std::string& tail) {
    return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}

bool is_mesh_name(const std::string& name) {
    std::string n = lower(name);
    if (ends_with(n, ".gz")) {
        n.resize(n.size() - 3);
    }
    for (const char* ext : {".ply", ".off", ".obj", ".stl", ".gltf", ".glb"}) {
        if (ends_with(n, ext)) {
            return true;
        }
    }
    return false;
}

// 'path', for messages (appended, not "'" + string: GCC 12 warns about that pattern, -Wrestrict).
std::string quoted(const fs::path& path) {
    std::string out = "'";
    out += path.string();
    out += '\'';
    return out;
}

// What DIR/sequence.json says: the rate and, per frame file, its objects' names.
struct Recorded {
    double fps = 0;
    std::unordered_map<std::string, std::vector<std::string>> names;  // file name -> names
};

// DIR/sequence.json (nothing when the file is absent); a malformed file is an error.
StatusOr<Recorded> read_recorded(const fs::path& dir) {
    Recorded rec;
    const fs::path file = dir / "sequence.json";
    std::error_code ec;
    if (!fs::exists(file, ec)) {
        return rec;
    }
    std::ifstream in(file);
    const auto doc = nlohmann::json::parse(in, nullptr, false);
    if (in.bad() || doc.is_discarded() || !doc.is_object()) {
        return invalid_argument(quoted(file) + " is not a JSON object");
    }
    if (doc.contains("fps")) {
        const auto& fps = doc["fps"];
        if (!fps.is_number() || !(fps.get<double>() > 0.0) || !(fps.get<double>() <= 1e6)) {
            return invalid_argument(quoted(file) + ": \"fps\" must be a number in (0, 1e6]");
        }
        rec.fps = fps.get<double>();
    }
    if (doc.contains("frames") && doc["frames"].is_array()) {
        for (const auto& f : doc["frames"]) {
            if (!f.is_object() || !f.contains("file") || !f["file"].is_string() ||
                !f.contains("objects") || !f["objects"].is_array()) {
                continue;
            }
            std::vector<std::string> names;
            for (const auto& n : f["objects"]) {
                if (n.is_string()) {
                    names.push_back(n.get<std::string>());
                }
            }
            if (names.size() == f["objects"].size()) {
                rec.names[f["file"].get<std::string>()] = std::move(names);
            }
        }
    }
    return rec;
}

}  // namespace

bool natural_less(const std::string& a, const std::string& b) {
    std::size_t i = 0;
    std::size_t j = 0;
    while (i < a.size() && j < b.size()) {
        if (is_digit(a[i]) && is_digit(b[j])) {
            std::size_t ie = i;
            std::size_t je = j;
            while (ie < a.size() && is_digit(a[ie])) {
                ++ie;
            }
            while (je < b.size() && is_digit(b[je])) {
                ++je;
            }
            // Compare the values without converting: skip leading zeros, then length, then digits.
            std::size_t is = i;
            std::size_t js = j;
            while (is + 1 < ie && a[is] == '0') {
                ++is;
            }
            while (js + 1 < je && b[js] == '0') {
                ++js;
            }
            if (ie - is != je - js) {
                return ie - is < je - js;
            }
            const int c = a.compare(is, ie - is, b, js, je - js);
            if (c != 0) {
                return c < 0;
            }
            if (ie - i != je - j) {
                return ie - i < je - j;
            }
            i = ie;
            j = je;
            continue;
        }
        if (a[i] != b[j]) {
            return static_cast<unsigned char>(a[i]) < static_cast<unsigned char>(b[j]);
        }
        ++i;
        ++j;
    }
    return a.size() - i < b.size() - j;
}

StatusOr<std::vector<std::string>> list_frame_files(const std::string& dir) {
    std::error_code ec;
    if (!fs::exists(dir, ec)) {
        return Status(StatusCode::not_found, "sequence folder '" + dir + "' does not exist");
    }
    if (!fs::is_directory(dir, ec)) {
        return invalid_argument("'" + dir + "' is not a folder (a sequence is a folder of " +
                                "numbered mesh files)");
    }
    std::vector<std::string> names;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
        const std::string name = it->path().filename().string();
        if (is_mesh_name(name) && it->is_regular_file(ec)) {
            names.push_back(name);
        }
    }
    if (ec) {
        return invalid_argument("cannot list the folder '" + dir + "': " + ec.message());
    }
    if (names.empty()) {
        return invalid_argument("the folder '" + dir +
                                "' holds no mesh files (.ply, .off, .obj, .stl, .gltf, .glb, "
                                "each also .gz)");
    }
    std::sort(names.begin(), names.end(), natural_less);
    std::vector<std::string> paths;
    paths.reserve(names.size());
    for (const auto& n : names) {
        paths.push_back((fs::path(dir) / n).string());
    }
    return paths;
}

namespace {

// One keyframe's objects: the whole model, or each connected component (as load_objects does;
// an MD2 keyframe's vertices are the model's own, so the vertex map is the identity).
std::vector<InputObject> keyframe_objects(const std::string& file, TriangleMesh mesh, bool split) {
    std::vector<InputObject> out;
    split_objects(file, std::move(mesh), {}, split, out);
    return out;
}

Status no_frame_selected(const std::string& dir, const SequenceOptions& options, std::size_t n) {
    std::string range = std::to_string(options.begin);
    range += ':';
    if (options.end != std::numeric_limits<std::size_t>::max()) {
        range += std::to_string(options.end);
    }
    return invalid_argument("--frames " + range + " selects no frame of '" + dir + "' (" +
                            std::to_string(n) + " frames, numbered 0.." + std::to_string(n - 1) +
                            ")");
}

StatusOr<Sequence> load_md2_sequence(const std::string& path, const SequenceOptions& options) {
    auto md2 = read_md2(path);
    if (!md2.ok()) {
        return md2.status();
    }
    const std::size_t n = md2->frames.size();
    if (options.begin >= n || options.end <= options.begin) {
        return no_frame_selected(path, options, n);
    }
    Sequence seq;
    seq.dir = path;
    seq.fps = MD2_KEYFRAME_FPS;
    for (std::size_t k = options.begin; k < std::min(n, options.end); ++k) {
        TriangleMesh mesh;
        mesh.vertices = std::move(md2->frames[k]);
        mesh.triangles = md2->triangles;
        seq.frames.push_back(
            {path, k, keyframe_objects(path, std::move(mesh), options.split_components)});
    }
    return seq;
}

}  // namespace

StatusOr<Sequence> load_sequence(const std::string& dir, const SequenceOptions& options) {
    std::error_code file_ec;
    if (ends_with(lower(dir), ".md2") && fs::is_regular_file(dir, file_ec)) {
        return load_md2_sequence(dir, options);
    }
    auto files = list_frame_files(dir);
    if (!files.ok()) {
        return files.status();
    }
    const std::size_t n = files->size();
    if (options.begin >= n || options.end <= options.begin) {
        return no_frame_selected(dir, options, n);
    }
    auto recorded = read_recorded(dir);
    if (!recorded.ok()) {
        return recorded.status();
    }
    Sequence seq;
    seq.dir = dir;
    seq.fps = recorded->fps;
    for (std::size_t k = options.begin; k < std::min(n, options.end); ++k) {
        const std::string& file = (*files)[k];
        auto objects = load_objects({file}, options.split_components,
                                    options.weld ? WeldMode::always : WeldMode::triangle_soups);
        if (!objects.ok()) {
            return Status(objects.status().code(),
                          "frame " + std::to_string(k) + ": " + objects.status().message());
        }
        if (objects->empty()) {
            return invalid_argument("frame " + std::to_string(k) + " ('" + file +
                                    "') holds no object");
        }
        // Object names recorded in sequence.json (as many as the file's objects) replace the
        // FILE#COMPONENT names: they say which object broke into which pieces.
        auto named = recorded->names.find(fs::path(file).filename().string());
        if (named != recorded->names.end() && named->second.size() == objects->size()) {
            for (std::size_t i = 0; i < objects->size(); ++i) {
                (*objects)[i].mesh.name = named->second[i];
            }
        }
        seq.frames.push_back({file, k, std::move(objects).value()});
    }
    return seq;
}

bool same_topology(const TriangleMesh& a, const TriangleMesh& b) {
    return a.vertices.size() == b.vertices.size() && a.triangles == b.triangles;
}

namespace {

// "ball3" -> "ball3.piece0", "ball3/2", "ball3#1": a piece's name starts with its object's name
// and a separator (or is the same name).
bool piece_of(const std::string& object, const std::string& piece) {
    if (piece == object) {
        return true;
    }
    return piece.size() > object.size() && piece.compare(0, object.size(), object) == 0 &&
           (piece[object.size()] == '.' || piece[object.size()] == '/' ||
            piece[object.size()] == '#');
}

// The middle runs (prev[p, p + old_mid), next[p, p + new_mid)) as pieces by name: each old object
// is replaced by the run of new objects named as its pieces (removed when it has none). False
// (nothing added to `update`) when the names do not say so for every new object, in order.
bool split_by_name(const std::vector<InputObject>& prev, const std::vector<ObjectId>& ids,
                   const std::vector<InputObject>& next, std::size_t p, std::size_t old_mid,
                   std::size_t new_mid, SceneUpdate& update) {
    std::vector<std::pair<std::size_t, std::size_t>> runs;  // per old object: [begin, end)
    std::size_t j = p;
    for (std::size_t i = p; i < p + old_mid; ++i) {
        const std::size_t begin = j;
        while (j < p + new_mid && piece_of(prev[i].mesh.name, next[j].mesh.name)) {
            ++j;
        }
        runs.emplace_back(begin, j);
    }
    if (j != p + new_mid) {
        return false;
    }
    for (std::size_t i = p; i < p + old_mid; ++i) {
        const auto [begin, end] = runs[i - p];
        if (begin == end) {
            update.removals.push_back(ids[i]);
            continue;
        }
        SceneUpdate::Replacement rep;
        rep.object = ids[i];
        for (std::size_t k = begin; k < end; ++k) {
            rep.fragments.push_back(next[k].mesh);
        }
        update.replacements.push_back(std::move(rep));
    }
    return true;
}

}  // namespace

FrameDiff diff_frames(const std::vector<InputObject>& prev, const std::vector<ObjectId>& ids,
                      const std::vector<InputObject>& next) {
    FrameDiff diff;
    auto same = [&](std::size_t i, std::size_t j) {
        return same_topology(prev[i].mesh.mesh, next[j].mesh.mesh);
    };
    auto move = [&](std::size_t i, std::size_t j) {
        if (prev[i].mesh.mesh.vertices != next[j].mesh.mesh.vertices) {
            diff.update.positions.push_back({ids[i], next[j].mesh.mesh.vertices});
        }
    };
    const std::size_t m = prev.size();
    const std::size_t n = next.size();
    if (m == n) {
        for (std::size_t i = 0; i < m; ++i) {
            if (same(i, i)) {
                move(i, i);
            } else {
                diff.update.replacements.push_back({ids[i], {next[i].mesh}});
                diff.topology_change = true;
            }
        }
        return diff;
    }
    diff.topology_change = true;
    std::size_t p = 0;  // common prefix
    while (p < std::min(m, n) && same(p, p)) {
        ++p;
    }
    std::size_t s = 0;  // common suffix, not overlapping the prefix
    while (s < std::min(m, n) - p && same(m - 1 - s, n - 1 - s)) {
        ++s;
    }
    if (p + s == m && s > 0) {
        // Only insertions, before the suffix: the first suffix object becomes the replaced one
        // (its fragments: itself and what comes before it), so that the order still holds.
        --s;
    }
    for (std::size_t i = 0; i < p; ++i) {
        move(i, i);
    }
    for (std::size_t k = 0; k < s; ++k) {
        move(m - 1 - k, n - 1 - k);
    }
    const std::size_t old_mid = m - p - s;
    const std::size_t new_mid = n - p - s;
    if (old_mid > 0 && split_by_name(prev, ids, next, p, old_mid, new_mid, diff.update)) {
        return diff;
    }
    if (old_mid == 0) {
        for (std::size_t j = p; j < p + new_mid; ++j) {
            diff.update.additions.push_back(next[j].mesh);
        }
        return diff;
    }
    std::size_t first_removed = p;
    if (new_mid > 0) {
        SceneUpdate::Replacement rep;
        rep.object = ids[p];
        for (std::size_t j = p; j < p + new_mid; ++j) {
            rep.fragments.push_back(next[j].mesh);
        }
        diff.update.replacements.push_back(std::move(rep));
        first_removed = p + 1;
    }
    for (std::size_t i = first_removed; i < p + old_mid; ++i) {
        diff.update.removals.push_back(ids[i]);
    }
    return diff;
}

}  // namespace proxima::client
