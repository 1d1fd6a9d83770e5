#pragma once
// Tracker options that `track` and `reenact` both offer, with one help text.
#include <string>

#include <CLI/CLI.hpp>

#include "face_reenact/tracker/face_tracker.h"

namespace face_reenact::cli {

// --max-face-width (TrackerOptions::max_face_width_px); `note` opens the parenthesis of the help
// text ("as track; " in reenact).
inline void add_max_face_width_option(CLI::App* command, int* value, const std::string& note = "") {
  command
      ->add_option("--max-face-width", *value,
                   "Track a larger face on coarser pyramid levels, so that it is at most this wide on the finest (px; " +
                       note + "default " + std::to_string(tracker::TrackerOptions{}.max_face_width_px) +
                       ", 0 = never coarser)")
      ->check(CLI::Range(0, 4096));
}

}  // namespace face_reenact::cli
