#include "face_reenact/stream/stream_state.h"

#include <gtest/gtest.h>

#include "face_reenact/common/error.h"
#include "stream_test_util.h"

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

constexpr SteadyClock::time_point T0{std::chrono::seconds(1000)};

void expect_balanced(const ReceiverStatistics& s) {
  EXPECT_EQ(s.received, s.applied + s.reordered + s.late + s.standby + s.rejected_total());
}

class StreamStateTest : public ::testing::Test {
 protected:
  StreamKey key_ = test_key();
  // A frame whose capture time follows its sequence number.
  std::vector<uint8_t> datagram(uint32_t stream, uint64_t seq) {
    ExpressionFrame f = make_frame(static_cast<uint32_t>(seq));
    f.capture_time_us = 1'000'000 + seq * 1000;
    return encode(key_, stream, seq, f);
  }
};

TEST_F(StreamStateTest, AppliesAndSamplesTheLatestFrame) {
  StreamStateOptions o;
  o.allowed_streams = {5};
  ExpressionStreamState s(key_, o);
  EXPECT_FALSE(s.sample(T0).has_frame);
  EXPECT_EQ(s.sample(T0).weight, 0.f);
  ExpressionFrame f = make_frame(1, true, true);
  ASSERT_EQ(s.process(encode(key_, 5, 10, f), T0, f.capture_time_us + 2000), DatagramError::kNone);
  const RemoteExpression r = s.sample(T0 + 10ms);
  EXPECT_TRUE(r.has_frame);
  EXPECT_TRUE(r.live);
  EXPECT_EQ(r.sequence, 10u);
  EXPECT_EQ(r.stream_id, 5u);
  EXPECT_EQ(r.expression, f.relative_expression());
  EXPECT_TRUE(r.has_rotation);
  EXPECT_EQ(r.rotation, f.rotation);
  EXPECT_NEAR(r.age_ms, 10.0, 1e-6);
  const ReceiverStatistics st = s.statistics(T0);
  EXPECT_EQ(st.applied, 1u);
  EXPECT_NEAR(st.latency_ms, 2.0, 1e-9);
  expect_balanced(st);
}

TEST_F(StreamStateTest, ReplaysDuplicatesAndOldDatagramsAreRejected) {
  ExpressionStreamState s(key_, {});
  const auto d = datagram(1, 5000);
  EXPECT_EQ(s.process(d, T0, 0), DatagramError::kNone);
  EXPECT_EQ(s.process(d, T0 + 1ms, 0), DatagramError::kReplay);  // exact replay
  EXPECT_EQ(s.process(datagram(1, 5000), T0 + 1ms, 0), DatagramError::kReplay);  // same seq, new nonce
  EXPECT_EQ(s.process(datagram(1, 5000 + ReplayWindow::kSize), T0 + 2ms, 0), DatagramError::kNone);
  EXPECT_EQ(s.process(datagram(1, 4999), T0 + 3ms, 0), DatagramError::kTooOld);
  const ReceiverStatistics st = s.statistics(T0);
  EXPECT_EQ(st.rejected(DatagramError::kReplay), 2u);
  EXPECT_EQ(st.rejected(DatagramError::kTooOld), 1u);
  EXPECT_EQ(st.applied, 2u);
  expect_balanced(st);
}

TEST_F(StreamStateTest, ForgedDatagramsDoNotAdvanceTheReplayWindow) {
  ExpressionStreamState s(key_, StreamStateOptions{{1}});
  auto forged = datagram(1, 900);
  forged.back() ^= 1;
  EXPECT_EQ(s.process(forged, T0, 0), DatagramError::kAuthFailed);
  // Had the forgery advanced the window, 100 would now be "too old".
  EXPECT_EQ(s.process(datagram(1, 100), T0, 0), DatagramError::kNone);
  EXPECT_EQ(s.process(encode(test_key(99), 1, 101, make_frame(1)), T0, 0), DatagramError::kAuthFailed);
  EXPECT_EQ(s.statistics(T0).rejected(DatagramError::kAuthFailed), 2u);
}

TEST_F(StreamStateTest, AllowListDropsUnknownStreamsBeforeCrypto) {
  StreamStateOptions o;
  o.allowed_streams = {1, 2};
  ExpressionStreamState s(key_, o);
  EXPECT_EQ(s.process(datagram(3, 1), T0, 0), DatagramError::kUnknownStream);
  // Even garbage after a valid-looking header is "unknown stream", not "auth failed".
  auto forged = datagram(4, 1);
  forged[40] ^= 0xFF;
  EXPECT_EQ(s.process(forged, T0, 0), DatagramError::kUnknownStream);
  EXPECT_EQ(s.process(datagram(2, 1), T0, 0), DatagramError::kNone);
  EXPECT_EQ(s.statistics(T0).rejected(DatagramError::kUnknownStream), 2u);
}

TEST_F(StreamStateTest, LocksOntoTheFirstAuthenticatedStream) {
  ExpressionStreamState s(key_, {});
  auto forged = datagram(8, 1);
  forged[50] ^= 1;
  EXPECT_EQ(s.process(forged, T0, 0), DatagramError::kAuthFailed);  // a forgery cannot take the lock
  EXPECT_EQ(s.process(datagram(7, 1), T0, 0), DatagramError::kNone);
  EXPECT_EQ(s.process(datagram(8, 2), T0, 0), DatagramError::kUnknownStream);
  EXPECT_EQ(s.process(datagram(7, 2), T0, 0), DatagramError::kNone);
  EXPECT_EQ(s.sample(T0).stream_id, 7u);
  s.reset();
  EXPECT_EQ(s.process(datagram(8, 3), T0, 0), DatagramError::kNone);
  EXPECT_EQ(s.sample(T0).stream_id, 8u);
}

TEST_F(StreamStateTest, CountsLossAndReorderingAndAppliesLatestOnly) {
  ExpressionStreamState s(key_, {});
  for (uint64_t seq : {1, 2, 5, 6}) s.process(datagram(1, seq), T0, 0);
  EXPECT_EQ(s.statistics(T0).lost, 2u);  // 3 and 4 missing
  EXPECT_EQ(s.process(datagram(1, 3), T0, 0), DatagramError::kNone);
  ReceiverStatistics st = s.statistics(T0);
  EXPECT_EQ(st.reordered, 1u);
  EXPECT_EQ(st.lost, 1u);
  EXPECT_EQ(st.applied, 4u);
  EXPECT_EQ(s.sample(T0).sequence, 6u);  // the late 3 did not replace 6
  // A jump far beyond any plausible loss is a restarted sender, not a million lost datagrams.
  s.process(datagram(1, 10'000'000), T0, 0);
  st = s.statistics(T0);
  EXPECT_EQ(st.lost, 1u);
  EXPECT_EQ(st.sequence_jumps, 1u);
  expect_balanced(st);
}

TEST_F(StreamStateTest, NewerSequenceWithOlderTimestampIsLate) {
  ExpressionStreamState s(key_, {});
  ExpressionFrame a = make_frame(1), b = make_frame(2);
  a.capture_time_us = 2'000'000;
  b.capture_time_us = 1'000'000;
  s.process(encode(key_, 1, 10, a), T0, 0);
  EXPECT_EQ(s.process(encode(key_, 1, 11, b), T0, 0), DatagramError::kNone);
  EXPECT_EQ(s.statistics(T0).late, 1u);
  EXPECT_EQ(s.sample(T0).sequence, 10u);
}

TEST_F(StreamStateTest, InvalidValuesAreCountedAndSpendTheSequenceNumber) {
  ExpressionStreamState s(key_, {});
  ExpressionFrame f = make_frame(1);
  f.expression[3] = std::numeric_limits<float>::quiet_NaN();
  RawDatagram r;
  r.flags = spec_flags(f);
  r.payload = spec_payload(f);
  r.sequence = 50;
  const auto d = spec_encode(key_, r);
  EXPECT_EQ(s.process(d, T0, 0), DatagramError::kInvalidValues);
  EXPECT_EQ(s.process(d, T0, 0), DatagramError::kReplay);
  EXPECT_FALSE(s.sample(T0).has_frame);
  EXPECT_EQ(s.statistics(T0).rejected(DatagramError::kInvalidValues), 1u);
}

TEST_F(StreamStateTest, FailsOverToAStandbyStreamOnlyAfterTheTimeout) {
  StreamStateOptions o;
  o.allowed_streams = {1, 2};
  o.timeout = 500ms;
  ExpressionStreamState s(key_, o);
  s.process(datagram(1, 1), T0, 0);
  s.process(datagram(2, 1), T0 + 10ms, 0);
  EXPECT_EQ(s.sample(T0 + 10ms).stream_id, 1u);
  EXPECT_EQ(s.statistics(T0).standby, 1u);
  s.process(datagram(2, 2), T0 + 600ms, 0);  // stream 1 silent for 600 ms
  EXPECT_EQ(s.sample(T0 + 600ms).stream_id, 2u);
  s.process(datagram(1, 2), T0 + 610ms, 0);  // 1 is back, but 2 is now live
  EXPECT_EQ(s.sample(T0 + 610ms).stream_id, 2u);
  const ReceiverStatistics st = s.statistics(T0);
  EXPECT_EQ(st.stream_switches, 2u);
  EXPECT_EQ(st.standby, 2u);
  expect_balanced(st);
}

TEST_F(StreamStateTest, FallbackRampWhenTheStreamStopsAndResumes) {
  StreamStateOptions o;
  o.timeout = 500ms;
  o.ramp = 200ms;
  ExpressionStreamState s(key_, o);
  // 30 Hz for one second.
  uint64_t seq = 1;
  for (int i = 0; i <= 30; ++i) s.process(datagram(1, seq++), T0 + i * 33ms, 0);
  const auto last = T0 + 30 * 33ms;
  EXPECT_NEAR(s.sample(T0).weight, 0.f, 1e-6);          // fade-in starts at 0
  EXPECT_NEAR(s.sample(T0 + 100ms).weight, 0.5f, 1e-5);
  EXPECT_NEAR(s.sample(T0 + 200ms).weight, 1.f, 1e-6);
  EXPECT_NEAR(s.sample(last + 500ms).weight, 1.f, 1e-6);  // within the timeout
  EXPECT_TRUE(s.sample(last + 500ms).live);
  EXPECT_NEAR(s.sample(last + 550ms).weight, 0.75f, 1e-5);  // fading out
  EXPECT_FALSE(s.sample(last + 550ms).live);
  EXPECT_NEAR(s.sample(last + 700ms).weight, 0.f, 1e-6);
  EXPECT_NEAR(s.sample(last + 5s).weight, 0.f, 1e-6);
  EXPECT_TRUE(s.sample(last + 5s).has_frame);  // the last frame is still there to fade from
  // Weight never increases while the stream is silent, whatever the sampling pattern.
  float prev = 1.f;
  for (int ms = 0; ms < 1000; ms += 7) {
    const float w = s.sample(last + std::chrono::milliseconds(ms)).weight;
    EXPECT_LE(w, prev + 1e-6f);
    EXPECT_GE(w, 0.f);
    prev = w;
  }
  // Resume in the middle of a fade-out: fade back in from where it was, no jump.
  const auto resume = last + 600ms;  // weight 0.5 at this instant
  const float before = s.sample(resume).weight;
  EXPECT_NEAR(before, 0.5f, 1e-5);
  s.process(datagram(1, seq++), resume, 0);
  EXPECT_NEAR(s.sample(resume).weight, before, 1e-5);
  EXPECT_NEAR(s.sample(resume + 50ms).weight, 0.75f, 1e-5);
  s.process(datagram(1, seq++), resume + 33ms, 0);
  EXPECT_NEAR(s.sample(resume + 100ms).weight, 1.f, 1e-6);
}

TEST_F(StreamStateTest, CallbackSeesEveryAppliedDatagram) {
  std::vector<uint64_t> seen;
  StreamStateOptions o;
  o.on_applied = [&](const AppliedDatagram& d) { seen.push_back(d.header.sequence); };
  ExpressionStreamState s(key_, o);
  for (uint64_t seq : {1, 3, 2, 3, 4}) s.process(datagram(1, seq), T0, 0);
  EXPECT_EQ(seen, (std::vector<uint64_t>{1, 3, 4}));
}

TEST_F(StreamStateTest, InvalidOptionsAreRefused) {
  StreamStateOptions o;
  o.allowed_streams = {1, 1};
  std::string why;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_THROW(ExpressionStreamState(key_, o), Error);
  o.allowed_streams.assign(17, 0);
  for (uint32_t i = 0; i < 17; ++i) o.allowed_streams[i] = i;
  EXPECT_FALSE(o.IsValid(&why));
  o.allowed_streams.clear();
  o.timeout = 0ms;
  EXPECT_FALSE(o.IsValid(&why));
}

TEST_F(StreamStateTest, GarbageIsCountedByReason) {
  ExpressionStreamState s(key_, {});
  std::vector<uint8_t> junk(300, 0x41);
  EXPECT_EQ(s.process(junk, T0, 0), DatagramError::kBadMagic);
  EXPECT_EQ(s.process(std::vector<uint8_t>(10, 0), T0, 0), DatagramError::kTruncated);
  EXPECT_EQ(s.process(std::vector<uint8_t>(9000, 0), T0, 0), DatagramError::kOversized);
  const ReceiverStatistics st = s.statistics(T0);
  EXPECT_EQ(st.rejected_total(), 3u);
  EXPECT_EQ(st.received, 3u);
}

}  // namespace
}  // namespace face_reenact::stream
