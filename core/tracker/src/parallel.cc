#include "parallel.h"

#include <algorithm>
#include <atomic>
#include <exception>
#include <system_error>
#include <thread>
#include <vector>

namespace face_reenact::tracker::internal {

void ParallelFor(int count, int threads, const std::function<void(int item)>& item) {
  if (count <= 0) return;
  const int workers = std::clamp(threads, 1, count) - 1;  // besides the caller
  std::vector<std::exception_ptr> failures(static_cast<size_t>(count));
  std::atomic<int> next{0};
  // Items are taken in order from a shared counter, so a slow thread does not hold up the rest.
  auto run = [&]() {
    for (int k = next.fetch_add(1); k < count; k = next.fetch_add(1)) {
      try {
        item(k);
      } catch (...) {
        failures[static_cast<size_t>(k)] = std::current_exception();
      }
    }
  };
  std::vector<std::thread> pool;
  pool.reserve(static_cast<size_t>(workers));
  for (int t = 0; t < workers; ++t) {
    try {
      pool.emplace_back(run);
    } catch (const std::system_error&) {
      break;  // no more threads to be had: the caller's thread takes the rest
    }
  }
  run();
  for (auto& t : pool) t.join();
  for (const auto& f : failures) {
    if (f) std::rethrow_exception(f);
  }
}

}  // namespace face_reenact::tracker::internal
