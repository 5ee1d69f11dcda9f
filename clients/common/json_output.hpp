#pragma once
// The CLI's JSON vocabulary (docs/api.md, "JSON output"; the schema docs/json-output.schema.json,
// checked over every command by tests/cli/test_json_schema.py): a point is [x, y, z], a box
// {"lo", "hi"}, a closest pair {"object", "triangle", "point", "other", "other_triangle",
// "other_point", "distance"} (a feature pair is its first part), plural names are arrays and
// counts are `*_count`. `proxima distance --json` is a contract used by external checks. Local
// and server modes both build a QueryResult and print it through here, so the two agree exactly.

#include <nlohmann/json.hpp>

#include "common/local_scene.hpp"
#include "proxima/query/penetration.hpp"
#include "proxima/query/query.hpp"

namespace proxima::client {

// [x, y, z].
nlohmann::json point_json(const Vec3& p);
// {"lo": [x, y, z], "hi": [x, y, z]}; both null for an empty box.
nlohmann::json box_json(const Aabb& box);

struct OutputOptions {
    bool self = false;
    bool collisions = false;
    bool tolerance = false;
    bool pns = false;
};

// {"objects": [...], "self": [...], "collisions": [...], "tolerance": [...], "pns": [...],
//  "stats": {...}}; triangle ids are indices in the objects' input files.
nlohmann::json distance_json(const std::vector<InputObject>& objects, const QueryResult& result,
                             const OutputOptions& options);

nlohmann::json stats_json(const QueryStats& stats);

// [{"object", "other", "depth", "direction": [x, y, z], "vector": [...], "triangles": [...],
//   "other_triangles": [...], "triangle", "other_triangle", "isolated", "closed",
//   "normal_fallback", "sides_split"}]; triangle ids are indices in the objects' input files.
nlohmann::json penetrations_json(const std::vector<InputObject>& objects,
                                 const std::vector<Penetration>& penetrations);

}  // namespace proxima::client
