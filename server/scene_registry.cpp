#include "scene_registry.hpp"

#include <cstdio>

namespace proxima::server {

void SceneEntry::publish_sizes() {
    const auto& scene = engine.scene();
    object_count.store(scene.size(), std::memory_order_relaxed);
    triangle_count.store(scene.triangle_count(), std::memory_order_relaxed);
}

SceneRegistry::SceneRegistry(std::uint64_t max_scenes)
    : m_max_scenes(max_scenes), m_rng(std::random_device{}()) {}

std::shared_ptr<SceneEntry> SceneRegistry::make_entry(std::string name, bool stream_owned) {
    std::uint64_t bits = 0;
    {
        std::lock_guard lock(m_mu);
        bits = m_rng();
    }
    char id[17];
    std::snprintf(id, sizeof(id), "%016llx", static_cast<unsigned long long>(bits));
    auto entry = std::make_shared<SceneEntry>(id, std::move(name), stream_owned);
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
    if (!m_scenes.emplace(entry->id, entry).second) {
        // 64 random bits: a collision is a broken random source, not bad luck.
        return {StatusCode::internal, "scene id " + entry->id + " generated twice"};
    }
    return {};
}

std::shared_ptr<SceneEntry> SceneRegistry::find(const std::string& id) const {
    std::lock_guard lock(m_mu);
    auto it = m_scenes.find(id);
    return it == m_scenes.end() || it->second->stream_owned ? nullptr : it->second;
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
    // `entry` may be the last reference: the engine is freed here, outside the registry lock.
    return true;
}

std::size_t SceneRegistry::size() const {
    std::lock_guard lock(m_mu);
    return m_scenes.size();
}

}  // namespace proxima::server
