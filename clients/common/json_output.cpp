#include "common/json_output.hpp"

#include <cmath>

namespace proxima::client {

nlohmann::json point_json(const Vec3& p) {
    return nlohmann::json::array({p.x, p.y, p.z});
}

nlohmann::json box_json(const Aabb& box) {
    if (box.empty()) {
        return {{"lo", nullptr}, {"hi", nullptr}};
    }
    return {{"lo", point_json(box.lo)}, {"hi", point_json(box.hi)}};
}

namespace {

nlohmann::json point(const Vec3& p) {
    return point_json(p);
}

// JSON has no infinity: "no such feature" is null.
nlohmann::json distance_value(double d) {
    return std::isfinite(d) ? nlohmann::json(d) : nlohmann::json(nullptr);
}

nlohmann::json pair_json(const std::vector<InputObject>& objects, const FeaturePair& p,
                         bool with_distance) {
    nlohmann::json j = {{"object", p.object},
                        {"triangle", objects[p.object].file_triangle[p.triangle]},
                        {"other", p.other},
                        {"other_triangle", objects[p.other].file_triangle[p.other_triangle]}};
    if (with_distance) {
        j["distance"] = p.distance;
    }
    return j;
}

}  // namespace

nlohmann::json stats_json(const QueryStats& s) {
    // Flat, with the names of the proto's Stats message.
    return {{"culler", s.culler},
            {"prepare_seconds", s.prepare_seconds},
            {"broad_phase_seconds", s.broad_phase_seconds},
            {"separation_seconds", s.separation_seconds},
            {"self_seconds", s.self_seconds},
            {"collision_seconds", s.collision_seconds},
            {"tolerance_seconds", s.tolerance_seconds},
            {"voronoi_seconds", s.voronoi_seconds},
            {"dvd_seconds", s.dvd_seconds},
            {"total_seconds", s.total_seconds},
            {"exact_tests", s.exact_tests},
            {"brute_force_tests", s.brute_force_tests},
            {"object_pairs_tested", s.object_pairs_tested},
            {"pns_pairs", s.pns_pairs},
            {"dvd_samples", s.dvd_samples},
            {"dvd_cell", s.dvd_cell},
            {"voronoi_culled", s.voronoi_culled},
            {"dvd_epsilon", s.dvd_epsilon}};
}

nlohmann::json distance_json(const std::vector<InputObject>& objects, const QueryResult& result,
                             const OutputOptions& options) {
    nlohmann::json out;
    auto& list = out["objects"] = nlohmann::json::array();
    for (std::size_t i = 0; i < objects.size(); ++i) {
        const auto& obj = objects[i];
        nlohmann::json o = {{"name", obj.mesh.name},
                            {"file", obj.file},
                            {"triangle_count", obj.file_triangle.size()}};
        if (obj.component >= 0) {
            o["component"] = obj.component;
        }
        if (i < result.separation.size()) {
            const auto& s = result.separation[i];
            if (s.other == NO_OBJECT) {
                o["separation"] = {
                    {"object", i},        {"triangle", nullptr},       {"point", nullptr},
                    {"other", nullptr},   {"other_triangle", nullptr}, {"other_point", nullptr},
                    {"distance", nullptr}};
            } else {
                const auto other = static_cast<std::size_t>(s.other);
                o["separation"] = {
                    {"object", i},
                    {"triangle", obj.file_triangle[s.triangle]},
                    {"point", point(s.point)},
                    {"other", s.other},
                    {"other_triangle", objects[other].file_triangle[s.other_triangle]},
                    {"other_point", point(s.other_point)},
                    {"distance", s.distance}};
            }
        }
        list.push_back(std::move(o));
    }
    if (options.self) {
        auto& self = out["self"] = nlohmann::json::array();
        for (std::size_t i = 0; i < result.self.size(); ++i) {
            const auto& ids = objects[i].file_triangle;
            for (std::size_t t = 0; t < result.self[i].size(); ++t) {
                const auto& s = result.self[i][t];
                // `closest` (the other triangle, in the same object) is a name of the external
                // contract of issue #2, kept where the vocabulary would say `other_triangle`.
                nlohmann::json e = {{"object", i}, {"triangle", ids[t]}};
                if (s.closest == NO_OBJECT) {
                    e["closest"] = nullptr;
                    e["distance"] = nullptr;
                } else {
                    e["closest"] = ids[static_cast<std::size_t>(s.closest)];
                    e["distance"] = distance_value(s.distance);
                }
                self.push_back(std::move(e));
            }
        }
    }
    if (options.collisions) {
        auto& c = out["collisions"] = nlohmann::json::array();
        for (const auto& p : result.collisions) {
            c.push_back(pair_json(objects, p, false));
        }
    }
    if (options.tolerance) {
        // The pairs within the tolerance: `within`, as in review (`tolerance` is the number).
        auto& c = out["within"] = nlohmann::json::array();
        for (const auto& p : result.tolerance) {
            c.push_back(pair_json(objects, p, true));
        }
    }
    if (options.pns) {
        auto& c = out["pns"] = nlohmann::json::array();
        for (const auto& p : result.pns) {
            c.push_back(pair_json(objects, p, false));
        }
    }
    out["stats"] = stats_json(result.stats);
    return out;
}

nlohmann::json penetrations_json(const std::vector<InputObject>& objects,
                                 const std::vector<Penetration>& penetrations) {
    auto out = nlohmann::json::array();
    auto vec = [](const Vec3& v) { return nlohmann::json::array({v.x, v.y, v.z}); };
    for (const auto& p : penetrations) {
        const auto& a = objects[p.object].file_triangle;
        const auto& b = objects[p.other].file_triangle;
        auto ids = [](const std::vector<std::uint32_t>& map,
                      const std::vector<std::uint32_t>& triangles) {
            auto list = nlohmann::json::array();
            for (auto t : triangles) {
                list.push_back(map[t]);
            }
            return list;
        };
        out.push_back({{"object", p.object},
                       {"other", p.other},
                       {"depth", p.depth},
                       {"direction", vec(p.direction)},
                       {"vector", vec(p.vector)},
                       {"triangles", ids(a, p.triangles)},
                       {"other_triangles", ids(b, p.other_triangles)},
                       {"triangle", a[p.triangle]},
                       {"other_triangle", b[p.other_triangle]},
                       {"isolated", p.isolated},
                       {"closed", p.closed},
                       {"normal_fallback", p.normal_fallback},
                       {"sides_split", p.sides_split}});
    }
    return out;
}

}  // namespace proxima::client
