#pragma once
// This process's threads as the kernel reports them (/proc/self/task/*/stat): name, nice value
// and the CPU time each has used. `bench live` turns two snapshots into a per-thread utilisation
// table; tests use the names and nice values to check the threads a component starts and leaves.
#include <string>
#include <vector>

namespace face_reenact {

struct ThreadInfo {
  int tid = 0;
  std::string name;    // at most 15 characters (pthread_setname_np)
  int nice = 0;
  double cpu_s = 0;    // user + system time, seconds (the kernel counts in clock ticks, 10 ms here)
};

// Every thread of this process; empty where /proc is not mounted. A thread that ends while it
// is read is left out.
std::vector<ThreadInfo> ProcessThreads();

// CPU seconds used by this process's threads (alive or ended) so far: user + system.
double ProcessCpuSeconds();

// Parses one /proc/<pid>/task/<tid>/stat line into `info` (name, nice, cpu_s); false when the
// line is not of that form. The name may hold spaces and parentheses: it ends at the last ')'.
bool ParseThreadStat(const std::string& stat, double clock_ticks_per_second, ThreadInfo* info);

}  // namespace face_reenact
