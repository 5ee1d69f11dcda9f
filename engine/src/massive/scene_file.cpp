#include "massive/scene_file.hpp"

#include <filesystem>
#include <map>

#include <nlohmann/json.hpp>

#include "massive/store_format.hpp"

namespace proxima::massive::detail {

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr char SCENE_FORMAT[] = "proxima-scene/1";

std::string type_name(const json& j) {
    return j.type_name();
}

}  // namespace

StatusOr<SceneFile> parse_scene_file(const std::string& path) {
    const std::string where = "scene file '" + path + "'";
    auto bad = [&](const std::string& json_path, const std::string& what) {
        return invalid_argument(where + ": " + json_path + ": " + what);
    };
    auto bytes = detail::read_whole_file(path);
    if (!bytes.ok()) {
        if (bytes.status().code() == StatusCode::not_found) {
            return not_found(where + ": no such file");
        }
        return Status(bytes.status().code(), where + ": " + bytes.status().message());
    }
    json doc;
    try {
        doc = json::parse(bytes.value());
    } catch (const json::exception& e) {
        return invalid_argument(where + ": not valid JSON: " + e.what());
    }
    if (!doc.is_object()) {
        return bad("(top level)", "expected an object, got " + type_name(doc));
    }
    if (!doc.contains("format")) {
        return bad("format", std::string("missing (expected \"") + SCENE_FORMAT + "\")");
    }
    if (!doc["format"].is_string() || doc["format"].get<std::string>() != SCENE_FORMAT) {
        return bad("format", "unknown format " + doc["format"].dump() + " (expected \"" +
                                 SCENE_FORMAT + "\")");
    }

    const fs::path base = fs::path(path).parent_path();
    std::map<std::string, std::string> meshes;
    if (!doc.contains("meshes") || !doc["meshes"].is_object()) {
        return bad("meshes",
                   doc.contains("meshes")
                       ? "expected an object (key -> mesh file), got " + type_name(doc["meshes"])
                       : "missing");
    }
    for (const auto& [key, value] : doc["meshes"].items()) {
        if (!value.is_string() || value.get<std::string>().empty()) {
            return bad("meshes." + key, "expected a mesh file path, got " + value.dump());
        }
        const fs::path p = value.get<std::string>();
        meshes[key] = p.is_absolute() ? p.string() : (base / p).string();
    }

    if (!doc.contains("objects") || !doc["objects"].is_array()) {
        return bad("objects", doc.contains("objects")
                                  ? "expected an array, got " + type_name(doc["objects"])
                                  : "missing");
    }
    SceneFile scene;
    scene.path = path;
    const auto& objects = doc["objects"];
    scene.objects.reserve(objects.size());
    for (std::size_t i = 0; i < objects.size(); ++i) {
        const std::string at = "objects[" + std::to_string(i) + "]";
        const auto& o = objects[i];
        if (!o.is_object()) {
            return bad(at, "expected an object, got " + type_name(o));
        }
        SceneObject object;
        if (!o.contains("name") || !o["name"].is_string() || o["name"].get<std::string>().empty()) {
            return bad(at + ".name", o.contains("name")
                                         ? "expected a non-empty string, got " + o["name"].dump()
                                         : "missing");
        }
        object.name = o["name"].get<std::string>();
        if (!o.contains("parts") || !o["parts"].is_array() || o["parts"].empty()) {
            return bad(at + ".parts", o.contains("parts")
                                          ? "expected a non-empty array, got " + o["parts"].dump()
                                          : "missing");
        }
        const auto& parts = o["parts"];
        for (std::size_t k = 0; k < parts.size(); ++k) {
            const std::string pat = at + ".parts[" + std::to_string(k) + "]";
            const auto& p = parts[k];
            if (!p.is_object()) {
                return bad(pat, "expected an object, got " + type_name(p));
            }
            ScenePart part;
            if (!p.contains("mesh") || !p["mesh"].is_string()) {
                return bad(pat + ".mesh", p.contains("mesh")
                                              ? "expected a key of meshes, got " + p["mesh"].dump()
                                              : "missing");
            }
            part.mesh_key = p["mesh"].get<std::string>();
            auto it = meshes.find(part.mesh_key);
            if (it == meshes.end()) {
                return bad(pat + ".mesh", "'" + part.mesh_key + "' is not a key of meshes");
            }
            part.mesh_path = it->second;
            if (p.contains("transform")) {
                const auto& t = p["transform"];
                const std::string what = "expected 12 finite numbers (row-major 3x4), got ";
                if (!t.is_array() || t.size() != 12) {
                    return bad(pat + ".transform",
                               what + (t.is_array() ? std::to_string(t.size()) + " values"
                                                    : type_name(t)));
                }
                Affine a;
                for (std::size_t e = 0; e < 12; ++e) {
                    if (!t[e].is_number()) {
                        return bad(pat + ".transform[" + std::to_string(e) + "]",
                                   what + t[e].dump());
                    }
                    a.m[e] = t[e].get<double>();
                }
                if (!a.finite()) {
                    return bad(pat + ".transform", what + "a non-finite value");
                }
                part.transform = a;
            }
            object.parts.push_back(std::move(part));
        }
        scene.objects.push_back(std::move(object));
    }
    return scene;
}

}  // namespace proxima::massive::detail
