#pragma once
// A synthetic recording (`face-reenact synth`) made once per build tree and shared by every test
// process that asks for the same one. CTest runs each case in its own process and synth takes
// seconds, so a file-level fixture would make it again for every case.
//
// The recording lives in FR_TEST_CACHE_DIR/NAME (the build tree's test-cache, set by fr_test). It is
// made under a file lock, so concurrent cases wait for one synth, and marked complete by a file
// holding the arguments that made it and the times the program and the files it read (the model,
// the wheel) were last written, written last: a recording made with other arguments, by an older
// build or from an older model, or cut short, is made again.
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

#include "face_reenact/common/subprocess.h"

namespace face_reenact::testing {

struct CachedRecordingSpec {
  std::string name;                     // the folder under the cache, one per recording
  std::vector<std::string> synth_args;  // what follows `face-reenact synth` (not --out)
};

// The recording's folder; empty with *why when synth failed (its output is in *why).
inline std::string cached_synthetic_recording(const std::string& cli, const CachedRecordingSpec& spec,
                                              std::string* why) {
  namespace fs = std::filesystem;
  const fs::path cache = FR_TEST_CACHE_DIR;
  const fs::path out = cache / spec.name;
  const fs::path marker = cache / (spec.name + ".made-with");
  std::error_code ec;
  std::ostringstream args;
  const auto with_file_time = [&](const std::string& a) {
    args << '\n' << a;
    if (fs::is_regular_file(a, ec)) args << '@' << fs::last_write_time(a, ec).time_since_epoch().count();
  };
  with_file_time(cli);
  for (const std::string& a : spec.synth_args) with_file_time(a);
  fs::create_directories(cache, ec);
  const int lock = ::open((cache / ".lock").c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (lock >= 0) ::flock(lock, LOCK_EX);
  std::string dir, error;
  std::ifstream previous(marker);
  const std::string made_with((std::istreambuf_iterator<char>(previous)), std::istreambuf_iterator<char>());
  if (made_with == args.str() && fs::exists(out / "recording.json")) {
    dir = out.string();
  } else {
    fs::remove(marker, ec);
    fs::remove_all(out, ec);
    std::vector<std::string> argv{cli, "synth"};
    argv.insert(argv.end(), spec.synth_args.begin(), spec.synth_args.end());
    argv.insert(argv.end(), {"--out", out.string()});
    const SubprocessResult r = run_subprocess(argv);
    if (r.exit_code != 0) {
      error = "face-reenact synth failed (" + std::to_string(r.exit_code) + "): " + r.output;
    } else {
      std::ofstream(marker) << args.str();
      dir = out.string();
    }
  }
  if (lock >= 0) ::close(lock);  // releases the lock
  if (why) *why = error;
  return dir;
}

}  // namespace face_reenact::testing
