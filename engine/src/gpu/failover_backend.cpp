#include "proxima/gpu/failover_backend.hpp"

#include <chrono>
#include <stdexcept>
#include <utility>

namespace proxima::gpu {

namespace {

double seconds_since(std::chrono::steady_clock::time_point start) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

FailoverBackend::FailoverBackend(std::shared_ptr<dvd::Backend> gpu,
                                 std::shared_ptr<dvd::Backend> cpu, LostCallback on_lost)
    : m_gpu(std::move(gpu)), m_cpu(std::move(cpu)), m_on_lost(std::move(on_lost)) {
    if (!m_gpu || !m_cpu) {
        throw std::invalid_argument("FailoverBackend needs a GPU and a CPU backend");
    }
    m_stats.gpu_active = true;
}

std::string FailoverBackend::name() const {
    if (gpu_active()) {
        return m_gpu->name();
    }
    std::lock_guard lock(m_mutex);
    return "cpu (gpu lost: " + m_stats.fallback_reason + ")";
}

Status FailoverBackend::run(const dvd::KernelInput& input, dvd::KernelOutput& output) {
    if (gpu_active()) {
        const auto start = std::chrono::steady_clock::now();
        Status s = m_gpu->run(input, output);
        const double seconds = seconds_since(start);
        {
            std::lock_guard lock(m_mutex);
            m_stats.gpu_seconds += seconds;
            if (s.ok()) {
                ++m_stats.gpu_jobs;
            }
        }
        if (s.ok() || s.code() == StatusCode::invalid_argument) {
            return s;
        }
        // The reason the backend gives for its loss says what broke (the reset status, the EGL
        // error); the job's status may only say that the context was gone when it got there.
        if (std::string lost = m_gpu->lost_reason(); !lost.empty()) {
            if (fail_over(lost) && m_on_lost) {
                m_on_lost(lost);
            }
        }
    }
    const auto start = std::chrono::steady_clock::now();
    Status s = m_cpu->run(input, output);
    const double seconds = seconds_since(start);
    std::lock_guard lock(m_mutex);
    m_stats.cpu_seconds += seconds;
    if (s.ok()) {
        ++m_stats.cpu_jobs;
    }
    return s;
}

bool FailoverBackend::fail_over(const std::string& reason) {
    std::lock_guard lock(m_mutex);
    if (!m_stats.gpu_active) {
        return false;  // another job's failure got here first
    }
    m_stats.gpu_active = false;
    m_stats.fallback_reason = reason;
    m_gpu_active.store(false, std::memory_order_release);
    return true;
}

dvd::BackendStats FailoverBackend::stats() const {
    std::lock_guard lock(m_mutex);
    return m_stats;
}

std::shared_ptr<FailoverBackend> make_failover_backend(std::shared_ptr<dvd::Backend> gpu,
                                                       std::shared_ptr<dvd::Backend> cpu,
                                                       FailoverBackend::LostCallback on_lost) {
    return std::make_shared<FailoverBackend>(std::move(gpu), std::move(cpu), std::move(on_lost));
}

}  // namespace proxima::gpu
