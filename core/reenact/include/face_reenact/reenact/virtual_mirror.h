#pragma once
// The virtual mirror (paper Sec. 7.5 and 8.3): one actor's own tracked face, re-textured (an image
// painted into the face's albedo: a logo, make-up, a tattoo) and re-lit (new SH lighting, applied
// to the coarsest level of the Laplacian pyramid only), rendered back into the same frame. The
// expression is the actor's own, so no mouth interior is synthesised: only the skin changes.
#include <array>
#include <memory>
#include <optional>
#include <string>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "face_reenact/gpu/image_formation.h"
#include "face_reenact/model/face_model.h"

namespace face_reenact::reenact {

// Named regions of the face, placed from the model's landmarks (so on every identity and
// expression the same part of the face).
enum class FaceRegion { kFace, kForehead, kNose, kLeftCheek, kRightCheek, kChin };
// "face", "forehead", "nose", "left-cheek", "right-cheek", "chin" (the person's left and right);
// false for any other name.
bool ParseFaceRegion(const std::string& name, FaceRegion* region);
const char* FaceRegionName(FaceRegion region);

// A rectangle of the model's texture layout (MakeHuman's UV layout, u to the right, v up), for
// textures made for that layout.
struct UvRect {
  float u0 = 0.f, v0 = 0.f, u1 = 1.f, v1 = 1.f;
  bool IsValid(std::string* why) const;  // finite, within [0, 1], u0 < u1 and v0 < v1
};

// Where the texture goes: a named region (the image keeps its aspect, centred in the region and
// upright on the face) or, when `region` is empty, a UV rectangle (the image stretched over it,
// its top row at v1).
struct TexturePlacement {
  std::optional<FaceRegion> region = FaceRegion::kFace;
  UvRect uv;
};

// The light the mirror renders with.
struct MirrorLight {
  enum class Kind {
    kTracked,       // the tracked light: no re-lighting
    kPreset,        // a direction and colour; the face's mean irradiance stays the tracked light's (ParseLightPreset)
    kCoefficients,  // SH coefficients used as they are (ReadLightFile)
  };
  Kind kind = Kind::kTracked;
  std::string name;  // the preset's name, or the file the coefficients came from
  // kPreset: the direction the light comes from (camera space: x right, y down, towards the
  // camera is -z), its colour and the share of the light that comes from everywhere.
  Eigen::Vector3f direction = Eigen::Vector3f(0.f, 0.f, -1.f);
  Eigen::Vector3f colour = Eigen::Vector3f::Ones();
  float ambient_share = 0.5f;
  // kCoefficients: gamma[channel * 9 + k] as FaceParameters::gamma (and track's PARAMS.jsonl).
  std::array<float, gpu::kNumShParameters> gamma{};
  bool IsValid(std::string* why) const;
};

// "front", "left", "right", "top", "bottom" (from the image's point of view), "warm", "cool"
// (from the front, coloured). Throws face_reenact::Error naming the presets for any other name.
MirrorLight ParseLightPreset(const std::string& name);
// A JSON file with "gamma": 27 finite numbers (an object of its own, or a line of track's
// PARAMS.jsonl). Throws face_reenact::Error saying what is wrong.
MirrorLight ReadLightFile(const std::string& path);
// The same from the file's text; `name` is what the messages call it.
MirrorLight ParseLightJson(const std::string& text, const std::string& name);
// The SH coefficients of a light preset, each channel as bright towards the camera as `tracked`'s
// times the preset's colour (VirtualMirror::Apply then scales them so that the face's mean
// irradiance stays the tracked light's: the face keeps its exposure, the light changes direction).
std::array<float, gpu::kNumShParameters> PresetCoefficients(const MirrorLight& light,
                                                            const std::array<float, gpu::kNumShParameters>& tracked);

struct MirrorOptions {
  cv::Mat texture;  // CV_8UC4 (BGRA, straight alpha) or CV_8UC3 (opaque); empty: no re-texturing
  TexturePlacement placement;
  float opacity = 1.0f;  // the texture's alpha is scaled by this, in [0, 1]
  MirrorLight light;     // kTracked: no re-lighting
  // The Laplacian pyramid level whose foreground is re-lit (the coarsest of that many levels):
  // the light changes only at the scale of 2^levels pixels, so the frame's own fine shading stays.
  int relight_levels = 4;
  // On frames with depth: a pixel whose depth lies this much nearer the camera than the fitted
  // face shows something in front of it (a hand, a cup, hair): it is neither painted nor re-lit,
  // and the change fades out around it as around the face's border. 0 turns the test off.
  float depth_occluder_m = 0.04f;
  bool IsValid(std::string* why) const;
};

// The front-ends' words for a mirror (the CLI's --texture / --at / --opacity / --light, the live
// session's and the OBS source's settings): `at` a region name or "uv:U0,V0,U1,V1"; `light` a
// preset's name, a .json file, or "" for the tracked light; `texture` an image file, or "" for
// none. Throws face_reenact::Error saying which one is wrong.
TexturePlacement ParseTexturePlacement(const std::string& at);
MirrorLight ParseMirrorLight(const std::string& light);
MirrorOptions MirrorOptionsFromSettings(const std::string& texture, const std::string& at, float opacity,
                                        const std::string& light);

struct MirrorResult {
  cv::Mat bgr;               // CV_8UC3, the frame with the face re-textured and re-lit
  bool drawn = false;        // false: no face surface in view, the frame unchanged
  int textured_pixels = 0;   // pixels the texture covers with any opacity
  int occluded_pixels = 0;   // face pixels the frame's depth shows something in front of
  double render_ms = 0.0;    // model evaluation and rasterisation
  double composite_ms = 0.0; // texture, light and blend
};

class VirtualMirror {
 public:
  // Throws face_reenact::Error on invalid options, or a model without the texture layout or the
  // landmarks the placement needs.
  VirtualMirror(const FaceModel& model, MirrorOptions options);
  ~VirtualMirror();
  VirtualMirror(const VirtualMirror&) = delete;
  VirtualMirror& operator=(const VirtualMirror&) = delete;

  // `frame_bgr`: CV_8UC3 of the camera's size; `tracked`: the frame's fit; `depth` (optional):
  // the frame's depth in metres, CV_32FC1 of the camera's size, registered to the colour (0 or
  // NaN where unknown). Throws face_reenact::Error on a frame or depth of another size or type, or
  // invalid parameters.
  MirrorResult Apply(const cv::Mat& frame_bgr, const gpu::PinholeCamera& camera,
                     const gpu::FaceParameters& tracked, const cv::Mat* depth = nullptr) const;

  // The texture layout coordinates (u, v) the placement maps to the texture's pixel (x, y):
  // for tests and for a person checking where a region lands.
  Eigen::Vector2f TexturePixelToUv(float x, float y) const;
  const MirrorOptions& options() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace face_reenact::reenact
