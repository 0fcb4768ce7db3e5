#include "dsr/util/parallel.h"

#include <pthread.h>

#include <condition_variable>
#include <cstdint>

namespace dsr {
namespace {

// The process's pool: threads wait for a job, take one of its slots, run it and report.
// One job at a time (busy_); jobs are told apart by a generation counter, so that a thread
// takes at most one slot of each.
class ThreadPool {
 public:
  void Run(int threads, const std::function<void()>& worker) {
    if (busy_.exchange(true)) {  // nested, or another thread's job: the caller alone
      worker();
      return;
    }
    try {
      Grow(threads - 1);
    } catch (...) {
      busy_ = false;
      throw;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      job_ = &worker;
      slots_ = std::min(threads - 1, num_threads_);
      pending_ = slots_;
      ++generation_;
    }
    wake_.notify_all();
    worker();
    {
      std::unique_lock<std::mutex> lock(mutex_);
      done_.wait(lock, [this] { return pending_ == 0; });
      job_ = nullptr;
    }
    busy_ = false;
  }

 private:
  // Starts threads until there are `helpers`. They are detached: they wait for work until
  // the process ends. A thread that cannot start throws std::system_error (out of memory for
  // its stack, or a thread limit); the threads started so far stay in the pool.
  void Grow(int helpers) {
    while (num_threads_ < helpers) {
      std::thread([this] { Loop(); }).detach();
      ++num_threads_;
    }
  }

  void Loop() {
    uint64_t seen = 0;
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      wake_.wait(lock, [&] { return generation_ != seen; });
      seen = generation_;
      if (slots_ == 0) continue;
      --slots_;
      const std::function<void()>* job = job_;
      lock.unlock();
      (*job)();
      lock.lock();
      if (--pending_ == 0) done_.notify_one();
    }
  }

  std::atomic<bool> busy_{false};
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  const std::function<void()>* job_ = nullptr;
  int slots_ = 0;    // slots of the current job not yet taken
  int pending_ = 0;  // slots of the current job not yet finished
  uint64_t generation_ = 0;
  int num_threads_ = 0;  // only Run (one caller at a time) touches it
};

// The process's pool, never destroyed. A child process made by fork() has none of its
// parent's threads (pipeline/experiment.cc runs each method in one): it starts a pool of
// its own, abandoning the copy of the parent's.
std::atomic<ThreadPool*> pool{nullptr};

void NewPoolAfterFork() { pool = new ThreadPool(); }

ThreadPool* Pool() {
  static const bool registered = [] {
    pool = new ThreadPool();
    pthread_atfork(nullptr, nullptr, &NewPoolAfterFork);
    return true;
  }();
  (void)registered;
  return pool.load();
}

}  // namespace

void RunOnThreads(int threads, const std::function<void()>& worker) {
  if (threads <= 1) {
    worker();
    return;
  }
  Pool()->Run(threads, worker);
}

}  // namespace dsr
