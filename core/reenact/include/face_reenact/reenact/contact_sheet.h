#pragma once
// A reenacted frame as a person judges it (issue #28, "a gallery a person can judge"): the source
// actor, the target and the output side by side, and below them the target's face, the output's
// face and the output's mouth enlarged, where lines along the lips or a wrong mouth show first.
#include <string>

#include <opencv2/core.hpp>

namespace face_reenact::reenact {

struct ContactSheetOptions {
  int panel_height = 240;  // every panel is scaled to this height
};

// `source`: the source actor's frame (CV_8UC3), or empty when there is none (a UDP stream
// carries expressions, not images: that panel says so). `target`, `output`: CV_8UC3 of one size.
// `face_mask` (CV_8UC1, the output's, optional): where the face was rendered; the zooms frame it
// (without it, the middle of the frame). `caption` goes under the top row's left corner.
// Throws face_reenact::Error on images of the wrong type or mismatched sizes.
cv::Mat ReenactmentContactSheet(const cv::Mat& source, const cv::Mat& target, const cv::Mat& output,
                                const cv::Mat& face_mask, const std::string& caption,
                                const ContactSheetOptions& options = {});

}  // namespace face_reenact::reenact
