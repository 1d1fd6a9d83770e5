#pragma once
// ExpressionReceiver: the target side of the expression stream. It owns a UDP socket (unicast
// or multicast) and a named thread ("fr-stream-rx") that reads datagrams in batches and feeds
// them to an ExpressionStreamState; consumers (the renderer, the OBS source, the virtual webcam)
// call sample(now) from their own threads without ever waiting on the network.
//
// The thread waits with poll() on the socket and an eventfd, so stop()/the destructor wake it
// and join it at once; it never blocks in recv.
#include <atomic>
#include <chrono>
#include <memory>
#include <string>
#include <thread>

#include "face_reenact/stream/stream_state.h"
#include "face_reenact/stream/udp.h"

namespace face_reenact::stream {

class ExpressionReceiver {
 public:
  struct Options {
    ListenSpec listen;                  // port 0: any free port (see port())
    std::string multicast_interface;    // IPv4 address of the interface to join the group on
    int receive_buffer_bytes = 1 << 20;
    StreamStateOptions stream;          // allow-list, timeout, ramp, on_applied callback
    std::string thread_name = "fr-stream-rx";  // at most 15 characters (Linux limit)

    bool IsValid(std::string* why) const;
  };

  // Opens the socket and starts the thread. Throws face_reenact::Error (bad options, port in
  // use, cannot join the group).
  ExpressionReceiver(const StreamKey& key, Options options);
  ~ExpressionReceiver();  // stop()
  ExpressionReceiver(const ExpressionReceiver&) = delete;
  ExpressionReceiver& operator=(const ExpressionReceiver&) = delete;

  uint16_t port() const { return port_; }
  RemoteExpression sample(SteadyClock::time_point now = SteadyClock::now()) const {
    return state_.sample(now);
  }
  ReceiverStatistics statistics(SteadyClock::time_point now = SteadyClock::now()) const {
    return state_.statistics(now);
  }
  // Why the thread stopped on its own (socket error), or empty.
  std::string thread_error() const;

  // Wakes and joins the thread; idempotent.
  void stop();

 private:
  void run();

  ExpressionStreamState state_;
  Options options_;
  UdpSocket socket_;
  int wake_fd_ = -1;
  uint16_t port_ = 0;
  std::atomic<bool> stopping_{false};
  mutable std::mutex error_mu_;
  std::string thread_error_;
  std::thread thread_;
};

}  // namespace face_reenact::stream
