#pragma once
// Fork-join over a fixed set of work items, for the CPU hot loops (the tracker's residual and
// Jacobian rows and PCG products, the CPU rasteriser). Each item writes only its own output, and
// the items are fixed by the data, not by the thread count, so results are bit-identical for any
// count.
//
// The helper threads are kept in one process-wide pool rather than started per call: a tracked
// frame makes 70-100 calls, and starting and joining a thread costs about 30 us here, plus a
// cold stack and cache for every new one. Between calls a helper watches for the next one for a
// moment before it sleeps (parallel.cc says why). Work handed over again and again to a thread of
// its own (the other actor's fit beside the target's) goes to a kept NamedThread for the same
// reason.
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <initializer_list>
#include <future>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <type_traits>

namespace face_reenact {

// Runs item(0) ... item(count - 1) on up to `threads` threads, the caller's among them, and
// returns when all have run. The caller always runs items itself, so a call made from inside an
// item (nested) or while every helper is busy still finishes: idle helpers join in, none is
// waited for. An exception from an item is rethrown here after the others have finished. When
// no helper thread can be started, the caller runs the rest.
void ParallelFor(int count, int threads, const std::function<void(int item)>& item);

// body(k) for each k in 0..count-1, in fixed blocks of `per_item` as ParallelFor's items: for
// per-element passes (pixels, rows, vertices) whose elements write only their own outputs. The
// blocks are fixed by the data, so the result is the same for any thread count.
template <typename Body>
void ParallelForBlocks(int count, int per_item, int threads, const Body& body) {
  ParallelFor((count + per_item - 1) / per_item, threads, [&](int item) {
    const int end = std::min(count, (item + 1) * per_item);
    for (int k = item * per_item; k < end; ++k) body(k);
  });
}

// Each of `tasks` once, as ParallelFor's items (in this order when one thread runs them): steps of
// one pass that read and write nothing in common (two images filtered at once), which a single
// thread would otherwise run one after the other while the pool waits.
void ParallelInvoke(int threads, std::initializer_list<std::function<void()>> tasks);

// A thread count option resolved: `requested` when positive, else one per hardware thread, at
// most 8 (beyond that the products here are bound by memory bandwidth).
int ResolvedThreadCount(int requested);

// A thread kept for one kind of work handed to it again and again (the source actor's fit beside
// the target's, each frame; the albedo texture's rebuilds), named once before anything can see
// it: a thread started per job carried its creator's name until it renamed itself, which a
// per-thread CPU table could catch, and it started with a cold stack, cache and thread-local
// scratch each time. Jobs run one at a time in the order submitted. Destroying it runs the jobs
// already submitted, then joins: whatever they read must outlive it (make it the last member).
class NamedThread {
 public:
  // `name`: at most 15 characters (the per-thread CPU tables show it). Returns once the thread
  // runs under that name. Throws std::system_error when no thread can be started.
  explicit NamedThread(std::string name);
  ~NamedThread();
  NamedThread(const NamedThread&) = delete;
  NamedThread& operator=(const NamedThread&) = delete;

  // Runs `job` on this thread after the jobs before it; the future has its result or exception.
  template <class Job>
  auto Submit(Job&& job) -> std::future<std::invoke_result_t<std::decay_t<Job>&>> {
    using Result = std::invoke_result_t<std::decay_t<Job>&>;
    auto task = std::make_shared<std::packaged_task<Result()>>(std::forward<Job>(job));
    std::future<Result> result = task->get_future();
    Post([task] { (*task)(); });
    return result;
  }

 private:
  void Post(std::function<void()> job);
  void Loop();

  std::string name_;
  std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::function<void()>> jobs_;
  bool stopping_ = false;
  std::thread thread_;
};

// Two independent halves of one step at once (the source actor's tracking and the target's):
// runs `beside` on `beside_thread` while the caller runs `here`, and returns what `beside`
// returned once both are done. `waited_ms`, when given, gets the time the caller waited for
// `beside` after `here` ended: what the second half added to the step. If `here` throws, `beside`
// is waited for first (it may read what the caller releases next), then the exception goes on.
template <class Beside, class Here>
auto RunBeside(NamedThread& beside_thread, Beside&& beside, Here&& here, double* waited_ms = nullptr) {
  auto done = beside_thread.Submit([&beside] { return beside(); });
  try {
    here();
  } catch (...) {
    done.wait();
    throw;
  }
  const auto waiting = std::chrono::steady_clock::now();
  auto result = done.get();
  if (waited_ms) *waited_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - waiting).count();
  return result;
}

}  // namespace face_reenact
