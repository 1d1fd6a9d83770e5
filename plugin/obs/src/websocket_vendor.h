#pragma once
// Remote control of "Face Reenact" sources through obs-websocket 5 (a Stream Deck, a script, a
// remote operator): a vendor "face-reenact" whose requests a client sends with obs-websocket's
// CallVendorRequest {vendorName, requestType, requestData}. docs/obs-source.md documents the
// requests and their fields.
//
// obs-websocket's vendor API is a set of libobs procs (no library to link): the global proc
// handler has "obs_websocket_api_get_ph", which returns obs-websocket's own proc handler with
// "vendor_register" and "vendor_request_register". This is our own small client of those procs
// (obs-websocket's header is not shipped by Debian's libobs-dev).
#include <obs-module.h>

#include <string>

#include "face_reenact/live/live_session.h"

namespace face_reenact::obs_plugin {

inline constexpr const char* kVendorName = "face-reenact";

// From obs_module_post_load (obs-websocket sets its procs up in its obs_module_load). Without
// obs-websocket (not installed, older than 5) logs one line and returns false; OBS goes on.
bool register_websocket_vendor();

// The requests' handlers, obs-websocket's callback signature (request data, response data, the
// registration's private pointer). Called on obs-websocket's thread. Every answer has "ok"; when
// it is false, "error" says why in plain words (an unknown source name, a source of another
// kind, a missing field) and nothing else is done.
//   GetStatus   {sourceName} -> {ok, sourceName, status, state, mode, tracking, source, ...}
//   Calibrate   {sourceName} -> {ok, sourceName, calibrationsRequested, status, state}
//   ListSources (no data)    -> {ok, sources: [{sourceName, status, state}]}
void vendor_get_status(obs_data_t* request, obs_data_t* response, void* unused);
void vendor_calibrate(obs_data_t* request, obs_data_t* response, void* unused);
void vendor_list_sources(obs_data_t* request, obs_data_t* response, void* unused);

// One word for what a source is doing ("tracking", "calibrating", "raw", ...: docs/obs-source.md).
const char* state_word(bool has_session, const live::LiveStatus& status);

// The vendor event "StateChanged" {sourceName, status, state} to obs-websocket's clients that
// subscribed to vendor events; nothing without obs-websocket. Any thread; never waits (obs-websocket
// sends it from its own threads).
void emit_state_changed(const char* source_name, const std::string& status, const char* state);

// Not unregistered at unload: obs-websocket has no proc to drop a vendor, and libobs does not
// unmap modules; a request after the sources are gone finds no source and says so.

}  // namespace face_reenact::obs_plugin
