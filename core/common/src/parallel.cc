#include "face_reenact/common/parallel.h"

#include <pthread.h>

#include <algorithm>
#include <atomic>
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
  int seats = 0;   // helpers still wanted (guarded by the pool's mutex)
  int active = 0;  // helpers running its items (guarded by the pool's mutex)

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
      wake = job->seats > 0;
      if (wake) queue_.push_back(job);
    }
    if (wake) work_.notify_all();
    job->Run();
    std::unique_lock<std::mutex> lock(mutex_);
    // Every item is taken: no helper may join from now on.
    queue_.erase(std::remove(queue_.begin(), queue_.end(), job), queue_.end());
    done_.wait(lock, [&] { return job->active == 0; });
  }

 private:
  WorkerPool() = default;

  void WorkerLoop() {
    // Named so a per-thread CPU table (bench live) and a profiler can tell the helpers apart.
    pthread_setname_np(pthread_self(), "fr-parallel");
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      work_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      Job* job = queue_.front();
      if (--job->seats == 0) queue_.pop_front();
      ++job->active;
      lock.unlock();
      job->Run();
      lock.lock();
      if (--job->active == 0) done_.notify_all();
    }
  }

  std::mutex mutex_;
  std::condition_variable work_, done_;
  std::deque<Job*> queue_;
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

int ResolvedThreadCount(int requested) {
  if (requested > 0) return requested;
  return static_cast<int>(std::clamp(std::thread::hardware_concurrency(), 1u, 8u));
}

}  // namespace face_reenact
