#include "face_reenact/stream/receiver.h"

#include <poll.h>
#include <pthread.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "face_reenact/common/error.h"

namespace face_reenact::stream {
namespace {

constexpr int kBatch = 32;
// Larger than any valid datagram, so an oversized one is seen as such rather than cut to fit.
constexpr size_t kReceiveBufferSize = 1024;
static_assert(kReceiveBufferSize > kMaxDatagramSize);
constexpr int kPollTimeoutMs = 250;  // upper bound on how long a missed wake-up could delay stop

}  // namespace

bool ExpressionReceiver::Options::IsValid(std::string* why) const {
  if (thread_name.empty() || thread_name.size() > 15) {
    if (why) *why = "thread name must have 1-15 characters";
    return false;
  }
  if (receive_buffer_bytes < 0) {
    if (why) *why = "receive buffer size must not be negative";
    return false;
  }
  return stream.IsValid(why);
}

ExpressionReceiver::ExpressionReceiver(const StreamKey& key, Options options)
    : state_(key, options.stream), options_(std::move(options)) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error("expression receiver: " + why);
  socket_ = UdpSocket::open_receiver(options_.listen, options_.multicast_interface,
                                     options_.receive_buffer_bytes);
  port_ = socket_.local_port();
  wake_fd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (wake_fd_ < 0) throw Error(std::string("cannot create an eventfd: ") + std::strerror(errno));
  try {
    thread_ = std::thread([this] { run(); });
  } catch (const std::system_error& e) {
    ::close(wake_fd_);
    throw Error(std::string("cannot start the receiver thread: ") + e.what());
  }
}

ExpressionReceiver::~ExpressionReceiver() {
  stop();
  if (wake_fd_ >= 0) ::close(wake_fd_);
}

void ExpressionReceiver::stop() {
  stopping_.store(true, std::memory_order_release);
  if (wake_fd_ >= 0) {
    const uint64_t one = 1;
    [[maybe_unused]] ssize_t n = ::write(wake_fd_, &one, sizeof(one));
  }
  if (thread_.joinable()) thread_.join();
}

std::string ExpressionReceiver::thread_error() const {
  std::lock_guard<std::mutex> lock(error_mu_);
  return thread_error_;
}

void ExpressionReceiver::run() {
  ::pthread_setname_np(::pthread_self(), options_.thread_name.c_str());
  try {
    // Per-message buffers for one batch, allocated once.
    struct Slot {
      alignas(8) uint8_t data[kReceiveBufferSize];
      alignas(cmsghdr) uint8_t control[CMSG_SPACE(sizeof(uint32_t))];
      iovec iov;
    };
    auto slots = std::make_unique<Slot[]>(kBatch);
    mmsghdr msgs[kBatch];
    uint32_t last_overflow = 0;
    bool have_overflow = false;

    pollfd fds[2] = {{socket_.fd(), POLLIN, 0}, {wake_fd_, POLLIN, 0}};
    while (!stopping_.load(std::memory_order_acquire)) {
      const int pr = ::poll(fds, 2, kPollTimeoutMs);
      if (pr < 0) {
        if (errno == EINTR) continue;
        throw Error(std::string("poll failed: ") + std::strerror(errno));
      }
      if (fds[1].revents) break;
      if (!(fds[0].revents & (POLLIN | POLLERR))) continue;
      // Drain what is queued, a batch at a time.
      for (;;) {
        for (int i = 0; i < kBatch; ++i) {
          slots[i].iov = {slots[i].data, kReceiveBufferSize};
          std::memset(&msgs[i], 0, sizeof(mmsghdr));
          msgs[i].msg_hdr.msg_iov = &slots[i].iov;
          msgs[i].msg_hdr.msg_iovlen = 1;
          msgs[i].msg_hdr.msg_control = slots[i].control;
          msgs[i].msg_hdr.msg_controllen = sizeof(slots[i].control);
        }
        const int n = ::recvmmsg(socket_.fd(), msgs, kBatch, MSG_DONTWAIT, nullptr);
        if (n < 0) {
          if (errno == EINTR) continue;
          if (errno == EAGAIN || errno == EWOULDBLOCK) break;
          // ICMP errors queued on the socket (e.g. ECONNREFUSED) are not fatal for a receiver.
          if (errno == ECONNREFUSED || errno == EHOSTUNREACH || errno == ENETUNREACH) continue;
          throw Error(std::string("receive failed: ") + std::strerror(errno));
        }
        const SteadyClock::time_point arrival = SteadyClock::now();
        const uint64_t wall_us = realtime_now_us();
        for (int i = 0; i < n; ++i) {
          for (cmsghdr* c = CMSG_FIRSTHDR(&msgs[i].msg_hdr); c; c = CMSG_NXTHDR(&msgs[i].msg_hdr, c)) {
            if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_RXQ_OVFL) {
              uint32_t total;
              std::memcpy(&total, CMSG_DATA(c), sizeof(total));
              if (have_overflow && total > last_overflow) state_.add_kernel_drops(total - last_overflow);
              if (!have_overflow && total > 0) state_.add_kernel_drops(total);
              last_overflow = total;
              have_overflow = true;
            }
          }
          const size_t len = std::min<size_t>(msgs[i].msg_len, kReceiveBufferSize);
          state_.process(std::span<const uint8_t>(slots[i].data, len), arrival, wall_us);
        }
        if (n < kBatch || stopping_.load(std::memory_order_acquire)) break;
      }
    }
  } catch (const std::exception& e) {
    std::lock_guard<std::mutex> lock(error_mu_);
    thread_error_ = e.what();
  }
}

}  // namespace face_reenact::stream
