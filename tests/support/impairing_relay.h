#pragma once
// A lossy network between an expression sender and a receiver, on 127.0.0.1: forwards datagrams
// from its own port to `to`, dropping, duplicating and holding back (reordering) some with a
// seeded generator, and dropping all of them while an outage is on. It records exactly what it
// forwarded, so a test can say what the receiver must have counted (ExpectedReceiverCounts).
// The receiver's own tests and the live session's (the webcam's and OBS's path) share it.
#include <poll.h>
#include <sys/socket.h>

#include <atomic>
#include <cstdint>
#include <mutex>
#include <random>
#include <set>
#include <thread>
#include <vector>

#include "face_reenact/stream/udp.h"

namespace face_reenact::testing {

class ImpairingRelay {
 public:
  // Of every 100 datagrams about 10 are dropped, 10 held back and released after one to a few
  // later ones, and 10 forwarded twice.
  ImpairingRelay(uint16_t to, uint32_t seed) : rng_(seed) {
    stream::ListenSpec in;
    in.address = "127.0.0.1";
    in_ = stream::UdpSocket::open_receiver(in, "", 1 << 20);
    out_ = stream::UdpSocket::open_sender(stream::resolve_endpoint("127.0.0.1:" + std::to_string(to), "relay"), {});
    thread_ = std::thread([this] { run(); });
  }
  ~ImpairingRelay() {
    stop_ = true;
    thread_.join();
  }
  ImpairingRelay(const ImpairingRelay&) = delete;
  ImpairingRelay& operator=(const ImpairingRelay&) = delete;

  uint16_t port() const { return in_.local_port(); }
  // Sequence numbers in the order they were forwarded (duplicates included).
  std::vector<uint64_t> forwarded() {
    std::lock_guard<std::mutex> l(mu_);
    return forwarded_;
  }
  // Datagrams that came in while an outage was on (all dropped), and those dropped at random.
  uint64_t dropped_in_outages() const { return outage_drops_; }
  uint64_t dropped_at_random() const { return random_drops_; }
  // While on, nothing gets through (a cable pulled, a Wi-Fi gap); datagrams held back when it
  // starts are lost with it (released after it, they would be older than the replay window).
  void set_outage(bool on) { outage_ = on; }
  // Forwards every held-back datagram with the next pass (before a test compares the counts).
  void flush() { flush_ = true; }

 private:
  void forward(const std::vector<uint8_t>& d) {
    out_.send(d);
    uint64_t seq = 0;
    for (int i = 0; i < 8; ++i) seq |= uint64_t(d[12 + i]) << (8 * i);  // the header's sequence number
    std::lock_guard<std::mutex> l(mu_);
    forwarded_.push_back(seq);
  }
  void run() {
    std::vector<std::vector<uint8_t>> held;
    pollfd p{in_.fd(), POLLIN, 0};
    while (!stop_) {
      if (flush_) {
        for (auto& h : held) forward(h);
        held.clear();
        flush_ = false;
      }
      if (::poll(&p, 1, 10) <= 0) continue;
      std::vector<uint8_t> d(2048);
      const ssize_t n = ::recv(in_.fd(), d.data(), d.size(), 0);
      if (n < 20) continue;
      d.resize(static_cast<size_t>(n));
      if (outage_) {
        outage_drops_ += 1 + held.size();
        held.clear();
        continue;
      }
      const int roll = static_cast<int>(rng_() % 100);
      if (roll < 10) {
        ++random_drops_;
        continue;
      }
      if (roll < 20) {  // released after 1-3 later datagrams
        held.push_back(d);
        continue;
      }
      forward(d);
      if (roll < 30) forward(d);
      if (!held.empty() && rng_() % 2 == 0) {
        forward(held.front());
        held.erase(held.begin());
      }
    }
  }
  std::mt19937 rng_;
  stream::UdpSocket in_, out_;
  std::atomic<bool> stop_{false}, flush_{false}, outage_{false};
  std::atomic<uint64_t> outage_drops_{0}, random_drops_{0};
  std::mutex mu_;
  std::vector<uint64_t> forwarded_;
  std::thread thread_;
};

// What a receiver locked onto one stream must count for datagrams arriving in `forwarded` order
// (each sent once, in sequence order, with rising capture times), by the protocol's rules
// (docs/stream-protocol.md): a sequence number seen before is a duplicate; one above the highest so far is
// applied and the numbers it skips are lost; one below it is reordered (not applied) and no longer
// lost. The first arrival anchors the count.
struct ExpectedReceiverCounts {
  uint64_t received = 0, applied = 0, duplicates = 0, reordered = 0, lost = 0, highest = 0;

  static ExpectedReceiverCounts From(const std::vector<uint64_t>& forwarded) {
    ExpectedReceiverCounts c;
    std::set<uint64_t> seen;
    for (uint64_t s : forwarded) {
      ++c.received;
      if (!seen.insert(s).second) {
        ++c.duplicates;
      } else if (seen.size() == 1) {
        ++c.applied;
        c.highest = s;
      } else if (s > c.highest) {
        c.lost += s - c.highest - 1;
        ++c.applied;
        c.highest = s;
      } else {
        ++c.reordered;
        if (c.lost > 0) --c.lost;
      }
    }
    return c;
  }
};

}  // namespace face_reenact::testing
