#include "metrics.hpp"

#include <exception>
#include <mutex>
#include <sstream>
#include <utility>

#include <prometheus/collectable.h>
#include <prometheus/counter.h>
#include <prometheus/exposer.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>
#include <prometheus/text_serializer.h>

namespace proxima::server {

namespace {

// Call latencies from 100 µs (a small unary call) to 5 min (a whole-model verification).
const prometheus::Histogram::BucketBoundaries LATENCY_BUCKETS = {
    0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1,
    0.25,   0.5,     1,      2.5,   5,      10,    30,   60,    300};

// The word after `prefix` in `message` ("quota max-scenes of ..." -> "max-scenes"), or "".
std::string word_after(const std::string& message, const std::string& prefix) {
    const auto at = message.find(prefix);
    if (at == std::string::npos) {
        return {};
    }
    const auto begin = at + prefix.size();
    auto end = message.find_first_of(" ,;)", begin);
    return message.substr(begin, end == std::string::npos ? std::string::npos : end - begin);
}

// The scrape-time values, as a Collectable the registry's exposer asks at every scrape.
class Sampled final : public prometheus::Collectable {
  public:
    void set(std::function<void(std::vector<Sample>&)> sampler) {
        std::lock_guard lock(m_mu);
        m_sampler = std::move(sampler);
    }

    std::vector<prometheus::MetricFamily> Collect() const override {
        std::vector<Sample> samples;
        {
            std::lock_guard lock(m_mu);
            if (m_sampler) {
                m_sampler(samples);
            }
        }
        std::vector<prometheus::MetricFamily> families;
        for (auto& s : samples) {
            // Samples of one name arrive together (one family, several label sets).
            if (families.empty() || families.back().name != s.name) {
                prometheus::MetricFamily f;
                f.name = s.name;
                f.help = s.help;
                f.type =
                    s.counter ? prometheus::MetricType::Counter : prometheus::MetricType::Gauge;
                families.push_back(std::move(f));
            }
            prometheus::ClientMetric m;
            for (auto& [k, v] : s.labels) {
                m.label.push_back({k, v});
            }
            if (s.counter) {
                m.counter.value = s.value;
            } else {
                m.gauge.value = s.value;
            }
            families.back().metric.push_back(std::move(m));
        }
        return families;
    }

  private:
    mutable std::mutex m_mu;
    std::function<void(std::vector<Sample>&)> m_sampler;
};

}  // namespace

struct Metrics::Impl {
    std::shared_ptr<prometheus::Registry> registry = std::make_shared<prometheus::Registry>();
    std::shared_ptr<Sampled> sampled = std::make_shared<Sampled>();
    std::shared_ptr<Sampled> health = std::make_shared<Sampled>();  // GET /healthz
    prometheus::Family<prometheus::Counter>& requests =
        prometheus::BuildCounter()
            .Name("proxima_requests_total")
            .Help("Finished calls by method and gRPC status code")
            .Register(*registry);
    prometheus::Family<prometheus::Histogram>& latency =
        prometheus::BuildHistogram()
            .Name("proxima_request_duration_seconds")
            .Help("Call duration from arrival to status, by method and gRPC status code")
            .Register(*registry);
    prometheus::Family<prometheus::Counter>& quota_rejections =
        prometheus::BuildCounter()
            .Name("proxima_quota_rejections_total")
            .Help("Calls refused with RESOURCE_EXHAUSTED by a token's quota")
            .Register(*registry);
    prometheus::Family<prometheus::Counter>& limit_rejections =
        prometheus::BuildCounter()
            .Name("proxima_limit_rejections_total")
            .Help("Calls refused with RESOURCE_EXHAUSTED by a daemon-wide limit")
            .Register(*registry);
    prometheus::Counter& frames = prometheus::BuildCounter()
                                      .Name("proxima_frames_total")
                                      .Help("Frames answered (StreamFrames and Query)")
                                      .Register(*registry)
                                      .Add({});
    prometheus::Counter& exact_tests =
        prometheus::BuildCounter()
            .Name("proxima_exact_tests_total")
            .Help("Exact primitive tests run by the queries of answered frames")
            .Register(*registry)
            .Add({});
    prometheus::Counter& scenes_expired =
        prometheus::BuildCounter()
            .Name("proxima_scenes_expired_total")
            .Help("Scenes deleted because no call used them for idle-scene-seconds")
            .Register(*registry)
            .Add({});
    prometheus::Counter& auth_failures =
        prometheus::BuildCounter()
            .Name("proxima_auth_failures_total")
            .Help("Calls refused with UNAUTHENTICATED (no, malformed or unknown token)")
            .Register(*registry)
            .Add({});
    std::unique_ptr<prometheus::Exposer> exposer;
};

Metrics::Metrics() : m_impl(std::make_unique<Impl>()) {}

Metrics::~Metrics() = default;

StatusOr<std::string> Metrics::listen(const std::string& address) {
    try {
        m_impl->exposer = std::make_unique<prometheus::Exposer>(address);
    } catch (const std::exception& e) {
        return Status(StatusCode::unavailable,
                      "cannot serve metrics on " + address + ": " + e.what());
    }
    m_impl->exposer->RegisterCollectable(m_impl->registry);
    m_impl->exposer->RegisterCollectable(m_impl->sampled);
    m_impl->exposer->RegisterCollectable(m_impl->health, "/healthz");
    const auto ports = m_impl->exposer->GetListeningPorts();
    const auto host = address.substr(0, address.rfind(':'));
    return host + ":" + std::to_string(ports.empty() ? 0 : ports.front());
}

void Metrics::record_call(const std::string& method, const Status& status, double seconds,
                          const std::string& principal) {
    const std::string code = status_code_name(status.code());
    m_impl->requests.Add({{"method", method}, {"code", code}}).Increment();
    m_impl->latency.Add({{"method", method}, {"code", code}}, LATENCY_BUCKETS).Observe(seconds);
    if (status.code() == StatusCode::resource_exhausted) {
        // Quota statuses start with "quota NAME of token" (auth.cpp); anything else that
        // mentions a quota (a full disk's "quota exceeded") is not one of ours.
        const bool quota_status = status.message().rfind("quota ", 0) == 0;
        if (auto quota = quota_status ? word_after(status.message(), "quota ") : std::string();
            !quota.empty()) {
            m_impl->quota_rejections.Add({{"quota", quota}, {"principal", principal}}).Increment();
        } else if (auto limit = word_after(status.message(), "the limit "); !limit.empty()) {
            m_impl->limit_rejections.Add({{"limit", limit}}).Increment();
        }
    }
    if (status.code() == StatusCode::unauthenticated) {
        m_impl->auth_failures.Increment();
    }
}

void Metrics::add_frames(std::uint64_t frames, std::uint64_t exact_tests) {
    m_impl->frames.Increment(static_cast<double>(frames));
    m_impl->exact_tests.Increment(static_cast<double>(exact_tests));
}

void Metrics::add_scene_expired() {
    m_impl->scenes_expired.Increment();
}

void Metrics::set_sampler(std::function<void(std::vector<Sample>&)> sampler) {
    m_impl->sampled->set(std::move(sampler));
}

void Metrics::set_serving(std::function<bool()> serving) {
    m_impl->health->set([serving = std::move(serving)](std::vector<Sample>& out) {
        out.push_back({"proxima_serving",
                       "1 while the gRPC health status is SERVING, 0 once shutdown starts",
                       false,
                       {},
                       serving() ? 1.0 : 0.0});
    });
}

std::string Metrics::render() const {
    auto families = m_impl->registry->Collect();
    auto sampled = m_impl->sampled->Collect();
    families.insert(families.end(), sampled.begin(), sampled.end());
    std::ostringstream out;
    prometheus::TextSerializer().Serialize(out, families);
    return out.str();
}

}  // namespace proxima::server
