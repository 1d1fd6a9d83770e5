#include "face_reenact/stream/sender.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "face_reenact/common/error.h"
#include "face_reenact/stream/stream_state.h"
#include "stream_test_util.h"
#include "support/temp_dir.h"

namespace face_reenact::stream {
namespace {

using namespace std::chrono_literals;
using testing::make_frame;

class ParameterFileTest : public ::testing::Test {
 protected:
  std::string write(const std::string& text) {
    const std::string p = (dir_ / ("f" + std::to_string(n_++) + ".jsonl")).string();
    std::ofstream(p, std::ios::binary) << text;
    return p;
  }
  std::string error_of(const std::string& text) {
    try {
      load_parameter_file(write(text));
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  }
  static std::string numbers(int n, const char* v = "0.5") {
    std::string s = "[";
    for (int i = 0; i < n; ++i) s += (i ? "," : "") + std::string(v);
    return s + "]";
  }
  const face_reenact::testing::TempDir tmp_{"fr-params"};
  const std::filesystem::path dir_ = tmp_.path();
  int n_ = 0;
};

TEST_F(ParameterFileTest, RoundTripsThroughTheWriter) {
  std::string text;
  std::vector<ParameterFrame> in;
  for (int i = 0; i < 5; ++i) {
    ParameterFrame pf;
    pf.frame = make_frame(static_cast<uint32_t>(i), i % 2 == 1, i == 3);
    pf.has_timestamp = true;
    pf.timestamp_us = 1000 + i * 33333;
    pf.frame_number = i;
    in.push_back(pf);
    text += format_parameter_line(pf) + "\n";
  }
  text += "\n   \n";  // blank lines are allowed
  const auto out = load_parameter_file(write(text));
  ASSERT_EQ(out.size(), in.size());
  for (size_t i = 0; i < in.size(); ++i) {
    EXPECT_EQ(out[i].frame.expression, in[i].frame.expression);
    EXPECT_EQ(out[i].frame.neutral_subtracted, in[i].frame.neutral_subtracted);
    if (!in[i].frame.neutral_subtracted) EXPECT_EQ(out[i].frame.neutral, in[i].frame.neutral);
    EXPECT_EQ(out[i].frame.has_rotation, in[i].frame.has_rotation);
    EXPECT_EQ(out[i].frame.rotation, in[i].frame.rotation);
    EXPECT_EQ(out[i].frame.translation, in[i].frame.translation);
    EXPECT_EQ(out[i].timestamp_us, in[i].timestamp_us);
    EXPECT_EQ(out[i].frame_number, in[i].frame_number);
  }
}

TEST_F(ParameterFileTest, ErrorsNameTheLineAndTheProblem) {
  const std::string e52 = numbers(52);
  EXPECT_NE(error_of("").find("has no frames"), std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + e52 + "}\nnot json\n").find(":2: not valid JSON"), std::string::npos);
  EXPECT_NE(error_of("[1,2]\n").find(":1: expected a JSON object"), std::string::npos);
  EXPECT_NE(error_of("{\"frame\": 1}\n").find("missing \"expression\""), std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + numbers(51) + "}\n").find("array of 52 numbers"), std::string::npos);
  EXPECT_NE(error_of("{\"expression\": [\"a\"" + std::string(",0.1") + "]}\n").find("array of 52"), std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + numbers(52, "5.0") + "}\n").find("expression coefficient 0"), std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + e52 + ", \"neutral\": [1]}\n").find("\"neutral\""), std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + e52 + ", \"timestamp_us\": -5}\n").find("non-negative"), std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + e52 + ", \"timestamp_us\": 10}\n{\"expression\": " + e52 +
                     ", \"timestamp_us\": 10}\n").find(":2: \"timestamp_us\" 10 does not increase"),
            std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + e52 + ", \"timestamp_us\": 10}\n{\"expression\": " + e52 + "}\n")
                .find("every line or on none"),
            std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + e52 + ", \"pose\": {\"rotation\": [1,2]}}\n").find("\"rotation\""),
            std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + e52 + ", \"pose\": {\"rotation\": [9,0,0]}}\n").find("rotation angle"),
            std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + e52 + ", \"pose\": 3}\n").find("\"pose\" must be an object"),
            std::string::npos);
  EXPECT_NE(error_of("{\"expression\": " + e52 + ", \"frame\": 1.5}\n").find("\"frame\" must be an integer"),
            std::string::npos);
  try {
    load_parameter_file((dir_ / "absent.jsonl").string());
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("absent.jsonl"), std::string::npos);
  }
  ParameterFileLimits small;
  small.max_line_bytes = 100;
  EXPECT_THROW(load_parameter_file(write("{\"expression\": " + e52 + "}\n"), small), Error);
  small = {};
  small.max_frames = 1;
  EXPECT_THROW(load_parameter_file(write("{\"expression\": " + e52 + "}\n{\"expression\": " + e52 + "}\n"), small),
               Error);
}

std::vector<ParameterFrame> frames_at(const std::vector<int64_t>& ts) {
  std::vector<ParameterFrame> v;
  for (size_t i = 0; i < ts.size(); ++i) {
    ParameterFrame pf;
    pf.frame = make_frame(static_cast<uint32_t>(i));
    pf.has_timestamp = ts[i] >= 0;
    pf.timestamp_us = ts[i];
    v.push_back(pf);
  }
  return v;
}

TEST(ReplayFileSource, ScheduleFollowsTimestampsWithoutDrift) {
  ReplayFileSource::Options o;
  o.loop = true;
  ReplayFileSource src(frames_at({5000, 38333, 71666, 105000}), o, "t");
  EXPECT_EQ(src.schedule_offset_ns(0, 0), 0);
  EXPECT_EQ(src.schedule_offset_ns(1, 0), 33'333'000);
  EXPECT_EQ(src.schedule_offset_ns(3, 0), 100'000'000);
  // The next pass starts one median interval after the last frame.
  EXPECT_EQ(src.schedule_offset_ns(0, 1), 133'333'000);
  EXPECT_EQ(src.schedule_offset_ns(3, 1000), 1000 * 133'333'000ll + 100'000'000);
}

TEST(ReplayFileSource, FixedRateScheduleIsComputedNotAccumulated) {
  ReplayFileSource::Options o;
  o.rate_hz = 30;
  o.loop = true;
  ReplayFileSource src(frames_at({0, 10, 20}), o, "t");  // --rate overrides timestamps
  EXPECT_EQ(src.schedule_offset_ns(1, 0), 33'333'333);
  // After 3 * 36000 frames (an hour at 30 Hz) the schedule is exactly 3600 s, no drift.
  EXPECT_EQ(src.schedule_offset_ns(0, 36000), 3600'000'000'000ll);
  ReplayFileSource dflt(frames_at({-1, -1}), {}, "t");  // no timestamps: 30 Hz
  EXPECT_EQ(dflt.schedule_offset_ns(1, 0), 33'333'333);
}

TEST(ReplayFileSource, PlaysEveryFrameNoEarlierThanScheduledThenEnds) {
  ReplayFileSource::Options o;
  o.rate_hz = 200;
  ReplayFileSource src(frames_at({-1, -1, -1, -1, -1}), o, "t");
  const auto start = std::chrono::steady_clock::now();
  int frames = 0, idles = 0;
  ExpressionFrame f;
  for (;;) {
    const auto st = src.next(&f, 2ms);
    if (st == ExpressionFrameSource::Status::kEnd) break;
    if (st == ExpressionFrameSource::Status::kIdle) ++idles;
    if (st == ExpressionFrameSource::Status::kFrame) {
      // Frame k is due 5 ms * k after the first.
      EXPECT_GE(std::chrono::steady_clock::now() - start, std::chrono::milliseconds(5 * frames) - 1ms);
      EXPECT_GT(f.capture_time_us, 0u);
      EXPECT_EQ(f.expression, make_frame(static_cast<uint32_t>(frames)).expression);
      ++frames;
    }
  }
  EXPECT_EQ(frames, 5);
  EXPECT_GT(idles, 0);  // it returned control while waiting (max_wait 2 ms < 5 ms period)
  EXPECT_EQ(src.next(&f, 1ms), ExpressionFrameSource::Status::kEnd);
}

TEST(ReplayFileSource, InvalidOptionsAreRefused) {
  ReplayFileSource::Options o;
  o.rate_hz = -1;
  EXPECT_THROW(ReplayFileSource(frames_at({-1}), o, "t"), Error);
  o.rate_hz = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(ReplayFileSource(frames_at({-1}), o, "t"), Error);
  EXPECT_THROW(ReplayFileSource({}, {}, "t"), Error);
}

TEST(LiveLinkSource, RelaysPacketsAndCountsMalformedOnes) {
  ListenSpec l;
  l.address = "127.0.0.1";
  LiveLinkSource src(l);
  UdpSocket phone = UdpSocket::open_sender(resolve_endpoint("127.0.0.1:" + std::to_string(src.port()), "t"), {});
  LiveLinkPacket p;
  p.subject_name = "face";
  for (int i = 0; i < kLiveLinkValues; ++i) p.values[i] = 0.01f * float(i % 40);
  ASSERT_EQ(phone.send(std::vector<uint8_t>{6, 0, 0}), 0);  // malformed
  ASSERT_EQ(phone.send(encode_livelink_packet(p)), 0);
  ExpressionFrame f;
  ExpressionFrameSource::Status st = ExpressionFrameSource::Status::kIdle;
  for (int i = 0; i < 100 && st != ExpressionFrameSource::Status::kFrame; ++i) st = src.next(&f, 50ms);
  ASSERT_EQ(st, ExpressionFrameSource::Status::kFrame);
  EXPECT_EQ(src.input_errors(), 1u);
  EXPECT_NE(src.last_input_error().find("Live Link packet"), std::string::npos);
  EXPECT_EQ(src.subject_name(), "face");
  for (int i = 0; i < kNumCoefficients; ++i) EXPECT_EQ(f.expression[i], p.values[i]);
  EXPECT_TRUE(f.has_rotation);
  // Out-of-range blendshapes parse but are not relayed.
  p.values[0] = 50.f;
  ASSERT_EQ(phone.send(encode_livelink_packet(p)), 0);
  std::this_thread::sleep_for(20ms);
  EXPECT_EQ(src.next(&f, 200ms), ExpressionFrameSource::Status::kIdle);
  EXPECT_EQ(src.input_errors(), 2u);
  EXPECT_EQ(src.next(&f, 1ms), ExpressionFrameSource::Status::kIdle);  // nothing pending
}

TEST(ExpressionSender, BadDestinationsAreClearErrors) {
  auto err = [](const std::string& to) {
    try {
      resolve_endpoint(to, "--to");
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(err("no-such-host.invalid:9000").find("cannot resolve host 'no-such-host.invalid'"), std::string::npos);
  EXPECT_NE(err("127.0.0.1").find("expected HOST:PORT"), std::string::npos);
  EXPECT_NE(err("127.0.0.1:99999").find("not a port number"), std::string::npos);
  EXPECT_NE(err("127.0.0.1:0").find("port 0"), std::string::npos);
  EXPECT_NE(err(":9000").find("missing host"), std::string::npos);
  EXPECT_NE(err("::1:9000").find("[ADDRESS]:PORT"), std::string::npos);
  EXPECT_EQ(resolve_endpoint("[::1]:9000", "t").port(), 9000);
  EXPECT_TRUE(resolve_endpoint("239.1.2.3:5000", "t").is_ipv4_multicast());
  EXPECT_FALSE(resolve_endpoint("127.0.0.1:5000", "t").is_ipv4_multicast());
  EXPECT_THROW(parse_listen_spec("abc", "--listen"), Error);
  EXPECT_THROW(parse_listen_spec("239.1.2.3:0", "--listen"), Error);
  EXPECT_THROW(parse_listen_spec("nohost:5", "--listen"), Error);
  EXPECT_TRUE(parse_listen_spec("239.1.2.3:5000", "--listen").multicast);
  EXPECT_EQ(parse_listen_spec("5000", "--listen").address, "0.0.0.0");
}

TEST(ExpressionSender, RefusesInvalidFramesAndCountsSendErrors) {
  // Nobody listens on this port: the first send may succeed, later ones report ECONNREFUSED.
  ListenSpec l;
  l.address = "127.0.0.1";
  uint16_t port;
  {
    UdpSocket probe = UdpSocket::open_receiver(l, "", 0);
    port = probe.local_port();
  }
  ExpressionSender tx(testing::test_key(), resolve_endpoint("127.0.0.1:" + std::to_string(port), "t"), {});
  ExpressionFrame bad = make_frame(1);
  bad.expression[0] = std::numeric_limits<float>::infinity();
  EXPECT_THROW(tx.send(bad), Error);
  for (int i = 0; i < 5; ++i) tx.send(make_frame(1));
  EXPECT_EQ(tx.statistics().sent + tx.statistics().send_errors, 5u);
  EXPECT_GT(tx.statistics().send_errors, 0u);
  EXPECT_FALSE(tx.statistics().last_error.empty());
  ExpressionSender::Options o;
  o.multicast.ttl = 300;
  EXPECT_THROW(ExpressionSender(testing::test_key(), resolve_endpoint("127.0.0.1:9", "t"), o), Error);
}

}  // namespace
}  // namespace face_reenact::stream
