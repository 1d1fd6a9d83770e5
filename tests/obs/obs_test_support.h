#pragma once
// A private X server for tests that run libobs or OBS: libobs 29 on Linux needs an X display
// (its hotkey and OpenGL set-up open one), so the tests start Xvfb on a free display number
// (-displayfd) and stop it afterwards. Mesa's llvmpipe gives OpenGL 4.5 there.
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace face_reenact::test {

class XvfbServer {
 public:
  XvfbServer() = default;
  ~XvfbServer() { stop(); }
  XvfbServer(const XvfbServer&) = delete;
  XvfbServer& operator=(const XvfbServer&) = delete;

  // Starts Xvfb; returns false with *why when it is not installed or does not come up in 20 s.
  bool start(std::string* why) {
    const char* candidates[] = {"/usr/bin/Xvfb", "/usr/local/bin/Xvfb"};
    std::string binary;
    for (const char* c : candidates)
      if (std::filesystem::exists(c)) binary = c;
    if (binary.empty()) return *why = "Xvfb is not installed (apt-get install xvfb)", false;
    int fds[2];
    if (::pipe(fds) != 0) return *why = "pipe() failed", false;
    pid_ = ::fork();
    if (pid_ < 0) return *why = "fork() failed", false;
    if (pid_ == 0) {
      ::close(fds[0]);
      int devnull = ::open("/dev/null", O_RDWR);
      if (devnull >= 0) {
        ::dup2(devnull, 0);
        ::dup2(devnull, 1);
        ::dup2(devnull, 2);
      }
      std::string fd = std::to_string(fds[1]);
      ::execl(binary.c_str(), binary.c_str(), "-displayfd", fd.c_str(), "-screen", "0", "640x480x24", "-nolisten",
              "tcp", "-noreset", static_cast<char*>(nullptr));
      ::_exit(127);
    }
    ::close(fds[1]);
    std::string number;
    pollfd p{fds[0], POLLIN, 0};
    while (::poll(&p, 1, 20000) > 0) {
      char c;
      if (::read(fds[0], &c, 1) != 1 || c == '\n') break;
      number += c;
    }
    ::close(fds[0]);
    if (number.empty()) {
      stop();
      return *why = "Xvfb did not start within 20 s", false;
    }
    display_ = ":" + number;
    return true;
  }
  void stop() {
    if (pid_ > 0) {
      ::kill(pid_, SIGTERM);
      int status = 0;
      ::waitpid(pid_, &status, 0);
      pid_ = -1;
    }
  }
  const std::string& display() const { return display_; }

 private:
  pid_t pid_ = -1;
  std::string display_;
};

}  // namespace face_reenact::test
