#pragma once
// The JSON shape of `proxima distance --json`, a contract used by external checks: keep the
// names. Local and server modes both build a QueryResult and print it through here, so the two
// agree exactly.

#include <nlohmann/json.hpp>

#include "common/local_scene.hpp"
#include "proxima/query/penetration.hpp"
#include "proxima/query/query.hpp"

namespace proxima::client {

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
