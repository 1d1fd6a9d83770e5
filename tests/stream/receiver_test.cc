// ExpressionReceiver and ExpressionSender over real UDP sockets on 127.0.0.1.
#include "face_reenact/stream/receiver.h"

#include <arpa/inet.h>
#include <dirent.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <fstream>
#include <thread>

#include "face_reenact/common/error.h"
#include "face_reenact/stream/sender.h"
#include "stream_test_util.h"
#include "support/impairing_relay.h"

namespace face_reenact::stream {
namespace {

using namespace std::chrono_literals;
using testing::encode;
using testing::make_frame;
using testing::RawDatagram;
using testing::spec_encode;
using testing::spec_flags;
using testing::spec_payload;
using testing::test_key;
using testing::wait_for;

ExpressionReceiver::Options loopback_options() {
  ExpressionReceiver::Options o;
  o.listen.address = "127.0.0.1";
  o.listen.port = 0;
  return o;
}

UdpEndpoint loopback(uint16_t port) { return resolve_endpoint("127.0.0.1:" + std::to_string(port), "test"); }

// A plain UDP socket for sending arbitrary bytes.
struct RawSender {
  explicit RawSender(uint16_t port) : socket(UdpSocket::open_sender(loopback(port), {})) {}
  void send(const std::vector<uint8_t>& d) { ASSERT_EQ(socket.send(d), 0); }
  UdpSocket socket;
};

void expect_balanced(const ReceiverStatistics& s) {
  EXPECT_EQ(s.received, s.applied + s.reordered + s.late + s.standby + s.rejected_total());
}

TEST(ExpressionReceiver, RoundTripFromSender) {
  const StreamKey key = test_key();
  ExpressionReceiver rx(key, loopback_options());
  ASSERT_NE(rx.port(), 0);
  ExpressionSender::Options so;
  so.stream_id = 3;
  ExpressionSender tx(key, loopback(rx.port()), so);
  ExpressionFrame last;
  for (uint32_t i = 0; i < 50; ++i) {
    last = make_frame(i, i % 2 == 0, i % 3 == 0);
    last.capture_time_us = realtime_now_us();
    ASSERT_TRUE(tx.send(last));
  }
  ASSERT_TRUE(wait_for([&] { return rx.statistics().applied == 50; })) << rx.statistics().applied;
  const RemoteExpression r = rx.sample();
  EXPECT_EQ(r.stream_id, 3u);
  EXPECT_EQ(r.expression, last.relative_expression());
  EXPECT_EQ(r.capture_time_us, last.capture_time_us);
  EXPECT_EQ(r.sequence + 1, tx.statistics().next_sequence);
  const ReceiverStatistics s = rx.statistics();
  EXPECT_EQ(s.received, 50u);
  EXPECT_EQ(s.lost, 0u);
  EXPECT_EQ(s.rejected_total(), 0u);
  EXPECT_GE(s.latency_min_ms, 0.0);  // same clock on both ends
  EXPECT_LT(s.latency_min_ms, 1000.0);
  EXPECT_TRUE(rx.thread_error().empty());
}

TEST(ExpressionReceiver, SenderSequenceStartsFromTheClockSoRestartsAreNotReplays) {
  const StreamKey key = test_key();
  ExpressionReceiver rx(key, loopback_options());
  {
    ExpressionSender tx(key, loopback(rx.port()), {});
    for (int i = 0; i < 5; ++i) tx.send(make_frame(i));
  }
  ASSERT_TRUE(wait_for([&] { return rx.statistics().applied == 5; }));
  std::this_thread::sleep_for(2ms);
  ExpressionSender restarted(key, loopback(rx.port()), {});
  for (int i = 0; i < 5; ++i) restarted.send(make_frame(10 + i));
  ASSERT_TRUE(wait_for([&] { return rx.statistics().applied == 10; })) << rx.statistics().applied;
  EXPECT_EQ(rx.statistics().rejected_total(), 0u);
}

TEST(ExpressionReceiver, ThreadIsNamedAndStopsPromptly) {
  auto rx = std::make_unique<ExpressionReceiver>(test_key(), loopback_options());
  bool found = false;
  ASSERT_TRUE(wait_for([&] {
    DIR* d = ::opendir("/proc/self/task");
    if (!d) return false;
    while (dirent* e = ::readdir(d)) {
      std::ifstream comm(std::string("/proc/self/task/") + e->d_name + "/comm");
      std::string name;
      if (std::getline(comm, name) && name == "fr-stream-rx") found = true;
    }
    ::closedir(d);
    return found;
  }, 2s));
  const auto t = std::chrono::steady_clock::now();
  rx.reset();  // destructor: wake-up fd, join
  EXPECT_LT(std::chrono::steady_clock::now() - t, 1s);
}

TEST(ExpressionReceiver, PortInUseIsAClearError) {
  ExpressionReceiver a(test_key(), loopback_options());
  auto o = loopback_options();
  o.listen.port = a.port();
  try {
    ExpressionReceiver b(test_key(), o);
    FAIL() << "second bind succeeded";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("cannot listen on UDP 127.0.0.1:" + std::to_string(a.port())),
              std::string::npos)
        << e.what();
  }
}

TEST(ExpressionReceiver, EveryKindOfBadDatagramIsRejectedAndCounted) {
  const StreamKey key = test_key();
  auto o = loopback_options();
  o.stream.allowed_streams = {1};
  ExpressionReceiver rx(key, o);
  RawSender raw(rx.port());
  uint64_t seq = 100;
  const auto good = encode(key, 1, seq++, make_frame(1));
  raw.send(good);
  raw.send(good);  // replay
  uint64_t flips = 0;
  for (size_t i = 8; i < good.size(); ++i) {  // forged: a bit flip at every position past the magic/version/flags
    auto bad = encode(key, 1, seq++, make_frame(2));
    bad[i] ^= 0x10;
    raw.send(bad);
    ++flips;
  }
  const auto fresh = encode(key, 1, seq++, make_frame(3));
  raw.send(std::vector<uint8_t>(fresh.begin(), fresh.begin() + 200));  // truncated
  auto oversized = fresh;
  oversized.resize(600, 0);
  raw.send(oversized);
  raw.send(std::vector<uint8_t>(1400, 0x55));  // oversized junk
  raw.send(encode(test_key(42), 1, seq++, make_frame(4)));  // wrong key
  raw.send(encode(key, 2, seq++, make_frame(5)));           // unknown stream
  ExpressionFrame nan_frame = make_frame(6);
  nan_frame.expression[10] = std::numeric_limits<float>::quiet_NaN();
  RawDatagram r;
  r.flags = spec_flags(nan_frame);
  r.payload = spec_payload(nan_frame);
  r.stream_id = 1;
  r.sequence = seq++;
  raw.send(spec_encode(key, r));
  auto bad_magic = encode(key, 1, seq++, make_frame(7));
  bad_magic[1] = 'X';
  raw.send(bad_magic);
  ExpressionFrame last = make_frame(8);
  raw.send(encode(key, 1, seq++, last));  // and a good one still gets through

  const uint64_t total = 2 + flips + 3 + 1 + 1 + 1 + 1 + 1;
  ASSERT_TRUE(wait_for([&] { return rx.statistics().received == total; })) << rx.statistics().received;
  const ReceiverStatistics s = rx.statistics();
  EXPECT_EQ(s.applied, 2u);
  EXPECT_EQ(s.rejected(DatagramError::kReplay), 1u);
  // Flips in the stream id (bytes 8-11) name a stream that is not allowed: dropped before crypto.
  EXPECT_EQ(s.rejected(DatagramError::kAuthFailed), flips - 4 + 1);
  EXPECT_EQ(s.rejected(DatagramError::kTruncated), 1u);
  EXPECT_EQ(s.rejected(DatagramError::kOversized), 2u);
  EXPECT_EQ(s.rejected(DatagramError::kUnknownStream), 4u + 1u);
  EXPECT_EQ(s.rejected(DatagramError::kInvalidValues), 1u);
  EXPECT_EQ(s.rejected(DatagramError::kBadMagic), 1u);
  expect_balanced(s);
  EXPECT_EQ(rx.sample().expression, last.relative_expression());
}

TEST(ExpressionReceiver, LossReorderingAndDuplicationThroughAnImpairingRelay) {
  const StreamKey key = test_key();
  ExpressionReceiver rx(key, loopback_options());
  face_reenact::testing::ImpairingRelay relay(rx.port(), 2024);
  ExpressionSender::Options so;
  so.first_sequence = 1000;
  ExpressionSender tx(key, loopback(relay.port()), so);
  const int n = 600;
  for (int i = 0; i < n; ++i) {
    ExpressionFrame f = make_frame(static_cast<uint32_t>(i));
    f.capture_time_us = 1'000'000 + static_cast<uint64_t>(i);
    tx.send(f);
    if (i % 20 == 0) std::this_thread::sleep_for(1ms);  // stay far from socket buffer limits
  }
  std::this_thread::sleep_for(50ms);
  relay.flush();
  std::vector<uint64_t> fwd;
  ASSERT_TRUE(wait_for([&] {
    fwd = relay.forwarded();
    return !fwd.empty() && rx.statistics().received == fwd.size();
  })) << rx.statistics().received << " of " << fwd.size();

  // What the receiver must report, from the relay's own record.
  const auto want = face_reenact::testing::ExpectedReceiverCounts::From(fwd);
  const ReceiverStatistics st = rx.statistics();
  EXPECT_GT(want.duplicates, 0u);
  EXPECT_GT(want.reordered, 0u);
  EXPECT_GT(want.lost, 0u);
  EXPECT_EQ(st.received, want.received);
  EXPECT_EQ(st.rejected(DatagramError::kReplay), want.duplicates);
  EXPECT_EQ(st.reordered, want.reordered);
  EXPECT_EQ(st.applied, want.applied);
  EXPECT_EQ(st.lost, want.lost);
  EXPECT_EQ(st.kernel_drops, 0u);
  EXPECT_EQ(rx.sample().sequence, want.highest);
  expect_balanced(st);
}

TEST(ExpressionReceiver, FadesOutWhenTheStreamStopsAndBackInWhenItResumes) {
  const StreamKey key = test_key();
  auto o = loopback_options();
  o.stream.timeout = 100ms;
  o.stream.ramp = 100ms;
  ExpressionReceiver rx(key, o);
  ExpressionSender tx(key, loopback(rx.port()), {});
  std::atomic<bool> sending{true};
  auto pump = [&] {
    while (sending) {
      ExpressionFrame f = make_frame(1);
      f.capture_time_us = realtime_now_us();
      tx.send(f);
      std::this_thread::sleep_for(10ms);
    }
  };
  std::thread t(pump);
  EXPECT_TRUE(wait_for([&] { return rx.sample().weight == 1.f; }));
  sending = false;
  t.join();
  // Well past timeout + ramp (200 ms), with margin for a loaded machine.
  EXPECT_TRUE(wait_for([&] { return rx.sample().weight == 0.f; }, 5s));
  std::this_thread::sleep_for(100ms);
  RemoteExpression r = rx.sample();
  EXPECT_FALSE(r.live);
  EXPECT_EQ(r.weight, 0.f);
  EXPECT_TRUE(r.has_frame);
  sending = true;
  std::thread t2(pump);
  EXPECT_TRUE(wait_for([&] { return rx.sample().live; }));
  EXPECT_TRUE(wait_for([&] { return rx.sample().weight == 1.f; }));
  sending = false;
  t2.join();
}

TEST(ExpressionReceiver, ConcurrentSamplingWhileReceiving) {
  const StreamKey key = test_key();
  ExpressionReceiver rx(key, loopback_options());
  ExpressionSender tx(key, loopback(rx.port()), {});
  std::atomic<bool> done{false};
  std::atomic<uint64_t> samples{0};
  std::vector<std::thread> consumers;
  for (int c = 0; c < 3; ++c)
    consumers.emplace_back([&] {
      while (!done) {
        const RemoteExpression r = rx.sample();
        if (r.has_frame) EXPECT_GE(r.weight, 0.f);
        ++samples;
      }
    });
  for (int i = 0; i < 2000; ++i) {
    tx.send(make_frame(static_cast<uint32_t>(i)));
    if (i % 100 == 0) std::this_thread::sleep_for(1ms);
  }
  EXPECT_TRUE(wait_for([&] { return rx.statistics().received == 2000; }));
  done = true;
  for (auto& t : consumers) t.join();
  EXPECT_GT(samples.load(), 0u);
}

TEST(ExpressionReceiver, ReportsDatagramsTheKernelDroppedWhenItFallsBehind) {
  const StreamKey key = test_key();
  auto o = loopback_options();
  o.receive_buffer_bytes = 4096;  // the kernel rounds this up, but it holds only a few datagrams
  std::atomic<bool> stalled{false};
  o.stream.on_applied = [&](const AppliedDatagram&) {
    if (!stalled.exchange(true)) std::this_thread::sleep_for(200ms);  // a slow consumer, once
  };
  ExpressionReceiver rx(key, o);
  ExpressionSender tx(key, loopback(rx.port()), {});
  tx.send(make_frame(0));
  ASSERT_TRUE(wait_for([&] { return stalled.load(); }));
  const uint64_t n = 300;
  for (uint64_t i = 1; i < n - 1; ++i) tx.send(make_frame(static_cast<uint32_t>(i)));
  // The kernel reports its drop count with the next datagram it queues (SO_RXQ_OVFL), so send
  // one more once the consumer has caught up.
  ASSERT_TRUE(wait_for([&] { return rx.statistics().received >= 2; }));
  std::this_thread::sleep_for(50ms);
  tx.send(make_frame(static_cast<uint32_t>(n)));
  ASSERT_TRUE(wait_for([&] {
    const ReceiverStatistics s = rx.statistics();
    return s.received + s.kernel_drops == n;
  })) << rx.statistics().received << " + " << rx.statistics().kernel_drops;
  const ReceiverStatistics s = rx.statistics();
  EXPECT_GT(s.kernel_drops, 0u);
  EXPECT_GT(s.lost, 0u);  // the dropped datagrams also show up as sequence gaps
}

TEST(ExpressionReceiver, ACallbackExceptionStopsTheThreadAndIsReported) {
  const StreamKey key = test_key();
  auto o = loopback_options();
  o.stream.on_applied = [](const AppliedDatagram&) { throw Error("consumer failed"); };
  ExpressionReceiver rx(key, o);
  ExpressionSender tx(key, loopback(rx.port()), {});
  tx.send(make_frame(1));
  ASSERT_TRUE(wait_for([&] { return !rx.thread_error().empty(); }));
  EXPECT_EQ(rx.thread_error(), "consumer failed");
  EXPECT_TRUE(rx.sample().has_frame);  // what arrived before is still there
}

// Multicast on the loopback interface, TTL 0 (never leaves this host). The port is a free
// ephemeral one and the stream id this process's, so concurrent runs do not disturb each other.
TEST(ExpressionReceiver, MulticastOnLoopback) {
  const std::string group = "239.255.42.99";
  const StreamKey key = test_key();
  uint16_t port;
  {
    ListenSpec l;
    l.address = "127.0.0.1";
    port = UdpSocket::open_receiver(l, "", 0).local_port();
  }
  const uint32_t stream_id = static_cast<uint32_t>(::getpid());
  auto o = loopback_options();
  o.listen.address = group;
  o.listen.port = port;
  o.listen.multicast = true;
  o.multicast_interface = "127.0.0.1";
  o.stream.allowed_streams = {stream_id};
  std::unique_ptr<ExpressionReceiver> a, b;
  try {
    a = std::make_unique<ExpressionReceiver>(key, o);
    b = std::make_unique<ExpressionReceiver>(key, o);  // a second target on the same group
  } catch (const Error& e) {
    GTEST_SKIP() << "this environment cannot join an IPv4 multicast group on the loopback interface: "
                 << e.what();
  }
  ExpressionSender::Options so;
  so.stream_id = stream_id;
  so.multicast.ttl = 0;
  so.multicast.loopback = true;
  so.multicast.interface_address = "127.0.0.1";
  ExpressionSender tx(key, resolve_endpoint(group + ":" + std::to_string(port), "test"), so);
  bool delivered = wait_for([&] {
    tx.send(make_frame(1));
    return a->statistics().applied > 0 && b->statistics().applied > 0;
  }, 3s);
  if (!delivered && a->statistics().received == 0 && b->statistics().received == 0)
    GTEST_SKIP() << "joined " << group << " on 127.0.0.1 but the environment delivers no multicast on loopback";
  EXPECT_TRUE(delivered);
  EXPECT_EQ(a->statistics().rejected(DatagramError::kAuthFailed), 0u);
  EXPECT_EQ(b->statistics().rejected(DatagramError::kInvalidValues), 0u);
  EXPECT_EQ(b->sample().expression, make_frame(1).relative_expression());
  EXPECT_EQ(a->sample().stream_id, stream_id);
}

}  // namespace
}  // namespace face_reenact::stream
