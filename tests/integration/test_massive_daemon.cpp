// proximad serving massive models (--models DIR, --cache-bytes): a small store built here (boxes
// and cylinders, some touching, some within a tolerance, some split into pieces) is listed,
// verified over gRPC with answers equal to the brute-force reference bit for bit, and reviewed by
// two members of one room whose results equal in-process AvatarTrackers replaying the same poses
// and edits. Also: unknown models, bad requests, a corrupt chunk (DATA_LOSS, the daemon serving
// on), cancellation, and a restart serving the same generation without a re-import.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <thread>
#include <tuple>
#include <variant>
#include <vector>

#include <unistd.h>

#include "client/proxima_client.hpp"
#include "daemon_process.hpp"
#include "proxima/massive/avatar.hpp"
#include "proxima/massive/region.hpp"
#include "proxima/massive/store.hpp"
#include "proxima/massive/verify.hpp"
#include "support/model_stores.hpp"
#include "wire.hpp"

namespace proxima::test {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using client::Client;
using client::ReviewEvent;

constexpr std::uint64_t CACHE_BYTES = 48 * 1024;     // a few pieces at a time: evictions
constexpr std::uint64_t MAX_PIECE_BYTES = 6 * 1024;  // cylinders split into several pieces

// A closed cylinder of radius r from `base` along +z (axis 2) or +x (axis 0), n segments.
TriangleMesh cylinder_mesh(Vec3 base, double r, double length, int n, int axis = 2) {
    TriangleMesh m;
    auto point = [&](double a, double b, double h) {
        return axis == 2 ? base + Vec3{a, b, h} : base + Vec3{h, a, b};
    };
    for (int ring = 0; ring < 2; ++ring) {
        for (int k = 0; k < n; ++k) {
            const double t = 2.0 * M_PI * k / n;
            m.vertices.push_back(point(r * std::cos(t), r * std::sin(t), ring * length));
        }
    }
    const auto bottom = static_cast<std::uint32_t>(m.vertices.size());
    m.vertices.push_back(point(0, 0, 0));
    m.vertices.push_back(point(0, 0, length));
    const auto top = bottom + 1;
    for (int k = 0; k < n; ++k) {
        const auto a = static_cast<std::uint32_t>(k);
        const auto b = static_cast<std::uint32_t>((k + 1) % n);
        const auto un = static_cast<std::uint32_t>(n);
        m.triangles.push_back({a, b, b + un});
        m.triangles.push_back({a, b + un, a + un});
        m.triangles.push_back({bottom, b, a});
        m.triangles.push_back({top, a + un, b + un});
    }
    return m;
}

// 6 x 6 cells 2 apart; in each row, cell pairs touch (0-1), are 0.05 apart (2-3) and overlap by
// 0.3 (4-5). Odd cells of odd rows are cylinders (split into pieces). Plus a long thin pipe along
// row 2 that crosses everything there.
std::vector<massive::ModelObject> model_objects() {
    std::vector<massive::ModelObject> objects;
    const double shift[6] = {0.0, -1.0, 0.0, -0.95, 0.0, -1.3};
    for (int j = 0; j < 6; ++j) {
        for (int i = 0; i < 6; ++i) {
            const Vec3 lo{2.0 * i + shift[i], 2.0 * j, 0.0};
            massive::ModelObject o;
            o.name = "row-" + std::to_string(j) + "/cell-" + std::to_string(i);
            if (j % 2 == 1 && i % 2 == 1) {
                o.mesh = cylinder_mesh(lo + Vec3{0.5, 0.5, 0.0}, 0.5, 1.0, 40);
            } else {
                o.mesh = box_mesh(lo, lo + Vec3{1, 1, 1});
            }
            objects.push_back(std::move(o));
        }
    }
    massive::ModelObject pipe;
    pipe.name = "pipe";
    pipe.mesh = cylinder_mesh({-0.5, 4.5, 1.1}, 0.15, 11.0, 48, 0);
    objects.push_back(std::move(pipe));
    return objects;
}

fs::path make_temp_dir(const std::string& name) {
    auto p = fs::temp_directory_path() /
             ("proxima-massive-daemon-" + name + "-" + std::to_string(::getpid()));
    fs::remove_all(p);
    fs::create_directories(p);
    return p;
}

void flip_byte(const fs::path& path, std::uint64_t at) {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(static_cast<std::streamoff>(at));
    char b = 0;
    f.read(&b, 1);
    b = static_cast<char>(b ^ 0x5a);
    f.seekp(static_cast<std::streamoff>(at));
    f.write(&b, 1);
    ASSERT_TRUE(f.good()) << path;
}

void write_store(const fs::path& dir) {
    massive::StoreOptions options;
    options.max_piece_bytes = MAX_PIECE_BYTES;
    options.chunk_bytes = 4096;
    options.source = "test_massive_daemon";
    write_model_store(dir.string(), model_objects(), options);
}

class MassiveDaemon : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        s_models = new fs::path(make_temp_dir("models"));
        write_store(*s_models / "plant");
    }
    static void TearDownTestSuite() {
        std::error_code ec;
        fs::remove_all(*s_models, ec);
        delete s_models;
        s_models = nullptr;
    }

    static std::vector<std::string> daemon_args(const fs::path& models) {
        return {"--models", models.string(), "--cache-bytes", std::to_string(CACHE_BYTES),
                "--gpu",    "off",           "--log-level",   "warn"};
    }

    static std::unique_ptr<Client> connect(const DaemonProcess& daemon) {
        auto c = Client::connect(daemon.address());
        EXPECT_TRUE(c.ok()) << c.status().to_string();
        return c.ok() ? std::move(c).value() : nullptr;
    }

    static std::shared_ptr<const massive::Store> open_local(const std::string& name = "plant") {
        auto store = massive::Store::open((*s_models / name).string());
        EXPECT_TRUE(store.ok()) << store.status().to_string();
        return store.ok() ? store.value() : nullptr;
    }

    static fs::path* s_models;
};

fs::path* MassiveDaemon::s_models = nullptr;

void expect_same_pairs(const std::vector<client::NamedObjectPair>& got,
                       const std::vector<massive::ObjectPairResult>& want,
                       const massive::Store& store) {
    ASSERT_EQ(got.size(), want.size());
    for (std::size_t k = 0; k < want.size(); ++k) {
        SCOPED_TRACE("pair " + std::to_string(k));
        EXPECT_EQ(got[k].pair, want[k]);  // every field, doubles bit for bit
        EXPECT_EQ(got[k].name_a, store.objects()[want[k].object_a].name);
        EXPECT_EQ(got[k].name_b, store.objects()[want[k].object_b].name);
    }
}

TEST_F(MassiveDaemon, ListModelsShowsTheStoreAndTheCache) {
    DaemonProcess daemon(daemon_args(*s_models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    auto store = open_local();
    ASSERT_TRUE(store);
    auto list = c->list_models();
    ASSERT_TRUE(list.ok()) << list.status().to_string();
    EXPECT_EQ(list->models_dir, s_models->string());
    EXPECT_EQ(list->cache_budget_bytes, CACHE_BYTES);
    EXPECT_EQ(list->cache.budget_bytes, CACHE_BYTES);
    EXPECT_TRUE(list->unavailable.empty());
    ASSERT_EQ(list->models.size(), 1u);
    const auto& m = list->models[0];
    const auto& s = store->summary();
    EXPECT_EQ(m.name, "plant");
    EXPECT_EQ(m.objects, s.objects);
    EXPECT_EQ(m.pieces, s.pieces);
    EXPECT_GT(m.pieces, m.objects);
    EXPECT_EQ(m.triangles, s.triangles);
    EXPECT_EQ(m.generation, s.generation);
    EXPECT_EQ(m.box.lo.x, -0.5);           // the pipe starts there
    EXPECT_NEAR(m.box.hi.z, 1.25, 1e-12);  // and is the highest object

    // A model imported while the daemon runs appears at the next listing.
    write_store(*s_models / "later");
    list = c->list_models();
    ASSERT_TRUE(list.ok());
    ASSERT_EQ(list->models.size(), 2u);
    EXPECT_EQ(list->models[0].name, "later");
    fs::remove_all(*s_models / "later");
    list = c->list_models();
    ASSERT_TRUE(list.ok());
    EXPECT_EQ(list->models.size(), 1u);
}

TEST_F(MassiveDaemon, VerifyModelEqualsBruteForce) {
    DaemonProcess daemon(daemon_args(*s_models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    auto store = open_local();
    ASSERT_TRUE(store);
    for (double tolerance : {0.0, 0.1}) {
        SCOPED_TRACE("tolerance " + std::to_string(tolerance));
        auto want = massive::verify_brute_force(*store, tolerance);
        ASSERT_TRUE(want.ok()) << want.status().to_string();
        ASSERT_FALSE(want->empty());
        std::vector<client::NamedObjectPair> pairs;
        std::size_t progress = 0;
        auto summary = c->verify_model("plant", tolerance, [&](const client::VerifyEvent& e) {
            if (e.kind == client::VerifyEvent::Kind::pair) {
                pairs.push_back(e.pair);
            } else {
                ++progress;
                EXPECT_LE(e.progress.done,
                          e.progress.total == 0 ? e.progress.done : e.progress.total);
            }
            return true;
        });
        ASSERT_TRUE(summary.ok()) << summary.status().to_string();
        // Pairs arrive as they complete; the reference is sorted by (object_a, object_b).
        std::sort(pairs.begin(), pairs.end(), [](const auto& x, const auto& y) {
            return std::tie(x.pair.object_a, x.pair.object_b) <
                   std::tie(y.pair.object_a, y.pair.object_b);
        });
        expect_same_pairs(pairs, want.value(), *store);
        EXPECT_GT(progress, 0u);
        EXPECT_EQ(summary->stats.pairs_found, want->size());
        EXPECT_EQ(summary->stats.objects, store->summary().objects);
        EXPECT_EQ(summary->stats.pieces, store->summary().pieces);
        EXPECT_GT(summary->stats.edges, 0u);
        EXPECT_GT(summary->stats.cache.loads, 0u);
        EXPECT_EQ(summary->stats.cache.budget_bytes, CACHE_BYTES);
        EXPECT_GT(summary->server_seconds, 0.0);
        if (tolerance > 0.0) {
            // The within-tolerance pairs (0.05 apart) are found, not only contacts.
            EXPECT_TRUE(std::any_of(pairs.begin(), pairs.end(),
                                    [](const auto& p) { return p.pair.distance > 0.0; }));
        }
    }
    // A slow reader gets the same answer (the daemon waits instead of buffering).
    auto want = massive::verify_brute_force(*store, 0.1);
    ASSERT_TRUE(want.ok());
    std::vector<client::NamedObjectPair> slow;
    auto summary = c->verify_model("plant", 0.1, [&](const client::VerifyEvent& e) {
        if (e.kind == client::VerifyEvent::Kind::pair) {
            slow.push_back(e.pair);
            std::this_thread::sleep_for(2ms);
        }
        return true;
    });
    ASSERT_TRUE(summary.ok()) << summary.status().to_string();
    EXPECT_TRUE(summary->stats.schedule_from_store);  // planned by the first run at 0.1
    std::sort(slow.begin(), slow.end(), [](const auto& x, const auto& y) {
        return std::tie(x.pair.object_a, x.pair.object_b) <
               std::tie(y.pair.object_a, y.pair.object_b);
    });
    expect_same_pairs(slow, want.value(), *store);
}

TEST_F(MassiveDaemon, UnknownModelsAndBadRequests) {
    DaemonProcess daemon(daemon_args(*s_models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    auto v = c->verify_model("nope", 0.0);
    EXPECT_EQ(v.status().code(), StatusCode::not_found) << v.status().to_string();
    v = c->verify_model("../plant", 0.0);
    EXPECT_EQ(v.status().code(), StatusCode::invalid_argument) << v.status().to_string();
    v = c->verify_model("plant", -1.0);
    EXPECT_EQ(v.status().code(), StatusCode::invalid_argument) << v.status().to_string();

    client::ReviewJoin join{"r", "nope", "alice", {"avatar", box_mesh({0, 0, 0}, {1, 1, 1})}};
    auto session = c->join_review(join);
    EXPECT_EQ(session.status().code(), StatusCode::not_found) << session.status().to_string();

    join.model = "plant";
    join.avatar.mesh.triangles[0][1] = 99;  // index out of range
    session = c->join_review(join);
    EXPECT_EQ(session.status().code(), StatusCode::invalid_argument)
        << session.status().to_string();

    // A pose before join: the generated stub, since the library always joins first.
    auto stub = make_stub(daemon.address());
    {
        grpc::ClientContext context;
        deadline_in(context, 10s);
        auto stream = stub->Review(&context);
        v1::ReviewRequest request;
        request.mutable_pose()->set_sequence(1);
        for (int k = 0; k < 12; ++k) {
            request.mutable_pose()->mutable_transform()->add_m(k % 5 == 0 ? 1.0 : 0.0);
        }
        stream->Write(request);
        stream->WritesDone();
        v1::ReviewEvent event;
        EXPECT_FALSE(stream->Read(&event));
        EXPECT_EQ(stream->Finish().error_code(), grpc::StatusCode::FAILED_PRECONDITION);
    }

    // A bad pose ends that member's stream; a second member sees it leave, the room goes on.
    join = {"r", "plant", "alice", {"avatar", box_mesh({0, 0, 0}, {0.3, 0.3, 0.3})}, 0.0, true};
    auto alice = c->join_review(join);
    ASSERT_TRUE(alice.ok()) << alice.status().to_string();
    join.member = "bob";
    auto bob = c->join_review(join);
    ASSERT_TRUE(bob.ok()) << bob.status().to_string();
    ASSERT_EQ((*bob)->joined().members.size(), 2u);
    join.member = "alice";  // a name already in the room
    auto twin = c->join_review(join);
    EXPECT_EQ(twin.status().code(), StatusCode::failed_precondition);
    massive::Affine nan_pose;
    nan_pose.m[3] = std::nan("");
    ASSERT_TRUE((*alice)->send_pose(1, nan_pose).ok());
    std::optional<Status> alice_end;
    for (int k = 0; k < 10 && !alice_end; ++k) {
        auto e = (*alice)->next(5s);
        if (!e.ok()) {
            alice_end = e.status();
        }
    }
    ASSERT_TRUE(alice_end);
    EXPECT_EQ(alice_end->code(), StatusCode::invalid_argument) << alice_end->to_string();
    bool left = false;
    for (int k = 0; k < 10 && !left; ++k) {
        auto e = (*bob)->next(5s);
        ASSERT_TRUE(e.ok()) << e.status().to_string();
        left = e->kind == ReviewEvent::Kind::member_left && e->member == "alice";
    }
    EXPECT_TRUE(left);
    ASSERT_TRUE((*bob)->send_pose(7, massive::Affine{}).ok());
    auto r = (*bob)->wait_result(7);
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    // Unknown object in an edit: NOT_FOUND, and the room's model is unchanged.
    ASSERT_TRUE((*bob)->delete_object(1, 9999).ok());
    auto end = (*bob)->next(5s);
    while (end.ok()) {
        end = (*bob)->next(5s);
    }
    EXPECT_EQ(end.status().code(), StatusCode::not_found) << end.status().to_string();
    // The daemon serves on.
    EXPECT_TRUE(c->list_models().ok());
}

// A member's view of the room, replayed in-process: its own tracker on a local ModelView that
// receives the same edits in the same order.
struct LocalMember {
    std::shared_ptr<massive::ModelView> view;
    std::unique_ptr<massive::AvatarTracker> tracker;
    massive::AvatarQueryOptions options;
};

massive::Affine translation(double x, double y, double z) {
    massive::Affine a;
    a.m[3] = x;
    a.m[7] = y;
    a.m[11] = z;
    return a;
}

void expect_same_hit(const massive::AvatarHit& got, const massive::AvatarHit& want) {
    EXPECT_EQ(got.object, want.object);
    EXPECT_EQ(got.distance, want.distance);
    EXPECT_EQ(got.object_triangle, want.object_triangle);
    EXPECT_EQ(got.avatar_triangle, want.avatar_triangle);
    EXPECT_EQ(got.object_point, want.object_point);
    EXPECT_EQ(got.avatar_point, want.avatar_point);
}

void expect_same_result(const client::ReviewPoseResult& got, const massive::AvatarResult& want,
                        const massive::ModelView& view) {
    ASSERT_EQ(got.result.collisions.size(), want.collisions.size());
    ASSERT_EQ(got.result.within.size(), want.within.size());
    for (std::size_t k = 0; k < want.collisions.size(); ++k) {
        expect_same_hit(got.result.collisions[k], want.collisions[k]);
        EXPECT_EQ(got.collision_names[k], view.object_name(want.collisions[k].object).value());
    }
    for (std::size_t k = 0; k < want.within.size(); ++k) {
        expect_same_hit(got.result.within[k], want.within[k]);
        EXPECT_EQ(got.within_names[k], view.object_name(want.within[k].object).value());
    }
    ASSERT_EQ(got.result.nearest.has_value(), want.nearest.has_value());
    if (want.nearest) {
        expect_same_hit(*got.result.nearest, *want.nearest);
        EXPECT_EQ(got.nearest_name, view.object_name(want.nearest->object).value());
    }
    EXPECT_EQ(got.result.candidate_pieces, want.candidate_pieces);
}

TEST_F(MassiveDaemon, TwoMembersReviewOneRoomWithEdits) {
    DaemonProcess daemon(daemon_args(*s_models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    auto store = open_local();
    ASSERT_TRUE(store);
    auto cache = std::make_shared<massive::GeometryCache>(CACHE_BYTES);
    auto local_view = std::make_shared<massive::ModelView>(store, cache);

    const double tolerance = 0.2;
    const NamedMesh avatar{"avatar", box_mesh({-0.15, -0.15, -0.15}, {0.15, 0.15, 0.15})};
    std::map<std::string, LocalMember> local;
    std::map<std::string, std::unique_ptr<client::ReviewSession>> remote;
    for (const std::string name : {"alice", "bob"}) {
        client::ReviewJoin join{"design-1", "plant", name, avatar, tolerance, true};
        auto session = c->join_review(join);
        ASSERT_TRUE(session.ok()) << session.status().to_string();
        EXPECT_EQ((*session)->joined().room, "design-1");
        EXPECT_EQ((*session)->joined().generation, store->summary().generation);
        EXPECT_EQ((*session)->joined().members.back().name, name);
        remote[name] = std::move(session).value();
        auto tracker = massive::AvatarTracker::create(local_view, avatar.mesh);
        ASSERT_TRUE(tracker.ok());
        local[name] = {local_view, std::move(tracker).value(), {tolerance, true}};
    }
    // Alice was alone when she joined; she hears about Bob.
    auto joined = remote["alice"]->next(5s);
    ASSERT_TRUE(joined.ok()) << joined.status().to_string();
    EXPECT_EQ(joined->kind, ReviewEvent::Kind::member_joined);
    EXPECT_EQ(joined->member, "bob");
    EXPECT_EQ(remote["bob"]->joined().members.size(), 2u);

    // Peer updates each member has seen, by peer: the latest sequence.
    std::map<std::string, std::map<std::string, client::ReviewPeerUpdate>> peers;
    std::map<std::string, std::vector<client::ReviewEditApplied>> edits;
    auto record = [&](const std::string& who) {
        return [&, who](const ReviewEvent& e) {
            if (e.kind == ReviewEvent::Kind::peer) {
                peers[who][e.peer.member] = e.peer;
            } else if (e.kind == ReviewEvent::Kind::edit_applied) {
                edits[who].push_back(e.edit);
            }
        };
    };
    std::uint64_t sequence = 0;
    std::map<std::string, client::ReviewPoseResult> last;
    std::size_t collisions = 0;
    std::size_t within = 0;
    // One pose of `who` at `pose`: the daemon's answer equals the local tracker's.
    auto step = [&](const std::string& who, const massive::Affine& pose) {
        SCOPED_TRACE(who + " pose " + std::to_string(sequence + 1));
        ++sequence;
        ASSERT_TRUE(remote[who]->send_pose(sequence, pose).ok());
        auto got = remote[who]->wait_result(sequence, record(who));
        ASSERT_TRUE(got.ok()) << got.status().to_string();
        auto& m = local[who];
        auto want = m.tracker->query(pose, m.options);
        ASSERT_TRUE(want.ok()) << want.status().to_string();
        EXPECT_EQ(got->model_version, local_view->version());
        expect_same_result(got.value(), want.value(), *local_view);
        collisions += got->result.collisions.size();
        within += got->result.within.size();
        last[who] = std::move(got).value();
    };
    // Alice walks row 0 (y = 0.5), Bob row 1 (y = 2.5), through contacts, gaps and overlaps.
    for (int k = 0; k <= 24; ++k) {
        const double x = -0.5 + 0.5 * k;
        step("alice", translation(x, 0.5, 0.5));
        step("bob", translation(x, 2.5, 0.5));
    }
    // Each has seen the other's latest pose (drain what is pending).
    for (const std::string who : {"alice", "bob"}) {
        while (true) {
            auto e = remote[who]->next(300ms);
            if (!e.ok()) {
                break;
            }
            record(who)(e.value());
        }
    }
    ASSERT_EQ(peers["alice"].count("bob"), 1u);
    ASSERT_EQ(peers["bob"].count("alice"), 1u);
    EXPECT_EQ(peers["alice"]["bob"].sequence, sequence);
    EXPECT_EQ(peers["bob"]["alice"].sequence, sequence - 1);
    EXPECT_EQ(peers["alice"]["bob"].transform.m, translation(11.5, 2.5, 0.5).m);
    // The walks went through contacts and near misses, and what peers see is the sender's result.
    EXPECT_GT(collisions, 0u);
    EXPECT_GT(within, collisions);
    for (const auto& [who, other] : {std::pair{"alice", "bob"}, std::pair{"bob", "alice"}}) {
        const auto& summary = peers[who][other].summary;
        const auto& result = last[other];
        EXPECT_EQ(summary.collisions, result.result.collisions.size());
        EXPECT_EQ(summary.within, result.result.within.size());
        ASSERT_EQ(summary.has_nearest, result.result.nearest.has_value());
        if (summary.has_nearest) {
            EXPECT_EQ(summary.nearest_object, result.result.nearest->object);
            EXPECT_EQ(summary.nearest_distance, result.result.nearest->distance);
            EXPECT_EQ(summary.nearest_name, result.nearest_name);
        }
    }

    // Edits by Alice, in Bob's way: every member sees each one, Bob's results change with them.
    auto edit_seen = [&](const std::string& who, std::uint64_t edit_sequence) {
        for (int k = 0; k < 50; ++k) {
            for (const auto& e : edits[who]) {
                if (e.member == "alice" && e.sequence == edit_sequence) {
                    return e;
                }
            }
            auto e = remote[who]->next(5s);
            EXPECT_TRUE(e.ok()) << e.status().to_string();
            if (!e.ok()) {
                break;
            }
            record(who)(e.value());
        }
        ADD_FAILURE() << who << " never saw edit " << edit_sequence;
        return client::ReviewEditApplied{};
    };
    // Beyond the model: nothing near. (Surfaces count: an avatar wholly inside a box without
    // touching its faces is 0.35 away from it, so the poses below straddle faces.)
    const massive::Affine bob_at = translation(20.55, 2.5, 0.5);
    step("bob", bob_at);

    // 1. Move object 0 (row 0, cell 0, a box at x 0..1, y 0..1) under Bob's avatar.
    ASSERT_TRUE(remote["alice"]->move_object(101, 0, translation(19.6, 2.0, 0.0)).ok());
    auto moved = edit_seen("bob", 101);
    EXPECT_EQ(moved.what, client::ReviewEditKind::move);
    EXPECT_EQ(moved.object, 0u);
    EXPECT_EQ(moved.object_name, "row-0/cell-0");
    EXPECT_EQ(edit_seen("alice", 101).model_version, moved.model_version);
    ASSERT_TRUE(local_view->move_object(0, translation(19.6, 2.0, 0.0)).ok());
    EXPECT_EQ(moved.model_version, local_view->version());
    step("bob", bob_at);
    {
        // Bob now collides with the moved box.
        ASSERT_TRUE(remote["bob"]->send_pose(++sequence, bob_at).ok());
        auto got = remote["bob"]->wait_result(sequence, record("bob"));
        ASSERT_TRUE(got.ok());
        ASSERT_EQ(got->result.collisions.size(), 1u);
        EXPECT_EQ(got->result.collisions[0].object, 0u);
        EXPECT_EQ(got->collision_names[0], "row-0/cell-0");
        auto want = local["bob"].tracker->query(bob_at, local["bob"].options);
        ASSERT_TRUE(want.ok());
    }

    // 2. Add an object where Bob will stand next.
    const massive::Affine bob_next = translation(25.0, 2.5, 0.5);
    const NamedMesh added{"crate", box_mesh({24.9, 2.4, 0.4}, {25.6, 3.0, 1.0})};
    ASSERT_TRUE(remote["alice"]->add_object(102, added).ok());
    auto add_seen = edit_seen("bob", 102);
    EXPECT_EQ(add_seen.what, client::ReviewEditKind::add);
    EXPECT_EQ(add_seen.object_name, "crate");
    auto local_id = local_view->add_object({added.name, added.mesh});
    ASSERT_TRUE(local_id.ok());
    EXPECT_EQ(add_seen.object, local_id.value());
    EXPECT_EQ(add_seen.object, store->objects().size());
    EXPECT_EQ(edit_seen("alice", 102).object, add_seen.object);
    step("bob", bob_next);
    ASSERT_EQ(last["bob"].result.collisions.size(), 1u);
    EXPECT_EQ(last["bob"].result.collisions[0].object, add_seen.object);
    EXPECT_EQ(last["bob"].collision_names[0], "crate");

    // 3. Delete the moved box: Bob at bob_at sees nothing again.
    ASSERT_TRUE(remote["alice"]->delete_object(103, 0).ok());
    auto deleted = edit_seen("bob", 103);
    EXPECT_EQ(deleted.what, client::ReviewEditKind::remove);
    EXPECT_EQ(deleted.object, 0u);
    EXPECT_EQ(deleted.object_name, "row-0/cell-0");
    ASSERT_TRUE(local_view->delete_object(0).ok());
    step("bob", bob_at);
    EXPECT_TRUE(last["bob"].result.collisions.empty());
    step("alice", translation(0.95, 0.5, 0.5));  // where box 0 was: gone for Alice too
    step("bob", bob_next);

    // A second room on the same model does not see the first room's edits.
    client::ReviewJoin other{"design-2", "plant", "carol", avatar, tolerance, true};
    auto carol = c->join_review(other);
    ASSERT_TRUE(carol.ok()) << carol.status().to_string();
    EXPECT_EQ((*carol)->joined().model_version, 0u);
    ASSERT_TRUE((*carol)->send_pose(1, translation(0.95, 0.5, 0.5)).ok());
    auto carol_result = (*carol)->wait_result(1);
    ASSERT_TRUE(carol_result.ok());
    ASSERT_FALSE(carol_result->result.collisions.empty());
    EXPECT_EQ(carol_result->result.collisions[0].object, 0u);  // box 0 still there
    EXPECT_TRUE((*carol)->finish().ok());

    // Bob leaves: Alice sees it; her stream ends cleanly.
    EXPECT_TRUE(remote["bob"]->finish().ok());
    bool left = false;
    for (int k = 0; k < 50 && !left; ++k) {
        auto e = remote["alice"]->next(5s);
        ASSERT_TRUE(e.ok()) << e.status().to_string();
        left = e->kind == ReviewEvent::Kind::member_left && e->member == "bob";
    }
    EXPECT_TRUE(left);
    EXPECT_TRUE(remote["alice"]->finish().ok());
    // The room went with its last member, and its edits with it: joining the same name starts a
    // fresh room on the stored model.
    auto again = c->join_review({"design-1", "plant", "dave", avatar, tolerance, true});
    ASSERT_TRUE(again.ok()) << again.status().to_string();
    EXPECT_EQ((*again)->joined().members.size(), 1u);
    EXPECT_EQ((*again)->joined().model_version, 0u);
    EXPECT_EQ((*again)->joined().object_count, store->objects().size());
}

// A member that stops reading, on a raw stub with a small flow-control window (so the
// transport stops accepting the daemon's writes instead of buffering on the client's side).
struct StalledMember {
    grpc::ClientContext context;
    std::shared_ptr<grpc::Channel> channel;
    std::unique_ptr<v1::Proximity::Stub> stub;
    std::unique_ptr<grpc::ClientReaderWriter<v1::ReviewRequest, v1::ReviewEvent>> stream;

    StalledMember(const std::string& address, const std::string& room, const NamedMesh& avatar) {
        grpc::ChannelArguments args;
        args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
        args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
        args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 16 * 1024);
        channel = grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args);
        stub = v1::Proximity::NewStub(channel);
        stream = stub->Review(&context);
        v1::ReviewRequest join;
        join.mutable_join()->set_room(room);
        join.mutable_join()->set_model("plant");
        join.mutable_join()->set_member("stalled");
        join.mutable_join()->set_tolerance(0.1);
        set_mesh(avatar, join.mutable_join()->mutable_avatar());
        EXPECT_TRUE(stream->Write(join));
        v1::ReviewEvent joined;
        EXPECT_TRUE(stream->Read(&joined));
        EXPECT_TRUE(joined.has_joined());
    }
};

// Backpressure: a member that does not read gets each peer's latest pose, not every pose; one
// that falls more than the bound behind on events that cannot be coalesced (joins, leaves,
// edits) is disconnected with RESOURCE_EXHAUSTED, the room going on without it.
TEST_F(MassiveDaemon, SlowMembersGetCoalescedPosesThenAreDisconnected) {
    DaemonProcess daemon(daemon_args(*s_models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    const NamedMesh avatar{"avatar", box_mesh({-0.15, -0.15, -0.15}, {0.15, 0.15, 0.15})};
    auto alice = c->join_review({"busy", "plant", "alice", avatar, 0.1, true});
    ASSERT_TRUE(alice.ok()) << alice.status().to_string();
    StalledMember stalled(daemon.address(), "busy", avatar);
    ASSERT_TRUE((*alice)->next(5s).ok());  // member_joined

    constexpr std::uint64_t POSES = 2000;
    for (std::uint64_t k = 1; k <= POSES; ++k) {
        ASSERT_TRUE(
            (*alice)->send_pose(k, translation(0.01 * static_cast<double>(k), 0.5, 0.5)).ok());
        auto r = (*alice)->wait_result(k);
        ASSERT_TRUE(r.ok()) << r.status().to_string();
    }
    // Joins and leaves cannot be coalesced: members with long names come and go until the
    // stalled member is more than the bound behind and is cut off; Alice sees it leave.
    bool gone = false;
    std::uint64_t visits = 0;
    for (; visits < 2000 && !gone; ++visits) {
        client::ReviewJoin visit{"busy", "plant", std::string(2000, 'v') + std::to_string(visits),
                                 avatar, 0.1,     true};
        auto visitor = c->join_review(visit);
        ASSERT_TRUE(visitor.ok()) << visitor.status().to_string();
        ASSERT_TRUE((*visitor)->finish().ok());
        for (;;) {
            auto e = (*alice)->next(5s);
            ASSERT_TRUE(e.ok()) << e.status().to_string();
            if (e->kind == ReviewEvent::Kind::member_left) {
                if (e->member == "stalled") {
                    gone = true;
                } else {
                    break;
                }
            }
        }
    }
    ASSERT_TRUE(gone) << "the stalled member was never disconnected after " << visits << " visits";
    // What the stalled member got: some of Alice's poses (coalesced: fewer than she sent, in
    // order), then the status.
    std::uint64_t peer_events = 0;
    std::uint64_t last_sequence = 0;
    v1::ReviewEvent event;
    while (stalled.stream->Read(&event)) {
        if (event.has_peer()) {
            EXPECT_GT(event.peer().sequence(), last_sequence);
            last_sequence = event.peer().sequence();
            ++peer_events;
        }
    }
    const auto status = stalled.stream->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << status.error_message();
    // (The poses still queued when it was cut off are dropped with it.)
    EXPECT_GT(peer_events, 0u);
    EXPECT_LT(peer_events, POSES) << "a reader that stalled should have had poses coalesced";
    // Alice goes on.
    ASSERT_TRUE((*alice)->send_pose(POSES + 1, translation(0.5, 0.5, 0.5)).ok());
    EXPECT_TRUE((*alice)->wait_result(POSES + 1).ok());
    EXPECT_TRUE((*alice)->finish().ok());
}

// Peer updates wait for company (--review-peer-interval, 0.02 s by default): a reader on a raw
// stub gets the updates of several posing members in `peers` messages, far fewer messages than
// poses, each member's sequence increasing and its last pose always delivered.
TEST_F(MassiveDaemon, PeerUpdatesArriveBatchedWithEachMembersLastPose) {
    DaemonProcess daemon(daemon_args(*s_models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    const NamedMesh avatar{"avatar", box_mesh({-0.15, -0.15, -0.15}, {0.15, 0.15, 0.15})};
    grpc::ClientContext context;
    // A lost update fails the test instead of hanging it.
    context.set_deadline(std::chrono::system_clock::now() + 120s);
    auto stub = v1::Proximity::NewStub(
        grpc::CreateChannel(daemon.address(), grpc::InsecureChannelCredentials()));
    auto watcher = stub->Review(&context);
    {
        v1::ReviewRequest join;
        join.mutable_join()->set_room("batched");
        join.mutable_join()->set_model("plant");
        join.mutable_join()->set_member("watcher");
        set_mesh(avatar, join.mutable_join()->mutable_avatar());
        ASSERT_TRUE(watcher->Write(join));
        v1::ReviewEvent joined;
        ASSERT_TRUE(watcher->Read(&joined));
        ASSERT_TRUE(joined.has_joined());
    }
    const std::vector<std::string> names = {"ann", "bob", "cy"};
    constexpr std::uint64_t POSES = 60;
    std::vector<std::unique_ptr<client::ReviewSession>> posers;
    for (const auto& name : names) {
        auto s = c->join_review({"batched", "plant", name, avatar, 0.1, true});
        ASSERT_TRUE(s.ok()) << s.status().to_string();
        posers.push_back(std::move(s).value());
    }
    // The watcher reads on its own thread while the members pose, one after the other.
    std::map<std::string, std::uint64_t> last;
    std::uint64_t messages = 0;
    std::uint64_t batches = 0;
    std::uint64_t updates = 0;
    bool in_order = true;
    std::thread reader([&] {
        v1::ReviewEvent event;
        auto take = [&](const v1::PeerUpdate& u) {
            in_order = in_order && u.sequence() > last[u.member()];
            last[u.member()] = u.sequence();
            ++updates;
        };
        while (watcher->Read(&event)) {
            if (event.has_peer()) {
                ++messages;
                take(event.peer());
            } else if (event.has_peers()) {
                ++messages;
                ++batches;
                std::set<std::string> members;
                for (const auto& u : event.peers().updates()) {
                    members.insert(u.member());
                    take(u);
                }
                in_order = in_order &&
                           members.size() == static_cast<std::size_t>(event.peers().updates_size());
            }
            if (last["ann"] == POSES && last["bob"] == POSES && last["cy"] == POSES) {
                return;
            }
        }
    });
    for (std::uint64_t k = 1; k <= POSES; ++k) {
        for (std::size_t m = 0; m < posers.size(); ++m) {
            const double x = 0.01 * static_cast<double>(k) + 0.3 * static_cast<double>(m);
            ASSERT_TRUE(posers[m]->send_pose(k, translation(x, 0.5, 0.5)).ok());
            auto r = posers[m]->wait_result(k, {}, 5s);
            ASSERT_TRUE(r.ok()) << r.status().to_string();
        }
    }
    reader.join();
    EXPECT_TRUE(in_order) << "a member twice in a batch, or a sequence going back";
    for (const auto& name : names) {
        EXPECT_EQ(last[name], POSES) << name << "'s last pose never reached the watcher";
    }
    EXPECT_GT(batches, 0u) << "no update went together with another";
    EXPECT_LT(messages, names.size() * POSES / 2)
        << messages << " messages for " << updates << " updates of " << names.size() * POSES
        << " poses: updates are not held for company";
    for (auto& p : posers) {
        EXPECT_TRUE(p->finish().ok());
    }
    context.TryCancel();
    (void)watcher->Finish();
}

TEST_F(MassiveDaemon, CorruptChunkIsDataLossAndTheDaemonServesOn) {
    const fs::path models = make_temp_dir("corrupt");
    fs::copy(*s_models / "plant", models / "plant", fs::copy_options::recursive);
    fs::copy(*s_models / "plant", models / "broken", fs::copy_options::recursive);
    // Flip a byte in the middle of the first chunk file of "broken".
    std::string generation;
    {
        std::ifstream in(models / "broken" / "CURRENT");
        in >> generation;
    }
    // One byte in every chunk of "broken", so whichever piece the traversal reads first is bad.
    ASSERT_TRUE(fs::exists(models / "broken" / generation / "chunks-0000.bin"));
    for (const auto& file : fs::directory_iterator(models / "broken" / generation)) {
        if (file.path().filename().string().rfind("chunks-", 0) != 0) {
            continue;
        }
        const auto size = fs::file_size(file.path());
        for (std::uint64_t at = 100; at < size; at += 4096) {
            flip_byte(file.path(), at);
        }
    }
    DaemonProcess daemon(daemon_args(models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    auto v = c->verify_model("broken", 0.1);
    EXPECT_EQ(v.status().code(), StatusCode::data_loss) << v.status().to_string();
    EXPECT_NE(v.status().message().find("chunk"), std::string::npos) << v.status().message();
    EXPECT_TRUE(daemon.running());
    auto list = c->list_models();
    ASSERT_TRUE(list.ok()) << list.status().to_string();
    EXPECT_EQ(list->models.size(), 2u);
    auto good = c->verify_model("plant", 0.1);
    EXPECT_TRUE(good.ok()) << good.status().to_string();
    auto info = c->server_info();
    EXPECT_TRUE(info.ok());
    // A review pose that needs a corrupt piece ends that member's stream with DATA_LOSS.
    const NamedMesh avatar{"avatar", box_mesh({-0.15, -0.15, -0.15}, {0.15, 0.15, 0.15})};
    auto member = c->join_review({"r", "broken", "alice", avatar, 0.5, true});
    ASSERT_TRUE(member.ok()) << member.status().to_string();
    ASSERT_TRUE((*member)->send_pose(1, translation(0.95, 0.5, 0.5)).ok());
    auto pose = (*member)->wait_result(1);
    EXPECT_EQ(pose.status().code(), StatusCode::data_loss) << pose.status().to_string();

    // A corrupt manifest: the store is listed as unavailable, not fatal.
    fs::copy(models / "plant", models / "bad-manifest", fs::copy_options::recursive);
    const fs::path manifest = models / "bad-manifest" / generation / "manifest.json";
    ASSERT_TRUE(fs::exists(manifest));
    flip_byte(manifest, fs::file_size(manifest) / 2);
    list = c->list_models();
    ASSERT_TRUE(list.ok());
    EXPECT_EQ(list->models.size(), 2u);
    ASSERT_EQ(list->unavailable.size(), 1u);
    EXPECT_EQ(list->unavailable[0].first, "bad-manifest");
    auto bad = c->verify_model("bad-manifest", 0.0);
    EXPECT_EQ(bad.status().code(), StatusCode::data_loss) << bad.status().to_string();
    // And a daemon started on that directory starts anyway.
    DaemonProcess second(daemon_args(models));
    EXPECT_TRUE(second.ok()) << second.error();
    std::error_code ec;
    fs::remove_all(models, ec);
}

// A member busy elsewhere (not reading its session for a while) while three peers walk: its
// session keeps reading and keeps at most one update per peer (the newest), so when it poses,
// its own answer comes after at most those few updates, not behind a backlog of every peer
// pose the room published meanwhile; and each peer's last pose still reaches it.
TEST_F(MassiveDaemon, ReviewSessionCoalescesPeerUpdatesWhileItsCallerIsBusy) {
    DaemonProcess daemon(daemon_args(*s_models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    const NamedMesh avatar{"avatar", box_mesh({-0.15, -0.15, -0.15}, {0.15, 0.15, 0.15})};
    const std::vector<std::string> names{"watcher", "p0", "p1", "p2"};
    std::map<std::string, std::unique_ptr<client::ReviewSession>> members;
    for (const auto& name : names) {
        auto session = c->join_review({"busy-1", "plant", name, avatar, 0.2, true});
        ASSERT_TRUE(session.ok()) << session.status().to_string();
        members[name] = std::move(session).value();
    }
    // The peers walk, 150 poses each, while the watcher reads nothing.
    constexpr std::uint64_t POSES = 150;
    for (std::uint64_t k = 1; k <= POSES; ++k) {
        for (std::size_t p = 1; p < names.size(); ++p) {
            const double x = -0.5 + 0.08 * static_cast<double>(k);
            ASSERT_TRUE(members[names[p]]
                            ->send_pose(k, translation(x, 2.0 * static_cast<double>(p), 0.5))
                            .ok());
            auto got = members[names[p]]->wait_result(k, {});
            ASSERT_TRUE(got.ok()) << got.status().to_string();
        }
    }
    // 3 x 150 peer poses were published to the watcher. Its answer comes after its queued
    // events: the member_joined events and at most one update per peer (two for a peer whose
    // last publish raced the watcher's reading).
    auto& watcher = *members["watcher"];
    ASSERT_TRUE(watcher.send_pose(1, translation(30.0, 30.0, 0.5)).ok());
    std::map<std::string, std::vector<std::uint64_t>> seen;
    std::size_t joins = 0;
    for (;;) {
        auto e = watcher.next(10s);
        ASSERT_TRUE(e.ok()) << e.status().to_string();
        if (e->kind == ReviewEvent::Kind::result) {
            EXPECT_EQ(e->result.sequence, 1u);
            break;
        }
        if (e->kind == ReviewEvent::Kind::member_joined) {
            ++joins;
        } else {
            ASSERT_EQ(e->kind, ReviewEvent::Kind::peer);
            seen[e->peer.member].push_back(e->peer.sequence);
        }
    }
    EXPECT_EQ(joins, 3u);
    std::size_t updates = 0;
    for (const auto& [peer, sequences] : seen) {
        SCOPED_TRACE(peer);
        EXPECT_LE(sequences.size(), 2u);
        EXPECT_TRUE(std::is_sorted(sequences.begin(), sequences.end()));
        updates += sequences.size();
    }
    EXPECT_LE(updates, 6u);
    // Nothing is lost that matters: each peer's newest pose reaches the watcher.
    for (std::size_t p = 1; p < names.size(); ++p) {
        SCOPED_TRACE(names[p]);
        for (int k = 0; k < 20 && (seen[names[p]].empty() || seen[names[p]].back() != POSES); ++k) {
            auto e = watcher.next(500ms);
            if (e.ok() && e->kind == ReviewEvent::Kind::peer) {
                seen[e->peer.member].push_back(e->peer.sequence);
            }
        }
        ASSERT_FALSE(seen[names[p]].empty());
        EXPECT_EQ(seen[names[p]].back(), POSES);
    }
    for (auto& [name, session] : members) {
        EXPECT_TRUE(session->finish().ok()) << name;
    }
}

TEST_F(MassiveDaemon, SigtermEndsReviewStreamsAndExitsZero) {
    DaemonProcess daemon(daemon_args(*s_models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    const NamedMesh avatar{"avatar", box_mesh({-0.15, -0.15, -0.15}, {0.15, 0.15, 0.15})};
    auto alice = c->join_review({"r", "plant", "alice", avatar, 0.1, true});
    ASSERT_TRUE(alice.ok()) << alice.status().to_string();
    ASSERT_TRUE((*alice)->send_pose(1, translation(0.95, 0.5, 0.5)).ok());
    ASSERT_TRUE((*alice)->wait_result(1).ok());
    daemon.signal(SIGTERM);
    auto end = (*alice)->next(10s);
    EXPECT_EQ(end.status().code(), StatusCode::unavailable) << end.status().to_string();
    const auto status = daemon.wait_exit(20s);
    ASSERT_TRUE(status.has_value()) << "proximad did not exit after SIGTERM";
    EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0);
}

TEST_F(MassiveDaemon, CancelledVerificationStopsAndTheDaemonServesOn) {
    DaemonProcess daemon(daemon_args(*s_models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    auto v = c->verify_model("plant", 0.3, [](const client::VerifyEvent&) { return false; });
    EXPECT_EQ(v.status().code(), StatusCode::cancelled) << v.status().to_string();
    auto again = c->verify_model("plant", 0.0);
    EXPECT_TRUE(again.ok()) << again.status().to_string();
}

TEST_F(MassiveDaemon, RestartServesTheSameGenerationWithoutReimport) {
    std::string generation;
    std::uint64_t pairs = 0;
    {
        DaemonProcess daemon(daemon_args(*s_models));
        ASSERT_TRUE(daemon.ok()) << daemon.error();
        auto c = connect(daemon);
        ASSERT_TRUE(c);
        auto list = c->list_models();
        ASSERT_TRUE(list.ok());
        ASSERT_EQ(list->models.size(), 1u);
        generation = list->models[0].generation;
        auto v = c->verify_model("plant", 0.0);
        ASSERT_TRUE(v.ok()) << v.status().to_string();
        pairs = v->stats.pairs_found;
    }
    DaemonProcess daemon(daemon_args(*s_models));
    ASSERT_TRUE(daemon.ok()) << daemon.error();
    auto c = connect(daemon);
    ASSERT_TRUE(c);
    auto list = c->list_models();
    ASSERT_TRUE(list.ok());
    ASSERT_EQ(list->models.size(), 1u);
    EXPECT_EQ(list->models[0].generation, generation);
    auto v = c->verify_model("plant", 0.0);
    ASSERT_TRUE(v.ok()) << v.status().to_string();
    EXPECT_EQ(v->stats.pairs_found, pairs);
    EXPECT_TRUE(v->stats.schedule_from_store);  // the plan persisted with the store
    EXPECT_EQ(open_local()->summary().generation, generation);
}

// The region calls' tests (FetchRegion, Snapshot with `model`): a daemon serving the models, a
// client on it and the "plant" store opened in this process.
class MassiveRegion : public MassiveDaemon {
  protected:
    void SetUp() override {
        m_daemon = std::make_unique<DaemonProcess>(daemon_args(*s_models));
        ASSERT_TRUE(m_daemon->ok()) << m_daemon->error();
        m_client = connect(*m_daemon);
        ASSERT_TRUE(m_client);
        m_store = open_local();
        ASSERT_TRUE(m_store);
    }

    std::unique_ptr<DaemonProcess> m_daemon;
    std::unique_ptr<Client> m_client;
    std::shared_ptr<const massive::Store> m_store;
};

// --- FetchRegion ---------------------------------------------------------------------------

struct FetchedRegion {
    std::vector<client::RegionPiece> pieces;
    std::vector<client::RegionProgress> progress;
    client::RegionSummary summary;
};

StatusOr<FetchedRegion> fetch_all(Client& c, const client::RegionRequest& request) {
    FetchedRegion out;
    auto summary = c.fetch_region(request, [&](const client::RegionEvent& e) {
        if (const auto* p = std::get_if<client::RegionPiece>(&e)) {
            // Progress is coalesced: the latest one counts the pieces sent before it.
            if (!out.progress.empty()) {
                EXPECT_LE(out.progress.back().pieces_sent, out.pieces.size());
            }
            out.pieces.push_back(*p);
        } else if (const auto* g = std::get_if<client::RegionProgress>(&e)) {
            out.progress.push_back(*g);
        }
        return true;
    });
    if (!summary.ok()) {
        return summary.status();
    }
    out.summary = summary.value();
    return out;
}

// Each triangle of the fetched pieces by (object, triangle id in the object): its 3 corners.
using RegionTriangles = std::map<std::pair<std::uint32_t, std::uint32_t>, std::array<Vec3, 3>>;

RegionTriangles region_triangles(const std::vector<client::RegionPiece>& pieces) {
    RegionTriangles out;
    for (const auto& p : pieces) {
        EXPECT_EQ(p.triangle_ids.size(), p.triangles.size());
        for (std::size_t t = 0; t < p.triangles.size(); ++t) {
            std::array<Vec3, 3> corners;
            for (int k = 0; k < 3; ++k) {
                corners[static_cast<std::size_t>(k)] = p.vertices.at(p.triangles[t][k]);
            }
            const bool fresh = out.emplace(std::pair{p.object, p.triangle_ids[t]}, corners).second;
            EXPECT_TRUE(fresh) << "object " << p.object << " triangle " << p.triangle_ids[t]
                               << " sent twice";
        }
    }
    return out;
}

// The object's stored triangles (as read in-process), through `map`, as float32 when asked.
void expect_object_triangles(const RegionTriangles& got, std::uint32_t object,
                             const TriangleMesh& stored, const massive::Affine& map, bool float32) {
    for (std::uint32_t t = 0; t < stored.triangles.size(); ++t) {
        const auto it = got.find({object, t});
        ASSERT_NE(it, got.end()) << "object " << object << " triangle " << t << " missing";
        for (int k = 0; k < 3; ++k) {
            Vec3 want = map.apply(stored.vertices[stored.triangles[t][k]]);
            if (float32) {
                want = {static_cast<float>(want.x), static_cast<float>(want.y),
                        static_cast<float>(want.z)};
            }
            EXPECT_EQ(it->second[static_cast<std::size_t>(k)], want)
                << "object " << object << " triangle " << t << " corner " << k;
        }
    }
}

TEST_F(MassiveRegion, FetchRegionWholeModelEqualsTheStore) {
    for (const bool float64 : {true, false}) {
        SCOPED_TRACE(float64 ? "float64" : "float32");
        client::RegionRequest request;
        request.model = "plant";
        request.center = {3, 3, 0};  // ignored with radius 0
        request.float64 = float64;
        auto region = fetch_all(*m_client, request);
        ASSERT_TRUE(region.ok()) << region.status().to_string();
        const auto& s = m_store->summary();
        EXPECT_EQ(region->pieces.size(), s.pieces);
        EXPECT_EQ(region->summary.pieces, s.pieces);
        EXPECT_EQ(region->summary.triangles, s.triangles);
        EXPECT_FALSE(region->summary.truncated);
        EXPECT_EQ(region->summary.model_version, 0u);
        EXPECT_EQ(region->summary.generation, s.generation);
        ASSERT_FALSE(region->progress.empty());
        EXPECT_EQ(region->progress.back().pieces_total, s.pieces);
        EXPECT_EQ(region->progress.back().triangles_total, s.triangles);
        // Radius 0: every distance 0, so the order is by object then piece.
        for (std::size_t k = 0; k < region->pieces.size(); ++k) {
            const auto& p = region->pieces[k];
            EXPECT_EQ(p.distance, 0.0);
            EXPECT_EQ(p.object_name, m_store->objects()[p.object].name);
            if (k > 0) {
                EXPECT_LE(region->pieces[k - 1].object, p.object);
            }
        }
        // The union is the store's triangles exactly: every id once, every corner bit for bit.
        const auto got = region_triangles(region->pieces);
        EXPECT_EQ(got.size(), s.triangles);
        for (std::uint32_t o = 0; o < m_store->objects().size(); ++o) {
            auto stored = massive::read_object(*m_store, o);
            ASSERT_TRUE(stored.ok()) << stored.status().to_string();
            expect_object_triangles(got, o, stored.value(), massive::Affine{}, !float64);
        }
    }
}

TEST_F(MassiveRegion, FetchRegionNearestFirstWithinTheRadius) {
    const auto& pieces = m_store->pieces();
    for (const double radius : {0.75, 2.5, 4.0}) {
        SCOPED_TRACE("radius " + std::to_string(radius));
        client::RegionRequest request;
        request.model = "plant";
        request.center = {5.2, 5.5, 0.5};
        request.radius = radius;
        request.float64 = true;
        auto region = fetch_all(*m_client, request);
        ASSERT_TRUE(region.ok()) << region.status().to_string();
        // The reference: every stored piece whose box is within the radius, by distance, object,
        // piece.
        std::vector<std::tuple<double, std::uint32_t, std::uint32_t>> want;
        for (std::uint32_t p = 0; p < pieces.size(); ++p) {
            const double d = massive::box_distance(pieces[p].box, request.center);
            if (d <= radius) {
                want.emplace_back(d, pieces[p].object, p);
            }
        }
        std::sort(want.begin(), want.end());
        ASSERT_GT(want.size(), 0u);
        ASSERT_LT(want.size(), pieces.size());  // some pieces are outside
        ASSERT_EQ(region->pieces.size(), want.size());
        std::uint64_t triangles = 0;
        for (std::size_t k = 0; k < want.size(); ++k) {
            const auto& [d, object, p] = want[k];
            const auto& got = region->pieces[k];
            EXPECT_EQ(got.object, object);
            EXPECT_EQ(got.distance, d);
            EXPECT_EQ(got.box.lo, pieces[p].box.lo);
            EXPECT_EQ(got.box.hi, pieces[p].box.hi);
            // The piece itself: the store's geometry with its object triangle ids.
            auto local = m_store->read_piece(p);
            ASSERT_TRUE(local.ok());
            EXPECT_EQ(got.triangle_ids, local->source_ids());
            EXPECT_EQ(got.vertices, local->vertices);
            EXPECT_EQ(got.triangles, local->triangles);
            triangles += got.triangles.size();
        }
        EXPECT_EQ(region->summary.pieces, want.size());
        EXPECT_EQ(region->summary.triangles, triangles);
        EXPECT_FALSE(region->summary.truncated);
    }

    // Only some objects: the pipe (crossing row 2) and one cylinder, whole.
    const auto pipe = static_cast<std::uint32_t>(m_store->objects().size() - 1);
    client::RegionRequest only;
    only.model = "plant";
    only.objects = {pipe, 7};
    auto region = fetch_all(*m_client, only);
    ASSERT_TRUE(region.ok()) << region.status().to_string();
    EXPECT_EQ(region->summary.triangles,
              m_store->objects()[pipe].triangle_count + m_store->objects()[7].triangle_count);
    for (const auto& p : region->pieces) {
        EXPECT_TRUE(p.object == pipe || p.object == 7) << p.object;
    }
    EXPECT_EQ(region->pieces.front().object, 7u);  // ties by object

    // max_triangles: the nearest pieces up to that many triangles, then truncated.
    client::RegionRequest capped;
    capped.model = "plant";
    capped.center = {0.5, 0.5, 0.5};
    capped.radius = 100.0;
    auto all = fetch_all(*m_client, capped);
    ASSERT_TRUE(all.ok()) << all.status().to_string();
    ASSERT_EQ(all->pieces.size(), m_store->summary().pieces);
    EXPECT_EQ(all->pieces.front().object, 0u);  // the centre is inside object 0
    std::uint64_t first_three = 0;
    for (std::size_t k = 0; k < 3; ++k) {
        first_three += all->pieces[k].triangles.size();
    }
    capped.max_triangles = first_three + all->pieces[3].triangles.size() - 1;
    auto cut = fetch_all(*m_client, capped);
    ASSERT_TRUE(cut.ok()) << cut.status().to_string();
    ASSERT_EQ(cut->pieces.size(), 3u);
    EXPECT_TRUE(cut->summary.truncated);
    EXPECT_EQ(cut->summary.triangles, first_three);
    for (std::size_t k = 0; k < 3; ++k) {
        EXPECT_EQ(cut->pieces[k].triangle_ids, all->pieces[k].triangle_ids);
        EXPECT_EQ(cut->pieces[k].object, all->pieces[k].object);
    }
    capped.max_triangles = m_store->summary().triangles;
    auto exact = fetch_all(*m_client, capped);
    ASSERT_TRUE(exact.ok());
    EXPECT_FALSE(exact->summary.truncated);
    EXPECT_EQ(exact->summary.pieces, m_store->summary().pieces);
}

TEST_F(MassiveRegion, FetchRegionShowsARoomsEdits) {
    write_store(*s_models / "other");  // found by the daemon's rescan when it is named
    const NamedMesh avatar{"avatar", box_mesh({-0.15, -0.15, -0.15}, {0.15, 0.15, 0.15})};
    auto alice = m_client->join_review({"region-room", "plant", "alice", avatar, 0.0, true});
    ASSERT_TRUE(alice.ok()) << alice.status().to_string();
    auto& session = *alice.value();
    auto edit = [&](std::uint64_t sequence) -> client::ReviewEditApplied {
        for (int k = 0; k < 20; ++k) {
            auto e = session.next(10s);
            EXPECT_TRUE(e.ok()) << e.status().to_string();
            if (!e.ok()) {
                break;
            }
            if (e->kind == ReviewEvent::Kind::edit_applied && e->edit.sequence == sequence) {
                return e->edit;
            }
        }
        ADD_FAILURE() << "edit " << sequence << " never applied";
        return {};
    };
    // Move cylinder 7 (split into pieces) far away, delete box 0, add a crate.
    const auto moved_to = translation(30.0, -4.0, 2.0);
    ASSERT_TRUE(session.move_object(1, 7, moved_to).ok());
    const auto moved = edit(1);
    EXPECT_EQ(moved.what, client::ReviewEditKind::move);
    EXPECT_EQ(moved.transform.m, moved_to.m);  // EditApplied.transform
    ASSERT_TRUE(session.delete_object(2, 0).ok());
    EXPECT_EQ(edit(2).object, 0u);
    const NamedMesh crate{"crate", box_mesh({24.9, 2.4, 0.4}, {25.6, 3.0, 1.0})};
    ASSERT_TRUE(session.add_object(3, crate).ok());
    const auto added = edit(3);
    ASSERT_EQ(added.object, m_store->objects().size());
    EXPECT_EQ(added.transform.m, massive::Affine{}.m);  // only moves carry one

    client::RegionRequest request;
    request.model = "plant";
    request.room = "region-room";
    request.float64 = true;
    auto region = fetch_all(*m_client, request);
    ASSERT_TRUE(region.ok()) << region.status().to_string();
    EXPECT_EQ(region->summary.model_version, 3u);
    const auto got = region_triangles(region->pieces);
    std::uint64_t want_triangles = 0;
    for (std::uint32_t o = 0; o < m_store->objects().size(); ++o) {
        SCOPED_TRACE("object " + std::to_string(o));
        auto stored = massive::read_object(*m_store, o);
        ASSERT_TRUE(stored.ok());
        if (o == 0) {
            EXPECT_EQ(got.count({0u, 0u}), 0u);  // deleted
            continue;
        }
        want_triangles += stored->triangles.size();
        expect_object_triangles(got, o, stored.value(), o == 7 ? moved_to : massive::Affine{},
                                false);
    }
    expect_object_triangles(got, added.object, crate.mesh, massive::Affine{}, false);
    want_triangles += crate.mesh.triangles.size();
    EXPECT_EQ(got.size(), want_triangles);
    EXPECT_EQ(region->summary.triangles, want_triangles);
    for (const auto& p : region->pieces) {
        if (p.object == added.object) {
            EXPECT_EQ(p.object_name, "crate");
        }
    }

    // Just the added object, near where it is; and the moved one is found where it went.
    request.objects = {added.object};
    request.center = {25.0, 2.5, 0.5};
    request.radius = 1.0;
    auto just = fetch_all(*m_client, request);
    ASSERT_TRUE(just.ok()) << just.status().to_string();
    ASSERT_EQ(just->pieces.size(), 1u);
    EXPECT_EQ(just->pieces[0].object, added.object);
    EXPECT_EQ(just->pieces[0].distance, 0.0);
    request.objects = {};
    request.center = {31.5, -1.5, 2.5};  // inside the moved cylinder's box
    request.radius = 0.1;
    auto near_moved = fetch_all(*m_client, request);
    ASSERT_TRUE(near_moved.ok()) << near_moved.status().to_string();
    ASSERT_EQ(near_moved->pieces.size(), 1u);
    EXPECT_EQ(near_moved->pieces[0].object, 7u);
    // Without the room: the stored model, unedited.
    request.room.clear();
    auto stored_view = fetch_all(*m_client, request);
    ASSERT_TRUE(stored_view.ok());
    EXPECT_TRUE(stored_view->pieces.empty());
    EXPECT_EQ(stored_view->summary.model_version, 0u);

    // A room on another model, an unknown room, an object the room does not have.
    request.model = "other";
    request.room = "region-room";
    auto wrong = fetch_all(*m_client, request);
    EXPECT_EQ(wrong.status().code(), StatusCode::failed_precondition) << wrong.status().to_string();
    request.model = "plant";
    request.room = "no-such-room";
    auto unknown = fetch_all(*m_client, request);
    EXPECT_EQ(unknown.status().code(), StatusCode::not_found) << unknown.status().to_string();
    request.room = "region-room";
    request.objects = {added.object + 1};
    auto beyond = fetch_all(*m_client, request);
    EXPECT_EQ(beyond.status().code(), StatusCode::invalid_argument) << beyond.status().to_string();
    session.cancel();
    fs::remove_all(*s_models / "other");
}

// A region request both region calls must refuse: what it is, the request, the status and a part
// of its message.
struct BadRegion {
    std::string what;
    client::RegionRequest request;
    StatusCode code;
    std::string message;
};

// "plant" within 1.0 of the origin, then `change`d.
template <typename Change>
client::RegionRequest plant_region(Change change) {
    client::RegionRequest r;
    r.model = "plant";
    r.radius = 1.0;
    change(r);
    return r;
}

// The bad requests FetchRegion and Snapshot with `model` refuse alike.
std::vector<BadRegion> bad_regions() {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    return {
        {"unknown model", plant_region([](auto& r) { r.model = "nope"; }), StatusCode::not_found,
         "nope"},
        {"negative radius", plant_region([](auto& r) { r.radius = -1.0; }),
         StatusCode::invalid_argument, "radius"},
        {"NaN radius", plant_region([&](auto& r) { r.radius = nan; }), StatusCode::invalid_argument,
         "radius"},
        {"NaN center", plant_region([&](auto& r) { r.center.y = nan; }),
         StatusCode::invalid_argument, "center"},
        {"unknown room", plant_region([](auto& r) { r.room = "nobody-here"; }),
         StatusCode::not_found, "nobody-here"},
    };
}

TEST_F(MassiveRegion, FetchRegionRejectsBadRequestsBeforeSendingAnything) {
    const double inf = std::numeric_limits<double>::infinity();
    auto cases = bad_regions();
    cases.push_back({"infinite radius", plant_region([&](auto& r) { r.radius = inf; }),
                     StatusCode::invalid_argument, "radius"});
    cases.push_back({"infinite center", plant_region([&](auto& r) { r.center.z = -inf; }),
                     StatusCode::invalid_argument, "center"});
    cases.push_back({"object out of range", plant_region([](auto& r) {
                         r.objects = {1, 999};
                     }),
                     StatusCode::invalid_argument, "objects[1]: object 999"});
    for (const auto& k : cases) {
        SCOPED_TRACE(k.what);
        std::size_t events = 0;
        auto got = m_client->fetch_region(k.request, [&](const client::RegionEvent&) {
            ++events;
            return true;
        });
        EXPECT_EQ(got.status().code(), k.code) << got.status().to_string();
        EXPECT_NE(got.status().message().find(k.message), std::string::npos)
            << got.status().to_string();
        EXPECT_EQ(events, 0u);
    }
    // An unknown scalar type: the generated stub, since the library never sends one.
    auto stub = make_stub(m_daemon->address());
    grpc::ClientContext context;
    deadline_in(context, 10s);
    v1::FetchRegionRequest raw;
    raw.set_model("plant");
    raw.set_type(static_cast<v1::ScalarType>(7));
    auto reader = stub->FetchRegion(&context, raw);
    v1::RegionEvent event;
    EXPECT_FALSE(reader->Read(&event));
    const auto status = reader->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(status.error_message().find("type"), std::string::npos) << status.error_message();
}

TEST_F(MassiveRegion, FetchRegionStopsOnCancelAndDeadline) {
    client::RegionRequest request;
    request.model = "plant";
    std::size_t pieces = 0;
    auto cancelled = m_client->fetch_region(request, [&](const client::RegionEvent& e) {
        pieces += std::holds_alternative<client::RegionPiece>(e) ? 1 : 0;
        return false;
    });
    EXPECT_EQ(cancelled.status().code(), StatusCode::cancelled) << cancelled.status().to_string();
    EXPECT_EQ(pieces, 1u);
    // A reader slower than its deadline: DEADLINE_EXCEEDED, not the whole model.
    pieces = 0;
    auto late = m_client->fetch_region(
        request,
        [&](const client::RegionEvent& e) {
            if (std::holds_alternative<client::RegionPiece>(e)) {
                ++pieces;
                std::this_thread::sleep_for(50ms);
            }
            return true;
        },
        500ms);
    EXPECT_EQ(late.status().code(), StatusCode::deadline_exceeded) << late.status().to_string();
    EXPECT_LT(pieces, m_store->summary().pieces);
    // The daemon serves on.
    auto again = m_client->fetch_region(request);
    ASSERT_TRUE(again.ok()) << again.status().to_string();
    EXPECT_EQ(again->pieces, m_store->summary().pieces);
}

TEST_F(MassiveRegion, FetchRegionStalledReaderDoesNotHoldUpOthers) {
    // A reader that takes one event and stops: the daemon waits for it (bounded), nothing else.
    auto stub = make_stub(m_daemon->address());
    grpc::ClientContext stalled;
    deadline_in(stalled, 30s);
    v1::FetchRegionRequest request;
    request.set_model("plant");
    request.set_type(v1::SCALAR_TYPE_FLOAT64);
    auto reader = stub->FetchRegion(&stalled, request);
    v1::RegionEvent first;
    ASSERT_TRUE(reader->Read(&first));
    EXPECT_TRUE(first.has_piece());
    // Meanwhile other calls are answered in full.
    for (int k = 0; k < 3; ++k) {
        auto other = m_client->fetch_region({"plant"});
        ASSERT_TRUE(other.ok()) << other.status().to_string();
        EXPECT_EQ(other->pieces, m_store->summary().pieces);
    }
    auto list = m_client->list_models();
    ASSERT_TRUE(list.ok()) << list.status().to_string();
    stalled.TryCancel();
    while (reader->Read(&first)) {
    }
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::CANCELLED);
}

// --- Snapshot of a model region ------------------------------------------------------------

// Pixel of world point p seen by `camera` in a width x height image (the renderer's look-at and
// perspective: x to the right, y down).
std::pair<int, int> project(const render::Camera& camera, const Vec3& p, int width, int height) {
    const auto normalize = [](Vec3 v) { return v * (1.0 / std::sqrt(dot(v, v))); };
    const Vec3 f = normalize(camera.target - camera.eye);
    const Vec3 r = normalize(cross(f, camera.up));
    const Vec3 u = cross(r, f);
    const Vec3 d = p - camera.eye;
    const double t = 1.0 / std::tan(camera.fov_degrees * 3.14159265358979323846 / 360.0);
    const double aspect = static_cast<double>(width) / height;
    const double nx = dot(d, r) / dot(d, f) * t / aspect;
    const double ny = dot(d, u) / dot(d, f) * t;
    return {static_cast<int>((nx + 1) / 2 * width), static_cast<int>((1 - ny) / 2 * height)};
}

// Row 0's cells 0 ([0,1]^3) and 1 ([1,2]x[0,1]x[0,1]) touch along x = 1: every triangle of cell
// 0's top face has a vertex on cell 1, so that face is red; the fitted camera sees it from above.
TEST_F(MassiveRegion, SnapshotOfARegionColoursItsTouchingPair) {
    client::RegionRequest region;
    region.model = "plant";
    region.center = {0.5, 0.5, 0.5};
    region.radius = 0.6;  // cells 0 and 1 of row 0 (row 1 starts 1.5 away)
    render::SnapshotRequest request;
    request.render.width = 160;
    request.render.height = 120;
    request.segments = false;
    auto shot = m_client->snapshot_region(region, request);
    if (shot.status().code() == StatusCode::unavailable && std::getenv("CI") == nullptr) {
        GTEST_SKIP() << "no EGL context here: " << shot.status().to_string();
    }
    ASSERT_TRUE(shot.ok()) << shot.status().to_string();
    ASSERT_TRUE(shot->region.has_value());
    EXPECT_EQ(shot->region->objects, 2u);
    EXPECT_EQ(shot->region->triangles, 24u);
    EXPECT_FALSE(shot->region->truncated);
    EXPECT_GT(shot->collision_count, 0u);
    // The same pieces FetchRegion sends for the same fields.
    auto fetched = m_client->fetch_region(region);
    ASSERT_TRUE(fetched.ok()) << fetched.status().to_string();
    EXPECT_EQ(shot->region->pieces, fetched->pieces);
    EXPECT_EQ(shot->region->triangles, fetched->triangles);
    EXPECT_EQ(shot->region->generation, fetched->generation);
    auto image = render::decode_png(shot->png);
    ASSERT_TRUE(image.ok()) << image.status().to_string();
    ASSERT_EQ(image->width, 160);
    ASSERT_EQ(image->height, 120);
    const auto [x, y] = project(shot->camera, {0.5, 0.5, 1.0}, 160, 120);
    ASSERT_TRUE(x >= 0 && x < 160 && y >= 0 && y < 120) << x << "," << y;
    const render::Rgb top = image->at(x, y);
    // A shade of red (flat shading with a headlight scales it by the facing cosine).
    EXPECT_TRUE(top.r > 80 && top.g * 4 < top.r && top.b * 4 < top.r)
        << "cell 0's top face at (" << x << "," << y << ") is " << int(top.r) << "," << int(top.g)
        << "," << int(top.b);
    EXPECT_EQ(image->at(0, 0), render::DEFAULT_BACKGROUND);
}

// With `room`: the room's view. Deleting cell 0 leaves cell 1 alone in the region: nothing
// touches, and the pixel above cell 0's top face shows the background instead of red.
TEST_F(MassiveRegion, SnapshotOfARegionShowsARoomsEdits) {
    const NamedMesh avatar{"avatar", box_mesh({-0.15, -0.15, -0.15}, {0.15, 0.15, 0.15})};
    auto alice = m_client->join_review({"snapshot-room", "plant", "alice", avatar, 0.0, true});
    ASSERT_TRUE(alice.ok()) << alice.status().to_string();
    auto& session = *alice.value();
    ASSERT_TRUE(session.delete_object(1, 0).ok());
    bool applied = false;
    for (int k = 0; k < 20 && !applied; ++k) {
        auto e = session.next(10s);
        ASSERT_TRUE(e.ok()) << e.status().to_string();
        applied = e->kind == ReviewEvent::Kind::edit_applied && e->edit.sequence == 1;
    }
    ASSERT_TRUE(applied);

    client::RegionRequest region;
    region.model = "plant";
    region.center = {0.5, 0.5, 0.5};
    region.radius = 0.6;
    render::SnapshotRequest request;
    request.render.width = 41;
    request.render.height = 41;
    request.segments = false;
    request.render.camera = render::Camera{{0.5, 0.5, 10}, {0.5, 0.5, 0}, {0, 1, 0}, 20};
    auto stored = m_client->snapshot_region(region, request);
    if (stored.status().code() == StatusCode::unavailable && std::getenv("CI") == nullptr) {
        GTEST_SKIP() << "no EGL context here: " << stored.status().to_string();
    }
    ASSERT_TRUE(stored.ok()) << stored.status().to_string();
    EXPECT_EQ(stored->region->objects, 2u);
    EXPECT_EQ(stored->region->model_version, 0u);
    auto image = render::decode_png(stored->png);
    ASSERT_TRUE(image.ok());
    const render::Rgb top = image->at(20, 20);
    EXPECT_TRUE(top.r > 80 && top.g * 4 < top.r && top.b * 4 < top.r)
        << int(top.r) << "," << int(top.g) << "," << int(top.b);

    region.room = "snapshot-room";
    auto edited = m_client->snapshot_region(region, request);
    ASSERT_TRUE(edited.ok()) << edited.status().to_string();
    EXPECT_EQ(edited->region->objects, 1u);
    EXPECT_EQ(edited->region->model_version, 1u);
    EXPECT_EQ(edited->collision_count, 0u);
    image = render::decode_png(edited->png);
    ASSERT_TRUE(image.ok());
    EXPECT_EQ(image->at(20, 20), render::DEFAULT_BACKGROUND);
}

TEST_F(MassiveRegion, SnapshotOfARegionRejectsBadRequests) {
    render::SnapshotRequest request;
    request.render.width = 8;
    request.render.height = 8;
    auto cases = bad_regions();
    cases.push_back({"nothing near", plant_region([](auto& r) {
                         r.center = {500, 500, 500};
                     }),
                     StatusCode::failed_precondition, "no piece"});
    for (const auto& k : cases) {
        SCOPED_TRACE(k.what);
        auto got = m_client->snapshot_region(k.request, request);
        EXPECT_EQ(got.status().code(), k.code) << got.status().to_string();
        EXPECT_NE(got.status().message().find(k.message), std::string::npos)
            << got.status().to_string();
    }
    // Exactly one of scene_id and model: the generated stub, since the library never sends
    // anything else.
    auto stub = make_stub(m_daemon->address());
    const auto call = [&](const v1::SnapshotRequest& raw) {
        grpc::ClientContext context;
        deadline_in(context, 10s);
        v1::SnapshotResponse response;
        return stub->Snapshot(&context, raw, &response);
    };
    v1::SnapshotRequest both;
    both.set_scene_id("some-scene");
    both.set_model("plant");
    both.set_width(8);
    both.set_height(8);
    auto status = call(both);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(status.error_message().find("not both"), std::string::npos) << status.error_message();
    v1::SnapshotRequest neither;
    neither.set_width(8);
    neither.set_height(8);
    status = call(neither);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(status.error_message().find("scene_id"), std::string::npos) << status.error_message();
    v1::SnapshotRequest scene_with_radius = neither;
    scene_with_radius.set_scene_id("some-scene");
    scene_with_radius.set_radius(2.0);
    status = call(scene_with_radius);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(status.error_message().find("radius"), std::string::npos) << status.error_message();
}

}  // namespace
}  // namespace proxima::test
