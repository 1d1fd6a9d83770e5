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
  // Growth allowed between the start and the end of the judged samples: resident memory as a
  // fraction of the start, open files and threads as counts.
  double rss_bound = 0.02;
  int open_files_bound = 0;
  int threads_bound = 0;

  bool IsValid(std::string* why) const;
};

struct ResourceTrend {
  bool measured = false;  // at least two samples after the warm-up
  bool grows = false;     // beyond a bound (only when measured)
  int judged_samples = 0;
  // The medians of the first and the last quarter of the judged samples (one sample each at
  // least): a leak shows as the end above the start, while a one-off spike moves neither median.
  int64_t rss_start = 0, rss_end = 0;
  double rss_growth = 0;  // (end - start) / start
  int open_files_start = 0, open_files_end = 0;
  int threads_start = 0, threads_end = 0;
  std::string verdict;  // one sentence: "no growth after the warm-up: ..." or what grew
};

ResourceTrend AnalyseResourceTrend(const std::vector<ResourceSample>& samples, const ResourceTrendOptions& options);

}  // namespace face_reenact
