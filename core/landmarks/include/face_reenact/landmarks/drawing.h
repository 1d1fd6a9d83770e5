#pragma once
// Pictures for people: landmarks drawn over the frame, and a contact sheet for videos.
#include <string>
#include <vector>

#include "face_reenact/landmarks/image.h"
#include "face_reenact/landmarks/landmark_detector.h"

namespace face_reenact::landmarks {

// A BGR copy of `image` with the face box, the 68 points (green = confident, red = not,
// hollow = invisible/pruned, jawline as a line) and the status written in the corner.
Image draw_landmarks(const ImageView& image, const LandmarkResult& result, const std::string& caption = "");
// Tiles (BGR) scaled to `tile_width` in rows of `columns`.
Image contact_sheet(const std::vector<Image>& tiles, int columns, int tile_width);

}  // namespace face_reenact::landmarks
