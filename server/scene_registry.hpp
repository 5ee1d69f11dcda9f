#pragma once
// Live scenes by id. Each scene has its own ProximityEngine behind its own mutex: the engine is
// not thread-safe, and one frame at a time per scene is also what makes results well defined
// (frames of one scene apply in the order they take the mutex). Different scenes run in
// parallel.

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <unordered_map>
#include <vector>

#include "auth.hpp"
#include "proxima/culling/dvd.hpp"
#include "proxima/query/query.hpp"
#include "proxima/status.hpp"

namespace proxima::server {

struct SceneEntry {
    SceneEntry(std::string scene_id, std::string scene_name, bool owned_by_stream,
               std::shared_ptr<Principal> owner_principal)
        : id(std::move(scene_id)),
          name(std::move(scene_name)),
          stream_owned(owned_by_stream),
          owner(std::move(owner_principal)) {
        touch();
    }
    // Gives back to the owner whatever the entry still holds (an entry never registered, or
    // freed without erase()).
    ~SceneEntry();

    const std::string id;
    const std::string name;
    const bool stream_owned;
    // The principal that made the scene: the only one that finds it, and the one its objects,
    // triangles and bytes are charged to.
    const std::shared_ptr<Principal> owner;

    std::mutex mutex;          // held for a whole frame, an upload's apply, a describe
    ProximityEngine engine;    // guarded by mutex
    std::uint64_t frames = 0;  // guarded by mutex: frames applied so far

    // Set when the scene leaves the registry; a frame that holds the entry already may finish,
    // later ones fail with NOT_FOUND. Atomic so DeleteScene need not wait for a running frame.
    std::atomic<bool> deleted{false};
    // Sizes after the last change, readable without the mutex: early limit checks run on gRPC's
    // callback threads, which must not wait behind a running frame. The authoritative check is
    // repeated under the mutex.
    std::atomic<std::uint64_t> object_count{0};
    std::atomic<std::uint64_t> triangle_count{0};
    // steady_clock nanoseconds of the last call that used the scene (idle expiry).
    std::atomic<std::int64_t> last_used_ns{0};

    // Call with `mutex` held after the scene changed.
    void publish_sizes();
    void touch();

    // Charges the owner for the scene holding `after` from now on (the quotas max-objects,
    // max-triangles, max-bytes-held): RESOURCE_EXHAUSTED naming the quota, or NOT_FOUND once the
    // scene was erased, and nothing changes. Call with `mutex` held, before applying the change
    // (and again with the old holding if applying fails).
    Status charge(const Holding& after);
    Holding charged() const;

  private:
    friend class SceneRegistry;
    // Gives everything back, once (erase, or the destructor of an entry never registered).
    void release_all();

    mutable std::mutex m_charge_mu;  // after `mutex` when both are held
    Holding m_charged;               // guarded by m_charge_mu
    bool m_counted = false;          // guarded by m_charge_mu: holds one of the owner's scenes
    bool m_released = false;         // guarded by m_charge_mu
};

class SceneRegistry {
  public:
    explicit SceneRegistry(std::uint64_t max_scenes);

    // The daemon's GPU backend (null when EGL did not start, with the reason), given to every
    // scene's engine made after this call.
    void set_gpu(std::shared_ptr<dvd::Backend> backend, std::string unavailable_reason);

    // A new, unregistered entry with a fresh random-looking id (16 hex digits). Ids are random
    // so that one client cannot guess another's scene by counting.
    std::shared_ptr<SceneEntry> make_entry(std::string name, bool stream_owned,
                                           std::shared_ptr<Principal> owner);
    // Fails early, before a request does expensive work, when the registry is full.
    Status check_capacity() const;
    // Makes the entry findable; resource_exhausted at max_scenes or at the owner's quota
    // max-scenes.
    Status insert(const std::shared_ptr<SceneEntry>& entry);
    // A scene made by CreateScene by `who`, or nullptr, which the caller reports exactly as an
    // unknown id: another principal's scene is not found, not forbidden, so ids do not leak.
    // Stream-owned scenes count towards the limit but are private to their stream: no other call
    // finds, changes or deletes them by id. Marks the scene used (idle expiry).
    std::shared_ptr<SceneEntry> find(const std::string& id, const Principal& who) const;
    // False when unknown. The entry lives on while a frame still holds it; its owner gets its
    // scene, objects, triangles and bytes back now.
    bool erase(const std::string& id);
    // Erases every scene made by CreateScene (not stream-owned) that no call used for
    // `idle_seconds`, and returns them (for the log).
    std::vector<std::shared_ptr<SceneEntry>> expire_idle(double idle_seconds);
    std::size_t size() const;
    std::uint64_t max_scenes() const { return m_max_scenes; }

  private:
    Status full_status() const;

    const std::uint64_t m_max_scenes;
    std::shared_ptr<dvd::Backend> m_gpu;
    std::string m_gpu_reason;
    mutable std::mutex m_mu;
    std::unordered_map<std::string, std::shared_ptr<SceneEntry>> m_scenes;
    std::mt19937_64 m_rng;
};

}  // namespace proxima::server
