#include "scene_registry.hpp"

#include <chrono>
#include <cstdio>

namespace proxima::server {

namespace {

std::int64_t now_ns() {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(
               std::chrono::steady_clock::now().time_since_epoch())
        .count();
}

}  // namespace

SceneEntry::~SceneEntry() {
    release_all();
}

void SceneEntry::publish_sizes() {
    const auto& scene = engine.scene();
    object_count.store(scene.size(), std::memory_order_relaxed);
    triangle_count.store(scene.triangle_count(), std::memory_order_relaxed);
}

void SceneEntry::touch() {
    last_used_ns.store(now_ns(), std::memory_order_relaxed);
}

Status SceneEntry::charge(const Holding& after) {
    std::lock_guard lock(m_charge_mu);
    if (m_released) {
        return not_found("scene " + id + " was deleted");
    }
    if (Status s = owner->change_holding(m_charged, after); !s.ok()) {
        return s;
    }
    m_charged = after;
    return {};
}

Holding SceneEntry::charged() const {
    std::lock_guard lock(m_charge_mu);
    return m_charged;
}

void SceneEntry::release_all() {
    std::lock_guard lock(m_charge_mu);
    if (m_released) {
        return;
    }
    m_released = true;
    (void)owner->change_holding(m_charged, Holding{});  // shrinking never fails
    m_charged = {};
    if (m_counted) {
        owner->release_scene();
        m_counted = false;
    }
}

SceneRegistry::SceneRegistry(std::uint64_t max_scenes)
    : m_max_scenes(max_scenes), m_rng(std::random_device{}()) {}

std::shared_ptr<SceneEntry> SceneRegistry::make_entry(std::string name, bool stream_owned,
                                                      std::shared_ptr<Principal> owner) {
    std::uint64_t bits = 0;
    {
        std::lock_guard lock(m_mu);
        bits = m_rng();
    }
    char id[17];
    std::snprintf(id, sizeof(id), "%016llx", static_cast<unsigned long long>(bits));
    auto entry = std::make_shared<SceneEntry>(id, std::move(name), stream_owned, std::move(owner));
    if (m_gpu) {
        entry->engine.set_gpu_backend(m_gpu);
    } else {
        entry->engine.set_gpu_unavailable_reason(m_gpu_reason);
    }
    return entry;
}

void SceneRegistry::set_gpu(std::shared_ptr<dvd::Backend> backend, std::string unavailable_reason) {
    m_gpu = std::move(backend);
    m_gpu_reason = std::move(unavailable_reason);
}

Status SceneRegistry::full_status() const {
    return {StatusCode::resource_exhausted,
            "the daemon already holds " + std::to_string(m_scenes.size()) +
                " scenes, the limit max-scenes = " + std::to_string(m_max_scenes) +
                "; delete a scene or close a stream first"};
}

Status SceneRegistry::check_capacity() const {
    std::lock_guard lock(m_mu);
    if (m_scenes.size() >= m_max_scenes) {
        return full_status();
    }
    return {};
}

Status SceneRegistry::insert(const std::shared_ptr<SceneEntry>& entry) {
    std::lock_guard lock(m_mu);
    if (m_scenes.size() >= m_max_scenes) {
        return full_status();
    }
    if (m_scenes.count(entry->id) != 0) {
        // 64 random bits: a collision is a broken random source, not bad luck.
        return {StatusCode::internal, "scene id " + entry->id + " generated twice"};
    }
    {
        std::lock_guard charge(entry->m_charge_mu);
        if (entry->m_released || entry->m_counted) {
            return {StatusCode::internal, "scene " + entry->id + " inserted twice"};
        }
        if (Status s = entry->owner->reserve_scene(); !s.ok()) {
            return s;
        }
        entry->m_counted = true;
    }
    m_scenes.emplace(entry->id, entry);
    return {};
}

std::shared_ptr<SceneEntry> SceneRegistry::find(const std::string& id, const Principal& who) const {
    std::lock_guard lock(m_mu);
    auto it = m_scenes.find(id);
    if (it == m_scenes.end() || it->second->stream_owned || it->second->owner.get() != &who) {
        return nullptr;
    }
    it->second->touch();
    return it->second;
}

bool SceneRegistry::erase(const std::string& id) {
    std::shared_ptr<SceneEntry> entry;
    {
        std::lock_guard lock(m_mu);
        auto it = m_scenes.find(id);
        if (it == m_scenes.end()) {
            return false;
        }
        entry = std::move(it->second);
        m_scenes.erase(it);
    }
    entry->deleted.store(true);
    entry->release_all();
    // `entry` may be the last reference: the engine is freed here, outside the registry lock.
    return true;
}

std::vector<std::shared_ptr<SceneEntry>> SceneRegistry::expire_idle(double idle_seconds) {
    const auto cutoff = now_ns() - static_cast<std::int64_t>(idle_seconds * 1e9);
    std::vector<std::shared_ptr<SceneEntry>> expired;
    {
        std::lock_guard lock(m_mu);
        for (auto it = m_scenes.begin(); it != m_scenes.end();) {
            const auto& e = it->second;
            // A scene a frame holds right now is in use, however long ago it was found.
            if (!e->stream_owned && e->last_used_ns.load() < cutoff && e->mutex.try_lock()) {
                e->mutex.unlock();
                expired.push_back(e);
                it = m_scenes.erase(it);
            } else {
                ++it;
            }
        }
    }
    for (auto& e : expired) {
        e->deleted.store(true);
        e->release_all();
    }
    return expired;
}

std::size_t SceneRegistry::size() const {
    std::lock_guard lock(m_mu);
    return m_scenes.size();
}

}  // namespace proxima::server
