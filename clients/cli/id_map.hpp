#pragma once
// Local mirror ids -> daemon ids, for clients that stream a procedural scene (scenes::step names
// objects by the ids of a local Scene) to a daemon that numbers its objects itself: `demo
// --server` and `load`'s simulator clients.

#include <string>
#include <unordered_map>

#include "client/proxima_client.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"

namespace proxima::cli {

// Local mirror ids -> daemon ids. The procedural steps name objects by the ids of the Scene they
// are given (our mirror); the daemon numbers its objects itself, so every id in an update is
// translated, and the ids the daemon gives new objects are learned from each result.
class IdMap {
  public:
    StatusOr<ObjectId> remote(ObjectId local) const {
        auto it = m_remote.find(local);
        if (it == m_remote.end()) {
            return Status(StatusCode::internal,
                          "object " + std::to_string(local) + " has no daemon id");
        }
        return it->second;
    }

    StatusOr<SceneUpdate> translate(const SceneUpdate& local) const {
        SceneUpdate out;
        for (auto id : local.removals) {
            auto r = remote(id);
            if (!r.ok()) {
                return r.status();
            }
            out.removals.push_back(r.value());
        }
        for (const auto& rep : local.replacements) {
            auto r = remote(rep.object);
            if (!r.ok()) {
                return r.status();
            }
            out.replacements.push_back({r.value(), rep.fragments});
        }
        for (const auto& pos : local.positions) {
            auto r = remote(pos.object);
            if (!r.ok()) {
                return r.status();
            }
            out.positions.push_back({r.value(), pos.vertices});
        }
        out.additions = local.additions;
        return out;
    }

    // After a frame: forget removed and replaced objects, learn the new ones' ids.
    Status update(const SceneUpdate& local_update, const SceneUpdateResult& local,
                  const client::FrameResponse& remote) {
        if (remote.added_ids.size() != local.added_ids.size() ||
            remote.fragment_ids.size() != local.fragment_ids.size()) {
            return {StatusCode::internal,
                    "the daemon reported ids for " + std::to_string(remote.added_ids.size()) +
                        " additions and " + std::to_string(remote.fragment_ids.size()) +
                        " topology changes; the frame had " +
                        std::to_string(local.added_ids.size()) + " and " +
                        std::to_string(local.fragment_ids.size())};
        }
        for (auto id : local_update.removals) {
            m_remote.erase(id);
        }
        for (const auto& rep : local_update.replacements) {
            m_remote.erase(rep.object);
        }
        for (std::size_t i = 0; i < local.fragment_ids.size(); ++i) {
            if (remote.fragment_ids[i].size() != local.fragment_ids[i].size()) {
                return {StatusCode::internal,
                        "the daemon reported " + std::to_string(remote.fragment_ids[i].size()) +
                            " fragment ids for topology change " + std::to_string(i) + " of " +
                            std::to_string(local.fragment_ids[i].size())};
            }
            for (std::size_t j = 0; j < local.fragment_ids[i].size(); ++j) {
                m_remote[local.fragment_ids[i][j]] = remote.fragment_ids[i][j];
            }
        }
        for (std::size_t i = 0; i < local.added_ids.size(); ++i) {
            m_remote[local.added_ids[i]] = remote.added_ids[i];
        }
        return {};
    }

  private:
    std::unordered_map<ObjectId, ObjectId> m_remote;
};

}  // namespace proxima::cli
