#include "websocket_vendor.h"

#include <atomic>
#include <cstring>
#include <exception>
#include <string>

#include "face_reenact_source.h"
#include "source_settings.h"

namespace face_reenact::obs_plugin {
namespace {

// obs-websocket's request callback as its "vendor_request_register" proc takes it (a pointer to
// this pair, copied by the proc): the function and the pointer it is called with.
using RequestFunction = void (*)(obs_data_t* request, obs_data_t* response, void* priv);
struct RequestCallback {
  RequestFunction callback;
  void* priv_data;
};

void fail(obs_data_t* response, const std::string& why) {
  obs_data_set_bool(response, "ok", false);
  obs_data_set_string(response, "error", why.c_str());
}

// obs-websocket's handler and our vendor there, once registered (for the events).
std::atomic<proc_handler_t*> g_websocket{nullptr};
std::atomic<void*> g_vendor{nullptr};

// The Face Reenact source named by the request's "sourceName", with a reference held (released
// by the destructor, so the source and its FaceReenactSource stay alive while a request uses
// them); on bad input `error` says why and `impl` is null.
class NamedSource {
 public:
  NamedSource(obs_data_t* request, std::string* error) {
    const char* name = request ? obs_data_get_string(request, "sourceName") : "";
    if (!name || !*name) {
      *error = "missing field 'sourceName' (the name of a Face Reenact source, a string)";
      return;
    }
    name_ = name;
    source_ = obs_get_source_by_name(name);
    if (!source_) {
      *error = "no source named '" + name_ + "'";
      return;
    }
    const char* id = obs_source_get_unversioned_id(source_);
    if (!id || std::strcmp(id, kSourceId) != 0) {
      *error = "source '" + name_ + "' is not a Face Reenact source (it is a '" + (id ? id : "?") + "')";
      return;
    }
    impl_ = static_cast<FaceReenactSource*>(obs_obj_get_data(source_));
    if (!impl_) *error = "source '" + name_ + "' could not be created (see the OBS log)";
  }
  ~NamedSource() { obs_source_release(source_); }
  NamedSource(const NamedSource&) = delete;
  NamedSource& operator=(const NamedSource&) = delete;

  FaceReenactSource* impl() const { return impl_; }
  const std::string& name() const { return name_; }

 private:
  std::string name_;
  obs_source_t* source_ = nullptr;
  FaceReenactSource* impl_ = nullptr;
};

// The fields every answer about one source carries (GetStatus, Calibrate, each ListSources
// item), from one reading of its status.
void set_state(obs_data_t* out, const char* name, const FaceReenactSource& impl, bool has_session,
               const live::LiveStatus& s) {
  obs_data_set_string(out, "sourceName", name);
  obs_data_set_string(out, "status", impl.status_line().c_str());
  obs_data_set_string(out, "state", state_word(has_session, s));
  obs_data_set_int(out, "calibrationsRequested", impl.calibrations_requested());
}

void set_state(obs_data_t* response, const NamedSource& source) {
  bool has_session = false;
  const live::LiveStatus s = source.impl()->live_status(&has_session);
  set_state(response, source.name().c_str(), *source.impl(), has_session, s);
}

// Catches what a handler throws: an exception must not cross into obs-websocket.
template <typename F>
void guarded(obs_data_t* response, const char* request_type, F&& f) {
  try {
    f();
  } catch (const std::exception& e) {
    blog(LOG_WARNING, "%s obs-websocket request %s failed: %s", kLogPrefix, request_type, e.what());
    fail(response, std::string("internal error: ") + e.what());
  } catch (...) {
    blog(LOG_WARNING, "%s obs-websocket request %s failed", kLogPrefix, request_type);
    fail(response, "internal error");
  }
}

// Calls a proc of obs-websocket's handler; false when it is missing or answers failure.
bool call_proc(proc_handler_t* ph, const char* name, calldata_t* cd) {
  return proc_handler_call(ph, name, cd) && calldata_bool(cd, "success");
}

}  // namespace

const char* state_word(bool has_session, const live::LiveStatus& s) {
  if (!has_session) return "not_running";  // settings incomplete, or the session failed to start
  if (!s.target_open) {
    if (s.target_error == "end of recording") return "ended";
    if (s.target_error.empty() || s.target_error == "opening") return "opening";
    return "no_input";
  }
  if (s.mode == live::OutputMode::kRaw) return "raw";
  if (!s.pipeline_ready) return s.pipeline_message.empty() ? "loading" : "unchanged";
  switch (s.tracking) {
    case live::TrackingState::kCalibrating: return "calibrating";
    case live::TrackingState::kTracking: return "tracking";
    case live::TrackingState::kLost: return "no_face";
    case live::TrackingState::kOff: return "starting";
  }
  return "starting";
}

void emit_state_changed(const char* source_name, const std::string& status, const char* state) {
  proc_handler_t* ws = g_websocket.load();
  void* vendor = g_vendor.load();
  if (!ws || !vendor) return;
  obs_data_t* data = obs_data_create();
  obs_data_set_string(data, "sourceName", source_name ? source_name : "");
  obs_data_set_string(data, "status", status.c_str());
  obs_data_set_string(data, "state", state);
  calldata_t cd = {};
  calldata_set_ptr(&cd, "vendor", vendor);
  calldata_set_string(&cd, "type", "StateChanged");
  calldata_set_ptr(&cd, "data", data);
  proc_handler_call(ws, "vendor_event_emit", &cd);  // fails harmlessly while the server is off
  calldata_free(&cd);
  obs_data_release(data);
}

void vendor_get_status(obs_data_t* request, obs_data_t* response, void*) {
  guarded(response, "GetStatus", [&] {
    std::string error;
    NamedSource source(request, &error);
    if (!source.impl()) return fail(response, error);
    bool has_session = false;
    live::LiveStatus s = source.impl()->live_status(&has_session);
    obs_data_set_bool(response, "ok", true);
    set_state(response, source.name().c_str(), *source.impl(), has_session, s);
    obs_data_set_bool(response, "running", has_session && s.running);
    obs_data_set_string(response, "mode", live::output_mode_name(s.mode));
    obs_data_set_string(response, "tracking", live::tracking_state_name(s.tracking));
    obs_data_set_string(response, "sourceState", live::source_state_name(s.source));
    obs_data_set_bool(response, "targetOpen", s.target_open);
    obs_data_set_bool(response, "pipelineReady", s.pipeline_ready);
    obs_data_set_bool(response, "calibrationPending", s.calibration_pending);
    obs_data_set_string(response, "calibrationProgress", s.calibration_progress.c_str());
    obs_data_set_string(response, "calibrationWarning", s.calibration_warning.c_str());
    obs_data_set_bool(response, "wantsOpenMouth", s.wants_open_mouth);
    obs_data_set_int(response, "framesOut", s.frames_out);
    obs_data_set_double(response, "outputFps", s.output_fps);
    obs_data_set_double(response, "targetFps", s.target_fps);
    obs_data_set_double(response, "packetsPerSecond", s.packets_per_second);
    obs_data_set_double(response, "sourceWeight", s.source_weight);
    obs_data_set_double(response, "processMs", s.process_ms);
    if (s.stream_source) {
      // The expression stream's receiver counts (docs/stream-protocol.md, "Statistics"): what the
      // network lost, reordered or duplicated, for a remote operator watching a puppeteer's link.
      const stream::ReceiverStatistics& r = s.stream_statistics;
      obs_data_t* counts = obs_data_create();
      obs_data_set_int(counts, "received", static_cast<long long>(r.received));
      obs_data_set_int(counts, "applied", static_cast<long long>(r.applied));
      obs_data_set_int(counts, "rejected", static_cast<long long>(r.rejected_total()));
      obs_data_set_int(counts, "lost", static_cast<long long>(r.lost));
      obs_data_set_int(counts, "reordered", static_cast<long long>(r.reordered));
      obs_data_set_int(counts, "late", static_cast<long long>(r.late));
      obs_data_set_int(counts, "kernelDrops", static_cast<long long>(r.kernel_drops));
      obs_data_set_double(counts, "latencyMs", r.latency_ms);
      obs_data_set_obj(response, "stream", counts);
      obs_data_release(counts);
    }
  });
}

void vendor_calibrate(obs_data_t* request, obs_data_t* response, void*) {
  guarded(response, "Calibrate", [&] {
    std::string error;
    NamedSource source(request, &error);
    if (!source.impl()) return fail(response, error);
    bool has_session = false;
    live::LiveStatus s = source.impl()->live_status(&has_session);
    if (has_session && s.mode == live::OutputMode::kRaw) {
      set_state(response, source);
      return fail(response, "source '" + source.name() + "' is in raw mode (tracking off): nothing to calibrate");
    }
    if (!source.impl()->calibrate()) {
      set_state(response, source);
      return fail(response, "source '" + source.name() + "' cannot calibrate: " + source.impl()->status_line());
    }
    obs_data_set_bool(response, "ok", true);
    set_state(response, source);
  });
}

void vendor_list_sources(obs_data_t*, obs_data_t* response, void*) {
  guarded(response, "ListSources", [&] {
    obs_data_array_t* list = obs_data_array_create();
    obs_enum_sources(
        [](void* param, obs_source_t* source) {
          const char* id = obs_source_get_unversioned_id(source);
          auto* impl = static_cast<FaceReenactSource*>(obs_obj_get_data(source));
          if (!id || std::strcmp(id, kSourceId) != 0 || !impl) return true;
          bool has_session = false;
          live::LiveStatus s = impl->live_status(&has_session);
          obs_data_t* item = obs_data_create();
          set_state(item, obs_source_get_name(source), *impl, has_session, s);
          obs_data_array_push_back(static_cast<obs_data_array_t*>(param), item);
          obs_data_release(item);
          return true;
        },
        list);
    obs_data_set_bool(response, "ok", true);
    obs_data_set_array(response, "sources", list);
    obs_data_array_release(list);
  });
}

bool register_websocket_vendor() {
  calldata_t cd = {};
  proc_handler_t* ws = nullptr;
  if (proc_handler_call(obs_get_proc_handler(), "obs_websocket_api_get_ph", &cd))
    ws = static_cast<proc_handler_t*>(calldata_ptr(&cd, "ph"));
  calldata_free(&cd);
  if (!ws) {
    blog(LOG_INFO, "%s obs-websocket (5.x) is not loaded: no remote control of the sources (vendor '%s')", kLogPrefix,
         kVendorName);
    return false;
  }

  cd = {};
  calldata_set_string(&cd, "name", kVendorName);
  void* vendor = call_proc(ws, "vendor_register", &cd) ? calldata_ptr(&cd, "vendor") : nullptr;
  calldata_free(&cd);
  if (!vendor) {
    blog(LOG_WARNING, "%s obs-websocket refused the vendor '%s' (registered twice?): no remote control", kLogPrefix,
         kVendorName);
    return false;
  }

  struct Request {
    const char* type;
    RequestFunction function;
  };
  const Request requests[] = {
      {"GetStatus", vendor_get_status}, {"Calibrate", vendor_calibrate}, {"ListSources", vendor_list_sources}};
  bool all = true;
  for (const Request& r : requests) {
    RequestCallback callback = {r.function, nullptr};  // obs-websocket copies it
    cd = {};
    calldata_set_ptr(&cd, "vendor", vendor);
    calldata_set_string(&cd, "type", r.type);
    calldata_set_ptr(&cd, "callback", &callback);
    if (!call_proc(ws, "vendor_request_register", &cd)) {
      blog(LOG_WARNING, "%s obs-websocket refused the request %s of vendor '%s'", kLogPrefix, r.type, kVendorName);
      all = false;
    }
    calldata_free(&cd);
  }
  g_websocket.store(ws);
  g_vendor.store(vendor);
  if (all)
    blog(LOG_INFO, "%s obs-websocket vendor '%s' registered: GetStatus, Calibrate, ListSources; event StateChanged",
         kLogPrefix, kVendorName);
  return all;
}

}  // namespace face_reenact::obs_plugin
