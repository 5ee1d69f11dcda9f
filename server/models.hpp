#pragma once
// The massive models the daemon serves: every subdirectory of --models DIR that holds a model
// store (massive::Store, written by `proxima import`), named by the subdirectory, and the one
// GeometryCache (budget --cache-bytes) that every verification and review room shares, so the
// daemon's memory for massive models is bounded by one number however many calls run.
//
// The directory is rescanned when models are listed and when a request names a model the
// registry does not know, so a model imported while the daemon runs is served without a restart.
// A rescan reads each store's CURRENT file and reopens only stores whose generation changed; a
// store that cannot be opened (a corrupt manifest: DATA_LOSS) is logged once per generation and
// listed as unavailable, never fatal. Calls already holding a store keep it (and its generation's
// files) while they run.

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "proxima/massive/cache.hpp"
#include "proxima/massive/store.hpp"
#include "proxima/status.hpp"

namespace proxima::server {

struct ModelEntry {
    std::string name;  // the subdirectory
    std::string dir;   // its path
    std::shared_ptr<const massive::Store> store;
    Aabb box;  // of every object
};

struct UnavailableModel {
    std::string name;
    std::string current;  // the CURRENT file's content when it failed (retried when it changes)
    Status status;
};

class ModelRegistry {
  public:
    // `models_dir` "" serves no models (every lookup is NOT_FOUND naming the missing flag).
    ModelRegistry(std::string models_dir, std::uint64_t cache_bytes);

    // The first scan, at start-up: unavailable when the directory cannot be listed (a typo in
    // --models must not look like an empty directory). Stores that fail to open are skipped.
    Status start();

    // Rescans, then the models by name / the ones that failed.
    std::vector<std::shared_ptr<const ModelEntry>> list();
    std::vector<UnavailableModel> unavailable() const;
    // The model `name`; an unknown name rescans first. INVALID_ARGUMENT for a name that cannot
    // be a subdirectory ("", "..", "a/b"), NOT_FOUND for no such store, the store's own status
    // (DATA_LOSS) when it exists but cannot be opened.
    StatusOr<std::shared_ptr<const ModelEntry>> find(const std::string& name);
    // The NOT_FOUND of a model name this daemon does not serve.
    Status unknown_model(const std::string& name) const;

    const std::shared_ptr<massive::GeometryCache>& cache() const { return m_cache; }
    const std::string& dir() const { return m_dir; }

  private:
    Status rescan();

    const std::string m_dir;
    const std::shared_ptr<massive::GeometryCache> m_cache;
    std::mutex m_scan_mu;  // one rescan at a time (they open stores: disk reads)
    mutable std::mutex m_mu;
    std::map<std::string, std::shared_ptr<const ModelEntry>> m_models;  // guarded by m_mu
    std::map<std::string, UnavailableModel> m_unavailable;              // guarded by m_mu
};

// True for names that can only mean one subdirectory: non-empty, no '/', not starting with '.'.
bool valid_model_name(const std::string& name);

}  // namespace proxima::server
