#pragma once
// A small fixed pool of threads for engine work. gRPC's callback threads must not block (a long
// query there would stall every other call), and engine work does block: on a scene's mutex while
// another frame of the same scene runs, and for the length of a query. oneTBB tasks should not
// block on mutexes, so this is a plain pool; the queries inside still use oneTBB's parallel loops.

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace proxima::server {

class WorkerPool {
  public:
    explicit WorkerPool(std::size_t threads);
    ~WorkerPool();  // runs what is queued, then joins
    WorkerPool(const WorkerPool&) = delete;
    WorkerPool& operator=(const WorkerPool&) = delete;

    // Runs `task` on a pool thread, in submission order across the pool (not one after another).
    void submit(std::function<void()> task);
    std::size_t size() const { return m_threads.size(); }

  private:
    void run();

    std::mutex m_mu;
    std::condition_variable m_ready;
    std::deque<std::function<void()>> m_tasks;
    bool m_stopping = false;
    std::vector<std::thread> m_threads;
};

}  // namespace proxima::server
