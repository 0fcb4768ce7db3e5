// util/parallel.h: ParallelFor on the persistent pool.
#include "dsr/util/parallel.h"

#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace dsr {
namespace {

TEST(ParallelFor, VisitsEveryIndexOnceForAnyThreadCount) {
  for (int threads : {0, 1, 2, 3, 8}) {
    std::vector<int> visits(1000, 0);
    ParallelFor(0, 1000, threads, [&](int64_t i) { ++visits[i]; });
    for (int v : visits) ASSERT_EQ(v, 1) << threads << " threads";
  }
}

TEST(ParallelFor, ReusesItsThreadsAcrossCalls) {
  // Each thread remembers the call it first worked in. Threads started once serve every
  // later call: 200 calls on 3 threads see at most 2 such first calls on the threads other
  // than the caller's (threads started per call would each show their own call).
  static thread_local int first_call = -1;
  std::mutex mutex;
  std::set<int> first_calls;
  const std::thread::id caller = std::this_thread::get_id();
  for (int call = 0; call < 200; ++call) {
    ParallelFor(0, 64, 3, [&](int64_t) {
      if (std::this_thread::get_id() == caller) return;
      if (first_call < 0) first_call = call;
      std::lock_guard<std::mutex> lock(mutex);
      first_calls.insert(first_call);
    });
  }
  EXPECT_LE(first_calls.size(), 2u);
}

TEST(ParallelFor, NestedCallsRunOnTheirCallersThread) {
  std::vector<std::atomic<int>> visits(16 * 16);
  ParallelFor(0, 16, 2, [&](int64_t i) {
    const std::thread::id outer = std::this_thread::get_id();
    ParallelFor(0, 16, 2, [&](int64_t j) {
      EXPECT_EQ(std::this_thread::get_id(), outer);
      ++visits[16 * i + j];
    });
  });
  for (const std::atomic<int>& v : visits) ASSERT_EQ(v.load(), 1);
}

TEST(ParallelFor, ConcurrentCallersEachGetEveryIndex) {
  std::vector<int> a(5000, 0), b(5000, 0);
  std::thread other([&] {
    for (int r = 0; r < 20; ++r) ParallelFor(0, 5000, 2, [&](int64_t i) { ++a[i]; });
  });
  for (int r = 0; r < 20; ++r) ParallelFor(0, 5000, 2, [&](int64_t i) { ++b[i]; });
  other.join();
  for (int i = 0; i < 5000; ++i) {
    ASSERT_EQ(a[i], 20);
    ASSERT_EQ(b[i], 20);
  }
}

TEST(ParallelFor, AnExceptionInAnyThreadReachesTheCallerAndThePoolGoesOn) {
  EXPECT_THROW(ParallelFor(0, 100, 2,
                           [&](int64_t i) {
                             if (i == 57) throw std::runtime_error("index 57");
                           }),
               std::runtime_error);
  std::atomic<int> count{0};
  ParallelFor(0, 100, 2, [&](int64_t) { ++count; });
  EXPECT_EQ(count.load(), 100);
}

TEST(ParallelFor, WorksInAChildProcessMadeAfterThePoolStarted) {
  // pipeline/experiment.cc runs each method in a fork()ed child; the child has none of the
  // parent's pool threads and must not wait for them (an alarm ends a child that hangs).
  std::atomic<int> count{0};
  ParallelFor(0, 100, 2, [&](int64_t) { ++count; });
  ASSERT_EQ(count.load(), 100);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    alarm(20);
    std::atomic<int> in_child{0};
    for (int call = 0; call < 10; ++call) ParallelFor(0, 100, 2, [&](int64_t) { ++in_child; });
    _exit(in_child.load() == 1000 ? 0 : 1);
  }
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status)) << "the child hung or crashed";
  EXPECT_EQ(WEXITSTATUS(status), 0);
}

}  // namespace
}  // namespace dsr
