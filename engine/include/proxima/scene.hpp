#pragma once
// A scene: the set of objects a simulator streams. Objects keep a stable id for their lifetime;
// their order in `objects()` is the order results are reported in. Every change goes through
// `apply`, which validates the whole update first and then applies all of it or none of it.

#include <cstdint>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "proxima/mesh/mesh.hpp"
#include "proxima/status.hpp"

namespace proxima {

using ObjectId = std::uint64_t;

struct SceneObject {
    ObjectId id = 0;
    std::string name;
    std::vector<Vec3> vertices;
    std::shared_ptr<const MeshTopology> topology;
    // Bumped whenever the topology is replaced; cullers rebuild (not refit) when it changes.
    std::uint64_t topology_version = 0;
    Aabb box;

    std::size_t triangle_count() const { return topology->triangle_count(); }
    const TriangleIndices& triangle(std::uint32_t t) const { return topology->triangle(t); }
};

struct NamedMesh {
    std::string name;
    TriangleMesh mesh;
};

// One frame's changes. Applied in this order: removals, replacements, position updates, additions.
struct SceneUpdate {
    struct Positions {
        ObjectId object = 0;
        std::vector<Vec3> vertices;  // same count and order as the object's current vertices
    };
    struct Replacement {
        ObjectId object = 0;
        std::vector<NamedMesh> fragments;  // take the replaced object's place, in this order
    };
    std::vector<ObjectId> removals;
    std::vector<Replacement> replacements;
    std::vector<Positions> positions;
    std::vector<NamedMesh> additions;  // appended at the end
};

struct SceneUpdateResult {
    // Ids given to new objects: fragments of each replacement in order, then additions.
    std::vector<std::vector<ObjectId>> fragment_ids;
    std::vector<ObjectId> added_ids;
};

class Scene {
  public:
    // Validates and adds one object at the end.
    StatusOr<ObjectId> add_object(NamedMesh mesh);
    // All-or-nothing: if any part is invalid (unknown id, an id named twice, wrong vertex count,
    // non-finite coordinate, bad index, empty mesh) nothing changes and the status says what.
    StatusOr<SceneUpdateResult> apply(SceneUpdate update);

    const std::vector<SceneObject>& objects() const { return m_objects; }
    std::size_t size() const { return m_objects.size(); }
    const SceneObject& operator[](std::size_t i) const { return m_objects[i]; }
    // Index in objects() of an id, or -1.
    std::ptrdiff_t index_of(ObjectId id) const;
    std::size_t triangle_count() const;
    // Incremented by every successful change: cullers use it to skip redundant refits.
    std::uint64_t generation() const { return m_generation; }

  private:
    SceneObject make_object(NamedMesh mesh);
    void reindex();

    std::vector<SceneObject> m_objects;
    std::unordered_map<ObjectId, std::size_t> m_index;
    ObjectId m_next_id = 1;
    std::uint64_t m_next_topology = 1;
    std::uint64_t m_generation = 0;
};

Aabb compute_box(std::span<const Vec3> vertices);

}  // namespace proxima
