#pragma once
// A discrete-Voronoi backend that runs every job on the GPU while the GPU works, and on the CPU
// kernel from the moment it does not: the issue-7 promise that a daemon whose GPU context is lost
// (a reset, a driver update, a GL error in the middle of a job) keeps serving with identical
// answers. The CPU kernel returns what the GPU kernel returns bit for bit on llvmpipe, and within
// the kernel error bound on any GPU; the culler's answers are exact either way (it widens every
// bound by kernel_error_bound), so the switch changes no answer.
//
// Policy, per job:
//   - GPU active: the job runs on the GPU. If it fails with an input error (invalid_argument),
//     that is the answer: the CPU would refuse it too. If it fails otherwise, it is re-run on the
//     CPU kernel; when the GPU backend then reports itself lost (Backend::lost_reason() non-empty,
//     as the EGL backend does after a context loss or a GL error), the GPU is off for good: the
//     loss callback runs once, and every later job goes straight to the CPU. A failure that
//     leaves the GPU backend working (a job over a GPU size limit) re-runs only that job.
//   - GPU lost: the job runs on the CPU kernel.
// Thread-safe: many scenes share one instance; jobs in flight on the GPU when it is lost fail
// there and are re-run on the CPU, so no caller sees the loss.

#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <string>

#include "proxima/culling/dvd.hpp"
#include "proxima/status.hpp"

namespace proxima::gpu {

class FailoverBackend final : public dvd::Backend {
  public:
    // Called once, on the thread whose job found the GPU lost, with the reason (the engine does
    // not log; the daemon logs it).
    using LostCallback = std::function<void(const std::string& reason)>;

    // `gpu` and `cpu` must not be null.
    FailoverBackend(std::shared_ptr<dvd::Backend> gpu, std::shared_ptr<dvd::Backend> cpu,
                    LostCallback on_lost = {});

    // The GPU's name ("gpu (<GL renderer>)") while it serves; "cpu (gpu lost: <reason>)" after.
    std::string name() const override;
    bool is_gpu() const override { return gpu_active(); }
    Status run(const dvd::KernelInput& input, dvd::KernelOutput& output) override;

    bool gpu_active() const { return m_gpu_active.load(std::memory_order_acquire); }
    // A consistent snapshot.
    dvd::BackendStats stats() const;

  private:
    // Switches to the CPU for good; true for the one caller that did.
    bool fail_over(const std::string& reason);

    const std::shared_ptr<dvd::Backend> m_gpu;
    const std::shared_ptr<dvd::Backend> m_cpu;
    const LostCallback m_on_lost;
    std::atomic<bool> m_gpu_active{true};
    mutable std::mutex m_mutex;
    dvd::BackendStats m_stats;  // guarded by m_mutex
};

std::shared_ptr<FailoverBackend> make_failover_backend(std::shared_ptr<dvd::Backend> gpu,
                                                       std::shared_ptr<dvd::Backend> cpu,
                                                       FailoverBackend::LostCallback on_lost = {});

}  // namespace proxima::gpu
