#include "face_reenact/common/parallel.h"

#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <exception>
#include <future>
#include <memory>
#include <mutex>
#include <string>
#include <system_error>
#include <thread>
#include <vector>

namespace face_reenact {
namespace {

// One ParallelFor call. It lives on the caller's stack; the caller takes it off the queue and
// waits for the helpers that joined it before returning, so no helper touches it afterwards.
struct Job {
  const std::function<void(int)>* item = nullptr;
  int count = 0;
  std::atomic<int> next{0};
  std::vector<std::exception_ptr>* failures = nullptr;
  int seats = 0;                // helpers still wanted (guarded by the pool's mutex)
  std::atomic<int> active{0};   // helpers running its items (raised under the pool's mutex)

  // Items are taken in order from a shared counter, so a slow thread does not hold up the rest.
  void Run() {
    for (int k = next.fetch_add(1); k < count; k = next.fetch_add(1)) {
      try {
        (*item)(k);
      } catch (...) {
        (*failures)[static_cast<size_t>(k)] = std::current_exception();
      }
    }
  }
};

// Waking a sleeping thread costs 50-100 us on these virtual machines (the futex and the
// scheduler: 74 us on average, measured in `track`), while a tracked frame makes 70-100 calls,
// most a few hundred microseconds long and a few microseconds apart: a helper that went to sleep
// after each call joined the next one late, the caller ran its first items alone, and at the end
// slept until the helper's last item woke it. So both sides first watch for a while before they
// sleep: a helper for the next call, the caller for its helpers' last items. Bounded, so an idle
// pool costs nothing, and short against a frame, so a pool between frames gives the core back to
// the other threads within a fraction of a millisecond.
constexpr auto kHelperWatch = std::chrono::microseconds(150);
constexpr auto kCallerWatch = std::chrono::microseconds(100);

inline void CpuRelax() {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#elif defined(__aarch64__)
  asm volatile("yield");
#endif
}

// Watches `ready` for up to `budget`; true once it holds.
template <class Ready>
bool WatchFor(std::chrono::microseconds budget, const Ready& ready) {
  const auto until = std::chrono::steady_clock::now() + budget;
  for (int spin = 0;; ++spin) {
    if (ready()) return true;
    CpuRelax();
    // Every 64 looks: the clock (reading it costs more than a look), and the core to any other
    // thread that waits for it (sched_yield returns at once when none does). With more threads
    // at work than cores (`reenact` tracks both actors and renders at once) a watch that kept
    // the core made the others wait.
    if ((spin & 63) == 63) {
      if (std::chrono::steady_clock::now() >= until) return ready();
      sched_yield();
    }
  }
}

class WorkerPool {
 public:
  static WorkerPool& Instance() {
    static WorkerPool pool;
    return pool;
  }

  ~WorkerPool() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stopping_ = true;
    }
    work_.notify_all();
    for (auto& t : workers_) t.join();
  }

  void Run(Job* job, int helpers) {
    bool wake = false;  // read under the lock: a helper may take a seat the moment it is queued
    {
      std::lock_guard<std::mutex> lock(mutex_);
      // Grow on demand; a failure to start one more thread only means fewer helpers.
      while (static_cast<int>(workers_.size()) < helpers && !spawn_failed_) {
        try {
          workers_.emplace_back([this] { WorkerLoop(); });
        } catch (const std::system_error&) {
          spawn_failed_ = true;
        }
      }
      job->seats = std::min(helpers, static_cast<int>(workers_.size()));
      if (job->seats > 0) {
        queue_.push_back(job);
        queued_.fetch_add(1, std::memory_order_release);
        wake = sleeping_ > 0;  // a watching helper sees the queue by itself
      }
    }
    if (wake) work_.notify_all();
    job->Run();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      // Every item is taken: no helper may join from now on.
      const auto at = std::find(queue_.begin(), queue_.end(), job);
      if (at != queue_.end()) {
        queue_.erase(at);
        queued_.fetch_sub(1, std::memory_order_relaxed);
      }
    }
    if (WatchFor(kCallerWatch, [&] { return job->active.load(std::memory_order_acquire) == 0; })) return;
    std::unique_lock<std::mutex> lock(mutex_);
    done_.wait(lock, [&] { return job->active.load(std::memory_order_acquire) == 0; });
  }

 private:
  WorkerPool() = default;

  void WorkerLoop() {
    // Named so a per-thread CPU table (bench live) and a profiler can tell the helpers apart.
    pthread_setname_np(pthread_self(), "fr-parallel");
    for (;;) {
      WatchFor(kHelperWatch, [&] { return queued_.load(std::memory_order_acquire) > 0; });
      std::unique_lock<std::mutex> lock(mutex_);
      ++sleeping_;
      work_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
      --sleeping_;
      if (stopping_) return;
      Job* job = queue_.front();
      if (--job->seats == 0) {
        queue_.pop_front();
        queued_.fetch_sub(1, std::memory_order_relaxed);
      }
      job->active.fetch_add(1, std::memory_order_relaxed);
      lock.unlock();
      job->Run();
      // The last helper out wakes a caller that went to sleep. The job may be gone the moment
      // `active` reaches zero (its caller may be watching), so it is not touched after that.
      if (job->active.fetch_sub(1, std::memory_order_acq_rel) == 1) {
        std::lock_guard<std::mutex> done_lock(mutex_);
        done_.notify_all();
      }
    }
  }

  std::mutex mutex_;
  std::condition_variable work_, done_;
  std::deque<Job*> queue_;
  std::atomic<int> queued_{0};  // queue_.size(), for helpers watching without the lock
  int sleeping_ = 0;            // helpers inside work_.wait (guarded by mutex_)
  std::vector<std::thread> workers_;
  bool stopping_ = false;
  bool spawn_failed_ = false;
};

}  // namespace

void ParallelFor(int count, int threads, const std::function<void(int item)>& item) {
  if (count <= 0) return;
  std::vector<std::exception_ptr> failures(static_cast<size_t>(count));
  Job job;
  job.item = &item;
  job.count = count;
  job.failures = &failures;
  const int helpers = std::clamp(threads, 1, count) - 1;  // besides the caller
  if (helpers == 0) {
    job.Run();
  } else {
    WorkerPool::Instance().Run(&job, helpers);
  }
  for (const auto& f : failures) {
    if (f) std::rethrow_exception(f);
  }
}

NamedThread::NamedThread(std::string name) : name_(std::move(name)) {
  // Shared, since the thread may still be inside set_value when the wait below returns.
  auto named = std::make_shared<std::promise<void>>();
  std::future<void> ready = named->get_future();
  thread_ = std::thread([this, named] {
    pthread_setname_np(pthread_self(), name_.substr(0, 15).c_str());
    named->set_value();
    Loop();
  });
  ready.wait();
}

NamedThread::~NamedThread() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_one();
  thread_.join();
}

void NamedThread::Post(std::function<void()> job) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    jobs_.push_back(std::move(job));
  }
  wake_.notify_one();
}

void NamedThread::Loop() {
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    wake_.wait(lock, [&] { return stopping_ || !jobs_.empty(); });
    if (jobs_.empty()) return;  // stopping, every submitted job run
    std::function<void()> job = std::move(jobs_.front());
    jobs_.pop_front();
    lock.unlock();
    job();  // a packaged task: its exception goes to its future
    lock.lock();
  }
}

void ParallelInvoke(int threads, std::initializer_list<std::function<void()>> tasks) {
  const std::function<void()>* first = tasks.begin();
  ParallelFor(static_cast<int>(tasks.size()), threads, [first](int k) { first[k](); });
}

int ResolvedThreadCount(int requested) {
  if (requested > 0) return requested;
  // Asked once: glibc answers hardware_concurrency by reading /sys on every call (an open, a read
  // and a close), and a live frame asks dozens of times (1 % of the worker's time).
  static const int hardware = static_cast<int>(std::clamp(std::thread::hardware_concurrency(), 1u, 8u));
  return hardware;
}

}  // namespace face_reenact
