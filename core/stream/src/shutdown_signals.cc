#include "face_reenact/stream/shutdown_signals.h"

#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <sys/signalfd.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "face_reenact/common/error.h"

namespace face_reenact::stream {

static_assert(sizeof(sigset_t) <= 128, "old_mask_ too small for sigset_t");

ShutdownSignals::ShutdownSignals() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  sigset_t old;
  if (pthread_sigmask(SIG_BLOCK, &set, &old) != 0) throw Error("cannot block SIGINT/SIGTERM");
  std::memcpy(old_mask_, &old, sizeof(old));
  fd_ = ::signalfd(-1, &set, SFD_NONBLOCK | SFD_CLOEXEC);
  if (fd_ < 0) {
    const int err = errno;
    pthread_sigmask(SIG_SETMASK, &old, nullptr);
    throw Error(std::string("cannot create a signalfd: ") + std::strerror(err));
  }
}

ShutdownSignals::~ShutdownSignals() {
  if (fd_ >= 0) ::close(fd_);
  sigset_t old;
  std::memcpy(&old, old_mask_, sizeof(old));
  pthread_sigmask(SIG_SETMASK, &old, nullptr);
}

int ShutdownSignals::wait(std::chrono::milliseconds timeout) {
  pollfd pfd{fd_, POLLIN, 0};
  const int pr = ::poll(&pfd, 1, static_cast<int>(timeout.count() < 0 ? 0 : timeout.count()));
  if (pr > 0) {
    signalfd_siginfo info;
    if (::read(fd_, &info, sizeof(info)) == static_cast<ssize_t>(sizeof(info))) {
      if (received_ == 0) received_ = static_cast<int>(info.ssi_signo);
      return static_cast<int>(info.ssi_signo);
    }
  }
  return 0;
}

}  // namespace face_reenact::stream
