// The pacing algorithm and the output loop, driven by a fake clock (no sleeps, no timing).
#include <gtest/gtest.h>

#include <atomic>
#include <deque>

#include "face_reenact/common/error.h"
#include "face_reenact/output/frame_pacer.h"
#include "face_reenact/output/webcam_streamer.h"

namespace face_reenact::output {
namespace {

using std::chrono::milliseconds;
using std::chrono::nanoseconds;
using std::chrono::seconds;

TEST(FrameRate, FromDouble) {
  EXPECT_EQ(FrameRate::from_double(30)->num, 30);
  EXPECT_EQ(FrameRate::from_double(30)->den, 1);
  EXPECT_EQ(FrameRate::from_double(29.97)->num, 2997);
  EXPECT_EQ(FrameRate::from_double(29.97)->den, 100);
  EXPECT_EQ(FrameRate::from_double(12.5)->num, 25);
  EXPECT_EQ(FrameRate::from_double(12.5)->den, 2);
  EXPECT_FALSE(FrameRate::from_double(0));
  EXPECT_FALSE(FrameRate::from_double(-5));
  EXPECT_FALSE(FrameRate::from_double(1000));
  EXPECT_FALSE(FrameRate::from_double(std::nan("")));
  EXPECT_FALSE(FrameRate::from_double(0.001));
  std::string why;
  EXPECT_FALSE((FrameRate{0, 1}).IsValid(&why));
  EXPECT_NE(why.find("frame rate"), std::string::npos);
}

TEST(FramePacer, DeadlinesAreExactAndDoNotDrift) {
  FramePacer p30(FrameRate{30, 1});
  EXPECT_EQ(p30.deadline(0), nanoseconds(0));
  EXPECT_EQ(p30.deadline(1), nanoseconds(33333333));
  EXPECT_EQ(p30.deadline(30), seconds(1));
  EXPECT_EQ(p30.deadline(30 * 3600 * 24), seconds(3600 * 24));  // a day later, still exact
  FramePacer ntsc(*FrameRate::from_double(29.97));
  EXPECT_EQ(ntsc.deadline(2997), seconds(100));
  EXPECT_EQ(ntsc.deadline(2997 * 1000), seconds(100000));
  // Consecutive periods differ by at most a nanosecond: no accumulated rounding.
  for (int64_t k = 1; k < 100000; k += 7) {
    int64_t period = (ntsc.deadline(k + 1) - ntsc.deadline(k)).count();
    ASSERT_GE(period, 33366699);
    ASSERT_LE(period, 33366701);
  }
}

TEST(FramePacer, NothingBeforeTheNextDeadline) {
  FramePacer pacer(FrameRate{10, 1});
  ASSERT_TRUE(pacer.on_wake(nanoseconds(0)));  // tick 0 is due at the start
  EXPECT_FALSE(pacer.on_wake(milliseconds(50)));
  EXPECT_FALSE(pacer.on_wake(milliseconds(99)));
  auto t = pacer.on_wake(milliseconds(100));
  ASSERT_TRUE(t);
  EXPECT_EQ(t->tick_index, 1);
  EXPECT_EQ(t->skipped, 0);
}

// Simulates a producer delivering at `producer_fps` and a writer waking exactly on deadlines.
PacerStatistics simulate(double output_fps, double producer_fps, double seconds_total) {
  FramePacer pacer(*FrameRate::from_double(output_fps));
  int64_t produced = 0;
  while (true) {
    nanoseconds deadline = pacer.next_deadline();
    if (deadline > nanoseconds(int64_t(seconds_total * 1e9))) break;
    // Deliver every producer frame due up to this deadline (frame i at i / producer_fps).
    while (nanoseconds(int64_t(std::ceil(double(produced) * 1e9 / producer_fps))) <= deadline - nanoseconds(1)) {
      pacer.frame_arrived();
      ++produced;
    }
    pacer.on_wake(deadline);
  }
  return pacer.statistics();
}

TEST(FramePacer, ProducerAtTheRateSendsEveryFrameOnce) {
  PacerStatistics s = simulate(30, 30, 10);
  EXPECT_EQ(s.fresh + s.repeated, 301);
  EXPECT_EQ(s.dropped, 0);
  EXPECT_LE(s.repeated, 1);  // only the very first deadline, before any frame
}

TEST(FramePacer, LateProducerIsFilledWithRepeats) {
  PacerStatistics s = simulate(30, 10, 10);
  EXPECT_EQ(s.fresh + s.repeated, 301);  // the output rate never falls
  EXPECT_EQ(s.dropped, 0);
  EXPECT_NEAR(double(s.fresh), 100, 1);
  EXPECT_NEAR(double(s.repeated), 201, 1);
}

TEST(FramePacer, FastProducerIsThinnedToTheRate) {
  PacerStatistics s = simulate(30, 60, 10);
  EXPECT_EQ(s.fresh + s.repeated, 301);
  EXPECT_NEAR(double(s.fresh), 300, 1);
  EXPECT_NEAR(double(s.dropped), 300, 2);
  EXPECT_EQ(s.missed_deadlines, 0);
}

TEST(FramePacer, LateWriterSkipsDeadlinesInsteadOfBursting) {
  FramePacer pacer(FrameRate{10, 1});
  pacer.frame_arrived();
  ASSERT_TRUE(pacer.on_wake(nanoseconds(0)));
  // The writer stalls for 0.45 s: deadlines at 0.1 .. 0.4 passed; one frame goes out for the
  // latest (0.4), the three before it are skipped, and the next is at 0.5 on the same grid.
  pacer.frame_arrived();
  auto t = pacer.on_wake(milliseconds(450));
  ASSERT_TRUE(t);
  EXPECT_EQ(t->tick_index, 4);
  EXPECT_EQ(t->skipped, 3);
  EXPECT_EQ(t->action, FramePacer::Action::kSendFresh);
  EXPECT_EQ(pacer.next_deadline(), milliseconds(500));
  EXPECT_EQ(pacer.statistics().missed_deadlines, 3);
  EXPECT_FALSE(pacer.on_wake(milliseconds(499)));
}

// --- OutputLoop with a fake sink -------------------------------------------------------------
class FakeSink : public FrameSink {
 public:
  std::deque<WriteOutcome> script;  // outcomes to return; kWritten when empty
  std::vector<std::vector<uint8_t>> written;
  int reopen_calls = 0, close_calls = 0;
  bool reopen_succeeds = true;

  WriteOutcome write_frame(std::span<const uint8_t> frame, std::string* error) override {
    WriteOutcome o = WriteOutcome::kWritten;
    if (!script.empty()) {
      o = script.front();
      script.pop_front();
    }
    if (o == WriteOutcome::kWritten)
      written.emplace_back(frame.begin(), frame.end());
    else if (error)
      *error = o == WriteOutcome::kDeviceLost ? "No such device" : "Resource temporarily unavailable";
    return o;
  }
  bool reopen(std::string* error) override {
    ++reopen_calls;
    if (!reopen_succeeds && error) *error = "device '/dev/video9' does not exist";
    return reopen_succeeds;
  }
  void close() override { ++close_calls; }
};

std::vector<uint8_t> frame_of(uint8_t value) { return std::vector<uint8_t>(8, value); }

TEST(OutputLoop, RepeatsTheInitialFrameUntilTheProducerDelivers) {
  FakeSink sink;
  OutputLoop loop(&sink, {FrameRate{10, 1}, seconds(2)}, frame_of(0));
  loop.on_wake(milliseconds(0));
  loop.on_wake(milliseconds(100));
  loop.offer(frame_of(1));
  loop.on_wake(milliseconds(200));
  loop.on_wake(milliseconds(300));  // nothing new: repeat frame 1
  ASSERT_EQ(sink.written.size(), 4u);
  EXPECT_EQ(sink.written[0], frame_of(0));
  EXPECT_EQ(sink.written[1], frame_of(0));
  EXPECT_EQ(sink.written[2], frame_of(1));
  EXPECT_EQ(sink.written[3], frame_of(1));
  EXPECT_EQ(loop.statistics().frames_written, 4);
  EXPECT_EQ(loop.statistics().pacer.fresh, 1);
  EXPECT_EQ(loop.statistics().pacer.repeated, 3);
}

TEST(OutputLoop, SendsOnlyTheNewestOfSeveralOffers) {
  FakeSink sink;
  OutputLoop loop(&sink, {FrameRate{10, 1}, seconds(2)}, frame_of(0));
  loop.offer(frame_of(1));
  loop.offer(frame_of(2));
  loop.offer(frame_of(3));
  loop.on_wake(milliseconds(0));
  ASSERT_EQ(sink.written.size(), 1u);
  EXPECT_EQ(sink.written[0], frame_of(3));
  EXPECT_EQ(loop.statistics().pacer.dropped, 2);
  loop.offer(std::vector<uint8_t>(5, 9));  // wrong size: never sent
  loop.on_wake(milliseconds(100));
  EXPECT_EQ(sink.written.back(), frame_of(3));
}

TEST(OutputLoop, TransientErrorsAreCountedAndStreamingGoesOn) {
  FakeSink sink;
  sink.script = {WriteOutcome::kTransientError, WriteOutcome::kTransientError};
  OutputLoop loop(&sink, {FrameRate{10, 1}, seconds(2)}, frame_of(0));
  for (int i = 0; i < 5; ++i) loop.on_wake(milliseconds(100 * i));
  EXPECT_EQ(loop.statistics().write_errors, 2);
  EXPECT_EQ(loop.statistics().frames_written, 3);
  EXPECT_EQ(loop.statistics().state, SinkState::kConnected);
  EXPECT_EQ(sink.reopen_calls, 0);
  EXPECT_NE(loop.statistics().last_error.find("temporarily"), std::string::npos);
}

TEST(OutputLoop, LostDeviceIsReopenedOnATimerAndGetsTheNewestFrame) {
  FakeSink sink;
  sink.script = {WriteOutcome::kWritten, WriteOutcome::kDeviceLost};
  sink.reopen_succeeds = false;
  OutputLoop loop(&sink, {FrameRate{10, 1}, seconds(1)}, frame_of(0));
  loop.on_wake(milliseconds(0));
  loop.on_wake(milliseconds(100));  // lost here
  EXPECT_EQ(loop.statistics().state, SinkState::kDisconnected);
  EXPECT_EQ(loop.statistics().disconnects, 1);
  EXPECT_EQ(sink.close_calls, 1);
  // No reopen before the interval has passed, however many deadlines go by.
  for (int t = 200; t < 1100; t += 100) loop.on_wake(milliseconds(t));
  EXPECT_EQ(sink.reopen_calls, 0);
  EXPECT_EQ(loop.statistics().undelivered, 9);
  loop.on_wake(milliseconds(1100));  // first attempt fails
  EXPECT_EQ(sink.reopen_calls, 1);
  EXPECT_NE(loop.statistics().last_error.find("does not exist"), std::string::npos);
  for (int t = 1200; t < 2100; t += 100) loop.on_wake(milliseconds(t));
  EXPECT_EQ(sink.reopen_calls, 1);
  // Meanwhile the producer moves on; after the reconnect its newest frame goes out at once.
  loop.offer(frame_of(7));
  sink.reopen_succeeds = true;
  loop.on_wake(milliseconds(2100));
  EXPECT_EQ(sink.reopen_calls, 2);
  EXPECT_EQ(loop.statistics().state, SinkState::kConnected);
  EXPECT_EQ(loop.statistics().reconnects, 1);
  EXPECT_TRUE(loop.statistics().last_error.empty());
  ASSERT_FALSE(sink.written.empty());
  EXPECT_EQ(sink.written.back(), frame_of(7));
  size_t before = sink.written.size();
  loop.on_wake(milliseconds(2200));
  EXPECT_EQ(sink.written.size(), before + 1);
}

TEST(OutputLoop, RejectsMissingSinkOrFrame) {
  FakeSink sink;
  EXPECT_THROW(OutputLoop(nullptr, {}, frame_of(0)), Error);
  EXPECT_THROW(OutputLoop(&sink, {}, {}), Error);
}

// --- WebcamStreamer end to end with a fake sink (checks content, never timing) ---------------
class ListSource : public FrameSource {
 public:
  explicit ListSource(std::vector<cv::Scalar> colours, bool fail_at_end = false)
      : colours_(std::move(colours)), fail_at_end_(fail_at_end) {}
  SourceStatus next(SourceFrame* frame, std::string* error) override {
    if (index_ >= colours_.size()) {
      if (fail_at_end_) {
        *error = "camera unplugged";
        return SourceStatus::kError;
      }
      return SourceStatus::kEnd;
    }
    frame->bgr = cv::Mat(24, 32, CV_8UC3, colours_[index_]);
    frame->timestamp = milliseconds(10 * int64_t(index_));
    ++index_;
    return SourceStatus::kFrame;
  }
  bool is_live() const override { return false; }
  std::string describe() const override { return "list"; }

 private:
  std::vector<cv::Scalar> colours_;
  bool fail_at_end_;
  size_t index_ = 0;
};

WebcamStreamer::Options small_options() {
  WebcamStreamer::Options o;
  o.width = 64;
  o.height = 48;
  o.rate = FrameRate{100, 1};
  return o;
}

TEST(WebcamStreamer, EndsAfterTheLastFrameWasWritten) {
  FakeSink sink;
  ListSource source({cv::Scalar(0, 0, 255), cv::Scalar(0, 255, 0), cv::Scalar(255, 0, 0)});
  WebcamStreamer streamer(&source, &sink, small_options());
  std::atomic<bool> stop{false};
  WebcamStreamer::Summary summary = streamer.run(stop);
  EXPECT_EQ(summary.stop_reason, "end of source");
  EXPECT_FALSE(summary.source_failed);
  EXPECT_EQ(summary.statistics.source_frames, 3);
  ASSERT_FALSE(sink.written.empty());
  // The last frame written is the last source frame (blue), letterboxed to 64x48 (same aspect).
  cv::Mat last = convert_to_bgr(sink.written.back(), PixelFormat::kYuyv, 64, 48);
  cv::Vec3b centre = last.at<cv::Vec3b>(24, 32);
  EXPECT_NEAR(centre[0], 255, 3);
  EXPECT_NEAR(centre[1], 0, 3);
  EXPECT_NEAR(centre[2], 0, 3);
  EXPECT_EQ(summary.statistics.frames_written, int64_t(sink.written.size()));
}

TEST(WebcamStreamer, SourceErrorIsReported) {
  FakeSink sink;
  ListSource source({cv::Scalar(1, 2, 3)}, /*fail_at_end=*/true);
  WebcamStreamer streamer(&source, &sink, small_options());
  std::atomic<bool> stop{false};
  WebcamStreamer::Summary summary = streamer.run(stop);
  EXPECT_TRUE(summary.source_failed);
  EXPECT_NE(summary.stop_reason.find("camera unplugged"), std::string::npos);
}

TEST(WebcamStreamer, StopsWhenAskedEvenWhileHoldingAFrame) {
  FakeSink sink;
  ListSource source({cv::Scalar(1, 2, 3)});
  WebcamStreamer::Options o = small_options();
  o.hold_last_frame = true;
  WebcamStreamer streamer(&source, &sink, o);
  std::atomic<bool> stop{true};
  WebcamStreamer::Summary summary = streamer.run(stop);
  EXPECT_EQ(summary.stop_reason, "stop requested");
}

TEST(WebcamStreamer, ValidatesItsArguments) {
  FakeSink sink;
  ListSource source({});
  WebcamStreamer::Options o = small_options();
  o.width = 63;
  EXPECT_THROW(WebcamStreamer(&source, &sink, o), Error);
  EXPECT_THROW(WebcamStreamer(nullptr, &sink, small_options()), Error);
}

}  // namespace
}  // namespace face_reenact::output
