#pragma once
// Private to the store: parsing the importer's scene files (format "proxima-scene/1", documented
// at import_files in proxima/massive/store.hpp).

#include <optional>
#include <string>
#include <vector>

#include "proxima/massive/model.hpp"

namespace proxima::massive::detail {

struct ScenePart {
    std::string mesh_key;
    std::string mesh_path;  // resolved: relative paths are taken from the scene file's directory
    std::optional<Affine> transform;
};

struct SceneObject {
    std::string name;
    std::vector<ScenePart> parts;
};

struct SceneFile {
    std::string path;
    std::vector<SceneObject> objects;
};

// Reads and checks the whole file: INVALID_ARGUMENT naming the file and the JSON path
// ("objects[3].parts[0].transform") for anything wrong, NOT_FOUND when the file is missing. Mesh
// files are not opened here.
StatusOr<SceneFile> parse_scene_file(const std::string& path);

}  // namespace proxima::massive::detail
