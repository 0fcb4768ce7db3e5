// Minimal fork-join parallelism over an index range with std::thread.
//
// ParallelFor hands out indices dynamically (an atomic counter), so it is deterministic
// only when each index writes its own outputs. Reductions that must be bit-identical for
// any thread count partition the range into fixed blocks, let ParallelFor fill one
// accumulator per block, and reduce the blocks in block order.
#ifndef DSR_UTIL_PARALLEL_H_
#define DSR_UTIL_PARALLEL_H_

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

#include <glog/logging.h>

namespace dsr {

// Number of threads to use for `requested` (<= 0 means all hardware threads).
inline int ResolveThreads(int requested) {
  if (requested > 0) return requested;
  return std::max(1u, std::thread::hardware_concurrency());
}

template <typename Fn>
void ParallelFor(int64_t begin, int64_t end, int num_threads, const Fn& fn) {
  if (end <= begin) return;
  const int64_t count = end - begin;
  const int threads = static_cast<int>(std::min<int64_t>(ResolveThreads(num_threads), count));
  if (threads <= 1) {
    for (int64_t i = begin; i < end; ++i) fn(i);
    return;
  }
  // An exception (std::bad_alloc) in any thread, or a thread that cannot be started, stops
  // handing out indices; every started thread is joined and the first exception is
  // rethrown in the caller's thread. (Escaping a std::thread, or unwinding past joinable
  // threads, would std::terminate the process.)
  std::atomic<int64_t> next{begin};
  std::mutex failure_mutex;
  std::exception_ptr failure;
  auto worker = [&]() {
    try {
      for (int64_t i = next.fetch_add(1); i < end; i = next.fetch_add(1)) fn(i);
    } catch (...) {
      next = end;
      std::lock_guard<std::mutex> lock(failure_mutex);
      if (!failure) failure = std::current_exception();
    }
  };
  std::vector<std::thread> pool;
  try {
    pool.reserve(threads - 1);
    for (int t = 1; t < threads; ++t) pool.emplace_back(worker);
  } catch (...) {
    next = end;
    std::lock_guard<std::mutex> lock(failure_mutex);
    if (!failure) failure = std::current_exception();
  }
  worker();
  for (auto& t : pool) t.join();
  if (failure) std::rethrow_exception(failure);
}

}  // namespace dsr

#endif  // DSR_UTIL_PARALLEL_H_
