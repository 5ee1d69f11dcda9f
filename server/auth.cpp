#include "auth.hpp"

#include <fnmatch.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <set>
#include <utility>

#include <openssl/evp.h>
#include <nlohmann/json.hpp>

namespace proxima::server {

namespace {

bool matches_any(const std::vector<std::string>& patterns, const std::string& name) {
    return std::any_of(patterns.begin(), patterns.end(), [&](const std::string& p) {
        return fnmatch(p.c_str(), name.c_str(), 0) == 0;
    });
}

// Takes `amount` from a counter unless that would pass `limit` (0: unlimited).
bool try_add(std::atomic<std::uint64_t>& counter, std::uint64_t amount, std::uint64_t limit,
             std::uint64_t& would_be) {
    std::uint64_t current = counter.load();
    for (;;) {
        would_be = current + amount;
        if (limit != 0 && would_be > limit) {
            return false;
        }
        if (counter.compare_exchange_weak(current, would_be)) {
            return true;
        }
    }
}

const char* const QUOTA_KEYS[] = {"max-scenes",     "max-objects",         "max-triangles",
                                  "max-bytes-held", "max-bytes-in-flight", "max-frames-per-second",
                                  "max-streams"};

StatusOr<Quotas> read_quotas(const nlohmann::json& json, const std::string& where) {
    Quotas q;
    if (!json.is_object()) {
        return invalid_argument(where + ".quotas must be an object");
    }
    for (const auto& [key, value] : json.items()) {
        const std::string field = where + ".quotas." + key;
        if (std::find(std::begin(QUOTA_KEYS), std::end(QUOTA_KEYS), key) == std::end(QUOTA_KEYS)) {
            return invalid_argument(field +
                                    " is not a quota (known: max-scenes, max-objects, "
                                    "max-triangles, max-bytes-held, max-bytes-in-flight, "
                                    "max-frames-per-second, max-streams)");
        }
        if (key == "max-frames-per-second") {
            if (!value.is_number() || !std::isfinite(value.get<double>()) ||
                value.get<double>() < 0) {
                return invalid_argument(field + " must be a number >= 0, got " + value.dump());
            }
            q.max_frames_per_second = value.get<double>();
            continue;
        }
        if (!value.is_number_unsigned() &&
            !(value.is_number_integer() && value.get<std::int64_t>() >= 0)) {
            return invalid_argument(field + " must be an integer >= 0 (0: unlimited), got " +
                                    value.dump());
        }
        const auto v = value.get<std::uint64_t>();
        if (key == "max-scenes") {
            q.max_scenes = v;
        } else if (key == "max-objects") {
            q.max_objects = v;
        } else if (key == "max-triangles") {
            q.max_triangles = v;
        } else if (key == "max-bytes-held") {
            q.max_bytes_held = v;
        } else if (key == "max-bytes-in-flight") {
            q.max_bytes_in_flight = v;
        } else {
            q.max_streams = v;
        }
    }
    return q;
}

StatusOr<std::vector<std::string>> read_patterns(const nlohmann::json& entry, const char* key,
                                                 const std::string& where) {
    std::vector<std::string> out;
    if (!entry.contains(key)) {
        return out;  // nothing granted unless listed
    }
    const auto& value = entry.at(key);
    if (!value.is_array()) {
        return invalid_argument(where + "." + key + " must be an array of name patterns");
    }
    for (const auto& p : value) {
        if (!p.is_string()) {
            return invalid_argument(where + "." + key + " holds " + p.dump() +
                                    ", not a string pattern");
        }
        out.push_back(p.get<std::string>());
    }
    return out;
}

bool is_hex64(const std::string& s) {
    return s.size() == 64 && std::all_of(s.begin(), s.end(), [](char c) {
               return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
           });
}

}  // namespace

std::string sha256_hex(const std::string& data) {
    unsigned char digest[EVP_MAX_MD_SIZE];
    unsigned int length = 0;
    EVP_Digest(data.data(), data.size(), digest, &length, EVP_sha256(), nullptr);
    std::string out;
    out.reserve(2 * static_cast<std::size_t>(length));
    char byte[3];
    for (unsigned int i = 0; i < length; ++i) {
        std::snprintf(byte, sizeof(byte), "%02x", digest[i]);
        out += byte;
    }
    return out;
}

Principal::Principal(std::string name, Quotas quotas, std::vector<std::string> scenes,
                     std::vector<std::string> rooms, std::vector<std::string> models,
                     bool anonymous)
    : m_name(std::move(name)),
      m_log_name(m_name.empty() ? "-" : m_name),
      m_quotas(quotas),
      m_scene_patterns(std::move(scenes)),
      m_room_patterns(std::move(rooms)),
      m_model_patterns(std::move(models)),
      m_anonymous(anonymous),
      m_bucket_tokens(std::max(1.0, quotas.max_frames_per_second)),
      m_bucket_time(std::chrono::steady_clock::now()) {}

bool Principal::may_create_scene(const std::string& scene_name) const {
    return m_anonymous || matches_any(m_scene_patterns, scene_name);
}

bool Principal::may_join_room(const std::string& room) const {
    return m_anonymous || matches_any(m_room_patterns, room);
}

bool Principal::may_use_model(const std::string& model) const {
    return m_anonymous || matches_any(m_model_patterns, model);
}

Status Principal::exhausted(const char* quota, std::uint64_t would_be, std::uint64_t limit) const {
    return {StatusCode::resource_exhausted,
            "quota " + std::string(quota) + " of token '" + m_name + "' exceeded: this needs " +
                std::to_string(would_be) + ", the quota is " + std::to_string(limit) +
                " (free some, or ask the operator for more)"};
}

Status Principal::reserve_scene() {
    std::uint64_t would_be = 0;
    if (!try_add(m_scenes, 1, m_quotas.max_scenes, would_be)) {
        return exhausted("max-scenes", would_be, m_quotas.max_scenes);
    }
    return {};
}

void Principal::release_scene() {
    m_scenes.fetch_sub(1);
}

Status Principal::reserve_stream() {
    std::uint64_t would_be = 0;
    if (!try_add(m_streams, 1, m_quotas.max_streams, would_be)) {
        return exhausted("max-streams", would_be, m_quotas.max_streams);
    }
    return {};
}

void Principal::release_stream() {
    m_streams.fetch_sub(1);
}

Status Principal::reserve_in_flight(std::uint64_t bytes) {
    std::uint64_t would_be = 0;
    if (!try_add(m_bytes_in_flight, bytes, m_quotas.max_bytes_in_flight, would_be)) {
        return exhausted("max-bytes-in-flight", would_be, m_quotas.max_bytes_in_flight);
    }
    return {};
}

void Principal::release_in_flight(std::uint64_t bytes) {
    m_bytes_in_flight.fetch_sub(bytes);
}

Status Principal::change_holding(const Holding& from, const Holding& to) {
    struct Part {
        std::atomic<std::uint64_t>& counter;
        std::uint64_t from, to, limit;
        const char* quota;
    };
    Part parts[] = {
        {m_objects, from.objects, to.objects, m_quotas.max_objects, "max-objects"},
        {m_triangles, from.triangles, to.triangles, m_quotas.max_triangles, "max-triangles"},
        {m_bytes_held, from.bytes, to.bytes, m_quotas.max_bytes_held, "max-bytes-held"}};
    // Growth first, all or nothing; then the shrinking parts, which cannot fail.
    std::size_t taken = 0;
    for (; taken < std::size(parts); ++taken) {
        auto& p = parts[taken];
        if (p.to <= p.from) {
            continue;
        }
        std::uint64_t would_be = 0;
        if (!try_add(p.counter, p.to - p.from, p.limit, would_be)) {
            for (std::size_t i = 0; i < taken; ++i) {
                if (parts[i].to > parts[i].from) {
                    parts[i].counter.fetch_sub(parts[i].to - parts[i].from);
                }
            }
            return exhausted(p.quota, would_be, p.limit);
        }
    }
    for (auto& p : parts) {
        if (p.to < p.from) {
            p.counter.fetch_sub(p.from - p.to);
        }
    }
    return {};
}

Status Principal::admit_frame() {
    const double rate = m_quotas.max_frames_per_second;
    if (rate <= 0) {
        return {};
    }
    std::lock_guard lock(m_bucket_mu);
    const auto now = std::chrono::steady_clock::now();
    const double elapsed = std::chrono::duration<double>(now - m_bucket_time).count();
    m_bucket_time = now;
    m_bucket_tokens = std::min(std::max(1.0, rate), m_bucket_tokens + elapsed * rate);
    if (m_bucket_tokens < 1.0) {
        char buf[64];
        std::snprintf(buf, sizeof(buf), "%g", rate);
        return {StatusCode::resource_exhausted,
                "quota max-frames-per-second of token '" + m_name + "' exceeded: more than " + buf +
                    " frames in the last second (send frames more slowly)"};
    }
    m_bucket_tokens -= 1.0;
    return {};
}

Authenticator::Authenticator() {
    m_principals.push_back(std::make_shared<Principal>("", Quotas{}, std::vector<std::string>{},
                                                       std::vector<std::string>{},
                                                       std::vector<std::string>{}, true));
}

StatusOr<std::unique_ptr<Authenticator>> Authenticator::from_file(const std::string& path) {
    std::ifstream in(path);
    if (!in) {
        return Status(StatusCode::not_found, "token file " + path + " cannot be read");
    }
    nlohmann::json json;
    try {
        json = nlohmann::json::parse(in);
    } catch (const nlohmann::json::exception& e) {
        return invalid_argument("token file " + path + ": not valid JSON: " + e.what());
    }
    return from_json(json, "token file " + path);
}

StatusOr<std::unique_ptr<Authenticator>> Authenticator::from_json(const nlohmann::json& json,
                                                                  const std::string& origin) {
    if (!json.is_object() || !json.contains("tokens") || !json.at("tokens").is_array()) {
        return invalid_argument(origin + ": expected {\"tokens\": [...]}");
    }
    for (const auto& [key, value] : json.items()) {
        if (key != "tokens") {
            return invalid_argument(origin + ": unknown key '" + key + "' (only \"tokens\")");
        }
    }
    std::unique_ptr<Authenticator> auth(new Authenticator());
    auth->m_principals.clear();
    std::set<std::string> names;
    std::size_t index = 0;
    for (const auto& entry : json.at("tokens")) {
        const std::string where = origin + ": tokens[" + std::to_string(index++) + "]";
        if (!entry.is_object()) {
            return invalid_argument(where + " must be an object");
        }
        for (const auto& item : entry.items()) {
            const std::string& key =
                item.key();  // captured below: no structured binding (clang 14)
            static const char* const KNOWN[] = {"name",  "token",  "sha256", "scenes",
                                                "rooms", "models", "quotas"};
            if (std::find_if(std::begin(KNOWN), std::end(KNOWN),
                             [&](const char* k) { return key == k; }) == std::end(KNOWN)) {
                return invalid_argument(where + ": unknown key '" + key +
                                        "' (name, token or sha256, scenes, rooms, models, quotas)");
            }
        }
        if (!entry.contains("name") || !entry.at("name").is_string() ||
            entry.at("name").get<std::string>().empty()) {
            return invalid_argument(where + ".name must be a non-empty string");
        }
        const auto name = entry.at("name").get<std::string>();
        if (!names.insert(name).second) {
            return invalid_argument(where + ": name '" + name + "' is used twice");
        }
        const std::string at = where + " ('" + name + "')";
        std::string hash;
        if (entry.contains("token") == entry.contains("sha256")) {
            return invalid_argument(at + ": give exactly one of \"token\" and \"sha256\"");
        }
        if (entry.contains("token")) {
            if (!entry.at("token").is_string() ||
                entry.at("token").get<std::string>().size() < 16) {
                return invalid_argument(at + ".token must be a string of at least 16 characters");
            }
            hash = sha256_hex(entry.at("token").get<std::string>());
        } else {
            if (!entry.at("sha256").is_string() ||
                !is_hex64(entry.at("sha256").get<std::string>())) {
                return invalid_argument(at +
                                        ".sha256 must be 64 lower-case hex digits (the SHA-256 of "
                                        "the token: `proximad --hash-token`)");
            }
            hash = entry.at("sha256").get<std::string>();
        }
        Quotas quotas;
        if (entry.contains("quotas")) {
            auto q = read_quotas(entry.at("quotas"), at);
            if (!q.ok()) {
                return q.status();
            }
            quotas = q.value();
        }
        auto scenes = read_patterns(entry, "scenes", at);
        auto rooms = read_patterns(entry, "rooms", at);
        auto models = read_patterns(entry, "models", at);
        for (const auto* p : {&scenes, &rooms, &models}) {
            if (!p->ok()) {
                return p->status();
            }
        }
        auto principal =
            std::make_shared<Principal>(name, quotas, std::move(scenes).value(),
                                        std::move(rooms).value(), std::move(models).value(), false);
        if (!auth->m_by_hash.emplace(hash, principal).second) {
            return invalid_argument(at + ": the same token as an earlier entry");
        }
        auth->m_principals.push_back(std::move(principal));
    }
    if (auth->m_principals.empty()) {
        return invalid_argument(origin +
                                ": no tokens (with a token file every call needs one; remove "
                                "--tokens to run without authentication)");
    }
    return auth;
}

StatusOr<std::shared_ptr<Principal>> Authenticator::authenticate(
    const std::string& authorization) const {
    if (!enabled()) {
        return m_principals.front();
    }
    if (authorization.empty()) {
        return Status(StatusCode::unauthenticated,
                      "this daemon needs a bearer token: send the metadata 'authorization: "
                      "Bearer <token>' (proxima --token-file FILE, or PROXIMA_TOKEN)");
    }
    static constexpr std::string_view BEARER = "Bearer ";
    if (authorization.size() <= BEARER.size() ||
        authorization.compare(0, BEARER.size(), BEARER) != 0) {
        return Status(StatusCode::unauthenticated,
                      "the authorization metadata must be 'Bearer <token>'");
    }
    auto it = m_by_hash.find(sha256_hex(authorization.substr(BEARER.size())));
    if (it == m_by_hash.end()) {
        return Status(StatusCode::unauthenticated, "unknown or revoked token");
    }
    return it->second;
}

}  // namespace proxima::server
