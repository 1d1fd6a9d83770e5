#include "face_reenact/common/process_resources.h"

#include <malloc.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <system_error>

#include "face_reenact/common/sanitizers.h"

namespace face_reenact {
namespace {

// Entries of a /proc folder; -1 when it cannot be listed.
int count_entries(const char* dir) {
  std::error_code ec;
  std::filesystem::directory_iterator it(dir, ec), end;
  if (ec) return -1;
  int n = 0;
  for (; it != end; it.increment(ec)) {
    if (ec) return -1;
    ++n;
  }
  return n;
}

template <typename T>
T median(std::vector<T> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

std::string megabytes(int64_t bytes) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f MB", static_cast<double>(bytes) / 1e6);
  return buf;
}

// glibc's allocator statistics; false where they do not describe this process's allocations.
bool read_heap(int64_t* in_use, int64_t* free_bytes) {
#if defined(FR_SANITIZER_ALLOCATOR) || !defined(__GLIBC__) || __GLIBC__ < 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ < 33)
  (void)in_use;
  (void)free_bytes;
  return false;  // the sanitizer's own allocator serves malloc; glibc's arenas hold next to nothing
#else
  const struct mallinfo2 m = mallinfo2();
  *in_use = static_cast<int64_t>(m.uordblks + m.hblkhd);
  *free_bytes = static_cast<int64_t>(m.fordblks);
  return true;
#endif
}

}  // namespace

bool ParseVmRss(const std::string& status_text, int64_t* bytes) {
  std::istringstream in(status_text);
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("VmRSS:", 0) != 0) continue;
    long long kb = -1;
    char unit[8] = {};
    if (std::sscanf(line.c_str() + 6, "%lld %7s", &kb, unit) != 2 || kb < 0 || std::string(unit) != "kB") return false;
    *bytes = static_cast<int64_t>(kb) * 1024;
    return true;
  }
  return false;
}

bool ReadProcessResources(ProcessResources* out, std::string* error) {
  std::ifstream status("/proc/self/status");
  std::stringstream text;
  text << status.rdbuf();
  ProcessResources r;
  if (!status || !ParseVmRss(text.str(), &r.rss_bytes)) {
    if (error) *error = "cannot read the resident memory from /proc/self/status (is /proc mounted?)";
    return false;
  }
  // The listing itself holds one descriptor of /proc/self/fd while it runs: not counted.
  r.open_files = count_entries("/proc/self/fd") - 1;
  r.threads = count_entries("/proc/self/task");
  if (r.open_files < 0 || r.threads < 0) {
    if (error) *error = "cannot list /proc/self/fd or /proc/self/task";
    return false;
  }
  if (!read_heap(&r.heap_in_use_bytes, &r.heap_free_bytes)) r.heap_in_use_bytes = r.heap_free_bytes = -1;
  *out = r;
  return true;
}

bool ResourceTrendOptions::IsValid(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!(warmup_seconds >= 0) || !std::isfinite(warmup_seconds)) return fail("the warm-up must be 0 s or more");
  if (!(rss_bound >= 0) || !std::isfinite(rss_bound)) return fail("the resident-memory bound must be 0 or more");
  if (open_files_bound < 0 || threads_bound < 0) return fail("the open-file and thread bounds must be 0 or more");
  return true;
}

ResourceTrend AnalyseResourceTrend(const std::vector<ResourceSample>& samples, const ResourceTrendOptions& options) {
  ResourceTrend t;
  std::vector<const ResourceSample*> judged;
  for (const ResourceSample& s : samples)
    if (s.seconds >= options.warmup_seconds) judged.push_back(&s);
  t.judged_samples = static_cast<int>(judged.size());
  if (judged.size() < 2) {
    char buf[160];
    std::snprintf(buf, sizeof buf, "not measured: %d sample(s) after the warm-up of %.0f s (at least 2 needed)",
                  t.judged_samples, options.warmup_seconds);
    t.verdict = buf;
    return t;
  }
  t.measured = true;
  const size_t quarter = std::max<size_t>(1, judged.size() / 4);
  auto medians = [&](size_t begin, ProcessResources* m) {
    std::vector<int64_t> rss, heap;
    std::vector<int> files, threads;
    for (size_t i = begin; i < begin + quarter; ++i) {
      rss.push_back(judged[i]->resources.rss_bytes);
      heap.push_back(judged[i]->resources.heap_in_use_bytes);
      files.push_back(judged[i]->resources.open_files);
      threads.push_back(judged[i]->resources.threads);
    }
    m->rss_bytes = median(rss);
    m->heap_in_use_bytes = median(heap);
    m->open_files = median(files);
    m->threads = median(threads);
  };
  ProcessResources start, end;
  medians(0, &start);
  medians(judged.size() - quarter, &end);
  t.rss_start = start.rss_bytes;
  t.rss_end = end.rss_bytes;
  t.rss_growth = start.rss_bytes > 0 ? static_cast<double>(end.rss_bytes - start.rss_bytes) / static_cast<double>(start.rss_bytes) : 0;
  t.heap_measured = std::all_of(judged.begin(), judged.end(),
                                 [](const ResourceSample* s) { return s->resources.heap_in_use_bytes >= 0; });
  if (t.heap_measured) {
    t.heap_start = start.heap_in_use_bytes;
    t.heap_end = end.heap_in_use_bytes;
    t.heap_growth = t.heap_start > 0 ? static_cast<double>(t.heap_end - t.heap_start) / static_cast<double>(t.heap_start) : 0;
  }
  t.open_files_start = start.open_files;
  t.open_files_end = end.open_files;
  t.threads_start = start.threads;
  t.threads_end = end.threads;

  std::vector<std::string> grew;
  char buf[200];
  std::snprintf(buf, sizeof buf, "resident memory %s -> %s (%+.1f %%, bound %.1f %%)", megabytes(t.rss_start).c_str(),
                megabytes(t.rss_end).c_str(), 100 * t.rss_growth, 100 * options.rss_bound);
  const std::string rss_text = buf;
  std::string heap_text;
  if (t.heap_measured) {
    std::snprintf(buf, sizeof buf, "heap in use %s -> %s (%+.1f %%)", megabytes(t.heap_start).c_str(),
                  megabytes(t.heap_end).c_str(), 100 * t.heap_growth);
    heap_text = buf;
  }
  const bool heap_grows = t.heap_measured && t.heap_growth > options.rss_bound;
  if (heap_grows) {
    grew.push_back(heap_text + ": live allocations pile up");
    t.leaks = true;
  }
  if (t.rss_growth > options.rss_bound) {
    if (t.heap_measured && !heap_grows) {
      grew.push_back(rss_text + " while the " + heap_text + " did not: freed memory the allocator keeps, not a leak");
    } else {
      grew.push_back(rss_text);
      if (!t.heap_measured) t.leaks = true;  // resident memory is all there is to judge by
    }
  }
  std::snprintf(buf, sizeof buf, "open files %d -> %d", t.open_files_start, t.open_files_end);
  const std::string files_text = buf;
  if (t.open_files_end - t.open_files_start > options.open_files_bound) {
    grew.push_back(files_text);
    t.leaks = true;
  }
  std::snprintf(buf, sizeof buf, "threads %d -> %d", t.threads_start, t.threads_end);
  const std::string threads_text = buf;
  if (t.threads_end - t.threads_start > options.threads_bound) {
    grew.push_back(threads_text);
    t.leaks = true;
  }

  std::snprintf(buf, sizeof buf, " (medians of the first and last quarter of %d samples after %.0f s)", t.judged_samples,
                options.warmup_seconds);
  t.grows = !grew.empty();
  if (t.grows) {
    t.verdict = t.leaks ? "grows after the warm-up: " : "grows after the warm-up (no leak): ";
    for (size_t i = 0; i < grew.size(); ++i) t.verdict += (i ? "; " : "") + grew[i];
  } else {
    t.verdict = "no growth after the warm-up: " + rss_text + (heap_text.empty() ? "" : ", " + heap_text) + ", " +
                files_text + ", " + threads_text;
  }
  t.verdict += buf;
  return t;
}

}  // namespace face_reenact
