#pragma once
// The JSON shape of `proxima distance --json`, a contract used by external checks: keep the
// names. Local and server modes both build a QueryResult and print it through here, so the two
// agree exactly.

#include <nlohmann/json.hpp>

#include "common/local_scene.hpp"
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

}  // namespace proxima::client
