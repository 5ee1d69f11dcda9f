// A review member's Outbox: ordered events in order up to a bound, peer updates coalesced to each
// peer's newest and sent together at most once per peer interval, never ahead of nothing and
// never holding an ordered event back.

#include <gtest/gtest.h>

#include <chrono>
#include <string>

#include "rooms.hpp"

using namespace proxima;
using namespace proxima::server;
using namespace std::chrono_literals;

namespace {

PeerEvent peer(const std::string& member, std::uint64_t sequence) {
    PeerEvent e;
    e.member = member;
    e.pose.has_pose = true;
    e.pose.sequence = sequence;
    return e;
}

std::vector<std::string> peers_of(const Outbox::Next& next) {
    std::vector<std::string> out;
    for (const auto& p : next.peers) {
        out.push_back(p.member + "#" + std::to_string(p.pose.sequence));
    }
    return out;
}

}  // namespace

TEST(Outbox, PeerUpdatesGoTogetherAtMostOncePerInterval) {
    Outbox box(8, 20ms);
    const auto t0 = Outbox::Clock::now();
    box.push_peer(peer("ann", 1));
    box.push_peer(peer("bob", 1));
    box.push_peer(peer("ann", 2));  // replaces ann#1, goes to the end
    // The first batch goes at once (no batch went before), oldest first, one per member.
    ASSERT_TRUE(box.peers_due(t0));
    auto next = box.pop(t0);
    ASSERT_TRUE(next && !next->item);
    EXPECT_EQ(peers_of(*next), (std::vector<std::string>{"bob#1", "ann#2"}));
    EXPECT_TRUE(box.empty());
    // The next updates wait for the interval.
    box.push_peer(peer("bob", 2));
    box.push_peer(peer("cy", 1));
    EXPECT_FALSE(box.peers_due(t0 + 5ms));
    EXPECT_FALSE(box.pop(t0 + 5ms).has_value());
    EXPECT_EQ(box.size(), 2u);
    box.push_peer(peer("bob", 3));
    EXPECT_FALSE(box.peers_due(t0 + 19ms));
    ASSERT_TRUE(box.peers_due(t0 + 20ms));
    next = box.pop(t0 + 20ms);
    ASSERT_TRUE(next && !next->item);
    EXPECT_EQ(peers_of(*next), (std::vector<std::string>{"cy#1", "bob#3"}));
    EXPECT_FALSE(box.pop(t0 + 20ms).has_value());
    EXPECT_FALSE(box.peers_due(t0 + 60ms)) << "nothing pending";
}

TEST(Outbox, OrderedEventsNeverWaitAndHeldUpdatesGoAheadOfThem) {
    Outbox box(8, 20ms);
    const auto t0 = Outbox::Clock::now();
    box.push_peer(peer("ann", 1));
    ASSERT_TRUE(box.pop(t0).has_value());  // starts an interval
    box.push_peer(peer("ann", 2));
    box.push_peer(peer("bob", 1));
    EXPECT_FALSE(box.pop(t0 + 1ms).has_value());
    ASSERT_TRUE(box.push(MemberJoinedEvent{"cy"}, false));
    box.push_peer(peer("dee", 1));  // after the ordered event: stays behind it
    // Inside the interval, the held updates go at once because an ordered event waits.
    auto next = box.pop(t0 + 2ms);
    ASSERT_TRUE(next && !next->item);
    EXPECT_EQ(peers_of(*next), (std::vector<std::string>{"ann#2", "bob#1"}));
    next = box.pop(t0 + 2ms);
    ASSERT_TRUE(next && next->item);
    EXPECT_TRUE(std::holds_alternative<MemberJoinedEvent>(next->item->event));
    EXPECT_EQ(box.ordered(), 0u);
    // dee's update started no new wait of its own: the last batch went at +2 ms.
    EXPECT_FALSE(box.pop(t0 + 21ms).has_value());
    next = box.pop(t0 + 22ms);
    ASSERT_TRUE(next && !next->item);
    EXPECT_EQ(peers_of(*next), (std::vector<std::string>{"dee#1"}));
}

TEST(Outbox, WithoutAnIntervalUpdatesGoAtOnceAndTheBoundHolds) {
    Outbox box(2);
    const auto t0 = Outbox::Clock::now();
    box.push_peer(peer("ann", 1));
    auto next = box.pop(t0);
    ASSERT_TRUE(next && !next->item);
    EXPECT_EQ(peers_of(*next), (std::vector<std::string>{"ann#1"}));
    box.push_peer(peer("ann", 2));
    next = box.pop(t0);  // the same instant: no wait
    ASSERT_TRUE(next && !next->item);
    EXPECT_EQ(peers_of(*next), (std::vector<std::string>{"ann#2"}));
    // Ordered events: at most two wait; a left member's update is dropped.
    EXPECT_TRUE(box.push(MemberJoinedEvent{"bob"}, false));
    box.push_peer(peer("bob", 1));
    box.drop_peer("bob");
    EXPECT_TRUE(box.push(MemberLeftEvent{"bob"}, false));
    EXPECT_FALSE(box.push(MemberJoinedEvent{"cy"}, false)) << "over the bound";
    EXPECT_EQ(box.size(), 2u);
    next = box.pop(t0);
    ASSERT_TRUE(next && next->item);
    EXPECT_TRUE(std::holds_alternative<MemberJoinedEvent>(next->item->event));
    next = box.pop(t0);
    ASSERT_TRUE(next && next->item);
    EXPECT_TRUE(std::holds_alternative<MemberLeftEvent>(next->item->event));
    EXPECT_FALSE(box.pop(t0).has_value());
}
