// Overlap graph and schedule tests (proxima/massive/overlap_graph.hpp): overlap_edges against an
// O(n^2) brute force (touching and zero-size boxes, tolerance 0 and > 0, same-object pairs), the
// plan's invariants on random clustered graphs (every edge exactly once, weights within M, exact
// node lists, determinism), each sub-algorithm on a graph made to trigger it (one component, a
// star for high-valence removal, a grid for METIS and cut-graph levels), the precondition on
// adjacent nodes too heavy for M, the binary form (round trip, every truncation, random byte
// flips), and an LRU simulation of the cache on a plant-like layout (the seed's Fig. 8 metric:
// weight loaded per byte of geometry with edges).

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <list>
#include <map>
#include <random>
#include <set>
#include <string>
#include <unordered_map>
#include <vector>

#include "proxima/distance/bounds.hpp"
#include "proxima/massive/partition.hpp"

namespace proxima::massive {
namespace {

using Edge = std::pair<std::uint32_t, std::uint32_t>;
using Kind = LocalizedSubgraph::Kind;

Aabb box_of(Vec3 lo, Vec3 hi) {
    return {lo, hi};
}

// The contract of overlap_edges, evaluated on every pair.
std::vector<Edge> brute_edges(const std::vector<GraphNode>& nodes, double tolerance) {
    double scale = 0.0;
    for (const auto& n : nodes) {
        if (!n.box.empty()) {
            scale = std::max(scale, coordinate_scale(n.box));
        }
    }
    const double r = tolerance * (1.0 + 1e-9) + rounding_slack(scale);
    std::vector<Edge> out;
    for (std::uint32_t i = 0; i < nodes.size(); ++i) {
        for (std::uint32_t j = i + 1; j < nodes.size(); ++j) {
            if (nodes[i].object != nodes[j].object && !nodes[i].box.empty() &&
                !nodes[j].box.empty() &&
                box_squared_distance(nodes[i].box, nodes[j].box) <= r * r) {
                out.emplace_back(i, j);
            }
        }
    }
    return out;
}

// Random boxes on a coarse grid (so that many touch exactly), some of zero size, some (when
// `long_boxes`) spanning much of the scene along one axis (they cross many sweep strips).
std::vector<GraphNode> random_boxes(std::mt19937_64& rng, std::size_t n, double extent,
                                    bool long_boxes) {
    std::uniform_int_distribution<int> cell(0, static_cast<int>(extent * 4));
    std::uniform_int_distribution<int> size(0, 6);
    std::uniform_int_distribution<std::uint32_t> object(0, static_cast<std::uint32_t>(n / 3));
    std::vector<GraphNode> nodes(n);
    for (auto& node : nodes) {
        Vec3 lo{cell(rng) * 0.25, cell(rng) * 0.25, cell(rng) * 0.25};
        Vec3 hi = lo;
        if (size(rng) != 0) {  // one box in seven is a point
            hi = lo + Vec3{size(rng) * 0.25, size(rng) * 0.25, size(rng) * 0.25};
        }
        if (long_boxes && rng() % 20 == 0) {
            hi[static_cast<int>(rng() % 3)] += extent * 0.25 * static_cast<double>(size(rng));
        }
        node.box = box_of(lo, hi);
        node.weight = 1 + rng() % 100;
        node.object = object(rng);
    }
    return nodes;
}

TEST(OverlapEdges, MatchesBruteForceOnRandomBoxes) {
    for (std::uint64_t seed = 1; seed <= 12; ++seed) {
        std::mt19937_64 rng(seed);
        const std::size_t n = 100 + 50 * seed;
        auto nodes = random_boxes(rng, n, 8.0 + static_cast<double>(seed), seed % 2 == 1);
        // Shift some seeds far from the origin: the rounding slack grows with the coordinates.
        if (seed % 3 == 0) {
            for (auto& node : nodes) {
                node.box.lo += Vec3{1e4, -2e4, 3e3};
                node.box.hi += Vec3{1e4, -2e4, 3e3};
            }
        }
        for (double tol : {0.0, 0.1, 0.25, 1.0}) {
            const auto got = overlap_edges(nodes, tol);
            const auto want = brute_edges(nodes, tol);
            ASSERT_EQ(got, want) << "seed " << seed << " tolerance " << tol;
            ASSERT_TRUE(std::is_sorted(got.begin(), got.end()));
        }
    }
}

TEST(OverlapEdges, TouchingDegenerateAndSameObject) {
    std::vector<GraphNode> nodes(7);
    nodes[0] = {box_of({0, 0, 0}, {1, 1, 1}), 1, 0};
    nodes[1] = {box_of({1, 0, 0}, {2, 1, 1}), 1, 1};              // shares a face with 0
    nodes[2] = {box_of({2, 1, 1}, {2, 1, 1}), 1, 2};              // a point on a corner of 1
    nodes[3] = {box_of({0, 0, 1.5}, {1, 1, 2}), 1, 3};            // 0.5 above 0
    nodes[4] = {box_of({0.5, 0.5, 0.5}, {0.6, 0.6, 0.6}), 1, 0};  // inside 0, same object
    nodes[5] = {Aabb{}, 1, 5};                                    // empty: never an edge
    nodes[6] = {box_of({5, 5, 5}, {5, 5, 5}), 1, 6};              // far away
    const std::vector<Edge> at0 = {{0, 1}, {1, 2}};
    EXPECT_EQ(overlap_edges(nodes, 0.0), at0);
    EXPECT_EQ(overlap_edges(nodes, 0.3999), at0);
    const std::vector<Edge> at04 = {{0, 1}, {1, 2}, {1, 4}};  // 4 is 0.4 from 1 (not from 0)
    EXPECT_EQ(overlap_edges(nodes, 0.4), at04);
    const std::vector<Edge> at05 = {{0, 1}, {0, 3}, {1, 2}, {1, 3}, {1, 4}};
    EXPECT_EQ(overlap_edges(nodes, 0.5), at05);  // exactly at the tolerance: kept
    EXPECT_EQ(overlap_edges(nodes, 0.5), brute_edges(nodes, 0.5));
    EXPECT_TRUE(overlap_edges({}, 1.0).empty());
    // Every box along one line: the sweep picks another axis and still finds exactly the pairs.
    std::vector<GraphNode> line;
    for (std::uint32_t i = 0; i < 200; ++i) {
        line.push_back({box_of({0, i * 1.0, 0}, {100, i * 1.0 + 0.5, 1}), 1, i});
    }
    EXPECT_EQ(overlap_edges(line, 0.5), brute_edges(line, 0.5));
    EXPECT_EQ(overlap_edges(line, 0.5).size(), 199u);
}

TEST(OverlapEdges, LongBeamsAmongSmallParts) {
    // Beams spanning the whole scene among small parts: every beam lies in every sweep strip.
    std::mt19937_64 rng(9);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    std::vector<GraphNode> nodes;
    for (std::uint32_t i = 0; i < 3000; ++i) {
        const Vec3 p{unit(rng) * 60, unit(rng) * 60, unit(rng) * 10};
        nodes.push_back({box_of(p, p + Vec3{0.5, 0.5, 0.5}), 1, i});
    }
    for (std::uint32_t i = 0; i < 300; ++i) {
        const int axis = static_cast<int>(i % 3);
        Vec3 p{unit(rng) * 60, unit(rng) * 60, unit(rng) * 10};
        p[axis] = 0;
        Vec3 q = p + Vec3{0.3, 0.3, 0.3};
        q[axis] = 60;
        nodes.push_back({box_of(p, q), 1, 3000 + i / 2});
    }
    for (double tol : {0.0, 0.2}) {
        EXPECT_EQ(overlap_edges(nodes, tol), brute_edges(nodes, tol)) << tol;
    }
}

// Clustered random boxes with about `valence` neighbours each.
std::vector<GraphNode> clustered_boxes(std::mt19937_64& rng, std::size_t n, std::size_t clusters,
                                       double box_size, double spread) {
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    std::normal_distribution<double> around(0.0, spread);
    const double side = std::cbrt(static_cast<double>(clusters)) * spread * 6.0;
    std::vector<Vec3> centre(clusters);
    for (auto& c : centre) {
        c = {unit(rng) * side, unit(rng) * side, unit(rng) * side};
    }
    std::vector<GraphNode> nodes(n);
    for (std::size_t i = 0; i < n; ++i) {
        const Vec3 c = centre[rng() % clusters];
        const Vec3 p{c.x + around(rng), c.y + around(rng), c.z + around(rng)};
        const Vec3 s{box_size * (0.2 + unit(rng)), box_size * (0.2 + unit(rng)),
                     box_size * (0.2 + unit(rng))};
        nodes[i].box = box_of(p, p + s);
        nodes[i].weight = 1000 + rng() % 9000;
        nodes[i].object = static_cast<std::uint32_t>(i / 2);  // pairs of pieces share an object
    }
    return nodes;
}

TEST(OverlapEdges, HundredThousandNodesAreFast) {
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    const std::size_t n = 100000;
    std::vector<GraphNode> nodes(n);
    for (std::size_t i = 0; i < n; ++i) {
        const Vec3 p{unit(rng) * 100, unit(rng) * 100, unit(rng) * 25};
        nodes[i] = {box_of(p, p + Vec3{1.5, 1.5, 1.5}), 1, static_cast<std::uint32_t>(i)};
    }
    const auto t0 = std::chrono::steady_clock::now();
    const auto edges = overlap_edges(nodes, 0.0);
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("overlap_edges: %zu nodes, %zu edges in %.3f s\n", n, edges.size(), s);
    EXPECT_GT(edges.size(), 500000u);
    EXPECT_LT(s, 20.0);
    // Spot-check against brute force on the first nodes' neighbourhoods.
    std::set<Edge> got(edges.begin(), edges.end());
    double scale = 0.0;
    for (const auto& node : nodes) {
        scale = std::max(scale, coordinate_scale(node.box));
    }
    const double r = rounding_slack(scale);
    for (std::uint32_t i = 0; i < 50; ++i) {
        for (std::uint32_t j = i + 1; j < n; ++j) {
            const bool near = box_squared_distance(nodes[i].box, nodes[j].box) <= r * r;
            ASSERT_EQ(near, got.count({i, j}) == 1) << i << " " << j;
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Plans

// Every invariant of a plan. Returns the number of high-valence subgraphs.
void check_schedule(const std::vector<GraphNode>& nodes, double tol, std::uint64_t M,
                    const Schedule& s) {
    const auto edges = overlap_edges(nodes, tol);
    ASSERT_EQ(s.edge_count, edges.size());
    ASSERT_EQ(s.node_count, nodes.size());
    ASSERT_EQ(s.cache_bytes, M);
    std::map<Edge, int> seen;
    std::uint32_t max_level = 0;
    for (std::size_t i = 0; i < s.subgraphs.size(); ++i) {
        const auto& g = s.subgraphs[i];
        ASSERT_FALSE(g.edges.empty()) << "subgraph " << i;
        max_level = std::max(max_level, g.level);
        std::set<std::uint32_t> touched;
        for (const auto& e : g.edges) {
            ASSERT_LT(e.first, e.second);
            ++seen[e];
            touched.insert(e.first);
            touched.insert(e.second);
        }
        const std::set<std::uint32_t> listed(g.nodes.begin(), g.nodes.end());
        ASSERT_EQ(listed.size(), g.nodes.size()) << "subgraph " << i << " lists a node twice";
        ASSERT_EQ(listed, touched) << "subgraph " << i;
        std::uint64_t weight = 0;
        for (auto v : g.nodes) {
            weight += nodes[v].weight;
        }
        ASSERT_EQ(g.weight, weight);
        if (g.kind != Kind::high_valence) {
            ASSERT_LE(g.weight, M) << "subgraph " << i;
            continue;
        }
        // High-valence subgraph: the resident nodes come first in `nodes` and every edge touches
        // one of them; their weight plus any one other node fits M.
        std::size_t k = 0;
        std::uint64_t resident = 0;
        for (; k < g.nodes.size(); ++k) {
            const std::set<std::uint32_t> prefix(g.nodes.begin(),
                                                 g.nodes.begin() + static_cast<std::ptrdiff_t>(k));
            if (std::all_of(g.edges.begin(), g.edges.end(), [&](const Edge& e) {
                    return prefix.count(e.first) + prefix.count(e.second) > 0;
                })) {
                break;
            }
            resident += nodes[g.nodes[k]].weight;
        }
        ASSERT_GT(k, 0u);
        ASSERT_LT(k, g.nodes.size());
        for (std::size_t j = k; j < g.nodes.size(); ++j) {
            ASSERT_LE(resident + nodes[g.nodes[j]].weight, M) << "subgraph " << i;
        }
    }
    ASSERT_EQ(seen.size(), edges.size());
    for (const auto& e : edges) {
        ASSERT_EQ(seen[e], 1) << e.first << "-" << e.second;
    }
    ASSERT_EQ(s.levels, max_level);
}

std::size_t count_kind(const Schedule& s, Kind kind) {
    return static_cast<std::size_t>(
        std::count_if(s.subgraphs.begin(), s.subgraphs.end(),
                      [&](const LocalizedSubgraph& g) { return g.kind == kind; }));
}

void expect_same(const Schedule& a, const Schedule& b) {
    EXPECT_EQ(a.tolerance, b.tolerance);
    EXPECT_EQ(a.cache_bytes, b.cache_bytes);
    EXPECT_EQ(a.node_count, b.node_count);
    EXPECT_EQ(a.edge_count, b.edge_count);
    EXPECT_EQ(a.components, b.components);
    EXPECT_EQ(a.high_valence_nodes, b.high_valence_nodes);
    EXPECT_EQ(a.metis_calls, b.metis_calls);
    EXPECT_EQ(a.levels, b.levels);
    ASSERT_EQ(a.subgraphs.size(), b.subgraphs.size());
    for (std::size_t i = 0; i < a.subgraphs.size(); ++i) {
        EXPECT_EQ(a.subgraphs[i].kind, b.subgraphs[i].kind);
        EXPECT_EQ(a.subgraphs[i].level, b.subgraphs[i].level);
        EXPECT_EQ(a.subgraphs[i].nodes, b.subgraphs[i].nodes);
        EXPECT_EQ(a.subgraphs[i].edges, b.subgraphs[i].edges);
        EXPECT_EQ(a.subgraphs[i].weight, b.subgraphs[i].weight);
    }
}

std::uint64_t total_weight(const std::vector<GraphNode>& nodes) {
    std::uint64_t w = 0;
    for (const auto& n : nodes) {
        w += n.weight;
    }
    return w;
}

TEST(PlanSchedule, RandomClusteredGraphsKeepEveryInvariant) {
    for (std::uint64_t seed = 1; seed <= 6; ++seed) {
        std::mt19937_64 rng(seed);
        const auto nodes = clustered_boxes(rng, 600 + 200 * seed, 5 + seed, 1.0, 2.0);
        const std::uint64_t W = total_weight(nodes);
        for (double fraction : {0.02, 0.05, 0.1, 0.3, 2.0}) {
            const auto M = static_cast<std::uint64_t>(static_cast<double>(W) * fraction);
            const double tol = seed % 2 == 0 ? 0.0 : 0.3;
            auto plan = plan_schedule(nodes, tol, M);
            ASSERT_TRUE(plan.ok()) << plan.status().to_string();
            check_schedule(nodes, tol, M, plan.value());
            if (HasFatalFailure()) {
                ADD_FAILURE() << "seed " << seed << " fraction " << fraction;
                return;
            }
            auto again = plan_schedule(nodes, tol, M);
            ASSERT_TRUE(again.ok());
            expect_same(plan.value(), again.value());
            EXPECT_EQ(serialize_schedule(plan.value()), serialize_schedule(again.value()));
            if (fraction > 1.0) {
                EXPECT_EQ(count_kind(plan.value(), Kind::component), plan->subgraphs.size());
                EXPECT_EQ(plan->subgraphs.size(), plan->components);
            }
        }
    }
}

TEST(PlanSchedule, SmallGraphIsOneComponentSubgraph) {
    std::vector<GraphNode> nodes;
    for (std::uint32_t i = 0; i < 10; ++i) {  // a chain 0-1-...-9, and an isolated node
        nodes.push_back({box_of({i * 1.0, 0, 0}, {i + 1.0, 1, 1}), 10, i});
    }
    nodes.push_back({box_of({50, 50, 50}, {51, 51, 51}), 10, 99});
    auto plan = plan_schedule(nodes, 0.0, 1000);
    ASSERT_TRUE(plan.ok()) << plan.status().to_string();
    ASSERT_EQ(plan->subgraphs.size(), 1u);
    const auto& g = plan->subgraphs[0];
    EXPECT_EQ(g.kind, Kind::component);
    EXPECT_EQ(g.level, 0u);
    EXPECT_EQ(g.edges.size(), 9u);
    EXPECT_EQ(g.nodes.size(), 10u);  // the isolated node is in no subgraph
    EXPECT_EQ(g.weight, 100u);
    EXPECT_EQ(plan->components, 1u);
    EXPECT_EQ(plan->levels, 0u);
    check_schedule(nodes, 0.0, 1000, plan.value());
    // No edge at all: an empty plan.
    auto none = plan_schedule({nodes.back()}, 0.0, 1000);
    ASSERT_TRUE(none.ok());
    EXPECT_TRUE(none->subgraphs.empty());
    EXPECT_EQ(none->edge_count, 0u);
}

TEST(PlanSchedule, EdgesFollowTheBreadthFirstValenceOrder) {
    // Hub 0 with leaves 1, 2, 3 and a tail 4-5-6: valences 4, 1, 1, 1, 2, 2, 1.
    const std::vector<GraphNode> nodes = {
        {box_of({0, 0, 0}, {10, 1, 1}), 5, 0},  {box_of({1, 1, 0}, {1.5, 2, 1}), 5, 1},
        {box_of({3, 1, 0}, {3.5, 2, 1}), 5, 2}, {box_of({5, 1, 0}, {5.5, 2, 1}), 5, 3},
        {box_of({7, 1, 0}, {7.5, 2, 1}), 5, 4}, {box_of({7, 2, 0}, {7.5, 3, 1}), 5, 5},
        {box_of({7, 3, 0}, {7.5, 4, 1}), 5, 6},
    };
    auto plan = plan_schedule(nodes, 0.0, 1000);
    ASSERT_TRUE(plan.ok()) << plan.status().to_string();
    ASSERT_EQ(plan->subgraphs.size(), 1u);
    const std::vector<Edge> order = {{0, 4}, {0, 1}, {0, 2}, {0, 3}, {4, 5}, {5, 6}};
    EXPECT_EQ(plan->subgraphs[0].edges, order);
    const std::vector<std::uint32_t> first_touch = {0, 4, 1, 2, 3, 5, 6};
    EXPECT_EQ(plan->subgraphs[0].nodes, first_touch);
}

TEST(PlanSchedule, HeavyCliqueNeedsManyLevels) {
    // 12 mutually overlapping nodes of ~0.45 M: at most two fit together, so every subgraph is
    // a single edge or two, spread over several cut-graph levels.
    std::vector<GraphNode> nodes;
    for (std::uint32_t i = 0; i < 12; ++i) {
        nodes.push_back({box_of({i * 0.01, 0, 0}, {1 + i * 0.01, 1, 1}), 450 + i, i});
    }
    auto plan = plan_schedule(nodes, 0.0, 1000);
    ASSERT_TRUE(plan.ok()) << plan.status().to_string();
    check_schedule(nodes, 0.0, 1000, plan.value());
    EXPECT_EQ(plan->edge_count, 66u);
    EXPECT_GE(plan->levels, 1u);
    // Zero weights and a budget that holds everything: one subgraph per component.
    for (auto& n : nodes) {
        n.weight = 0;
    }
    auto light = plan_schedule(nodes, 0.0, 1);
    ASSERT_TRUE(light.ok());
    EXPECT_EQ(light->subgraphs.size(), 1u);
    check_schedule(nodes, 0.0, 1, light.value());
}

TEST(PlanSchedule, StarTriggersHighValence) {
    // A hub touching 200 small boxes that do not touch each other.
    std::vector<GraphNode> nodes;
    nodes.push_back({box_of({0, 0, 0}, {100, 1, 1}), 500, 0});
    for (std::uint32_t i = 0; i < 200; ++i) {
        const double x = i * 0.5;
        nodes.push_back({box_of({x, 1, 0}, {x + 0.2, 2, 1}), 10 + i % 7, i + 1});
    }
    const std::uint64_t M = 600;  // the whole star weighs ~3300
    auto plan = plan_schedule(nodes, 0.0, M);
    ASSERT_TRUE(plan.ok()) << plan.status().to_string();
    check_schedule(nodes, 0.0, M, plan.value());
    ASSERT_EQ(count_kind(plan.value(), Kind::high_valence), 1u);
    EXPECT_EQ(plan->subgraphs.size(), 1u);
    EXPECT_EQ(plan->high_valence_nodes, 1u);
    EXPECT_EQ(plan->subgraphs[0].nodes.front(), 0u);  // the hub is the resident node
    EXPECT_EQ(plan->subgraphs[0].edges.size(), 200u);
    EXPECT_GT(plan->subgraphs[0].weight, M);  // the documented exception
}

TEST(PlanSchedule, GridTriggersPartitionsAndCutLevels) {
    // A 40 x 40 grid of unit boxes, each touching its 8 neighbours: no high-valence node.
    std::vector<GraphNode> nodes;
    for (std::uint32_t i = 0; i < 40; ++i) {
        for (std::uint32_t j = 0; j < 40; ++j) {
            nodes.push_back({box_of({i * 1.0, j * 1.0, 0}, {i + 1.0, j + 1.0, 1}),
                             100 + (i * 7 + j * 3) % 50, i * 40 + j});
        }
    }
    const std::uint64_t M = total_weight(nodes) / 10;
    auto plan = plan_schedule(nodes, 0.0, M);
    ASSERT_TRUE(plan.ok()) << plan.status().to_string();
    check_schedule(nodes, 0.0, M, plan.value());
    EXPECT_GT(plan->metis_calls, 0u);
    EXPECT_GE(plan->levels, 1u);
    EXPECT_GE(count_kind(plan.value(), Kind::partition), 10u);
    EXPECT_EQ(plan->high_valence_nodes, 0u);
    bool cut_level = false;
    for (const auto& g : plan->subgraphs) {
        cut_level = cut_level || g.level >= 1;
    }
    EXPECT_TRUE(cut_level);
}

TEST(PlanSchedule, HeavyAdjacentNodesAreAPreconditionFailure) {
    std::vector<GraphNode> nodes = {
        {box_of({0, 0, 0}, {1, 1, 1}), 10, 0},
        {box_of({5, 0, 0}, {6, 1, 1}), 70, 1},
        {box_of({6, 0, 0}, {7, 1, 1}), 60, 2},
    };
    auto plan = plan_schedule(nodes, 0.0, 100);
    ASSERT_FALSE(plan.ok());
    EXPECT_EQ(plan.status().code(), StatusCode::failed_precondition);
    const auto& m = plan.status().message();
    for (const char* part : {"1 (70 bytes)", "2 (60 bytes)", "M = 100", "--max-piece-bytes"}) {
        EXPECT_NE(m.find(part), std::string::npos) << m;
    }
    EXPECT_TRUE(plan_schedule(nodes, 0.0, 130).ok());
    // A node heavier than M but isolated needs no test: fine.
    nodes.push_back({box_of({50, 0, 0}, {51, 1, 1}), 1000, 3});
    EXPECT_TRUE(plan_schedule(nodes, 0.0, 130).ok());
    // Overflowing sums are still caught.
    nodes[1].weight = ~0ull - 5;
    EXPECT_EQ(plan_schedule(nodes, 0.0, 130).status().code(), StatusCode::failed_precondition);
}

TEST(PlanSchedule, BadArguments) {
    const std::vector<GraphNode> nodes = {{box_of({0, 0, 0}, {1, 1, 1}), 1, 0}};
    EXPECT_EQ(plan_schedule(nodes, -1.0, 10).status().code(), StatusCode::invalid_argument);
    EXPECT_EQ(plan_schedule(nodes, std::nan(""), 10).status().code(), StatusCode::invalid_argument);
    EXPECT_EQ(plan_schedule(nodes, 0.0, 0).status().code(), StatusCode::invalid_argument);
}

TEST(PlanSchedule, ReportsProgress) {
    std::mt19937_64 rng(3);
    const auto nodes = clustered_boxes(rng, 2000, 8, 1.0, 2.0);
    std::vector<Progress> seen;
    auto plan = plan_schedule(nodes, 0.0, total_weight(nodes) / 8,
                              [&](const Progress& p) { seen.push_back(p); });
    ASSERT_TRUE(plan.ok());
    ASSERT_GE(seen.size(), 2u);
    for (std::size_t i = 0; i < seen.size(); ++i) {
        EXPECT_EQ(seen[i].step, "partitioning");
        EXPECT_EQ(seen[i].unit, "edges");
        if (i > 0) {
            EXPECT_GE(seen[i].done, seen[i - 1].done);
        }
    }
    EXPECT_EQ(seen.back().done, plan->edge_count);
    EXPECT_EQ(seen.back().total, plan->edge_count);
}

// ---------------------------------------------------------------------------------------------
// Binary form

Schedule sample_schedule() {
    std::mt19937_64 rng(11);
    const auto nodes = clustered_boxes(rng, 400, 4, 1.0, 2.0);
    auto plan = plan_schedule(nodes, 0.1, total_weight(nodes) / 6);
    EXPECT_TRUE(plan.ok());
    return std::move(plan).value();
}

TEST(ScheduleBytes, RoundTrip) {
    const Schedule s = sample_schedule();
    ASSERT_GT(s.subgraphs.size(), 2u);
    const std::string bytes = serialize_schedule(s);
    auto back = deserialize_schedule(bytes);
    ASSERT_TRUE(back.ok()) << back.status().to_string();
    expect_same(s, back.value());
    EXPECT_EQ(serialize_schedule(back.value()), bytes);
    // The empty plan too.
    Schedule empty;
    empty.cache_bytes = 5;
    auto e = deserialize_schedule(serialize_schedule(empty));
    ASSERT_TRUE(e.ok()) << e.status().to_string();
    expect_same(empty, e.value());
}

TEST(ScheduleBytes, MalformedBytesAreRejectedNeverCrash) {
    const Schedule s = sample_schedule();
    const std::string bytes = serialize_schedule(s);
    for (std::size_t len = 0; len < bytes.size(); ++len) {
        auto r = deserialize_schedule(std::string_view(bytes).substr(0, len));
        ASSERT_FALSE(r.ok()) << len;
        ASSERT_EQ(r.status().code(), StatusCode::invalid_argument) << len;
    }
    EXPECT_FALSE(deserialize_schedule(bytes + "x").ok());
    std::mt19937_64 rng(5);
    int accepted = 0;
    for (int trial = 0; trial < 3000; ++trial) {
        std::string m = bytes;
        const int flips = 1 + trial % 4;
        for (int f = 0; f < flips; ++f) {
            m[rng() % m.size()] = static_cast<char>(rng() & 0xff);
        }
        auto r = deserialize_schedule(m);
        if (r.ok()) {
            ++accepted;  // a flip in a statistic or a weight: still structurally valid
            for (const auto& g : r->subgraphs) {
                for (const auto& [a, b] : g.edges) {
                    ASSERT_LT(a, b);
                    ASSERT_LT(b, r->node_count);
                }
            }
        } else {
            ASSERT_EQ(r.status().code(), StatusCode::invalid_argument);
        }
    }
    std::printf("random flips: %d of 3000 decoded to a structurally valid schedule\n", accepted);
    // Huge counts in a short buffer: rejected without allocating them.
    std::string huge = bytes.substr(0, 8 + 4 + 8 * 8 + 4);
    for (int k = 0; k < 8; ++k) {
        huge.push_back('\xff');
    }
    EXPECT_EQ(deserialize_schedule(huge).status().code(), StatusCode::invalid_argument);
}

// ---------------------------------------------------------------------------------------------
// Cache simulation (seed Fig. 8): an LRU cache of budget M loads the nodes of each edge in plan
// order; the metric is the weight loaded over the weight of the nodes that have edges.

struct LruResult {
    std::uint64_t loaded = 0;
    std::uint64_t needed = 0;
    double ratio() const { return needed == 0 ? 0.0 : double(loaded) / double(needed); }
};

LruResult simulate_lru(const std::vector<GraphNode>& nodes, const Schedule& s, std::uint64_t M) {
    std::list<std::uint32_t> lru;  // front: most recent
    std::unordered_map<std::uint32_t, std::list<std::uint32_t>::iterator> where;
    std::uint64_t used = 0;
    LruResult r;
    std::vector<char> has_edge(nodes.size(), 0);
    auto touch = [&](std::uint32_t v, std::uint32_t keep) {
        if (auto it = where.find(v); it != where.end()) {
            lru.splice(lru.begin(), lru, it->second);
            return;
        }
        while (used + nodes[v].weight > M && !lru.empty()) {
            auto victim = std::prev(lru.end());
            if (*victim == keep) {
                if (victim == lru.begin()) {
                    break;
                }
                victim = std::prev(victim);
            }
            used -= nodes[*victim].weight;
            where.erase(*victim);
            lru.erase(victim);
        }
        lru.push_front(v);
        where[v] = lru.begin();
        used += nodes[v].weight;
        r.loaded += nodes[v].weight;
    };
    for (const auto& g : s.subgraphs) {
        for (const auto& [a, b] : g.edges) {
            touch(a, UINT32_MAX);
            touch(b, a);
            has_edge[a] = has_edge[b] = 1;
        }
    }
    for (std::size_t v = 0; v < nodes.size(); ++v) {
        r.needed += has_edge[v] != 0 ? nodes[v].weight : 0;
    }
    return r;
}

// A plant-like layout: equipment areas on a grid over a few floors. Each area has a floor grating
// (one object cut into pieces), tanks and pumps standing on it, pipe runs (polylines of
// axis-aligned segments, one object each, cut into pieces of length <= 3) leaving the equipment
// and crossing each other, and links (beams and pipes) to the neighbouring areas and the floor
// above; piece weights from triangle counts spread over two decades.
std::vector<GraphNode> plant_layout(std::uint64_t seed, int grid, int floors) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    std::vector<GraphNode> nodes;
    std::uint32_t object = 0;
    auto weight = [&](double scale) {
        const double tris = scale * 200.0 * std::pow(100.0, unit(rng));
        return piece_weight(static_cast<std::uint64_t>(tris / 2), static_cast<std::uint64_t>(tris));
    };
    auto add = [&](Vec3 lo, Vec3 hi, double scale) {
        nodes.push_back({box_of(cwise_min(lo, hi), cwise_max(lo, hi)), weight(scale), object});
    };
    // A straight pipe segment from a to b of radius r, cut into pieces of length <= 3 (same
    // object).
    auto segment = [&](Vec3 a, Vec3 b, double r) {
        const int pieces = std::max(1, static_cast<int>(std::ceil(norm(b - a) / 3.0)));
        const Vec3 rr{r, r, r};
        for (int k = 0; k < pieces; ++k) {
            const Vec3 p = a + (b - a) * (double(k) / pieces);
            const Vec3 q = a + (b - a) * (double(k + 1) / pieces);
            add(cwise_min(p, q) - rr, cwise_max(p, q) + rr, 0.5);
        }
    };
    const double spacing = 14.0;
    const double storey = 6.0;
    for (int f = 0; f < floors; ++f) {
        for (int i = 0; i < grid; ++i) {
            for (int j = 0; j < grid; ++j) {
                const Vec3 c{i * spacing, j * spacing, f * storey};
                // Floor grating, 3 x 3 pieces of one object.
                for (int a = 0; a < 3; ++a) {
                    for (int b = 0; b < 3; ++b) {
                        const Vec3 lo = c + Vec3{-6 + 4.0 * a, -6 + 4.0 * b, -0.2};
                        add(lo, lo + Vec3{4, 4, 0.2}, 0.3);
                    }
                }
                ++object;
                // Equipment standing on the grating.
                std::vector<Aabb> equipment;
                const int count = 3 + static_cast<int>(rng() % 4);
                for (int e = 0; e < count; ++e) {
                    const Vec3 p = c + Vec3{unit(rng) * 8 - 5, unit(rng) * 8 - 5, 0};
                    const Vec3 s{1 + unit(rng) * 2, 1 + unit(rng) * 2, 1 + unit(rng) * 3};
                    add(p, p + s, 3.0);
                    ++object;
                    equipment.push_back(nodes.back().box);
                }
                // Pipe runs leaving the equipment: 2-4 segments, turning at right angles.
                const int runs = 20 + static_cast<int>(rng() % 16);
                for (int k = 0; k < runs; ++k) {
                    const Aabb& from = equipment[rng() % equipment.size()];
                    Vec3 a{from.hi.x, from.lo.y + unit(rng) * (from.hi.y - from.lo.y),
                           from.lo.z + unit(rng) * (from.hi.z - from.lo.z)};
                    const double r = 0.05 + unit(rng) * 0.2;
                    const int turns = 2 + static_cast<int>(rng() % 3);
                    int axis = 0;
                    for (int t = 0; t < turns; ++t) {
                        Vec3 b = a;
                        b[axis] += (unit(rng) < 0.3 ? -1 : 1) * (1 + unit(rng) * 5);
                        b.z = std::clamp(b.z, c.z + r,
                                         c.z + storey - 0.5);  // may rest on the grating
                        segment(a, b, r);
                        a = b;
                        axis = (axis + 1 + static_cast<int>(rng() % 2)) % 3;
                    }
                    ++object;
                }
                // Links: a beam and a pipe to the next area along x and y, a column upwards.
                for (int d = 0; d < 2; ++d) {
                    if ((d == 0 ? i : j) + 1 >= grid) {
                        continue;
                    }
                    Vec3 dir{d == 0 ? 1.0 : 0.0, d == 0 ? 0.0 : 1.0, 0.0};
                    Vec3 side{d == 0 ? 0.0 : 1.0, d == 0 ? 1.0 : 0.0, 0.0};
                    // The beam runs under both gratings, the pipe rests on them.
                    const Vec3 a = c + dir * 4.0 + side * 3.0 + Vec3{0, 0, -0.5};
                    const Vec3 b = c + dir * (spacing - 4.0) + side * 3.0 + Vec3{0, 0, -0.2};
                    add(a, b + side * 0.3, 0.2);
                    ++object;
                    segment(c + dir * 4.0 + side * 1.0 + Vec3{0, 0, 0.15},
                            c + dir * (spacing - 4.0) + side * 1.0 + Vec3{0, 0, 0.15}, 0.15);
                    ++object;
                }
                if (f + 1 < floors) {
                    add(c + Vec3{-6, -6, -0.2}, c + Vec3{-5.7, -5.7, storey},
                        0.2);  // grating to grating
                    ++object;
                }
            }
        }
    }
    return nodes;
}

void print_plan(const char* label, const Schedule& s, const LruResult& r, double seconds) {
    std::printf(
        "%s: %llu edges, %llu components, %zu subgraphs (%zu component, %zu high-valence, %zu "
        "partition), "
        "levels %u, metis calls %llu, hv nodes %llu, plan %.3f s, loads per node byte %.3f\n",
        label, static_cast<unsigned long long>(s.edge_count),
        static_cast<unsigned long long>(s.components), s.subgraphs.size(),
        count_kind(s, Kind::component), count_kind(s, Kind::high_valence),
        count_kind(s, Kind::partition), s.levels, static_cast<unsigned long long>(s.metis_calls),
        static_cast<unsigned long long>(s.high_valence_nodes), seconds, r.ratio());
}

TEST(CacheSimulation, PlantLayoutLoadsEachByteFewTimes) {
    const auto nodes = plant_layout(1, 8, 3);
    const std::uint64_t W = total_weight(nodes);
    std::printf("plant layout: %zu nodes, total weight %.1f MB\n", nodes.size(), W / 1e6);
    for (double fraction : {0.05, 0.10, 0.25, 0.50}) {
        const auto M = static_cast<std::uint64_t>(static_cast<double>(W) * fraction);
        const auto t0 = std::chrono::steady_clock::now();
        auto plan = plan_schedule(nodes, 0.05, M);
        const double s =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        ASSERT_TRUE(plan.ok()) << plan.status().to_string();
        check_schedule(nodes, 0.05, M, plan.value());
        const auto r = simulate_lru(nodes, plan.value(), M);
        char label[64];
        std::snprintf(label, sizeof label, "M = %2.0f%%", fraction * 100);
        print_plan(label, plan.value(), r, s);
        if (fraction == 0.10) {
            EXPECT_LE(r.ratio(), 3.0);
        }
        if (fraction == 0.50) {
            EXPECT_LE(r.ratio(), 2.0);
        }
    }
}

// Dense overlapping clusters: ~20K nodes, ~200K edges (also the timing of plan_schedule).
TEST(CacheSimulation, DenseClustersTwentyThousandNodes) {
    std::mt19937_64 rng(21);
    const auto nodes = clustered_boxes(rng, 20000, 4, 2.3, 6.0);
    const std::uint64_t W = total_weight(nodes);
    for (double fraction : {0.05, 0.10, 0.25, 0.50}) {
        const auto M = static_cast<std::uint64_t>(static_cast<double>(W) * fraction);
        const auto t0 = std::chrono::steady_clock::now();
        auto plan = plan_schedule(nodes, 0.0, M);
        const double s =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        ASSERT_TRUE(plan.ok()) << plan.status().to_string();
        const auto r = simulate_lru(nodes, plan.value(), M);
        char label[64];
        std::snprintf(label, sizeof label, "20K dense, M = %2.0f%%", fraction * 100);
        print_plan(label, plan.value(), r, s);
        EXPECT_LT(s, 30.0);
        if (fraction == 0.10) {
            EXPECT_LE(r.ratio(), 2.0);
            check_schedule(nodes, 0.0, M, plan.value());
        }
    }
}

}  // namespace
}  // namespace proxima::massive
