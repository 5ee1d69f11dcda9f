#pragma once
// The daemon's Prometheus metrics (`--metrics-listen HOST:PORT`, GET /metrics, text format;
// every metric is listed in docs/server.md "Metrics"). Counters that calls update are kept in a
// prometheus-cpp registry; values the daemon already tracks elsewhere (live scenes, the geometry
// cache, the GPU backend, each token's usage) are read when the endpoint is scraped, so they cost
// nothing between scrapes and can never drift from their source.

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "proxima/status.hpp"

namespace prometheus {
class Registry;
class Exposer;
struct MetricFamily;
}  // namespace prometheus

namespace proxima::server {

// A value read at scrape time.
struct Sample {
    std::string name;  // e.g. "proxima_live_scenes"
    std::string help;
    bool counter = false;  // else a gauge
    std::vector<std::pair<std::string, std::string>> labels;
    double value = 0;
};

class Metrics {
  public:
    Metrics();
    ~Metrics();
    Metrics(const Metrics&) = delete;
    Metrics& operator=(const Metrics&) = delete;

    // Serves GET /metrics (and GET /healthz, set_serving) on `address` (HOST:PORT, port 0 picks
    // one); returns HOST:PORT bound.
    StatusOr<std::string> listen(const std::string& address);

    // One finished call: proxima_requests_total and proxima_request_duration_seconds by method
    // and status code; a RESOURCE_EXHAUSTED naming a quota ("quota max-scenes of token ...")
    // also counts in proxima_quota_rejections_total{quota, principal}, and one naming a daemon
    // limit ("... the limit max-scenes ...") in proxima_limit_rejections_total{limit}.
    void record_call(const std::string& method, const Status& status, double seconds,
                     const std::string& principal);
    // Frames answered (StreamFrames and Query) and the exact tests their queries ran.
    void add_frames(std::uint64_t frames, std::uint64_t exact_tests);
    void add_scene_expired();

    // Called at every scrape; appends the current values of things tracked elsewhere.
    void set_sampler(std::function<void(std::vector<Sample>&)> sampler);
    // GET /healthz on the same listener: the one gauge `proxima_serving`, 1 while `serving()`
    // (the gRPC health status is SERVING), 0 once shutdown starts. For load balancers that
    // cannot speak the gRPC health protocol (HAProxy: `http-check expect string
    // "proxima_serving 1"`, deploy/haproxy/haproxy.cfg).
    void set_serving(std::function<bool()> serving);

    // The text exposition format of everything (what GET /metrics returns).
    std::string render() const;

  private:
    struct Impl;
    std::unique_ptr<Impl> m_impl;
};

}  // namespace proxima::server
