#include "worker_pool.hpp"

#include <utility>

namespace proxima::server {

WorkerPool::WorkerPool(std::size_t threads) {
    m_threads.reserve(threads);
    for (std::size_t i = 0; i < threads; ++i) {
        m_threads.emplace_back([this] { run(); });
    }
}

WorkerPool::~WorkerPool() {
    {
        std::lock_guard lock(m_mu);
        m_stopping = true;
    }
    m_ready.notify_all();
    for (auto& t : m_threads) {
        t.join();
    }
}

void WorkerPool::submit(std::function<void()> task) {
    {
        std::lock_guard lock(m_mu);
        m_tasks.push_back(std::move(task));
    }
    m_ready.notify_one();
}

void WorkerPool::run() {
    for (;;) {
        std::function<void()> task;
        {
            std::unique_lock lock(m_mu);
            m_ready.wait(lock, [this] { return m_stopping || !m_tasks.empty(); });
            // Queued work still runs while stopping: a reactor waits for its task to finish.
            if (m_tasks.empty()) {
                return;
            }
            task = std::move(m_tasks.front());
            m_tasks.pop_front();
        }
        task();
    }
}

}  // namespace proxima::server
