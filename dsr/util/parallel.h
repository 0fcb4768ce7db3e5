// Minimal fork-join parallelism over an index range, on a persistent pool of threads.
//
// ParallelFor hands out indices dynamically (an atomic counter), so it is deterministic
// only when each index writes its own outputs. Reductions that must be bit-identical for
// any thread count partition the range into fixed blocks, let ParallelFor fill one
// accumulator per block, and reduce the blocks in block order.
//
// The threads are started once, on first use, and kept for the process (a solve calls
// ParallelFor several times per iteration; starting threads each time cost more than some
// of the loops). A ParallelFor inside another one's body, or one called while another
// thread's runs, runs on its caller's thread alone: the pool is never waited for.
#ifndef DSR_UTIL_PARALLEL_H_
#define DSR_UTIL_PARALLEL_H_

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>

#include <glog/logging.h>

namespace dsr {

// Number of threads to use for `requested` (<= 0 means all hardware threads).
inline int ResolveThreads(int requested) {
  if (requested > 0) return requested;
  return std::max(1u, std::thread::hardware_concurrency());
}

// Runs `worker` on `threads` threads at once, the caller's among them, and returns when
// every call has returned; `worker` must not throw. The other threads come from the pool;
// when it is busy (see above) only the caller's call runs, so a worker must share out the
// work itself (as ParallelFor's do). Throws std::system_error, before any call, when the
// pool cannot start a thread it needs (the tools report it as out of memory, one line).
void RunOnThreads(int threads, const std::function<void()>& worker);

template <typename Fn>
void ParallelFor(int64_t begin, int64_t end, int num_threads, const Fn& fn) {
  if (end <= begin) return;
  const int64_t count = end - begin;
  const int threads = static_cast<int>(std::min<int64_t>(ResolveThreads(num_threads), count));
  if (threads <= 1) {
    for (int64_t i = begin; i < end; ++i) fn(i);
    return;
  }
  // An exception (std::bad_alloc) in any thread stops handing out indices; every call
  // returns and the first exception is rethrown in the caller's thread. A thread that
  // cannot start throws from RunOnThreads itself.
  std::atomic<int64_t> next{begin};
  std::mutex failure_mutex;
  std::exception_ptr failure;
  RunOnThreads(threads, [&]() {
    try {
      for (int64_t i = next.fetch_add(1); i < end; i = next.fetch_add(1)) fn(i);
    } catch (...) {
      next = end;
      std::lock_guard<std::mutex> lock(failure_mutex);
      if (!failure) failure = std::current_exception();
    }
  });
  if (failure) std::rethrow_exception(failure);
}

}  // namespace dsr

#endif  // DSR_UTIL_PARALLEL_H_
