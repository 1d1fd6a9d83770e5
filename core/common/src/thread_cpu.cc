#include "face_reenact/common/thread_cpu.h"

#include <sys/resource.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sstream>

namespace face_reenact {

bool ParseThreadStat(const std::string& stat, double clock_ticks_per_second, ThreadInfo* info) {
  const size_t open = stat.find('('), close = stat.rfind(')');
  if (open == std::string::npos || close == std::string::npos || close < open || close + 2 > stat.size()) return false;
  if (!(clock_ticks_per_second > 0)) return false;
  ThreadInfo out;
  out.tid = std::atoi(stat.c_str());
  out.name = stat.substr(open + 1, close - open - 1);
  // After ") " come field 3 (state) onwards: utime is field 14, stime 15, nice 19 (proc(5)).
  std::istringstream rest(stat.substr(close + 2));
  std::string token;
  long long utime = -1, stime = -1;
  bool have_nice = false;
  for (int field = 3; field <= 19 && rest >> token; ++field) {
    if (field == 14) utime = std::atoll(token.c_str());
    if (field == 15) stime = std::atoll(token.c_str());
    if (field == 19) {
      out.nice = std::atoi(token.c_str());
      have_nice = true;
    }
  }
  if (utime < 0 || stime < 0 || !have_nice) return false;
  out.cpu_s = static_cast<double>(utime + stime) / clock_ticks_per_second;
  *info = std::move(out);
  return true;
}

std::vector<ThreadInfo> ProcessThreads() {
  std::vector<ThreadInfo> threads;
  const long ticks = ::sysconf(_SC_CLK_TCK);
  std::error_code ec;
  for (const auto& task : std::filesystem::directory_iterator("/proc/self/task", ec)) {
    FILE* f = std::fopen((task.path() / "stat").c_str(), "r");
    if (!f) continue;  // the thread ended meanwhile
    char buf[1024] = {};
    const size_t n = std::fread(buf, 1, sizeof buf - 1, f);
    std::fclose(f);
    ThreadInfo info;
    if (ParseThreadStat(std::string(buf, n), static_cast<double>(ticks), &info)) threads.push_back(std::move(info));
  }
  return threads;
}

double ProcessCpuSeconds() {
  rusage usage{};
  if (::getrusage(RUSAGE_SELF, &usage) != 0) return 0;
  auto seconds = [](const timeval& t) { return static_cast<double>(t.tv_sec) + 1e-6 * static_cast<double>(t.tv_usec); };
  return seconds(usage.ru_utime) + seconds(usage.ru_stime);
}

}  // namespace face_reenact
