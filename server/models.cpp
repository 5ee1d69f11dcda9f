#include "models.hpp"

#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <system_error>
#include <utility>

#include <spdlog/spdlog.h>

namespace proxima::server {

namespace fs = std::filesystem;

namespace {

// The store's CURRENT file (the live generation's name), trimmed; "" when there is none (not a
// store, or an import that has not committed yet).
std::string read_current(const fs::path& dir) {
    std::ifstream in(dir / "CURRENT");
    if (!in) {
        return {};
    }
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const auto end = text.find_last_not_of(" \t\r\n");
    return end == std::string::npos ? std::string() : text.substr(0, end + 1);
}

Aabb model_box(const massive::Store& store) {
    Aabb box;
    for (const auto& o : store.objects()) {
        box.extend(o.box);
    }
    return box;
}

}  // namespace

bool valid_model_name(const std::string& name) {
    return !name.empty() && name.front() != '.' && name.find('/') == std::string::npos &&
           name.find('\0') == std::string::npos;
}

ModelRegistry::ModelRegistry(std::string models_dir, std::uint64_t cache_bytes)
    : m_dir(std::move(models_dir)),
      m_cache(std::make_shared<massive::GeometryCache>(cache_bytes)) {}

Status ModelRegistry::start() {
    if (m_dir.empty()) {
        return {};
    }
    std::error_code ec;
    if (!fs::is_directory(m_dir, ec)) {
        return {StatusCode::unavailable,
                "--models " + m_dir + " is not a directory (create it, or fix the path)"};
    }
    Status s = rescan();
    std::lock_guard lock(m_mu);
    spdlog::info("models dir={} served={} unavailable={} cache_bytes={}", m_dir, m_models.size(),
                 m_unavailable.size(), m_cache->budget());
    return s;
}

Status ModelRegistry::rescan() {
    if (m_dir.empty()) {
        return {};
    }
    std::lock_guard scan(m_scan_mu);
    std::error_code ec;
    fs::directory_iterator it(m_dir, ec);
    if (ec) {
        // Keep serving what is open: a transient error must not make every model vanish.
        spdlog::warn("models rescan dir={} failed: {}", m_dir, ec.message());
        return {StatusCode::unavailable, "cannot list --models " + m_dir + ": " + ec.message()};
    }
    std::set<std::string> seen;
    for (; it != fs::directory_iterator(); it.increment(ec)) {
        if (ec) {
            break;
        }
        const auto name = it->path().filename().string();
        std::error_code dir_ec;
        if (!valid_model_name(name) || !it->is_directory(dir_ec)) {
            continue;
        }
        const std::string current = read_current(it->path());
        if (current.empty()) {
            continue;  // not a store (yet)
        }
        seen.insert(name);
        {
            std::lock_guard lock(m_mu);
            if (auto m = m_models.find(name);
                m != m_models.end() && m->second->store->summary().generation == current) {
                continue;
            }
            if (auto u = m_unavailable.find(name);
                u != m_unavailable.end() && u->second.current == current) {
                continue;  // failed before in this generation: logged already
            }
        }
        // Opening reads the manifest: done outside m_mu so lookups of other models go on.
        auto store = massive::Store::open(it->path().string());
        std::lock_guard lock(m_mu);
        if (!store.ok()) {
            if (store.status().code() == StatusCode::not_found) {
                seen.erase(name);  // CURRENT names no generation (yet): not a store
                continue;
            }
            spdlog::warn("model unavailable name={} dir={} status={} message=\"{}\"", name,
                         it->path().string(), status_code_name(store.status().code()),
                         store.status().message());
            m_models.erase(name);
            m_unavailable[name] = {name, current, store.status()};
            continue;
        }
        auto entry = std::make_shared<ModelEntry>();
        entry->name = name;
        entry->dir = it->path().string();
        entry->store = std::move(store).value();
        entry->box = model_box(*entry->store);
        const auto& s = entry->store->summary();
        if (auto old = m_models.find(name); old != m_models.end()) {
            // A re-import replaced the store under a served name: calls from now on see the new
            // generation; rooms and verifications already running keep the one they opened.
            spdlog::info(
                "model switched name={} from_generation={} to_generation={} objects={} pieces={} "
                "triangles={} bytes={}",
                name, old->second->store->summary().generation, s.generation, s.objects, s.pieces,
                s.triangles, s.bytes);
        } else {
            spdlog::info(
                "model opened name={} generation={} objects={} pieces={} triangles={} "
                "bytes={}",
                name, s.generation, s.objects, s.pieces, s.triangles, s.bytes);
        }
        m_unavailable.erase(name);
        m_models[name] = std::move(entry);
    }
    std::lock_guard lock(m_mu);
    for (auto m = m_models.begin(); m != m_models.end();) {
        if (seen.count(m->first) == 0) {
            spdlog::info("model removed name={} (its store is gone from {})", m->first, m_dir);
            m = m_models.erase(m);
        } else {
            ++m;
        }
    }
    std::erase_if(m_unavailable, [&](const auto& u) { return seen.count(u.first) == 0; });
    return {};
}

std::vector<std::shared_ptr<const ModelEntry>> ModelRegistry::list() {
    (void)rescan();  // a failed listing keeps the models already open (and was logged)
    std::lock_guard lock(m_mu);
    std::vector<std::shared_ptr<const ModelEntry>> out;
    out.reserve(m_models.size());
    for (const auto& [name, entry] : m_models) {
        out.push_back(entry);
    }
    return out;
}

std::vector<UnavailableModel> ModelRegistry::unavailable() const {
    std::lock_guard lock(m_mu);
    std::vector<UnavailableModel> out;
    for (const auto& [name, u] : m_unavailable) {
        out.push_back(u);
    }
    return out;
}

StatusOr<std::shared_ptr<const ModelEntry>> ModelRegistry::find(const std::string& name) {
    if (m_dir.empty()) {
        return not_found("model '" + name +
                         "': this daemon serves no models (start it with --models DIR)");
    }
    if (!valid_model_name(name)) {
        return invalid_argument("model name '" + name +
                                "' is not a subdirectory name of --models (empty, starts with "
                                "'.', or has a '/')");
    }
    for (int attempt = 0; attempt < 2; ++attempt) {
        {
            std::lock_guard lock(m_mu);
            if (auto m = m_models.find(name); m != m_models.end()) {
                return m->second;
            }
            if (attempt == 1) {
                if (auto u = m_unavailable.find(name); u != m_unavailable.end()) {
                    return Status(
                        u->second.status.code(),
                        "model '" + name + "' cannot be opened: " + u->second.status.message());
                }
                break;
            }
        }
        if (Status s = rescan(); !s.ok()) {
            return s;
        }
    }
    return unknown_model(name);
}

Status ModelRegistry::unknown_model(const std::string& name) const {
    return not_found("no model named '" + name + "' in " + m_dir +
                     " (ListModels lists them; `proxima import` writes one)");
}

}  // namespace proxima::server
