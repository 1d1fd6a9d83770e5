#pragma once
// Fork-join over a fixed set of work items, for the CPU hot loops (the tracker's residual and
// Jacobian rows and PCG products, the CPU rasteriser). Each item writes only its own output, and
// the items are fixed by the data, not by the thread count, so results are bit-identical for any
// count.
//
// The helper threads are kept in one process-wide pool rather than started per call: a tracked
// frame makes about 70 calls, and starting and joining a thread costs about 30 us here, plus a
// cold stack and cache for every new one.
#include <pthread.h>

#include <chrono>
#include <functional>
#include <future>

namespace face_reenact {

// Runs item(0) ... item(count - 1) on up to `threads` threads, the caller's among them, and
// returns when all have run. The caller always runs items itself, so a call made from inside an
// item (nested) or while every helper is busy still finishes: idle helpers join in, none is
// waited for. An exception from an item is rethrown here after the others have finished. When
// no helper thread can be started, the caller runs the rest.
void ParallelFor(int count, int threads, const std::function<void(int item)>& item);

// A thread count option resolved: `requested` when positive, else one per hardware thread, at
// most 8 (beyond that the products here are bound by memory bandwidth).
int ResolvedThreadCount(int requested);

// Two independent halves of one step at once (the source actor's tracking and the target's):
// runs `beside` on a thread of its own, named `thread_name` (at most 15 characters; the per-thread
// CPU tables show it), while the caller runs `here`, and returns what `beside` returned once both
// are done. `waited_ms`, when given, gets the time the caller waited for `beside` after `here`
// ended: what the second half added to the step. If `here` throws, `beside` is waited for first
// (it may read what the caller releases next), then the exception goes on.
template <class Beside, class Here>
auto RunBeside(const char* thread_name, Beside&& beside, Here&& here, double* waited_ms = nullptr) {
  auto done = std::async(std::launch::async, [&beside, thread_name] {
    pthread_setname_np(pthread_self(), thread_name);
    return beside();
  });
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
