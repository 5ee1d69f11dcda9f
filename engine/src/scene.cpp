#include "proxima/scene.hpp"

#include <unordered_set>

namespace proxima {

Aabb compute_box(std::span<const Vec3> vertices) {
    Aabb box;
    for (const auto& v : vertices) {
        box.extend(v);
    }
    return box;
}

namespace {
std::string object_label(const std::string& name, ObjectId id) {
    return name.empty() ? "object " + std::to_string(id)
                        : "object " + std::to_string(id) + " ('" + name + "')";
}
}  // namespace

SceneObject Scene::make_object(NamedMesh mesh) {
    SceneObject obj;
    obj.id = m_next_id++;
    obj.name = std::move(mesh.name);
    obj.box = compute_box(mesh.mesh.vertices);
    obj.topology = std::make_shared<const MeshTopology>(std::move(mesh.mesh.triangles),
                                                        mesh.mesh.vertices.size());
    obj.vertices = std::move(mesh.mesh.vertices);
    obj.topology_version = m_next_topology++;
    return obj;
}

void Scene::reindex() {
    m_index.clear();
    for (std::size_t i = 0; i < m_objects.size(); ++i) {
        m_index.emplace(m_objects[i].id, i);
    }
}

std::ptrdiff_t Scene::index_of(ObjectId id) const {
    auto it = m_index.find(id);
    return it == m_index.end() ? -1 : static_cast<std::ptrdiff_t>(it->second);
}

std::size_t Scene::triangle_count() const {
    std::size_t n = 0;
    for (const auto& o : m_objects) {
        n += o.triangle_count();
    }
    return n;
}

StatusOr<ObjectId> Scene::add_object(NamedMesh mesh) {
    SceneUpdate u;
    u.additions.push_back(std::move(mesh));
    auto r = apply(std::move(u));
    if (!r.ok()) {
        return r.status();
    }
    return r->added_ids.front();
}

StatusOr<SceneUpdateResult> Scene::apply(SceneUpdate update) {
    // ---- Validate everything before touching anything.
    std::unordered_set<ObjectId> named;
    auto claim = [&](ObjectId id, const char* what) -> Status {
        if (index_of(id) < 0) {
            return not_found(std::string(what) + ": object " + std::to_string(id) +
                             " is not in the scene");
        }
        if (!named.insert(id).second) {
            return invalid_argument(std::string(what) + ": object " + std::to_string(id) +
                                    " is named more than once in one update");
        }
        return {};
    };
    for (auto id : update.removals) {
        if (Status s = claim(id, "removal"); !s.ok()) {
            return s;
        }
    }
    for (const auto& r : update.replacements) {
        if (Status s = claim(r.object, "topology change"); !s.ok()) {
            return s;
        }
        for (std::size_t f = 0; f < r.fragments.size(); ++f) {
            const auto label =
                "topology change of object " + std::to_string(r.object) + ", fragment " +
                std::to_string(f) +
                (r.fragments[f].name.empty() ? "" : " ('" + r.fragments[f].name + "')");
            if (Status s = validate_mesh(r.fragments[f].mesh, label); !s.ok()) {
                return s;
            }
        }
    }
    for (const auto& p : update.positions) {
        if (Status s = claim(p.object, "vertex update"); !s.ok()) {
            return s;
        }
        const auto& obj = m_objects[static_cast<std::size_t>(index_of(p.object))];
        if (Status s =
                validate_positions(p.vertices, obj.vertices.size(), object_label(obj.name, obj.id));
            !s.ok()) {
            return s;
        }
    }
    for (std::size_t a = 0; a < update.additions.size(); ++a) {
        const auto& add = update.additions[a];
        const auto label =
            "new object " + std::to_string(a) + (add.name.empty() ? "" : " ('" + add.name + "')");
        if (Status s = validate_mesh(add.mesh, label); !s.ok()) {
            return s;
        }
    }

    // ---- Apply: nothing below can fail on input (only on memory exhaustion).
    SceneUpdateResult result;
    std::vector<SceneObject> next;
    next.reserve(m_objects.size() + update.additions.size());
    std::unordered_set<ObjectId> removed(update.removals.begin(), update.removals.end());
    std::unordered_map<ObjectId, SceneUpdate::Replacement*> replaced;
    for (auto& r : update.replacements) {
        replaced.emplace(r.object, &r);
    }
    result.fragment_ids.resize(update.replacements.size());
    for (auto& obj : m_objects) {
        if (removed.count(obj.id) != 0) {
            continue;
        }
        if (auto it = replaced.find(obj.id); it != replaced.end()) {
            const auto which = static_cast<std::size_t>(it->second - update.replacements.data());
            for (auto& frag : it->second->fragments) {
                next.push_back(make_object(std::move(frag)));
                result.fragment_ids[which].push_back(next.back().id);
            }
            continue;
        }
        next.push_back(std::move(obj));
    }
    m_objects = std::move(next);
    reindex();
    for (auto& p : update.positions) {
        auto& obj = m_objects[m_index.at(p.object)];
        obj.vertices = std::move(p.vertices);
        obj.box = compute_box(obj.vertices);
    }
    for (auto& add : update.additions) {
        m_objects.push_back(make_object(std::move(add)));
        result.added_ids.push_back(m_objects.back().id);
    }
    reindex();
    ++m_generation;
    return result;
}

}  // namespace proxima
