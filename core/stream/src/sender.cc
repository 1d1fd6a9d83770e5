#include "face_reenact/stream/sender.h"

#include <poll.h>
#include <sys/socket.h>
#include <time.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "face_reenact/common/error.h"
#include "face_reenact/stream/stream_state.h"

namespace face_reenact::stream {
namespace {

int64_t monotonic_ns() {
  timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return int64_t(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

void sleep_until_ns(int64_t t) {
  timespec ts{static_cast<time_t>(t / 1'000'000'000), static_cast<long>(t % 1'000'000'000)};
  // Absolute deadline: an interrupted or late wake-up never shifts the schedule.
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

template <size_t N>
bool read_numbers(const nlohmann::json& j, std::array<float, N>* out) {
  if (!j.is_array() || j.size() != N) return false;
  for (size_t i = 0; i < N; ++i) {
    if (!j[i].is_number()) return false;
    (*out)[i] = j[i].get<float>();
  }
  return true;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
std::vector<ParameterFrame> load_parameter_file(const std::string& path, const ParameterFileLimits& limits) {
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  if (ec) throw Error("parameter file '" + path + "': " + ec.message());
  if (size > limits.max_bytes)
    throw Error("parameter file '" + path + "' is " + std::to_string(size) + " bytes, more than the limit of " +
                std::to_string(limits.max_bytes));
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open parameter file '" + path + "'");

  std::vector<ParameterFrame> frames;
  std::string line;
  size_t line_no = 0;
  auto fail = [&](const std::string& m) { return Error(path + ":" + std::to_string(line_no) + ": " + m); };
  while (std::getline(in, line)) {
    ++line_no;
    if (line.size() > limits.max_line_bytes)
      throw fail("line is " + std::to_string(line.size()) + " bytes, longer than " +
                 std::to_string(limits.max_line_bytes));
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos) continue;  // blank lines are allowed
    const nlohmann::json j = nlohmann::json::parse(line, nullptr, /*allow_exceptions=*/false);
    if (j.is_discarded()) throw fail("not valid JSON");
    if (!j.is_object()) throw fail("expected a JSON object");
    if (frames.size() >= limits.max_frames)
      throw fail("more than " + std::to_string(limits.max_frames) + " frames");

    ParameterFrame pf;
    const auto e = j.find("expression");
    if (e == j.end()) throw fail("missing \"expression\"");
    if (!read_numbers(*e, &pf.frame.expression))
      throw fail("\"expression\" must be an array of " + std::to_string(kNumCoefficients) + " numbers");
    if (auto n = j.find("neutral"); n != j.end()) {
      if (!read_numbers(*n, &pf.frame.neutral))
        throw fail("\"neutral\" must be an array of " + std::to_string(kNumCoefficients) + " numbers");
      pf.frame.neutral_subtracted = false;
    }
    if (auto t = j.find("timestamp_us"); t != j.end()) {
      if (!t->is_number_integer() || t->get<int64_t>() < 0)
        throw fail("\"timestamp_us\" must be a non-negative integer");
      pf.has_timestamp = true;
      pf.timestamp_us = t->get<int64_t>();
    }
    if (auto f = j.find("frame"); f != j.end()) {
      if (!f->is_number_integer()) throw fail("\"frame\" must be an integer");
      pf.frame_number = f->get<int64_t>();
    }
    if (auto p = j.find("pose"); p != j.end()) {
      if (!p->is_object()) throw fail("\"pose\" must be an object with \"rotation\" and/or \"translation\"");
      if (auto r = p->find("rotation"); r != p->end()) {
        if (!read_numbers(*r, &pf.frame.rotation))
          throw fail("\"pose\".\"rotation\" must be an array of 3 numbers (axis-angle, radians)");
        pf.frame.has_rotation = true;
      }
      if (auto t = p->find("translation"); t != p->end()) {
        if (!read_numbers(*t, &pf.frame.translation))
          throw fail("\"pose\".\"translation\" must be an array of 3 numbers (metres)");
        pf.frame.has_translation = true;
      }
    }
    std::string why;
    if (!frame_values_valid(pf.frame, &why)) throw fail(why);
    if (!frames.empty()) {
      if (pf.has_timestamp != frames.front().has_timestamp)
        throw fail("\"timestamp_us\" must be on every line or on none");
      if (pf.has_timestamp && pf.timestamp_us <= frames.back().timestamp_us)
        throw fail("\"timestamp_us\" " + std::to_string(pf.timestamp_us) + " does not increase (previous " +
                   std::to_string(frames.back().timestamp_us) + ")");
    }
    frames.push_back(pf);
  }
  if (in.bad()) throw Error("parameter file '" + path + "': read error");
  if (frames.empty()) throw Error("parameter file '" + path + "' has no frames");
  return frames;
}

std::string format_parameter_line(const ParameterFrame& pf) {
  nlohmann::json j;
  if (pf.frame_number >= 0) j["frame"] = pf.frame_number;
  if (pf.has_timestamp) j["timestamp_us"] = pf.timestamp_us;
  j["expression"] = pf.frame.expression;
  if (!pf.frame.neutral_subtracted) j["neutral"] = pf.frame.neutral;
  if (pf.frame.has_rotation || pf.frame.has_translation) {
    nlohmann::json pose = nlohmann::json::object();
    if (pf.frame.has_rotation) pose["rotation"] = pf.frame.rotation;
    if (pf.frame.has_translation) pose["translation"] = pf.frame.translation;
    j["pose"] = pose;
  }
  return j.dump();
}

// ---------------------------------------------------------------------------------------------
bool ReplayFileSource::Options::IsValid(std::string* why) const {
  if (!std::isfinite(rate_hz) || rate_hz < 0 || rate_hz > 10000) {
    if (why) *why = "rate must be between 0 (use timestamps) and 10000 Hz";
    return false;
  }
  if (max_lag.count() <= 0) {
    if (why) *why = "max_lag must be positive";
    return false;
  }
  return true;
}

ReplayFileSource::ReplayFileSource(std::vector<ParameterFrame> frames, Options options, std::string name)
    : frames_(std::move(frames)), options_(options), name_(std::move(name)) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error("replay: " + why);
  if (frames_.empty()) throw Error("replay: no frames");
  use_timestamps_ = options_.rate_hz == 0 && frames_.front().has_timestamp;
  const double rate = options_.rate_hz > 0 ? options_.rate_hz : 30.0;
  period_ns_ = static_cast<int64_t>(std::llround(1e9 / rate));
  if (use_timestamps_) {
    // One pass lasts from the first timestamp to the last plus the typical (median) interval,
    // so a loop's first frame follows the previous loop's last at the usual spacing.
    int64_t interval_ns = period_ns_;
    if (frames_.size() > 1) {
      std::vector<int64_t> d;
      d.reserve(frames_.size() - 1);
      for (size_t i = 1; i < frames_.size(); ++i) d.push_back(frames_[i].timestamp_us - frames_[i - 1].timestamp_us);
      std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
      interval_ns = d[d.size() / 2] * 1000;
    }
    loop_length_ns_ = (frames_.back().timestamp_us - frames_.front().timestamp_us) * 1000 + interval_ns;
  } else {
    loop_length_ns_ = 0;  // computed from the frame count in schedule_offset_ns
  }
}

int64_t ReplayFileSource::schedule_offset_ns(size_t index, uint64_t loop) const {
  if (use_timestamps_)
    return static_cast<int64_t>(loop) * loop_length_ns_ +
           (frames_[index].timestamp_us - frames_.front().timestamp_us) * 1000;
  // Computed from the frame number, never accumulated, so rounding cannot drift.
  const double rate = options_.rate_hz > 0 ? options_.rate_hz : 30.0;
  const long double n = static_cast<long double>(loop) * frames_.size() + index;
  return static_cast<int64_t>(std::llround(n * 1e9L / rate));
}

ReplayFileSource::Status ReplayFileSource::next(ExpressionFrame* frame, std::chrono::milliseconds max_wait) {
  if (index_ >= frames_.size()) {
    if (!options_.loop) return Status::kEnd;
    index_ = 0;
    ++loop_;
  }
  int64_t now = monotonic_ns();
  if (!started_) {
    start_ns_ = now;
    started_ = true;
  }
  const int64_t offset = schedule_offset_ns(index_, loop_);
  int64_t deadline = start_ns_ + offset;
  if (now - deadline > std::chrono::nanoseconds(options_.max_lag).count()) {
    start_ns_ = now - offset;  // fell far behind: restart the schedule here
    deadline = now;
    ++schedule_resets_;
  }
  if (deadline > now) {
    const int64_t wake = std::min(deadline, now + std::chrono::nanoseconds(max_wait).count());
    sleep_until_ns(wake);
    if (wake < deadline) return Status::kIdle;
  }
  *frame = frames_[index_].frame;
  frame->capture_time_us = realtime_now_us();
  ++index_;
  return Status::kFrame;
}

std::string ReplayFileSource::description() const {
  std::string d = "replay of '" + name_ + "' (" + std::to_string(frames_.size()) + " frames, ";
  if (use_timestamps_)
    d += "at its timestamps";
  else
    d += "at " + std::to_string(options_.rate_hz > 0 ? options_.rate_hz : 30.0) + " Hz";
  return d + (options_.loop ? ", looping)" : ")");
}

// ---------------------------------------------------------------------------------------------
LiveLinkSource::LiveLinkSource(const ListenSpec& listen)
    : socket_(UdpSocket::open_receiver(listen, "", 1 << 18)) {}

LiveLinkSource::Status LiveLinkSource::next(ExpressionFrame* frame, std::chrono::milliseconds max_wait) {
  pollfd pfd{socket_.fd(), POLLIN, 0};
  const int pr = ::poll(&pfd, 1, static_cast<int>(std::max<int64_t>(0, max_wait.count())));
  if (pr <= 0) return Status::kIdle;
  uint8_t buf[2048];
  const ssize_t n = ::recv(socket_.fd(), buf, sizeof(buf), MSG_DONTWAIT | MSG_TRUNC);
  if (n < 0) return Status::kIdle;
  if (static_cast<size_t>(n) > sizeof(buf)) {
    ++errors_;
    last_error_ = "Live Link packet of " + std::to_string(n) + " bytes is too large";
    return Status::kIdle;
  }
  LiveLinkPacket packet;
  std::string why;
  if (!parse_livelink_packet(std::span<const uint8_t>(buf, static_cast<size_t>(n)), &packet, &why)) {
    ++errors_;
    last_error_ = why;
    return Status::kIdle;
  }
  ExpressionFrame f = livelink_to_frame(packet, realtime_now_us());
  if (!frame_values_valid(f, &why)) {
    ++errors_;
    last_error_ = "Live Link packet: " + why;
    return Status::kIdle;
  }
  subject_ = packet.subject_name;
  *frame = f;
  return Status::kFrame;
}

std::string LiveLinkSource::description() const {
  return "Live Link Face on UDP port " + std::to_string(port());
}

// ---------------------------------------------------------------------------------------------
bool ExpressionSender::Options::IsValid(std::string* why) const {
  if (multicast.ttl < 0 || multicast.ttl > 255) {
    if (why) *why = "multicast TTL must be 0-255";
    return false;
  }
  return true;
}

ExpressionSender::ExpressionSender(const StreamKey& key, const UdpEndpoint& destination, Options options)
    : key_(key), destination_(destination), options_(std::move(options)) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error("sender: " + why);
  socket_ = UdpSocket::open_sender(destination_, options_.multicast);
  sequence_ = options_.first_sequence != 0 ? options_.first_sequence : realtime_now_us();
  stats_.next_sequence = sequence_;
}

bool ExpressionSender::send(const ExpressionFrame& frame) {
  std::array<uint8_t, kMaxDatagramSize> buf;
  const size_t len = encode_datagram(key_, options_.stream_id, sequence_, frame, buf);
  ++sequence_;
  stats_.next_sequence = sequence_;
  const int err = socket_.send(std::span<const uint8_t>(buf.data(), len));
  if (err != 0) {
    ++stats_.send_errors;
    stats_.last_error = std::strerror(err);
    return false;
  }
  ++stats_.sent;
  return true;
}

}  // namespace face_reenact::stream
