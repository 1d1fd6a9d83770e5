#include "face_reenact_source.h"

#include <util/platform.h>

#include <opencv2/imgproc.hpp>

#include "source_settings.h"
#include "websocket_vendor.h"

namespace face_reenact::obs_plugin {
namespace {

using Clock = std::chrono::steady_clock;

bool same_inputs(const live::LiveSession::Options& a, const live::LiveSession::Options& b) {
  return a.target == b.target && a.source == b.source && a.key_file == b.key_file && a.model_path == b.model_path &&
         a.mode == b.mode && a.camera_width == b.camera_width && a.camera_height == b.camera_height;
}

}  // namespace

FaceReenactSource::FaceReenactSource(obs_data_t* settings, obs_source_t* source) : source_(source) {
  update(settings);
}

FaceReenactSource::~FaceReenactSource() {
  std::unique_ptr<live::LiveSession> session;
  {
    std::lock_guard lock(mu_);
    session = std::move(session_);
    ++generation_;
  }
  if (session) session->stop();  // at most one pipeline call; no frame reaches OBS afterwards
  join_retired(/*all=*/true);
}

void FaceReenactSource::update(obs_data_t* settings) {
  live::LiveSession::Options options;
  std::string why;
  bool usable = options_from_settings(settings, &options, &why);
  std::unique_ptr<live::LiveSession> old;
  {
    std::lock_guard lock(mu_);
    if (usable && session_ && same_inputs(options, current_options_)) return;  // nothing changed
    old = std::move(session_);
    settings_problem_ = usable ? "" : why;
    ++generation_;
  }
  if (old) retire(std::move(old));
  join_retired(/*all=*/false);
  if (!usable) {
    blog(LOG_WARNING, "%s '%s': not started: %s", kLogPrefix, obs_source_get_name(source_), why.c_str());
    obs_source_output_video(source_, nullptr);  // nothing to show until the settings are complete
    return;
  }
  uint64_t generation = generation_.load();
  options.on_frame = [this, generation](const live::LiveFrame& frame) { output_frame(frame, generation); };
  blog(LOG_INFO, "%s '%s': target %s, source %s, mode %s, model '%s'", kLogPrefix, obs_source_get_name(source_),
       options.target.c_str(), options.source.c_str(), live::output_mode_name(options.mode), options.model_path.c_str());
  try {
    auto session = std::make_unique<live::LiveSession>(options);
    std::lock_guard lock(mu_);
    session_ = std::move(session);
    current_options_ = options;
  } catch (const std::exception& e) {
    std::lock_guard lock(mu_);
    settings_problem_ = e.what();
    blog(LOG_WARNING, "%s '%s': not started: %s", kLogPrefix, obs_source_get_name(source_), e.what());
  }
}

void FaceReenactSource::retire(std::unique_ptr<live::LiveSession> session) {
  auto done = std::make_shared<std::atomic<bool>>(false);
  std::thread t([s = std::move(session), done]() mutable {
    s->stop();
    s.reset();
    done->store(true);
  });
  std::lock_guard lock(mu_);
  retired_.push_back({std::move(t), done});
}

void FaceReenactSource::join_retired(bool all) {
  std::vector<Retiring> to_join;
  {
    std::lock_guard lock(mu_);
    for (auto it = retired_.begin(); it != retired_.end();) {
      if (all || it->done->load()) {
        to_join.push_back(std::move(*it));
        it = retired_.erase(it);
      } else {
        ++it;
      }
    }
  }
  for (auto& r : to_join) r.thread.join();
}

bool FaceReenactSource::calibrate() {
  std::lock_guard lock(mu_);
  if (!session_) return false;
  session_->RequestCalibration();
  ++calibrations_requested_;
  blog(LOG_INFO, "%s '%s': calibration requested", kLogPrefix, obs_source_get_name(source_));
  return true;
}

// On the session's publishing thread (its worker).
void FaceReenactSource::output_frame(const live::LiveFrame& frame, uint64_t generation) {
  if (generation != generation_.load() || frame.bgr.empty()) return;
  thread_local cv::Mat bgra;
  cv::cvtColor(frame.bgr, bgra, cv::COLOR_BGR2BGRA);
  obs_source_frame out = {};
  out.data[0] = bgra.data;
  out.linesize[0] = static_cast<uint32_t>(bgra.step[0]);
  out.width = static_cast<uint32_t>(bgra.cols);
  out.height = static_cast<uint32_t>(bgra.rows);
  out.format = VIDEO_FORMAT_BGRA;
  out.full_range = true;
  out.timestamp = os_gettime_ns();
  obs_source_output_video(source_, &out);  // copies the pixels
}

live::LiveStatus FaceReenactSource::live_status(bool* has_session) const {
  std::lock_guard lock(mu_);
  *has_session = session_ != nullptr;
  return session_ ? session_->status() : live::LiveStatus();
}

std::string FaceReenactSource::status_line() const {
  std::lock_guard lock(mu_);
  if (!session_) return "Not running: " + (settings_problem_.empty() ? std::string("no settings") : settings_problem_);
  return session_->status().Headline();
}

// On OBS's graphics thread, every frame: only a cheap status check twice a second.
void FaceReenactSource::video_tick() {
  Clock::time_point now = Clock::now();
  if (now < next_status_check_) return;
  next_status_check_ = now + std::chrono::milliseconds(500);
  bool has_session = false;
  live::LiveStatus status = live_status(&has_session);
  // A log line and a properties refresh when what the line says changes, not its numbers (rates,
  // the calibration's progress, a lost frame's measurements): one line per change of state.
  std::string key = has_session ? status.StateLine() : status_line();
  bool changed = key != last_state_key_;
  if (changed) {
    last_state_key_ = key;
    std::string line = status_line();
    blog(LOG_INFO, "%s '%s': %s", kLogPrefix, obs_source_get_name(source_), line.c_str());
    emit_state_changed(obs_source_get_name(source_), line, state_word(has_session, status));
  }
  // The properties window shows the status line: refresh it when the state changes, and every
  // few seconds for the rates (more often would rebuild the window under the user's cursor).
  if (changed || now >= next_refresh_) {
    next_refresh_ = now + std::chrono::seconds(5);
    obs_source_update_properties(source_);
  }
}

}  // namespace face_reenact::obs_plugin
