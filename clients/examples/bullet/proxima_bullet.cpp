// proxima-bullet: a Bullet soft-body simulation (Debian's libbullet-dev, the float64 build) that
// streams its deformed nodes to proximad every step and uses the answers (issue #19):
//   - CCD from the previous to the new node positions limits the step: the nodes of contacting
//     primitives are frozen at the step's start and the step is checked again, a few rounds, then
//     every node is rewound to a fraction of the earliest time of impact; so no primitive pair
//     ever passes through another between the states the client keeps, and frozen nodes stop;
//   - separation and self distances: near-contacts are reported;
//   - penetration vectors: soft nodes still inside a static obstacle (Bullet's response failed and
//     the state was already intersecting) are pushed out along the vector;
// docs/simulators.md ("Bullet soft bodies") has the details and measured costs.
//   - Bullet's own soft-rigid contacts (btSoftBody::m_rcontacts) are compared with the service's
//     near-contacts and CCD contacts, and the disagreements are counted.
// Headless; prints per-step timings (Bullet step, service round trip) and writes a JSON log.
// Ids in the output are the caller's: node indices (m_nodes), face indices (m_faces) of the soft
// bodies, edge indices of ccd::mesh_edges over those faces, triangle indices of the obstacles.

#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <numbers>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <BulletSoftBody/btSoftBodyHelpers.h>
#include <BulletSoftBody/btSoftBodyRigidBodyCollisionConfiguration.h>
#include <BulletSoftBody/btSoftRigidDynamicsWorld.h>
#include <btBulletDynamicsCommon.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "client/proxima_client.hpp"
#include "proxima/ccd/frame_ccd.hpp"
#include "proxima/frame_pipeline.hpp"
#include "proxima/query/penetration.hpp"
#include "proxima/query/query.hpp"

#ifndef BT_USE_DOUBLE_PRECISION
#error "proxima-bullet is built against Bullet's float64 build (pkg-config bullet-float64)"
#endif

namespace {

using namespace proxima;
using nlohmann::json;

double milliseconds_since(std::chrono::steady_clock::time_point start) {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
        .count();
}

Vec3 to_vec(const btVector3& v) {
    return {v.x(), v.y(), v.z()};
}

btVector3 to_bt(const Vec3& v) {
    return {v.x, v.y, v.z};
}

json point_json(const Vec3& p) {
    return json::array({p.x, p.y, p.z});
}

// JSON has no infinity: "no such feature" is null.
json distance_json(double d) {
    return std::isfinite(d) ? json(d) : json(nullptr);
}

struct Args {
    std::string scene = "cloth-sphere";
    std::string server;
    std::size_t steps = 300;
    int resolution = 20;
    double dt = 1.0 / 60.0;
    double margin = 0.02;
    double near = 0.05;
    double rewind = 0.5;
    int max_freeze = 4;
    double inset = 0.01;
    std::string json_file;
    std::string record_file;
    bool check = false;
    bool no_limit = false;
    bool pushout_only = false;
    bool quiet = false;
    std::string snapshot_dir;         // --snapshots DIR: PNGs through the daemon's Snapshot call
    std::size_t snapshot_every = 10;  // every this many steps (and step 0 and the last)
    int snapshot_width = 640;
    int snapshot_height = 480;
};

// --- The Bullet world ------------------------------------------------------------------------

// A static obstacle: a Bullet rigid body and the triangle mesh the service sees for it.
struct Obstacle {
    std::string name;
    TriangleMesh mesh;
};

// A soft body and its faces as triangles over its node indices.
struct Soft {
    std::string name;
    btSoftBody* body = nullptr;
    std::vector<TriangleIndices> triangles;
};

class World {
  public:
    World()
        : m_config(std::make_unique<btSoftBodyRigidBodyCollisionConfiguration>()),
          m_dispatcher(std::make_unique<btCollisionDispatcher>(m_config.get())),
          m_broadphase(std::make_unique<btDbvtBroadphase>()),
          m_solver(std::make_unique<btSequentialImpulseConstraintSolver>()),
          m_world(std::make_unique<btSoftRigidDynamicsWorld>(m_dispatcher.get(), m_broadphase.get(),
                                                             m_solver.get(), m_config.get())) {
        m_world->setGravity(btVector3(0, -9.81, 0));
        auto& info = m_world->getWorldInfo();
        info.m_dispatcher = m_dispatcher.get();
        info.m_broadphase = m_broadphase.get();
        info.m_gravity = btVector3(0, -9.81, 0);
        info.air_density = 1.2;
        info.water_density = 0;
        info.m_sparsesdf.Initialize();
    }

    ~World() {
        for (auto& s : soft) {
            m_world->removeSoftBody(s.body);
            delete s.body;  // NOLINT: Bullet's helpers return owning raw pointers
        }
        for (auto& b : m_bodies) {
            m_world->removeRigidBody(b.get());
        }
    }

    World(const World&) = delete;
    World& operator=(const World&) = delete;

    btSoftBodyWorldInfo& info() { return m_world->getWorldInfo(); }
    btSoftRigidDynamicsWorld& world() { return *m_world; }

    void add_static(std::unique_ptr<btCollisionShape> shape, const btTransform& where) {
        m_motion.push_back(std::make_unique<btDefaultMotionState>(where));
        btRigidBody::btRigidBodyConstructionInfo ci(0, m_motion.back().get(), shape.get());
        ci.m_friction = 0.8;
        m_bodies.push_back(std::make_unique<btRigidBody>(ci));
        m_world->addRigidBody(m_bodies.back().get());
        m_shapes.push_back(std::move(shape));
    }

    // A shape a compound refers to: kept alive as long as the world.
    void keep_shape(std::unique_ptr<btCollisionShape> shape) {
        m_shapes.push_back(std::move(shape));
    }

    void add_soft(std::string name, btSoftBody* body) {
        Soft s;
        s.name = std::move(name);
        s.body = body;
        const btSoftBody::Node* first = &body->m_nodes[0];
        for (int f = 0; f < body->m_faces.size(); ++f) {
            const auto& face = body->m_faces[f];
            TriangleIndices t{};
            for (int k = 0; k < 3; ++k) {
                t[k] = static_cast<std::uint32_t>(face.m_n[k] - first);
            }
            s.triangles.push_back(t);
        }
        m_world->addSoftBody(body);
        soft.push_back(std::move(s));
    }

    std::vector<Soft> soft;
    std::vector<Obstacle> obstacles;

  private:
    std::unique_ptr<btSoftBodyRigidBodyCollisionConfiguration> m_config;
    std::unique_ptr<btCollisionDispatcher> m_dispatcher;
    std::unique_ptr<btDbvtBroadphase> m_broadphase;
    std::unique_ptr<btSequentialImpulseConstraintSolver> m_solver;
    std::unique_ptr<btSoftRigidDynamicsWorld> m_world;
    std::vector<std::unique_ptr<btCollisionShape>> m_shapes;
    std::vector<std::unique_ptr<btDefaultMotionState>> m_motion;
    std::vector<std::unique_ptr<btRigidBody>> m_bodies;
};

// A closed, outward-oriented UV sphere with its vertices on the sphere (so it lies inside
// Bullet's exact sphere).
TriangleMesh uv_sphere(const Vec3& center, double radius, int rings, int sectors) {
    TriangleMesh m;
    m.vertices.push_back(center + Vec3{0, radius, 0});
    for (int r = 1; r < rings; ++r) {
        const double phi = std::numbers::pi * r / rings;
        for (int s = 0; s < sectors; ++s) {
            const double theta = 2 * std::numbers::pi * s / sectors;
            m.vertices.push_back(center + Vec3{radius * std::sin(phi) * std::cos(theta),
                                               radius * std::cos(phi),
                                               radius * std::sin(phi) * std::sin(theta)});
        }
    }
    m.vertices.push_back(center + Vec3{0, -radius, 0});
    const auto bottom = static_cast<std::uint32_t>(m.vertices.size() - 1);
    auto at = [&](int r, int s) {
        return static_cast<std::uint32_t>(1 + (r - 1) * sectors + (s % sectors));
    };
    for (int s = 0; s < sectors; ++s) {
        m.triangles.push_back({0, at(1, s + 1), at(1, s)});
        m.triangles.push_back({bottom, at(rings - 1, s), at(rings - 1, s + 1)});
    }
    for (int r = 1; r + 1 < rings; ++r) {
        for (int s = 0; s < sectors; ++s) {
            m.triangles.push_back({at(r, s), at(r, s + 1), at(r + 1, s + 1)});
            m.triangles.push_back({at(r, s), at(r + 1, s + 1), at(r + 1, s)});
        }
    }
    return m;
}

// The 12 outward triangles of an oriented box (center, half extents, rotation about z), appended.
void append_box(TriangleMesh& m, const btTransform& where, const btVector3& half) {
    const auto base = static_cast<std::uint32_t>(m.vertices.size());
    for (int i = 0; i < 8; ++i) {
        const btVector3 corner((i & 1) ? half.x() : -half.x(), (i & 2) ? half.y() : -half.y(),
                               (i & 4) ? half.z() : -half.z());
        m.vertices.push_back(to_vec(where * corner));
    }
    static constexpr std::array<std::array<std::uint32_t, 3>, 12> FACES{{{0, 2, 3},
                                                                         {0, 3, 1},
                                                                         {4, 5, 7},
                                                                         {4, 7, 6},
                                                                         {0, 1, 5},
                                                                         {0, 5, 4},
                                                                         {2, 6, 7},
                                                                         {2, 7, 3},
                                                                         {0, 4, 6},
                                                                         {0, 6, 2},
                                                                         {1, 3, 7},
                                                                         {1, 7, 5}}};
    for (const auto& f : FACES) {
        m.triangles.push_back({base + f[0], base + f[1], base + f[2]});
    }
}

// cloth-sphere: a square cloth (resolution x resolution nodes, 3 m wide) dropped off-centre over a
// static sphere of radius 1.
void build_cloth_sphere(World& w, const Args& args) {
    const double radius = 1.0;
    w.add_static(std::make_unique<btSphereShape>(radius), btTransform::getIdentity());
    // The service's sphere lies --inset inside Bullet's (its vertices on the smaller sphere).
    w.obstacles.push_back({"sphere", uv_sphere({0, 0, 0}, radius - args.inset, 16, 32)});
    const double h = 1.4;
    const double s = 1.5;
    const Vec3 offset{0.35, 0, 0.2};
    btSoftBody* cloth = btSoftBodyHelpers::CreatePatch(
        w.info(), to_bt(offset + Vec3{-s, h, -s}), to_bt(offset + Vec3{s, h, -s}),
        to_bt(offset + Vec3{-s, h, s}), to_bt(offset + Vec3{s, h, s}), args.resolution,
        args.resolution, 0, true);
    cloth->getCollisionShape()->setMargin(args.margin);
    cloth->m_cfg.kDF = 0.4;
    cloth->m_cfg.piterations = 4;
    cloth->m_materials[0]->m_kLST = 0.6;
    cloth->generateBendingConstraints(2, cloth->m_materials[0]);
    cloth->setTotalMass(0.5);
    w.add_soft("cloth", cloth);
}

// ball-bowl: a soft ball (Bullet's ellipsoid, pressurised) dropped into a bowl made of boxes: a
// floor and a ring of tilted walls (a compound of convex boxes, which Bullet's soft-rigid
// collision handles; the service sees the same boxes as one triangle mesh).
void build_ball_bowl(World& w, const Args& args) {
    auto compound = std::make_unique<btCompoundShape>();
    std::vector<std::unique_ptr<btCollisionShape>> children;
    TriangleMesh bowl;
    const btVector3 floor_half(1.0, 0.05, 1.0);
    btTransform floor_at = btTransform::getIdentity();
    floor_at.setOrigin(btVector3(0, -0.05, 0));
    // The service's boxes lie --inset inside Bullet's.
    const btVector3 inset(args.inset, args.inset, args.inset);
    append_box(bowl, floor_at, floor_half - inset);
    children.push_back(std::make_unique<btBoxShape>(floor_half));
    compound->addChildShape(floor_at, children.back().get());
    const int walls = 8;
    const btVector3 wall_half(0.45, 0.5, 0.04);
    for (int i = 0; i < walls; ++i) {
        const double a = 2 * std::numbers::pi * i / walls;
        // Each wall leans outwards by 30 degrees, its bottom edge on the floor's rim.
        btQuaternion q(btVector3(0, 1, 0), -a + std::numbers::pi / 2);
        q *= btQuaternion(btVector3(1, 0, 0), -std::numbers::pi / 6);
        btTransform at(q, btVector3(std::cos(a) * 1.1, 0.43, std::sin(a) * 1.1));
        append_box(bowl, at, wall_half - inset);
        children.push_back(std::make_unique<btBoxShape>(wall_half));
        compound->addChildShape(at, children.back().get());
    }
    w.obstacles.push_back({"bowl", std::move(bowl)});
    w.add_static(std::move(compound), btTransform::getIdentity());
    for (auto& c : children) {
        w.keep_shape(std::move(c));
    }
    btSoftBody* ball = btSoftBodyHelpers::CreateEllipsoid(
        w.info(), btVector3(0.2, 1.6, 0.1), btVector3(0.4, 0.4, 0.4), args.resolution * 10);
    ball->getCollisionShape()->setMargin(args.margin);
    // Bullet's pressure demo (SoftDemo's Init_Pressure), scaled down.
    ball->m_materials[0]->m_kLST = 0.1;
    ball->m_cfg.kDF = 1.0;
    ball->m_cfg.kDP = 0.001;
    ball->m_cfg.kPR = 500;
    ball->m_cfg.piterations = 4;
    ball->setTotalMass(30, true);
    w.add_soft("ball", ball);
}

// ropes: two ropes (ribbons 2 nodes wide and --resolution nodes long, Bullet's patches; a
// rope proper, CreateRope, has no faces to send) hanging from anchors 1.4 m apart, released
// horizontal and pointing away from each other, so that they swing down into each other. Bullet's
// soft-soft collision (VF_SS) is on.
void build_ropes(World& w, const Args& args) {
    const double length = 1.2;
    const double width = 0.08;
    const double top = 2.0;
    for (int k = 0; k < 2; ++k) {
        const double anchor = k == 0 ? -0.7 : 0.7;
        const double tip = k == 0 ? anchor - length : anchor + length;
        // corner00/10: the anchored end (fixed), corner01/11: the tip; a small tilt along z
        // keeps the two from being exactly coplanar.
        const double dz = k == 0 ? 0.0 : 0.03;
        btSoftBody* rope = btSoftBodyHelpers::CreatePatch(
            w.info(), btVector3(anchor, top, -width / 2 + dz),
            btVector3(anchor, top, width / 2 + dz), btVector3(tip, top, -width / 2),
            btVector3(tip, top, width / 2), 2, args.resolution, 1 + 2, true);
        rope->getCollisionShape()->setMargin(args.margin);
        rope->m_cfg.collisions = btSoftBody::fCollision::SDF_RS | btSoftBody::fCollision::VF_SS;
        rope->m_cfg.kDF = 0.2;
        rope->m_cfg.piterations = 8;
        rope->m_materials[0]->m_kLST = 0.9;
        rope->setTotalMass(0.3);
        w.add_soft(k == 0 ? "rope-a" : "rope-b", rope);
    }
}

// --- Comparing the daemon's answers with the in-process engine (--check) ---------------------

std::uint64_t bits(double d) {
    return std::bit_cast<std::uint64_t>(d);
}

bool same_point(const Vec3& a, const Vec3& b) {
    return bits(a.x) == bits(b.x) && bits(a.y) == bits(b.y) && bits(a.z) == bits(b.z);
}

// "" when the two outcomes are equal (timings aside), else the first difference.
std::string difference(const FrameOutcome& local, const client::FrameResponse& remote) {
    const auto& a = local.result;
    const auto& b = remote.result;
    if (a.separation.size() != b.separation.size()) {
        return "separation count";
    }
    for (std::size_t i = 0; i < a.separation.size(); ++i) {
        const auto& x = a.separation[i];
        const auto& y = b.separation[i];
        if (x.other != y.other || x.triangle != y.triangle ||
            x.other_triangle != y.other_triangle || bits(x.distance) != bits(y.distance) ||
            !same_point(x.point, y.point) || !same_point(x.other_point, y.other_point)) {
            return "separation of object " + std::to_string(i);
        }
    }
    if (a.self.size() != b.self.size()) {
        return "self count";
    }
    for (std::size_t i = 0; i < a.self.size(); ++i) {
        if (a.self[i].size() != b.self[i].size()) {
            return "self count of object " + std::to_string(i);
        }
        for (std::size_t t = 0; t < a.self[i].size(); ++t) {
            const auto& x = a.self[i][t];
            const auto& y = b.self[i][t];
            // Self points travel only with self_points (not asked for here).
            if (x.closest != y.closest || bits(x.distance) != bits(y.distance)) {
                return "self distance of object " + std::to_string(i) + " triangle " +
                       std::to_string(t);
            }
        }
    }
    auto same_pairs = [](const std::vector<FeaturePair>& x, const std::vector<FeaturePair>& y) {
        if (x.size() != y.size()) {
            return false;
        }
        for (std::size_t i = 0; i < x.size(); ++i) {
            if (x[i] < y[i] || y[i] < x[i] || bits(x[i].distance) != bits(y[i].distance)) {
                return false;
            }
        }
        return true;
    };
    if (!same_pairs(a.collisions, b.collisions)) {
        return "collisions";
    }
    if (!same_pairs(a.tolerance, b.tolerance)) {
        return "tolerance pairs";
    }
    if (local.ccd.has_value() != remote.ccd.has_value()) {
        return "ccd present";
    }
    if (local.ccd) {
        const auto& x = local.ccd->pairs;
        const auto& y = remote.ccd->pairs;
        if (x.size() != y.size()) {
            return "ccd pair count";
        }
        for (std::size_t i = 0; i < x.size(); ++i) {
            if (x[i].kind != y[i].kind || x[i].object != y[i].object ||
                x[i].primitive != y[i].primitive || x[i].other != y[i].other ||
                x[i].other_primitive != y[i].other_primitive || bits(x[i].toi) != bits(y[i].toi) ||
                x[i].capped != y[i].capped) {
                return "ccd pair " + std::to_string(i);
            }
        }
        if (local.ccd->earliest != remote.ccd->earliest) {
            return "ccd earliest";
        }
    }
    if (local.penetrations.size() != remote.penetrations.size()) {
        return "penetration count";
    }
    for (std::size_t i = 0; i < local.penetrations.size(); ++i) {
        const auto& x = local.penetrations[i];
        const auto& y = remote.penetrations[i];
        if (x.object != y.object || x.other != y.other || !same_point(x.vector, y.vector) ||
            bits(x.depth) != bits(y.depth) || x.triangles != y.triangles ||
            x.other_triangles != y.other_triangles) {
            return "penetration " + std::to_string(i);
        }
    }
    return "";
}

// --- The session with the daemon -------------------------------------------------------------

struct Spread {
    std::vector<double> values;
    json to_json() const {
        if (values.empty()) {
            return nullptr;
        }
        auto v = values;
        std::sort(v.begin(), v.end());
        double sum = 0;
        for (double x : v) {
            sum += x;
        }
        const auto at = [&](double q) {
            return v[std::min(v.size() - 1,
                              static_cast<std::size_t>(q * static_cast<double>(v.size())))];
        };
        return {{"mean", sum / static_cast<double>(v.size())},
                {"p50", at(0.5)},
                {"p99", at(0.99)},
                {"max", v.back()}};
    }
};

class Session {
  public:
    Session(World& world, const Args& args) : m_world(world), m_args(args) {}
    // On an error path (close() not reached): cancel the stream and delete the scene, one
    // attempt, so that the daemon does not keep it until it expires.
    ~Session() {
        if (m_stream) {
            m_stream->cancel();
            m_stream.reset();
        }
        if (m_client && !m_scene_id.empty()) {
            (void)m_client->delete_scene(m_scene_id);
        }
    }
    Session(const Session&) = delete;
    Session& operator=(const Session&) = delete;

    Status open() {
        client::ConnectOptions options;  // float64 vertices: bit-identical answers
        auto c = client::Client::connect(m_args.server, options);
        if (!c.ok()) {
            return c.status();
        }
        m_client = std::move(c).value();
        std::vector<NamedMesh> objects;
        for (const auto& s : m_world.soft) {
            objects.push_back({s.name, TriangleMesh{positions(s), s.triangles}});
            m_sent.push_back(objects.back().mesh.vertices);
        }
        for (const auto& o : m_world.obstacles) {
            objects.push_back({o.name, o.mesh});
        }
        auto scene = m_client->create_scene("proxima-bullet " + m_args.scene, objects);
        if (!scene.ok()) {
            return scene.status();
        }
        m_scene_id = scene->scene_id;
        for (const auto& o : scene->objects) {
            m_ids.push_back(o.id);
        }
        if (m_args.check) {
            m_mirror = std::make_unique<ProximityEngine>();
            for (const auto& o : objects) {
                auto id = m_mirror->scene().add_object(o);
                if (!id.ok()) {
                    return id.status();
                }
                m_local_ids.push_back(id.value());
            }
        }
        auto stream = m_client->open_stream(m_scene_id);
        if (!stream.ok()) {
            return stream.status();
        }
        m_stream = std::move(stream).value();
        return {};
    }

    Status close() {
        Status st;
        if (m_stream) {
            st = m_stream->finish();
            m_stream.reset();
        }
        if (m_client && !m_scene_id.empty()) {
            auto deleted = m_client->delete_scene(m_scene_id);
            m_scene_id.clear();
            if (st.ok()) {
                st = deleted;
            }
        }
        return st;
    }

    static std::vector<Vec3> positions(const Soft& s) {
        std::vector<Vec3> out;
        out.reserve(static_cast<std::size_t>(s.body->m_nodes.size()));
        for (int i = 0; i < s.body->m_nodes.size(); ++i) {
            out.push_back(to_vec(s.body->m_nodes[i].m_x));
        }
        return out;
    }

    enum class Ask {
        nothing,  // only move the nodes (back to the step's start, before a CCD retry)
        queries,  // separation, self, tolerance (near-contacts), collisions and penetrations
        ccd,      // the queries and CCD from the daemon's current positions to these
    };

    // One positions-only frame with the soft bodies' nodes. Adds the round trip to
    // `round_trip_ms` and counts the frame in `frames`.
    StatusOr<client::FrameResponse> exchange(const std::vector<std::vector<Vec3>>& soft_positions,
                                             Ask ask, double& round_trip_ms, int& frames) {
        FrameRequest frame;
        frame.frame = m_frame++;
        frame.queries.separation = ask != Ask::nothing;
        frame.queries.self = ask != Ask::nothing;
        if (ask != Ask::nothing) {
            frame.queries.tolerance = m_args.near;
        }
        // Penetration vectors need the collisions (the daemon adds them itself; run_frame does
        // not).
        frame.queries.collisions = ask != Ask::nothing;
        frame.penetration = ask != Ask::nothing;
        frame.ccd = ask == Ask::ccd;
        frame.ccd_request.elementary.min_distance = 0.0;
        ++frames;
        for (std::size_t i = 0; i < soft_positions.size(); ++i) {
            frame.update.positions.push_back({m_ids[i], soft_positions[i]});
        }
        std::optional<FrameRequest> local;
        if (m_mirror) {
            local = frame;
            for (std::size_t i = 0; i < soft_positions.size(); ++i) {
                local->update.positions[i].object = m_local_ids[i];
            }
        }
        m_sent = soft_positions;
        const auto start = std::chrono::steady_clock::now();
        if (auto st = m_stream->send(frame); !st.ok()) {
            return st;
        }
        auto response = m_stream->receive();
        round_trip_ms += milliseconds_since(start);
        if (!response.ok()) {
            return response.status();
        }
        server_ms += response->server_seconds * 1e3;
        if (local) {
            auto outcome = run_frame(*m_mirror, std::move(*local), nullptr);
            ++checked_frames;
            const std::string diff =
                outcome.ok() ? difference(outcome.value(), response.value())
                             : "the in-process engine failed: " + outcome.status().to_string();
            if (!diff.empty()) {
                ++mismatches;
                if (first_mismatch.empty()) {
                    first_mismatch = "frame " + std::to_string(frame.frame) + ": " + diff;
                }
            }
        }
        return response;
    }

    // An offscreen PNG of the daemon's scene as it is now (the last frame sent), coloured as the
    // review page colours results: collisions red, near-contacts (within --near) amber, each
    // object's closest pair as a segment. The first snapshot's fitted camera is kept for the
    // others, so consecutive images share one view.
    StatusOr<render::Snapshot> snapshot() {
        render::SnapshotRequest request;
        request.render.width = m_args.snapshot_width;
        request.render.height = m_args.snapshot_height;
        request.render.camera = m_snapshot_camera;
        request.collisions = true;
        request.tolerance = m_args.near;
        request.segments = true;
        auto shot = m_client->snapshot(m_scene_id, request);
        if (shot.ok() && !m_snapshot_camera) {
            m_snapshot_camera = shot->camera;
        }
        return shot;
    }

    // The soft bodies' positions in the daemon's scene (the last frame sent).
    const std::vector<std::vector<Vec3>>& sent() const { return m_sent; }

    std::uint64_t checked_frames = 0;
    std::uint64_t mismatches = 0;
    std::string first_mismatch;
    double server_ms = 0;  // per step, reset by the caller

  private:
    World& m_world;
    const Args& m_args;
    std::unique_ptr<client::Client> m_client;
    std::unique_ptr<client::FrameStream> m_stream;
    std::string m_scene_id;
    std::vector<ObjectId> m_ids;
    std::unique_ptr<ProximityEngine> m_mirror;
    std::vector<ObjectId> m_local_ids;
    std::uint64_t m_frame = 0;
    std::vector<std::vector<Vec3>> m_sent;
    std::optional<render::Camera> m_snapshot_camera;
};

// --- The simulation loop ---------------------------------------------------------------------

json ccd_pair_json(const World& w, const ccd::CcdPair& p) {
    auto name = [&](std::uint32_t o) {
        return o < w.soft.size() ? w.soft[o].name : w.obstacles[o - w.soft.size()].name;
    };
    return {{"kind", ccd::ccd_kind_name(p.kind)},
            {"object", p.object},
            {"name", name(p.object)},
            {"primitive", p.primitive},
            {"other", p.other},
            {"other_name", name(p.other)},
            {"other_primitive", p.other_primitive},
            {"toi", p.toi},
            {"capped", p.capped}};
}

// The contacts that involve a soft body (two static obstacles cannot move into each other: pieces
// of one obstacle that touch, like the bowl's boxes, touch at t = 0 every step), with `earliest`
// recomputed.
ccd::CcdResult soft_contacts(const ccd::CcdResult& all, std::size_t soft_count) {
    ccd::CcdResult out;
    out.stats = all.stats;
    for (const auto& p : all.pairs) {
        if (p.object < soft_count || p.other < soft_count) {
            if (!out.earliest || p.toi < out.pairs[*out.earliest].toi) {
                out.earliest = out.pairs.size();
            }
            out.pairs.push_back(p);
        }
    }
    return out;
}

struct Totals {
    std::uint64_t limited_steps = 0;  // steps whose CCD found a contact
    std::uint64_t rewinds = 0;        // of those, the ones limited by a global rewind
    double min_rewind = 1.0;
    std::uint64_t pushouts = 0;
    std::uint64_t ccd_contacts = 0;
    std::uint64_t ccd_contacts_bullet_missed = 0;
    std::uint64_t self_contacts_bullet_ignores = 0;
    std::uint64_t bullet_contacts_not_near = 0;
    std::uint64_t near_without_bullet_contact = 0;
    double min_separation = std::numeric_limits<double>::infinity();
    double min_self_distance = std::numeric_limits<double>::infinity();
    Spread bullet_ms;
    Spread round_trip_ms;
    Spread server_ms;
};

int run(const Args& args) {
    World world;
    if (args.scene == "cloth-sphere") {
        build_cloth_sphere(world, args);
    } else if (args.scene == "ball-bowl") {
        build_ball_bowl(world, args);
    } else {
        build_ropes(world, args);
    }
    const std::size_t soft_count = world.soft.size();
    // Per soft body: its topology (vertex -> triangles) and its CCD edges (ids of ee contacts).
    std::vector<std::unique_ptr<MeshTopology>> topologies;
    std::vector<std::vector<std::array<std::uint32_t, 2>>> edges;
    for (const auto& s : world.soft) {
        topologies.push_back(std::make_unique<MeshTopology>(
            s.triangles, static_cast<std::size_t>(s.body->m_nodes.size())));
        edges.push_back(ccd::mesh_edges(*topologies.back()));
    }

    // The obstacles on their own, for the push-out's inside test.
    Scene obstacle_scene;
    for (const auto& o : world.obstacles) {
        if (auto added = obstacle_scene.add_object({o.name, o.mesh}); !added.ok()) {
            std::fprintf(stderr, "proxima-bullet: error: %s\n", added.status().to_string().c_str());
            return 1;
        }
    }

    Session session(world, args);
    if (auto st = session.open(); !st.ok()) {
        std::fprintf(stderr, "proxima-bullet: error: %s (daemon at %s)\n",
                     client::describe_status(st).c_str(), args.server.c_str());
        return 1;
    }

    // --snapshots: step 0 first, so a daemon that cannot render (no EGL) fails the run before it
    // simulates anything.
    std::size_t snapshots_taken = 0;
    double snapshot_ms = 0;
    auto take_snapshot = [&](std::size_t step) -> StatusOr<std::string> {
        if (args.snapshot_dir.empty()) {
            return std::string{};
        }
        const auto start = std::chrono::steady_clock::now();
        auto shot = session.snapshot();
        if (!shot.ok()) {
            return shot.status();
        }
        char name[64];
        std::snprintf(name, sizeof name, "%s-%06zu.png", args.scene.c_str(), step);
        const auto path = std::filesystem::path(args.snapshot_dir) / name;
        std::ofstream out(path, std::ios::binary);
        out.write(shot->png.data(), static_cast<std::streamsize>(shot->png.size()));
        out.close();
        if (!out) {
            return Status(StatusCode::unavailable, "cannot write '" + path.string() + "'");
        }
        snapshot_ms += milliseconds_since(start);
        ++snapshots_taken;
        return path.string();
    };
    if (!args.snapshot_dir.empty()) {
        std::error_code ec;
        std::filesystem::create_directories(args.snapshot_dir, ec);
        if (ec) {
            std::fprintf(stderr, "proxima-bullet: error: cannot create '%s': %s\n",
                         args.snapshot_dir.c_str(), ec.message().c_str());
            return 1;
        }
        if (auto first = take_snapshot(0); !first.ok()) {
            std::fprintf(stderr,
                         "proxima-bullet: error: %s (the snapshot of step 0, daemon at %s)\n",
                         client::describe_status(first.status()).c_str(), args.server.c_str());
            return 1;
        }
    }

    json record;
    if (!args.record_file.empty()) {
        record["scene"] = args.scene;
        record["objects"] = json::array();
        for (const auto& s : world.soft) {
            json tris = json::array();
            for (const auto& t : s.triangles) {
                tris.push_back({t[0], t[1], t[2]});
            }
            record["objects"].push_back({{"name", s.name}, {"soft", true}, {"triangles", tris}});
        }
        for (const auto& o : world.obstacles) {
            json verts = json::array();
            for (const auto& v : o.mesh.vertices) {
                verts.push_back({v.x, v.y, v.z});
            }
            json tris = json::array();
            for (const auto& t : o.mesh.triangles) {
                tris.push_back({t[0], t[1], t[2]});
            }
            record["objects"].push_back(
                {{"name", o.name}, {"soft", false}, {"vertices", verts}, {"triangles", tris}});
        }
        record["states"] = json::array();
    }
    auto record_state = [&](std::size_t step) {
        if (args.record_file.empty()) {
            return;
        }
        json state = json::array();
        for (const auto& s : world.soft) {
            json flat = json::array();
            for (int i = 0; i < s.body->m_nodes.size(); ++i) {
                const auto& x = s.body->m_nodes[i].m_x;
                flat.push_back(x.x());
                flat.push_back(x.y());
                flat.push_back(x.z());
            }
            state.push_back(std::move(flat));
        }
        record["states"].push_back({{"step", step}, {"positions", std::move(state)}});
    };
    record_state(0);

    json log_steps = json::array();
    Totals totals;
    if (!args.quiet) {
        std::printf("%5s %10s %10s %10s %9s %9s %6s %6s %7s %7s\n", "step", "bullet-ms", "rtt-ms",
                    "server-ms", "toi", "rewind", "near", "bullet", "missed", "self-cc");
    }
    for (std::size_t step = 1; step <= args.steps; ++step) {
        std::vector<std::vector<Vec3>> prev;
        for (const auto& s : world.soft) {
            prev.push_back(Session::positions(s));
        }
        // CCD runs from the daemon's scene: it must be the state Bullet steps from.
        if (prev != session.sent()) {
            std::fprintf(stderr,
                         "proxima-bullet: error: internal: Bullet's nodes differ from the daemon's "
                         "scene at step %zu\n",
                         step);
            return 1;
        }
        const auto bullet_start = std::chrono::steady_clock::now();
        world.world().stepSimulation(args.dt, 0);
        const double bullet_ms = milliseconds_since(bullet_start);
        std::vector<std::vector<Vec3>> cur;
        for (const auto& s : world.soft) {
            cur.push_back(Session::positions(s));
        }
        // Bullet's contacts of this step: soft-rigid (m_rcontacts, by (soft body, node), compared
        // with the near-contacts below) and soft-soft (m_scontacts, counted).
        std::set<std::pair<std::size_t, std::uint32_t>> bullet_nodes;
        std::size_t bullet_contacts = 0;
        for (std::size_t i = 0; i < soft_count; ++i) {
            const auto* body = world.soft[i].body;
            bullet_contacts += static_cast<std::size_t>(body->m_rcontacts.size()) +
                               static_cast<std::size_t>(body->m_scontacts.size());
            for (int c = 0; c < body->m_rcontacts.size(); ++c) {
                bullet_nodes.insert({i, static_cast<std::uint32_t>(body->m_rcontacts[c].m_node -
                                                                   &body->m_nodes[0])});
            }
        }

        double round_trip_ms = 0;
        session.server_ms = 0;
        int frames = 0;
        auto fail_stream = [&](const Status& st) {
            std::fprintf(stderr, "proxima-bullet: error: %s (stream to %s, step %zu)\n",
                         client::describe_status(st).c_str(), args.server.c_str(), step);
            return 1;
        };
        auto response = session.exchange(cur, Session::Ask::ccd, round_trip_ms, frames);
        if (!response.ok()) {
            return fail_stream(response.status());
        }
        json step_log;
        step_log["step"] = step;
        ccd::CcdResult ccd_result = soft_contacts(*response->ccd, soft_count);
        std::optional<double> earliest;
        std::uint64_t missed = 0;
        std::uint64_t self_contacts = 0;
        json pairs = json::array();
        for (const auto& p : ccd_result.pairs) {
            if (p.object != p.other) {
                ++missed;  // soft-rigid (SDF_RS) or soft-soft (VF_SS): Bullet let it through
            } else {
                ++self_contacts;  // Bullet's soft bodies here have no self-collision
            }
            if (pairs.size() < 16) {
                pairs.push_back(ccd_pair_json(world, p));
            }
        }
        if (ccd_result.earliest) {
            earliest = ccd_result.pairs[*ccd_result.earliest].toi;
        }
        step_log["ccd"] = {
            {"pair_count", ccd_result.pairs.size()},
            {"earliest", earliest ? ccd_pair_json(world, ccd_result.pairs[*ccd_result.earliest])
                                  : json(nullptr)},
            {"pairs", pairs}};
        totals.ccd_contacts += ccd_result.pairs.size();
        totals.ccd_contacts_bullet_missed += missed;
        totals.self_contacts_bullet_ignores += self_contacts;

        // The soft nodes of the primitives in CCD contacts.
        auto involved = [&](const ccd::CcdResult& r,
                            std::set<std::pair<std::size_t, std::uint32_t>>& out) {
            for (const auto& p : r.pairs) {
                if (p.kind == ccd::CcdKind::vertex_face) {
                    if (p.object < soft_count) {
                        out.insert({p.object, p.primitive});
                    }
                    if (p.other < soft_count) {
                        for (auto n : world.soft[p.other].triangles[p.other_primitive]) {
                            out.insert({p.other, n});
                        }
                    }
                    continue;
                }
                if (p.object < soft_count) {
                    for (auto n : edges[p.object][p.primitive]) {
                        out.insert({p.object, n});
                    }
                }
                if (p.other < soft_count) {
                    for (auto n : edges[p.other][p.other_primitive]) {
                        out.insert({p.other, n});
                    }
                }
            }
        };

        // Limiting the step. The nodes of contacting primitives are frozen at their positions at
        // the step's start (which had no contact) and the step is checked again by CCD from the
        // start, until no contact is left (the frozen set only grows: at worst every node is
        // frozen, the contact-free start). After --max-freeze rounds with contacts left, every
        // node is rewound to --rewind times the earliest time of impact of the last check: no
        // pair touches before it (a CCD time of impact is never late).
        std::vector<std::vector<Vec3>> kept = cur;
        std::set<std::pair<std::size_t, std::uint32_t>> frozen;
        int freeze_rounds = 0;
        std::optional<double> rewound_to;
        const bool limit = !args.no_limit && !args.pushout_only;
        while (limit && !ccd_result.pairs.empty() && freeze_rounds < args.max_freeze) {
            ++freeze_rounds;
            involved(ccd_result, frozen);
            for (const auto& [i, n] : frozen) {
                kept[i][n] = prev[i][n];
            }
            // Back to the step's start on the daemon, then CCD to the limited positions.
            response = session.exchange(prev, Session::Ask::nothing, round_trip_ms, frames);
            if (!response.ok()) {
                return fail_stream(response.status());
            }
            response = session.exchange(kept, Session::Ask::ccd, round_trip_ms, frames);
            if (!response.ok()) {
                return fail_stream(response.status());
            }
            ccd_result = soft_contacts(*response->ccd, soft_count);
        }
        if (limit && !ccd_result.pairs.empty()) {
            const double s = args.rewind * ccd_result.pairs[*ccd_result.earliest].toi;
            rewound_to = s;
            ++totals.rewinds;
            totals.min_rewind = std::min(totals.min_rewind, s);
            for (std::size_t i = 0; i < soft_count; ++i) {
                for (std::size_t v = 0; v < kept[i].size(); ++v) {
                    kept[i][v] = prev[i][v] + s * (kept[i][v] - prev[i][v]);
                }
            }
            response = session.exchange(kept, Session::Ask::queries, round_trip_ms, frames);
            if (!response.ok()) {
                return fail_stream(response.status());
            }
        }
        if (freeze_rounds > 0 || rewound_to) {
            ++totals.limited_steps;
            for (std::size_t i = 0; i < soft_count; ++i) {
                auto* body = world.soft[i].body;
                for (std::size_t v = 0; v < kept[i].size(); ++v) {
                    body->m_nodes[static_cast<int>(v)].m_x = to_bt(kept[i][v]);
                }
            }
            // A frozen node stops (an inelastic response to its contact).
            for (const auto& [i, n] : frozen) {
                world.soft[i].body->m_nodes[static_cast<int>(n)].m_v.setZero();
            }
        }

        std::size_t pushed_nodes = 0;
        if (!args.no_limit && freeze_rounds == 0 && !rewound_to) {
            // No contact along the step. Soft nodes inside a (closed) obstacle next to the
            // overlapping features of a penetration (a state that was already intersecting:
            // Bullet's response failed) are moved by the penetration vector, in the direction
            // that takes them out (an exact winding-number test decides inside; a soft body's
            // faces have no outward side for the vector's sign to rely on), and stop.
            std::set<std::pair<std::size_t, std::uint32_t>> moved;
            std::vector<std::vector<Vec3>> next = cur;
            for (const auto& pen : response->penetrations) {
                if (pen.object == pen.other || pen.vector == Vec3{}) {
                    continue;
                }
                const bool soft_first = pen.object < soft_count;
                const std::uint32_t soft = soft_first ? pen.object : pen.other;
                const std::uint32_t obstacle = soft_first ? pen.other : pen.object;
                if (soft >= soft_count || obstacle < soft_count) {
                    continue;  // soft-soft: no inside to test against
                }
                const auto& solid = obstacle_scene[obstacle - soft_count];
                const Vec3 by = soft_first ? pen.vector : -pen.vector;
                for (auto t : soft_first ? pen.triangles : pen.other_triangles) {
                    for (auto n : world.soft[soft].triangles[t]) {
                        const Vec3 at = next[soft][n];
                        if (moved.count({soft, n}) != 0 || detail::winding_number(solid, at) == 0) {
                            continue;
                        }
                        for (const Vec3& step : {by, -by}) {
                            if (detail::winding_number(solid, at + step) == 0) {
                                next[soft][n] = at + step;
                                moved.insert({soft, n});
                                break;
                            }
                        }
                    }
                }
            }
            if (!moved.empty()) {
                for (const auto& [i, n] : moved) {
                    auto& node = world.soft[i].body->m_nodes[static_cast<int>(n)];
                    node.m_x = to_bt(next[i][n]);
                    node.m_v.setZero();
                }
                pushed_nodes = moved.size();
                ++totals.pushouts;
                response = session.exchange(next, Session::Ask::queries, round_trip_ms, frames);
                if (!response.ok()) {
                    return fail_stream(response.status());
                }
            }
        }
        record_state(step);

        // Near-contacts of the kept state, against Bullet's contacts.
        const auto& result = response->result;
        std::set<std::pair<std::size_t, std::uint32_t>> near_triangles;  // soft vs obstacle
        std::size_t near_self = 0;
        for (const auto& p : result.tolerance) {
            if (p.object == p.other) {
                ++near_self;
            } else if (p.object < soft_count && p.other >= soft_count) {
                near_triangles.insert({p.object, p.triangle});
            } else if (p.other < soft_count && p.object >= soft_count) {
                near_triangles.insert({p.other, p.other_triangle});
            }
        }
        std::uint64_t bullet_not_near = 0;
        for (const auto& [i, n] : bullet_nodes) {
            bool near = false;
            for (auto t : topologies[i]->vertex_triangles(n)) {
                near = near || near_triangles.count({i, t}) != 0;
            }
            bullet_not_near += near ? 0 : 1;
        }
        std::uint64_t near_no_bullet = 0;
        for (const auto& [i, t] : near_triangles) {
            bool touched = false;
            for (auto n : world.soft[i].triangles[t]) {
                touched = touched || bullet_nodes.count({i, n}) != 0;
            }
            near_no_bullet += touched ? 0 : 1;
        }
        totals.bullet_contacts_not_near += bullet_not_near;
        totals.near_without_bullet_contact += near_no_bullet;

        json separation = json::array();
        for (std::size_t o = 0; o < result.separation.size(); ++o) {
            const auto& sep = result.separation[o];
            separation.push_back({{"object", o},
                                  {"triangle", sep.triangle},
                                  {"point", point_json(sep.point)},
                                  {"other", sep.other},
                                  {"other_triangle", sep.other_triangle},
                                  {"other_point", point_json(sep.other_point)},
                                  {"distance", distance_json(sep.distance)}});
            totals.min_separation = std::min(totals.min_separation, sep.distance);
        }
        json min_self = json::array();
        for (std::size_t i = 0; i < soft_count && i < result.self.size(); ++i) {
            double m = std::numeric_limits<double>::infinity();
            for (const auto& sd : result.self[i]) {
                m = std::min(m, sd.distance);
            }
            totals.min_self_distance = std::min(totals.min_self_distance, m);
            min_self.push_back(distance_json(m));
        }
        step_log["bullet_ms"] = bullet_ms;
        step_log["round_trip_ms"] = round_trip_ms;
        step_log["stats"] = {{"self_seconds", result.stats.self_seconds},
                             {"separation_seconds", result.stats.separation_seconds},
                             {"tolerance_seconds", result.stats.tolerance_seconds},
                             {"collision_seconds", result.stats.collision_seconds},
                             {"total_seconds", result.stats.total_seconds},
                             {"ccd_seconds", ccd_result.stats.total_seconds}};
        step_log["server_ms"] = session.server_ms;
        step_log["frame_count"] = frames;
        step_log["freeze_rounds"] = freeze_rounds;
        step_log["frozen_node_count"] = frozen.size();
        step_log["rewound_to"] = rewound_to ? json(*rewound_to) : json(nullptr);
        step_log["pushed_node_count"] = pushed_nodes;
        step_log["separation"] = separation;
        step_log["min_self_distance"] = min_self;
        step_log["near_contact_count"] = near_triangles.size();
        step_log["near_self_count"] = near_self;
        step_log["collision_count"] = result.collisions.size();
        step_log["penetration_count"] = response->penetrations.size();
        step_log["bullet_contact_count"] = bullet_contacts;
        step_log["disagreements"] = {{"ccd_contacts_bullet_missed", missed},
                                     {"self_contacts_bullet_ignores", self_contacts},
                                     {"bullet_contacts_not_near", bullet_not_near},
                                     {"near_without_bullet_contact", near_no_bullet}};
        if (!args.snapshot_dir.empty() && (step % args.snapshot_every == 0 || step == args.steps)) {
            auto shot = take_snapshot(step);
            if (!shot.ok()) {
                std::fprintf(stderr, "proxima-bullet: error: %s (the snapshot of step %zu)\n",
                             client::describe_status(shot.status()).c_str(), step);
                return 1;
            }
            step_log["snapshot"] = shot.value();
        }
        log_steps.push_back(std::move(step_log));
        totals.bullet_ms.values.push_back(bullet_ms);
        totals.round_trip_ms.values.push_back(round_trip_ms);
        totals.server_ms.values.push_back(session.server_ms);
        if (!args.quiet) {
            std::printf("%5zu %10.3f %10.3f %10.3f %9s %9s %6zu %6zu %7llu %7llu\n", step,
                        bullet_ms, round_trip_ms, session.server_ms,
                        earliest ? std::to_string(*earliest).substr(0, 8).c_str() : "-",
                        rewound_to ? std::to_string(*rewound_to).substr(0, 8).c_str() : "-",
                        near_triangles.size(), bullet_contacts,
                        static_cast<unsigned long long>(missed),
                        static_cast<unsigned long long>(self_contacts));
            std::fflush(stdout);
        }
    }
    if (auto st = session.close(); !st.ok()) {
        std::fprintf(stderr, "proxima-bullet: error: %s (closing the stream to %s)\n",
                     client::describe_status(st).c_str(), args.server.c_str());
        return 1;
    }

    json summary = {
        {"step_count", args.steps},
        {"limited_step_count", totals.limited_steps},
        {"rewind_count", totals.rewinds},
        {"min_rewound_to", totals.rewinds > 0 ? json(totals.min_rewind) : json(nullptr)},
        {"pushout_count", totals.pushouts},
        {"ccd_contact_count", totals.ccd_contacts},
        {"ccd_contacts_bullet_missed", totals.ccd_contacts_bullet_missed},
        {"self_contacts_bullet_ignores", totals.self_contacts_bullet_ignores},
        {"bullet_contacts_not_near", totals.bullet_contacts_not_near},
        {"near_without_bullet_contact", totals.near_without_bullet_contact},
        {"min_separation", distance_json(totals.min_separation)},
        {"min_self_distance", distance_json(totals.min_self_distance)},
        {"bullet_ms", totals.bullet_ms.to_json()},
        {"round_trip_ms", totals.round_trip_ms.to_json()},
        {"server_ms", totals.server_ms.to_json()}};
    if (!args.snapshot_dir.empty()) {
        summary["snapshots"] = {
            {"directory", args.snapshot_dir}, {"count", snapshots_taken}, {"ms", snapshot_ms}};
    }
    if (args.check) {
        summary["check"] = {
            {"frame_count", session.checked_frames},
            {"mismatch_count", session.mismatches},
            {"first_mismatch",
             session.first_mismatch.empty() ? json(nullptr) : json(session.first_mismatch)}};
    }
    std::size_t nodes = 0;
    std::size_t triangles = 0;
    for (const auto& s : world.soft) {
        nodes += static_cast<std::size_t>(s.body->m_nodes.size());
        triangles += s.triangles.size();
    }
    for (const auto& o : world.obstacles) {
        triangles += o.mesh.triangles.size();
    }
    if (!args.json_file.empty()) {
        json log = {{"scene", args.scene},
                    {"server", args.server},
                    {"bullet", {{"version", BT_BULLET_VERSION}, {"precision", "float64"}}},
                    {"dt", args.dt},
                    {"margin", args.margin},
                    {"near", args.near},
                    {"rewind", args.rewind},
                    {"max_freeze", args.max_freeze},
                    {"inset", args.inset},
                    {"response", args.no_limit       ? "none"
                                 : args.pushout_only ? "pushout"
                                                     : "ccd"},
                    {"node_count", nodes},
                    {"triangle_count", triangles},
                    {"steps", std::move(log_steps)},
                    {"summary", summary}};
        std::ofstream out(args.json_file, std::ios::binary);
        out << log.dump() << '\n';
        if (!out) {
            std::fprintf(stderr, "proxima-bullet: error: cannot write '%s'\n",
                         args.json_file.c_str());
            return 1;
        }
    }
    if (!args.record_file.empty()) {
        std::ofstream out(args.record_file, std::ios::binary);
        out << record.dump() << '\n';
        if (!out) {
            std::fprintf(stderr, "proxima-bullet: error: cannot write '%s'\n",
                         args.record_file.c_str());
            return 1;
        }
    }
    const auto bullet = totals.bullet_ms.to_json();
    const auto rtt = totals.round_trip_ms.to_json();
    std::fprintf(
        stderr,
        "proxima-bullet: %zu steps of %s (%zu nodes, %zu triangles), %llu rewinds, "
        "%llu contacts Bullet missed, Bullet step %.3f ms, round trip %.3f ms (means)%s%s\n",
        args.steps, args.scene.c_str(), nodes, triangles,
        static_cast<unsigned long long>(totals.rewinds),
        static_cast<unsigned long long>(totals.ccd_contacts_bullet_missed),
        bullet.is_null() ? 0.0 : bullet["mean"].get<double>(),
        rtt.is_null() ? 0.0 : rtt["mean"].get<double>(), args.json_file.empty() ? "" : "; JSON in ",
        args.json_file.c_str());
    if (args.check && session.mismatches > 0) {
        std::fprintf(stderr,
                     "proxima-bullet: error: %llu of %llu frames differ from the in-process "
                     "engine (first: %s)\n",
                     static_cast<unsigned long long>(session.mismatches),
                     static_cast<unsigned long long>(session.checked_frames),
                     session.first_mismatch.c_str());
        return 1;
    }
    return 0;
}

int run_main(int argc, char** argv) {
    Args args;
    CLI::App app{
        "proxima-bullet: a Bullet soft-body simulation (float64) that streams its nodes to "
        "proximad every step and uses CCD, distances and penetration vectors"};
    app.add_option("--scene", args.scene, "cloth-sphere, ball-bowl or ropes")
        ->check(CLI::IsMember({"cloth-sphere", "ball-bowl", "ropes"}));
    app.add_option("--server", args.server, "the daemon's HOST:PORT")->required();
    app.add_option("--steps", args.steps, "simulation steps")->check(CLI::Range(1, 1000000));
    app.add_option("--resolution", args.resolution,
                   "cloth nodes per side; ropes: nodes along each rope; ball: 10x this many hull "
                   "points")
        ->check(CLI::Range(3, 200));
    app.add_option("--dt", args.dt, "Bullet's time step, seconds")->check(CLI::Range(1e-5, 0.1));
    app.add_option("--margin", args.margin, "the soft bodies' collision margin")
        ->check(CLI::Range(1e-4, 1.0));
    app.add_option("--near", args.near, "near-contact distance (the tolerance query)")
        ->check(CLI::Range(0.0, 10.0));
    app.add_option("--rewind", args.rewind,
                   "on a contact, rewind to this fraction of the earliest time of impact")
        ->check(CLI::Range(0.0, 0.99));
    app.add_option("--max-freeze", args.max_freeze,
                   "rounds of freezing contacting nodes before a global rewind")
        ->check(CLI::Range(0, 100));
    app.add_option("--inset", args.inset,
                   "how far the service's mesh of an obstacle lies inside Bullet's shape")
        ->check(CLI::Range(0.0, 0.5));
    app.add_option("--json", args.json_file, "write the JSON log to FILE");
    app.add_option("--record", args.record_file,
                   "write every kept state (the soft nodes per step) and the topologies to FILE");
    app.add_flag("--check", args.check,
                 "run every frame in-process too and compare (exit 1 on any difference)");
    app.add_flag(
        "--no-limit", args.no_limit,
        "report contacts but keep Bullet's state as it is (no step limiting, no push-out): "
        "what Bullet alone does");
    app.add_flag("--pushout-only", args.pushout_only,
                 "no step limiting; only push soft triangles out of obstacles along the "
                 "penetration vectors after the step")
        ->excludes("--no-limit");
    app.add_flag("--quiet", args.quiet, "no per-step lines");
    app.add_option("--snapshots", args.snapshot_dir,
                   "save PNG snapshots of the daemon's scene (its Snapshot call) into DIR: step 0, "
                   "every --snapshot-every steps and the last, named SCENE-STEP.png");
    app.add_option("--snapshot-every", args.snapshot_every, "steps between snapshots")
        ->check(CLI::Range(1, 1000000));
    app.add_option("--snapshot-width", args.snapshot_width, "snapshot width, pixels")
        ->check(CLI::Range(1, render::MAX_SNAPSHOT_SIDE));
    app.add_option("--snapshot-height", args.snapshot_height, "snapshot height, pixels")
        ->check(CLI::Range(1, render::MAX_SNAPSHOT_SIDE));
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        if (e.get_exit_code() == 0) {
            return app.exit(e);
        }
        std::fprintf(stderr, "proxima-bullet: error: %s\nRun 'proxima-bullet --help'\n", e.what());
        return 2;
    }
    return run(args);
}

}  // namespace

int main(int argc, char** argv) {
    try {
        return run_main(argc, argv);
    } catch (const std::exception& e) {
        std::fprintf(stderr, "proxima-bullet: error: %s\n", e.what());
        return 1;
    }
}
