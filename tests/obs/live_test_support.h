#pragma once
// Shared by the live-session and OBS tests: a tiny synthetic RGB-D recording made once with
// `face-reenact synth` (160x120, 12 frames: ~2 s) and shared by the test processes, and helpers.
#include <gtest/gtest.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <opencv2/core.hpp>
#include <opencv2/core/mat.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "face_reenact/capture/recording.h"
#include "face_reenact/common/thread_cpu.h"
#include "support/cached_recording.h"

namespace face_reenact::test {

inline constexpr int kRecordingWidth = 160;
inline constexpr int kRecordingHeight = 120;
inline constexpr int kRecordingFrames = 12;

// A UDP port on 127.0.0.1 that nothing listens on: the kernel's pick, released again.
inline uint16_t free_udp_port() {
  int fd = ::socket(AF_INET, SOCK_DGRAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  ::close(fd);
  return ntohs(a.sin_port);
}

// Runs a shell command, returns its exit status and (stdout+stderr) in *output.
inline int run_command(const std::string& command, std::string* output) {
  std::string full = command + " 2>&1";
  FILE* pipe = ::popen(full.c_str(), "r");
  if (!pipe) return -1;
  char buf[4096];
  std::string text;
  size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, pipe)) > 0) text.append(buf, n);
  int status = ::pclose(pipe);
  if (output) *output = text;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

inline std::string quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

// A synthetic recording (`face-reenact synth`), made once and shared by every test process
// (support/cached_recording.h). Empty with *why when it cannot be made (no CLI, no model).
struct TestRecordingSpec {
  std::string name;
  int width, height, frames, seed;
};
inline std::string make_test_recording(const TestRecordingSpec& spec, std::string* why) {
  const char* cli = std::getenv("FR_CLI");
  const char* model = std::getenv("FR_MODEL");
  if (!cli || !std::filesystem::exists(cli)) {
    if (why) *why = "the face-reenact program (FR_CLI) is not built";
    return {};
  }
  if (!model || !std::filesystem::exists(model)) {
    if (why) *why = std::string("no face model at FR_MODEL='") + (model ? model : "") + "' (run ./setup.sh to generate it)";
    return {};
  }
  return testing::cached_synthetic_recording(
      cli,
      {spec.name,
       {"--size", std::to_string(spec.width) + "x" + std::to_string(spec.height), "--frames", std::to_string(spec.frames),
        "--seed", std::to_string(spec.seed), "--quiet", "--model", model}},
      why);
}

// The tests' usual recording: 160x120, 12 frames (~2 s), a face too small for the landmark
// detector (so the pipeline runs without ever calibrating).
inline const std::string& test_recording(std::string* why) {
  static std::string dir, error;
  static bool tried = false;
  if (!tried) {
    tried = true;
    dir = make_test_recording({"recording", kRecordingWidth, kRecordingHeight, kRecordingFrames, 7}, &error);
  }
  if (why) *why = error;
  return dir;
}

// The recording's colour frames (BGR), in order.
inline std::vector<cv::Mat> recording_frames(const std::string& dir) {
  capture::RecordingReader reader(dir);
  std::vector<cv::Mat> frames;
  for (int i = 0; i < reader.frame_count(); ++i) frames.push_back(reader.read(i).color);
  return frames;
}

// Mean absolute difference per channel value between `image` (BGR) and the closest frame.
inline double closest_frame_difference(const cv::Mat& image, const std::vector<cv::Mat>& frames, int* index = nullptr) {
  double best = 1e9;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].size() != image.size() || frames[i].type() != image.type()) continue;
    cv::Mat diff;
    cv::absdiff(frames[i], image, diff);
    cv::Scalar d = cv::mean(diff);
    double mean = (d[0] + d[1] + d[2]) / 3;
    if (mean < best) {
      best = mean;
      if (index) *index = static_cast<int>(i);
    }
  }
  return best;
}

// Names of this process's threads.
inline std::vector<std::string> thread_names() {
  std::vector<std::string> names;
  for (const ThreadInfo& t : ProcessThreads()) names.push_back(t.name);
  return names;
}

// Nice values of the threads whose name starts with `prefix`.
inline std::vector<int> thread_nice_values(const std::string& prefix) {
  std::vector<int> values;
  for (const ThreadInfo& t : ProcessThreads())
    if (t.name.rfind(prefix, 0) == 0) values.push_back(t.nice);
  return values;
}

inline int count_threads_with_prefix(const std::string& prefix) {
  int n = 0;
  for (const auto& name : thread_names()) n += name.rfind(prefix, 0) == 0;
  return n;
}

// The count of threads with `prefix` once it is `expected`, or the last count after `timeout`.
// A thread that is ending or starting about now (the pipeline's loading thread, "fr-live-load",
// ends once the model is loaded) may be counted or not at any one moment; a thread that stays is
// counted every time. (Until 2026-11-29 the actor's fit ran on a thread started per frame that
// carried its creator's name, "fr-live", until it renamed itself: the clean-clone suite once saw
// one thread too many. It is a kept NamedThread now, named before it is seen.)
inline int settled_thread_count(const std::string& prefix, int expected,
                                std::chrono::milliseconds timeout = std::chrono::seconds(5)) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  int n = count_threads_with_prefix(prefix);
  while (n != expected && std::chrono::steady_clock::now() < end) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
    n = count_threads_with_prefix(prefix);
  }
  return n;
}

}  // namespace face_reenact::test
