#pragma once
// What this process holds (resident memory, open files, threads, from /proc/self) and whether
// a series of such samples grows after a warm-up. `face-reenact bench soak` samples a live session
// for an hour and says whether anything leaks (issue #29: "an hour of faults").
#include <cstdint>
#include <string>
#include <vector>

namespace face_reenact {

struct ProcessResources {
  int64_t rss_bytes = 0;  // VmRSS of /proc/self/status
  int open_files = 0;     // entries of /proc/self/fd (sockets, pipes and devices included)
  int threads = 0;        // entries of /proc/self/task
  // What malloc has handed out and not had back (glibc's mallinfo2: uordblks + hblkhd, every
  // arena), and the free memory it keeps in its arenas (fordblks). A leak grows the first; an
  // allocator that keeps freed pages grows the resident memory while the first stays flat, which
  // resident memory alone cannot tell apart. -1 where the C library does not say (not glibc, or
  // a sanitizer's allocator in its place).
  int64_t heap_in_use_bytes = -1;
  int64_t heap_free_bytes = -1;
};

// Reads them now; false with *error where /proc is not mounted or not readable.
bool ReadProcessResources(ProcessResources* out, std::string* error);

// The VmRSS line of a /proc/<pid>/status text, in bytes; false when it has none.
bool ParseVmRss(const std::string& status_text, int64_t* bytes);

struct ResourceSample {
  double seconds = 0;  // since the run started
  ProcessResources resources;
  int64_t frames = 0;  // output frames written so far
  std::string note;    // what the program was doing (the live session's headline)
};

struct ResourceTrendOptions {
  // Samples before this are the warm-up (model load, calibration, caches filling) and are not
  // judged.
  double warmup_seconds = 120;
  // Growth allowed between the start and the end of the judged samples: resident memory and the
  // heap in use as a fraction of their start, open files and threads as counts.
  double rss_bound = 0.02;
  int open_files_bound = 0;
  int threads_bound = 0;

  bool IsValid(std::string* why) const;
};

struct ResourceTrend {
  bool measured = false;  // at least two samples after the warm-up
  bool grows = false;     // anything beyond its bound (only when measured)
  // The heap in use, open files or threads beyond their bound: live objects piling up. Resident
  // memory that grows while the heap in use does not is the allocator keeping freed pages: it
  // counts in `grows`, not here.
  bool leaks = false;
  int judged_samples = 0;
  // The medians of the first and the last quarter of the judged samples (one sample each at
  // least): a leak shows as the end above the start, while a one-off spike moves neither median.
  int64_t rss_start = 0, rss_end = 0;
  double rss_growth = 0;  // (end - start) / start
  bool heap_measured = false;  // every judged sample has the heap in use
  int64_t heap_start = 0, heap_end = 0;
  double heap_growth = 0;
  int open_files_start = 0, open_files_end = 0;
  int threads_start = 0, threads_end = 0;
  std::string verdict;  // one sentence: "no growth after the warm-up: ..." or what grew
};

ResourceTrend AnalyseResourceTrend(const std::vector<ResourceSample>& samples, const ResourceTrendOptions& options);

}  // namespace face_reenact
