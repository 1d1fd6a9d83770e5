#pragma once
// The mouth pass of paper Sec. 7.4.1 (internal to fr_reenact): what the re-rendered face shows
// inside its lip opening. The compositor (face_compositor.cc) renders the output face, teeth and
// tongue included, and hands the pass its G-buffer; the pass draws the interior over it: the
// actor's own open mouth warped into the opening (mouth_interior.h), or the model's teeth and
// tongue lit through the opening (darker the deeper and the narrower) and a dark cavity behind
// them, and mends what the rasterised lips leave around a barely opened mouth.
// docs/reenactment.md ("Mouth") says why each rule is there.
#include <array>
#include <functional>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/reenact/mouth_interior.h"

namespace face_reenact::reenact::internal {

// A pixel the frame's trust in its own sample reaches this is the frame's: the mouth pass leaves
// it (the frame shows the mouth's own surface there), and the frame texture draws a mouth part
// there from its sample alone.
inline constexpr float kShownByTheFrame = 0.5f;

// One output frame's mouth, as the compositor knows it.
struct MouthPassInput {
  const gpu::GBuffer* gbuffer = nullptr;  // the output's rendering (colour as shaded)
  std::vector<Eigen::Vector2f> opening;   // the inner-lip polygon in pixels (iBUG 60-67); empty: none
  float lip_z = 0.f;                      // the inner-lip vertices' mean camera depth (m)
  const std::vector<FacePart>* vertex_part = nullptr;  // the model's part of each vertex
  const std::vector<char>* in_mouth = nullptr;         // face vertices behind the inner lip line
  // The teeth texture's pattern at a teeth pixel of the G-buffer (1 without a texture).
  std::function<Eigen::Vector3f(size_t pixel)> teeth_pattern;
  Eigen::Vector3f entering_light = Eigen::Vector3f::Ones();  // linear irradiance entering the opening
  // The model's teeth and tongue without an open-mouth image: each vertex's albedo (3 per model
  // vertex, linear RGB, as the output is rendered) lit by `front_light`, the light arriving from
  // in front of the face (the camera-facing irradiance, in the colour teeth are lit with), of
  // which a point inside the mouth gets the share its opening lets through (MouthApertureLight).
  // The opening's size in metres comes from its pixels at the lip line's depth: focal_px.
  const Eigen::VectorXf* vertex_albedo = nullptr;
  Eigen::Vector3f front_light = Eigen::Vector3f::Ones();
  float focal_px = 0.f;
  Eigen::Vector3f skin_cast = Eigen::Vector3f::Ones();       // the actor's skin against the model's
  const MouthExemplar* exemplar = nullptr;  // the actor's own open mouth, or null
  // How much of the interior replaces what the opening shows (0..1), and with the frame texture
  // the frame's trust in its own sample of each drawn pixel (frame-sized CV_32FC1; null: none).
  float mouth_alpha = 1.f;
  const cv::Mat* frame_shown = nullptr;
};

// The share of the light from in front of the face that reaches a surface `depth_m` behind the lip
// line, facing out of a mouth whose opening is a disc of radius `opening_radius_m`: the
// cosine-weighted part of its hemisphere the opening subtends, sin^2 of the opening's half-angle,
// r^2 / (r^2 + d^2). 1 at the lip line; a wide-open mouth (r 1.8 cm) lets 0.2 of it reach a tongue
// 3.5 cm in, a barely parted one (r 0.5 cm) 0.28 reach teeth 8 mm in. Non-finite or non-positive
// radius: 0 behind the lip line.
float MouthApertureLight(float opening_radius_m, float depth_m);

// The light the model's teeth and tongue are drawn with: kMouthBounceLight of the light from in
// front whatever their depth, the aperture's share (above) of the rest. The aperture alone is an
// even sky seen through a hole; a real mouth also gets its share of a light in front of it
// straight through the opening (a screen, a window) and the light its moist inside reflects. Lit
// by the aperture alone, the model's tongue 3 cm in drew at 6 % of its albedo's front-lit colour
// in a moderately open mouth: a flat black gash (liveportrait_d10 onto the webcam clip, --mouth
// model, output frames 40 and 80), where the shared clips' real openings, seen through their
// fits' inner-lip polygons, have a median luminance of 0.40-0.58 of the skin around the mouth and
// a darker quartile of 0.29-0.36 (330 source frames of d0, d6, d10, d12 and d14, radii 4-14 mm).
// The tongue's albedo is 0.82 of the skin's in luminance. At 0.35 a deep tongue showed at that
// darker quartile, but a flat fill that bright reads as less open: re-tracked, d6 onto the webcam
// clip (--mouth model, 150 frames) read jawOpen 0.109 from the source's against 0.069 with the
// aperture alone. At 0.2 it shows at about a fifth of the skin, the opening still reads open
// (0.077; the whole expression 0.073 against 0.074), and the gash is a tongue.
constexpr float kMouthBounceLight = 0.2f;
float MouthInteriorLight(float opening_radius_m, float depth_m);

struct MouthPassResult {
  bool drawn = false;          // some interior pixel was drawn
  bool from_exemplar = false;  // some of it from the open-mouth image
};

// Draws the interior into `rendered` (float BGR 0..255, frame-sized) and marks the pixels it drew
// in the compositor's masks: `face_mask` (drawn), `mouth_mask` (mostly the opening's, CV_8UC1) and
// `face_depth` (0 where the opening shows mostly the interior).
MouthPassResult DrawMouth(const MouthPassInput& in, cv::Mat* rendered, cv::Mat* face_mask, cv::Mat* mouth_mask,
                          cv::Mat* face_depth);

}  // namespace face_reenact::reenact::internal
