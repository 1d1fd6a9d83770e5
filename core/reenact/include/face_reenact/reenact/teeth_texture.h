#pragma once
// The teeth proxy's texture (paper Sec. 7.4.1): the model's upper and lower teeth are smooth
// bands (68 vertices each in the MakeHuman helper geometry), drawn in one flat colour they read
// as a grey strip. A TeethTexture is a photo's row of teeth, rectified between the inner-lip
// line above and below them, that the compositor lays over the bands: each teeth pixel looks it
// up at the point's place across the dental arch (u) and from the gum to the biting edge (v),
// and takes its pattern (the gaps, the edges, the darker corners) relative to the teeth's own
// bright colour, so the model's lighting and shading stay in charge of the brightness.
//
// The default texture is built at set-up (`face-reenact model teeth`) from NASA's public-domain
// portrait of Eileen Collins (smiling, her upper teeth showing), for a target actor who never
// opens the mouth in front of the camera; an actor's own open mouth (mouth_interior.h) replaces
// the whole interior when there is one.
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "face_reenact/model/face_model.h"

namespace face_reenact::reenact {

struct TeethTexture {
  cv::Mat bgr;  // CV_8UC3, sRGB: columns u (left mouth corner -> right), rows v (gum -> edge)
  // The teeth's bright colour in linear RGB (the median of the texture's brightest third in its
  // middle half): TeethPattern is relative to it.
  Eigen::Vector3f reference = Eigen::Vector3f::Ones();
  std::string source;  // where it came from (the file, or the photo)
  bool empty() const { return bgr.empty(); }
};

// Rectifies the teeth between `inner_lips` (the photo's 8 inner-lip points, iBUG 60-67 order:
// left corner, three along the upper lip, right corner, three back along the lower lip) into a
// width x height texture: column u runs from corner to corner, row v from the upper lip's line
// down to the lower lip's at that u. Throws face_reenact::Error when the photo is not 8-bit BGR,
// the points are not finite or inside it, or the opening is shut (less than 2 px between the
// lips over the middle half, where a smile shows its teeth).
TeethTexture BuildTeethTexture(const cv::Mat& photo_bgr, const std::vector<Eigen::Vector2f>& inner_lips, int width = 256,
                               int height = 64);

// Reads / writes a texture as PNG. LoadTeethTexture throws face_reenact::Error for a file that
// is missing, not an image, or smaller than 16x4 pixels.
TeethTexture LoadTeethTexture(const std::string& path);
void SaveTeethTexture(const TeethTexture& texture, const std::string& path);

// The default texture's file beside the face model `model_path` (face-teeth.png).
std::string DefaultTeethTexturePath(const std::string& model_path);
// The default texture for the model at `model_path`; null, with the reason in `why`, when it is
// missing or unreadable (the model's teeth are then drawn in their flat colour: never an error,
// a missing texture must not stop a reenactment).
std::shared_ptr<const TeethTexture> LoadDefaultTeethTexture(const std::string& model_path, std::string* why);

// The texture's pattern at (u, v) in [0, 1]^2 (clamped): its linear colour over `reference`,
// each channel within [0, 1.25] (a gap between two teeth is dark, the teeth about 1).
Eigen::Vector3f TeethPattern(const TeethTexture& texture, float u, float v);

// Per-vertex texture coordinates of the model's teeth (NaN for every other vertex), from the
// mean shape: u = where the vertex lies between the mouth's inner corners (iBUG 60 and 64; the
// back teeth lie beyond and clamp to the texture's edge), v = from the band's gum (0) to its
// biting edge (1), upper and lower teeth alike. Empty when the model has no teeth or no
// inner-lip landmarks.
std::vector<Eigen::Vector2f> TeethTextureCoordinates(const FaceModel& model);

}  // namespace face_reenact::reenact
