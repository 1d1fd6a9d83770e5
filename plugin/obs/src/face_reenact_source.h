#pragma once
// The C++ side of the "Face Reenact" OBS source. The obs_source_info callbacks (source_info.cc)
// forward here and stay thin. Threading:
//   - update()/calibrate()/properties run on OBS's UI thread, video_tick on its graphics
//     thread, calibrate()/status_line()/live_status() also on obs-websocket's thread (its
//     vendor requests, websocket_vendor.h): none of them waits for the pipeline (a replaced
//     session is stopped on a retiring thread, so even a long pipeline call never stalls the UI);
//   - the live session's worker thread hands every output frame to OBS with
//     obs_source_output_video (async source), converted to BGRA there.
#include <obs-module.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "face_reenact/live/live_session.h"

namespace face_reenact::obs_plugin {

class FaceReenactSource {
 public:
  FaceReenactSource(obs_data_t* settings, obs_source_t* source);
  ~FaceReenactSource();  // stops the session and joins every thread it started
  FaceReenactSource(const FaceReenactSource&) = delete;
  FaceReenactSource& operator=(const FaceReenactSource&) = delete;

  void update(obs_data_t* settings);
  // Restarts the target's calibration (the Calibrate button, obs-websocket's Calibrate). False
  // when no session runs (settings incomplete): nothing to calibrate. Any thread.
  bool calibrate();
  // Calibrations requested of this source's sessions so far (a remote client sees it move).
  int64_t calibrations_requested() const { return calibrations_requested_.load(); }
  void video_tick();
  // The status line (also what the properties show and the proc handler returns).
  std::string status_line() const;
  live::LiveStatus live_status(bool* has_session) const;

 private:
  void output_frame(const live::LiveFrame& frame, uint64_t generation);
  void retire(std::unique_ptr<live::LiveSession> session);
  void join_retired(bool all);

  obs_source_t* const source_;
  mutable std::mutex mu_;  // session_, settings_problem_, retired_
  std::unique_ptr<live::LiveSession> session_;
  std::string settings_problem_;  // why no session runs (settings incomplete)
  live::LiveSession::Options current_options_;
  struct Retiring {
    std::thread thread;
    std::shared_ptr<std::atomic<bool>> done;
  };
  std::vector<Retiring> retired_;
  // Frames of a session that is being replaced are dropped (its worker may still run briefly).
  std::atomic<uint64_t> generation_{0};
  std::atomic<int64_t> calibrations_requested_{0};
  // Graphics-thread state: status change detection (logs and property refreshes).
  std::string last_state_key_;
  std::chrono::steady_clock::time_point next_status_check_{};
  std::chrono::steady_clock::time_point next_refresh_{};
};

}  // namespace face_reenact::obs_plugin
