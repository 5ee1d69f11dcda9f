#pragma once
// Who a call is made as, what it may use, and how much of the daemon it may hold.
//
// The operator's token file (`--tokens FILE`, docs/server.md "Security") lists bearer tokens;
// each call sends one as the metadata `authorization: Bearer <token>`. A token names a
// *principal*: its scenes are its own (another principal's scene ids answer NOT_FOUND, exactly
// as ids that never existed, so ids do not leak), it may join only the review rooms and use only
// the models its patterns allow, and its quotas bound what all its calls hold together. Without a
// token file every call is the one anonymous principal, with no quotas (the daemon-wide limits
// still apply) and access to everything: the single-user, loopback set-up.
//
// Quota accounting is lock-free (atomic reservations): a reservation that would pass a quota
// fails with RESOURCE_EXHAUSTED naming the quota and the principal, and changes nothing, so one
// principal at its quota never affects another.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "proxima/status.hpp"

namespace proxima::server {

// 0 means unlimited.
struct Quotas {
    std::uint64_t max_scenes = 0;
    std::uint64_t max_objects = 0;          // over all the principal's scenes
    std::uint64_t max_triangles = 0;        // over all the principal's scenes
    std::uint64_t max_bytes_held = 0;       // geometry of the principal's scenes (scene_bytes())
    std::uint64_t max_bytes_in_flight = 0;  // request bytes read but not yet answered
    double max_frames_per_second = 0;       // StreamFrames frames and Query calls, bursts of 1 s
    std::uint64_t max_streams = 0;  // StreamFrames, Review, VerifyModel, FetchRegion, UploadObject
};

// Bytes of geometry a scene of this size holds, as the quota counts them: float64 vertices and
// 32-bit indices, the form the engine keeps (its hierarchies come on top, proportional to it).
inline std::uint64_t scene_bytes(std::uint64_t vertices, std::uint64_t triangles) {
    return vertices * 24 + triangles * 12;
}

// What a scene holds, in the units of the quotas.
struct Holding {
    std::uint64_t objects = 0;
    std::uint64_t triangles = 0;
    std::uint64_t bytes = 0;
};

class Principal {
  public:
    Principal(std::string name, Quotas quotas, std::vector<std::string> scenes,
              std::vector<std::string> rooms, std::vector<std::string> models, bool anonymous);

    // "" for the anonymous principal of a daemon without a token file.
    const std::string& name() const { return m_name; }
    // For log lines: the name, or "-" when anonymous.
    const std::string& log_name() const { return m_log_name; }
    const Quotas& quotas() const { return m_quotas; }
    bool anonymous() const { return m_anonymous; }

    // Glob patterns (fnmatch: `*`, `?`, `[...]`) from the token file. A scene's name must match
    // one of `scenes` for the principal to create it (stream-owned scenes have the name "").
    bool may_create_scene(const std::string& scene_name) const;
    bool may_join_room(const std::string& room) const;
    bool may_use_model(const std::string& model) const;

    // Each reserve_* either takes the whole amount or fails with RESOURCE_EXHAUSTED naming the
    // quota and changes nothing; release_* gives back what a successful reserve took.
    Status reserve_scene();
    void release_scene();
    Status reserve_stream();
    void release_stream();
    Status reserve_in_flight(std::uint64_t bytes);
    void release_in_flight(std::uint64_t bytes);
    // A scene goes from holding `from` to holding `to`: growth is checked against the quotas
    // (all three or none are taken), shrinking always succeeds.
    Status change_holding(const Holding& from, const Holding& to);
    // One frame: fails when the token bucket (max_frames_per_second tokens, refilled at that
    // rate) is empty.
    Status admit_frame();

    // Current usage, for ServerInfo, metrics and tests.
    std::uint64_t scenes() const { return m_scenes.load(); }
    std::uint64_t objects() const { return m_objects.load(); }
    std::uint64_t triangles() const { return m_triangles.load(); }
    std::uint64_t bytes_held() const { return m_bytes_held.load(); }
    std::uint64_t bytes_in_flight() const { return m_bytes_in_flight.load(); }
    std::uint64_t streams() const { return m_streams.load(); }

  private:
    Status exhausted(const char* quota, std::uint64_t would_be, std::uint64_t limit) const;

    const std::string m_name;
    const std::string m_log_name;
    const Quotas m_quotas;
    const std::vector<std::string> m_scene_patterns;
    const std::vector<std::string> m_room_patterns;
    const std::vector<std::string> m_model_patterns;
    const bool m_anonymous;

    std::atomic<std::uint64_t> m_scenes{0};
    std::atomic<std::uint64_t> m_objects{0};
    std::atomic<std::uint64_t> m_triangles{0};
    std::atomic<std::uint64_t> m_bytes_held{0};
    std::atomic<std::uint64_t> m_bytes_in_flight{0};
    std::atomic<std::uint64_t> m_streams{0};

    std::mutex m_bucket_mu;
    double m_bucket_tokens = 0;  // guarded by m_bucket_mu
    std::chrono::steady_clock::time_point m_bucket_time;
};

// The principals of a token file (or the anonymous one), looked up by the token a call presents.
class Authenticator {
  public:
    // No token file: every call is the anonymous principal.
    Authenticator();

    // Parses a token file (docs/server.md "Token file"): invalid_argument naming the entry and
    // key for anything malformed (unknown keys included: a misspelt quota must not silently
    // become unlimited), not_found/unavailable when it cannot be read.
    static StatusOr<std::unique_ptr<Authenticator>> from_file(const std::string& path);
    static StatusOr<std::unique_ptr<Authenticator>> from_json(const nlohmann::json& json,
                                                              const std::string& origin);

    bool enabled() const { return !m_by_hash.empty(); }
    std::size_t size() const { return m_principals.size(); }

    // `authorization` is the metadata value ("" when absent). UNAUTHENTICATED with a message
    // that says what to send; never echoes the token.
    StatusOr<std::shared_ptr<Principal>> authenticate(const std::string& authorization) const;

    const std::vector<std::shared_ptr<Principal>>& principals() const { return m_principals; }

  private:
    std::vector<std::shared_ptr<Principal>> m_principals;
    // SHA-256 of the token (hex) -> principal. Tokens are kept only as hashes, and the lookup
    // compares hashes, so no comparison time depends on how much of a guessed token is right.
    std::unordered_map<std::string, std::shared_ptr<Principal>> m_by_hash;
};

// Lower-case hex SHA-256 of `data` (the token file's "sha256" form; `proximad --hash-token`).
std::string sha256_hex(const std::string& data);

}  // namespace proxima::server
