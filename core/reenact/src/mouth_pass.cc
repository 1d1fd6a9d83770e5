#include "mouth_pass.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <opencv2/imgproc.hpp>

#include "face_parts.h"
#include "image_sampling.h"

namespace face_reenact::reenact::internal {
namespace {

// Linear-RGB albedo of the mouth cavity's back wall: dark red-brown, and it receives little of
// the scene's light (most of the hemisphere above it is the inside of the mouth).
const Eigen::Vector3f kCavityAlbedo(0.09f, 0.025f, 0.025f);
// A face-part surface this far behind the lip line (inside the lip opening) is the cavity wall.
constexpr float kCavityDepthM = 0.003f;
// Any face surface this far behind the lip line that shows beside the opening is the inside of
// the mouth seen past a lip (the model's mouth bag); the skin beside the mouth is never this deep.
constexpr float kInsideTheMouthM = 0.03f;

}  // namespace

float MouthApertureLight(float opening_radius_m, float depth_m) {
  if (!(depth_m > 0.f)) return 1.f;
  if (!(opening_radius_m > 0.f) || !std::isfinite(opening_radius_m) || !std::isfinite(depth_m)) return 0.f;
  const float r2 = opening_radius_m * opening_radius_m;
  return r2 / (r2 + depth_m * depth_m);
}

float MouthInteriorLight(float opening_radius_m, float depth_m) {
  return kMouthBounceLight + (1.f - kMouthBounceLight) * MouthApertureLight(opening_radius_m, depth_m);
}

MouthPassResult DrawMouth(const MouthPassInput& in, cv::Mat* rendered_bgr, cv::Mat* face_mask_out, cv::Mat* mouth_mask_out,
                          cv::Mat* face_depth_out) {
  MouthPassResult result;
  const std::vector<Eigen::Vector2f>& opening_px = in.opening;
  if (opening_px.empty() || !in.gbuffer) return result;
  const gpu::GBuffer& g = *in.gbuffer;
  cv::Mat& rendered = *rendered_bgr;
  cv::Mat& face_mask = *face_mask_out;
  cv::Mat& mouth_mask = *mouth_mask_out;
  cv::Mat& face_depth = *face_depth_out;
  const int w = rendered.cols, h = rendered.rows;
  const float lip_z = in.lip_z;
  const float mouth_alpha = in.mouth_alpha;
  const cv::Mat frame_shown = in.frame_shown ? *in.frame_shown : cv::Mat();
  const std::vector<char>& in_mouth = *in.in_mouth;
  auto part_of = [&](int32_t v) { return (*in.vertex_part)[static_cast<size_t>(v)]; };
  constexpr int kSubpixelBits = 4;
  std::vector<cv::Point> polygon;
  for (const Eigen::Vector2f& uv : opening_px)
    polygon.emplace_back(static_cast<int>(std::lround(uv.x() * (1 << kSubpixelBits))),
                         static_cast<int>(std::lround(uv.y() * (1 << kSubpixelBits))));
  // Light reaching the cavity: the part of the target's lighting that enters the opening.
  Eigen::Vector3f cavity_rgb;
  for (int c = 0; c < 3; ++c) cavity_rgb[c] = in.entering_light[c] * kCavityAlbedo[c] * in.skin_cast[c];
  // The actor's own open mouth, when there is one, in place of the model's teeth and the
  // cavity: darker as the opening narrows, since less light enters it.
  const MouthExemplar* mouth = in.exemplar;
  const bool use_exemplar = mouth && !mouth->empty() && mouth->opening.size() == opening_px.size();
  const double opening_area_px = PolygonArea(opening_px);
  const float exemplar_light = use_exemplar ? MouthInteriorBrightness(opening_area_px, mouth->area_px) : 1.f;
  // The opening as a disc of its area, in metres at the lip line's depth (MouthApertureLight).
  const float opening_radius_m =
      in.focal_px > 0.f ? static_cast<float>(std::sqrt(opening_area_px / M_PI)) * lip_z / in.focal_px : 0.f;
  // A teeth or tongue pixel's colour lit from in front (MouthPassInput::vertex_albedo): its
  // albedo interpolated over its triangle; without the albedo, the rendering's own colour.
  auto shaded = [&](size_t p) { return Eigen::Vector3f(g.color[3 * p], g.color[3 * p + 1], g.color[3 * p + 2]); };
  auto front_lit = [&](size_t p) -> Eigen::Vector3f {
    if (!in.vertex_albedo) return shaded(p);
    Eigen::Vector3f albedo = Eigen::Vector3f::Zero();
    for (int k = 0; k < 3; ++k)
      albedo += g.barycentric[3 * p + k] * in.vertex_albedo->segment<3>(3 * static_cast<Eigen::Index>(g.vertices[3 * p + k]));
    return albedo.cwiseProduct(in.front_light);
  };
  // The interior is drawn as a layer of its own (premultiplied colour and coverage) and
  // softened by about a camera's blur before it goes over the face: drawn sharp, one sample per
  // pixel, a barely opened mouth's cavity was a row of hard, nearly black dashes along the lip
  // line (d14 smiling, on the webcam clip, output frame 40), where the frame's own lip line is
  // a soft shadow; a wider opening's teeth and its outline against the lips' rasterised inner
  // faces were stair-stepped. (0.8 px: at 1.2 the line nearly vanished.)
  constexpr float kInteriorSoftnessPx = 0.8f;
  // With an open-mouth image, the model's mouth geometry just outside the inner-lip polygon
  // takes it too: the lips' inner faces and the teeth the rasteriser draws between the polygon
  // and the lips' silhouette were a hard, stair-stepped dark wedge at the mouth's corners and
  // a grey-green sliver under it (d6 on the webcam clip, frame 60). Mean-value coordinates
  // extend past the polygon, so those pixels sample the image just past its opening: the
  // inside of its lips. Only within kBeyondOpeningPx of the polygon, and only where the frame
  // texture does not show that surface itself: at a barely opened, pursed mouth (d14 on the
  // webcam clip, output frame 36; an opening of 82 px) the model's inner lip faces reach 4-11 px
  // past the corners, where the target's own lip corner is what the frame shows (trusted at
  // 0.6-1), and the image's dark opening drew a grey hook down the left corner and a dot
  // under it. Without an image the teeth and the wall behind the lips (more than
  // kCavityDepthM behind their line) there are the mouth pass's too, shaded as inside the
  // opening; left to the face's rendering they were unshaded: a lower lip rolled in over an
  // opened jaw showed white specks of back teeth at the mouth's corners. No farther past the
  // polygon than the opening is high on average (its area over its width): over a barely opened
  // mouth (d14 smiling with her eyes shut, output frame 73; about a pixel high) the lips' inner
  // faces at the corners, 4-11 mm behind the lip line, took the image's dark corner of a wide
  // opening, a dark blob at each corner of a closed-looking mouth. Smaller so, the blobs stayed
  // (the cavity's colour, 7 px long, where no image stood in): a barely opened mouth (below)
  // takes nothing past its polygon, and those faces keep the face's rendering, the lips' colour.
  constexpr int kBeyondOpeningPx = 6;
  constexpr int kFollowInsidePx = 8;  // below
  const int margin = static_cast<int>(std::ceil(3.0f * kInteriorSoftnessPx)) + kBeyondOpeningPx + kFollowInsidePx;
  cv::Rect zone = cv::boundingRect(polygon);
  zone = cv::Rect(zone.x >> kSubpixelBits, zone.y >> kSubpixelBits, (zone.width >> kSubpixelBits) + 2,
                  (zone.height >> kSubpixelBits) + 2);
  zone = grown_within(zone, margin, w, h);
  // A barely opened mouth: the opening under kBarelyOpenPx high on average (its area over its
  // width). The rules for it follow.
  constexpr float kBarelyOpenPx = 2.0f;
  float left = std::numeric_limits<float>::infinity(), right = -left;
  for (const Eigen::Vector2f& uv : opening_px) {
    left = std::min(left, uv.x());
    right = std::max(right, uv.x());
  }
  const double mean_height_px = PolygonArea(opening_px) / std::max(1.0, static_cast<double>(right - left));
  const bool barely_open = mean_height_px < kBarelyOpenPx;
  // The opening's coverage of each pixel, anti-aliased at 1/16 px: a hard-edged polygon drew
  // the lip line as a staircase of interior and lip pixels (seen on the webcam clip). Over a barely
  // opened mouth, the share of kCoverageSamples x kCoverageSamples samples inside the polygon
  // instead: OpenCV's anti-aliased fill draws every edge as a line a pixel or two wide, so an
  // opening thinner than a pixel was covered in full, a dark stroke 2-3 px high along the last
  // 12 px to a corner (d14 with closed lips onto the webcam clip, output frame 73). Not over wider
  // openings: there the fill's fuller edge darkens the cavity wall the rasteriser draws just inside
  // the polygon, which the exact share left lighter, and the teeth at the corners stood out
  // against it (NoUnshadedTeethPastTheOpeningsCorners, 2 specks).
  constexpr int kCoverageSamples = 4;
  cv::Mat opening = cv::Mat::zeros(h, w, CV_8UC1);
  if (!barely_open) {
    cv::fillPoly(opening, std::vector<std::vector<cv::Point>>{polygon}, cv::Scalar(255), cv::LINE_AA, kSubpixelBits);
  } else if (!zone.empty()) {
    std::vector<cv::Point> fine;
    // Pixel i spans [i - 0.5, i + 0.5]; its samples sit at the centres of its kCoverageSamples parts.
    for (const Eigen::Vector2f& uv : opening_px)
      fine.emplace_back(
          static_cast<int>(std::lround(((uv.x() - zone.x + 0.5f) * kCoverageSamples - 0.5f) * (1 << kSubpixelBits))),
          static_cast<int>(std::lround(((uv.y() - zone.y + 0.5f) * kCoverageSamples - 0.5f) * (1 << kSubpixelBits))));
    cv::Mat samples = cv::Mat::zeros(zone.height * kCoverageSamples, zone.width * kCoverageSamples, CV_8UC1);
    cv::fillPoly(samples, std::vector<std::vector<cv::Point>>{fine}, cv::Scalar(255), cv::LINE_8, kSubpixelBits);
    cv::Mat coverage;
    cv::resize(samples, coverage, zone.size(), 0, 0, cv::INTER_AREA);
    coverage.copyTo(opening(zone));
  }
  // The zone's pixels within `reach_px` of the opening as it stands (nonzero: near).
  auto near_the_opening = [&](int reach_px) {
    cv::Mat near;
    cv::dilate(opening(zone), near, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * reach_px + 1, 2 * reach_px + 1)));
    return near;
  };
  // The lips themselves, as the rasteriser drew them in and around the opening (the inner
  // faces of the lips take an open-mouth image's colour, so they are not lips here).
  auto lip_at = [&](int i, int j) {
    const size_t p = static_cast<size_t>(j) * w + i;
    if (g.triangle[p] < 0) return false;
    const int32_t v0 = g.vertices[3 * p];
    return !(kMouthParts & part_bit(part_of(v0))) && g.position[3 * p + 2] - lip_z <= kCavityDepthM &&
           !(use_exemplar && in_mouth[static_cast<size_t>(v0)]);
  };
  cv::Mat lips(zone.size(), CV_8UC1);
  for (int j = 0; j < zone.height; ++j)
    for (int i = 0; i < zone.width; ++i) lips.at<uchar>(j, i) = lip_at(i + zone.x, j + zone.y) ? 255 : 0;
  // A barely opened mouth (the opening under kBarelyOpenPx high on average: its area over its
  // width) is covered by the model's lips, but their meshes do not quite meet everywhere:
  // through gaps of one or two pixels the tongue or the teeth behind show. Taken as the opening
  // (its anti-aliased edge, or the geometry just past it, below) they drew a dashed dark line
  // along the lips where the frame's lip line is a soft shadow (d14 smiling with her eyes shut
  // on the webcam clip, output frame 73: dashes of (107, 57, 55) between lips at (190, 130,
  // 135)); they are lip, in the colour of the lip pixels above and below them. A wider opening
  // keeps them: there the lips do not meet, and what shows between them is the mouth's inside.
  // A gap pixel takes the mean of the nearest lip pixels above and below it (within 2 px). With an
  // open-mouth image the lips' inner faces are not lips here (lip_at), and near a corner a gap can
  // have only those above and below it: then it takes the mean of the skin within 3 px around it
  // (the inner faces as the face's rendering drew them, which is lip), not the teeth it shows
  // (liveportrait_d10 onto the webcam clip, output frame 99: two teeth pixels of (227, 210, 190)).
  auto fill_lip_gap = [&](int i, int j) {
    cv::Vec3f sum(0.f, 0.f, 0.f);
    int n = 0;
    for (const int step : {-1, 1})
      for (int d = 1; d <= 2; ++d) {
        const int y = j + step * d;
        if (y < zone.y || y >= zone.y + zone.height || !lips.at<uchar>(y - zone.y, i - zone.x)) continue;
        sum += rendered.at<cv::Vec3f>(y, i);
        ++n;
        break;
      }
    constexpr int kSkinAroundPx = 3;
    const int y0 = std::max(zone.y, j - kSkinAroundPx), y1 = std::min(zone.y + zone.height - 1, j + kSkinAroundPx);
    const int x0 = std::max(zone.x, i - kSkinAroundPx), x1 = std::min(zone.x + zone.width - 1, i + kSkinAroundPx);
    for (int y = y0; n == 0 && y <= y1; ++y)
      for (int x = x0; x <= x1; ++x) {
        const size_t q = static_cast<size_t>(y) * w + x;
        if (g.triangle[q] < 0 || (kMouthParts & part_bit(part_of(g.vertices[3 * q])))) continue;
        sum += rendered.at<cv::Vec3f>(y, x);
        ++n;
      }
    if (n > 0) rendered.at<cv::Vec3f>(j, i) = sum / static_cast<float>(n);
  };
  cv::Mat lip_gaps = cv::Mat::zeros(zone.size(), CV_8UC1);
  constexpr uchar kUnderOnly = 128;  // a gap whose pixel the opening partly covers (below)
  if (barely_open) {
    cv::morphologyEx(lips, lip_gaps, cv::MORPH_CLOSE, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(1, 3)));
    lip_gaps &= ~lips;
    // So are the teeth and the tongue the rasteriser draws on the polygon's edge or outside it:
    // such an opening takes nothing past its polygon (below), and left to the face's rendering,
    // in full or under a partly covered pixel, they were white specks and dashes on the lip line
    // (d14 onto the webcam clip, output frames 95-97: tooth pixels at 170-190 between lips at
    // 125-145). Not only within 2 px of the polygon, as until 2026-12-03: cracks between the lips'
    // meshes near a corner show teeth 3-4 px from it (liveportrait_d10 onto the webcam clip, output
    // frames 100-101: (254, 235, 214) among lips at (167, 122, 119)).
    for (int j = zone.y; j < zone.y + zone.height; ++j)
      for (int i = zone.x; i < zone.x + zone.width; ++i) {
        const size_t p = static_cast<size_t>(j) * w + i;
        if (opening.at<uchar>(j, i) == 255 || g.triangle[p] < 0) continue;
        // On the edge (partly the opening's) only the rendering under the interior's share is lip.
        if ((kMouthParts & part_bit(part_of(g.vertices[3 * p]))) && !lip_gaps.at<uchar>(j - zone.y, i - zone.x))
          lip_gaps.at<uchar>(j - zone.y, i - zone.x) = opening.at<uchar>(j, i) ? kUnderOnly : 255;
      }
  }
  for (int j = zone.y; j < zone.y + zone.height; ++j)
    for (int i = zone.x; i < zone.x + zone.width; ++i) {
      if (!lip_gaps.at<uchar>(j - zone.y, i - zone.x)) continue;
      const size_t p = static_cast<size_t>(j) * w + i;
      // Only what the frame does not show: where it does, its own pixel is what the gap shows.
      if (g.triangle[p] < 0 || (!frame_shown.empty() && frame_shown.at<float>(j, i) >= kShownByTheFrame)) continue;
      fill_lip_gap(i, j);
      if (lip_gaps.at<uchar>(j - zone.y, i - zone.x) != kUnderOnly) lips.at<uchar>(j - zone.y, i - zone.x) = 255;
    }
  cv::Mat past_opening = cv::Mat::zeros(zone.size(), CV_8UC1);  // taken past the polygon (below)
  if (!barely_open) {
    // The mouth's inside past the polygon that the frame does not show: teeth, tongue, the faces
    // behind the lip line, and any face surface far behind it (the inside of the mouth seen past
    // a lip pulled down), lip gaps excepted.
    cv::Mat inside = cv::Mat::zeros(zone.size(), CV_8UC1);
    for (int j = zone.y; j < zone.y + zone.height; ++j) {
      const uchar* orow = opening.ptr<uchar>(j);
      for (int i = zone.x; i < zone.x + zone.width; ++i) {
        const size_t p = static_cast<size_t>(j) * w + i;
        if (orow[i] == 255 || g.triangle[p] < 0) continue;
        if (!frame_shown.empty() && frame_shown.at<float>(j, i) >= kShownByTheFrame) continue;
        const int32_t v0 = g.vertices[3 * p];
        const float depth_behind = g.position[3 * p + 2] - lip_z;
        const bool inside_geometry =
            (kMouthParts & part_bit(part_of(v0))) || depth_behind > kInsideTheMouthM ||
            (in_mouth[static_cast<size_t>(v0)] && (use_exemplar || depth_behind > kCavityDepthM));
        if (!inside_geometry) continue;
        if (lips.at<uchar>(j - zone.y, i - zone.x)) continue;  // a gap between the lips, filled above
        inside.at<uchar>(j - zone.y, i - zone.x) = 255;
      }
    }
    const int beyond_px = std::clamp(static_cast<int>(std::lround(mean_height_px)), 1, kBeyondOpeningPx);
    past_opening = inside & near_the_opening(beyond_px);
    // Where a lip the output pulls far from the polygon (d6's bared teeth onto d10, output frame
    // 120: mouthLowerDown 0.67 over jawOpen 0.48) leaves more of the inside than that between the
    // polygon and the lip, the rest of it was left to the face's rendering: the albedo map's teeth
    // and tongue, a grey-green stroke along each side of the lower lip. The taken region follows
    // the inside where it continues from there, a pixel at a time, up to kFollowInsidePx farther.
    for (int step = 0; step < kFollowInsidePx; ++step) {
      cv::Mat grown;
      cv::dilate(past_opening, grown, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(3, 3)));
      grown &= inside;
      if (cv::countNonZero(grown != past_opening) == 0) break;
      past_opening = grown;
    }
    for (int j = zone.y; j < zone.y + zone.height; ++j) {
      uchar* orow = opening.ptr<uchar>(j);
      for (int i = zone.x; i < zone.x + zone.width; ++i)
        if (past_opening.at<uchar>(j - zone.y, i - zone.x)) orow[i] = 255;
    }
  }
  // Where the output rolls a lip out (d6's grimace on the webcam clip, frame 60), the faces
  // between the lip's rim and its body turn away from the camera and are culled: the rim is
  // left as a strip one or two pixels high inside the opening, the teeth showing through the
  // gap behind it; elsewhere along the line the rim's pixels stick out of the lip's edge one at
  // a time. Unseen by the frame, the rim takes the albedo map's colour of the lip's inner face,
  // which the mouth's shadow taught: they drew a dotted dark line along the teeth. No lip looks
  // like that. Lip pixels in the opening or within kLipStripReachPx of it that a 3x3 cross of
  // lip does not fit over are drawn as the interior: the open-mouth image's there, or else the
  // interior drawn around them.
  constexpr int kLipStripReachPx = 2;
  cv::Mat solid_lips;
  cv::morphologyEx(lips, solid_lips, cv::MORPH_OPEN, cv::getStructuringElement(cv::MORPH_CROSS, cv::Size(3, 3)));
  const cv::Mat near_lips = near_the_opening(kLipStripReachPx);
  struct Strip {
    int i, j;
    float alpha;
  };
  // A strip gives way only to an interior lighter than itself: what it drew was a dark line,
  // and at a smiling mouth's corners, where the opening tapers into the lips (d14 on the webcam
  // clip), the cavity's colour would lengthen the dark opening.
  auto rim_gives_way = [&](int i, int j, const cv::Vec3f& colour) {
    const cv::Vec3f& own = rendered.at<cv::Vec3f>(j, i);
    return colour[0] + colour[1] + colour[2] >= own[0] + own[1] + own[2];
  };
  std::vector<Strip> strips;  // lip strips that take the colour of the interior around them
  cv::Mat layer = cv::Mat::zeros(zone.size(), CV_32FC3), layer_alpha = cv::Mat::zeros(zone.size(), CV_32FC1);
  int drawn = 0, from_exemplar = 0;
  // One pixel of the interior layer drawn: its masks and depth.
  auto mark_drawn = [&](int i, int j, uchar coverage, float alpha) {
    if (coverage >= 128) mouth_mask.at<uchar>(j, i) = 255;
    face_mask.at<uchar>(j, i) = 255;
    // The output depth has no surface in an opening that shows mostly the interior.
    if (alpha >= 0.5f) face_depth.at<float>(j, i) = 0.0f;
    ++drawn;
  };
  for (int j = zone.y; j < zone.y + zone.height; ++j) {
    const uchar* orow = opening.ptr<uchar>(j);
    for (int i = zone.x; i < zone.x + zone.width; ++i) {
      // Over a barely opened mouth the opening's own coverage decides, not the lips the rasteriser
      // drew across it: the model's inner lip edges wander a pixel above and below the polygon
      // through the landmarks, and where they covered it the slit was skipped (or left to a strip
      // that gives way only to lighter colours), a dark line broken into dashes that crawled from
      // frame to frame (d14 onto the webcam clip, output frames 34-40, openings 0.6-1.6 px high
      // on average). Inside the polygon the slit is drawn at its coverage: one thin line, fainter
      // where the opening is thinner.
      const bool lip = lips.at<uchar>(j - zone.y, i - zone.x) != 0 && !(barely_open && orow[i] > 0);
      const bool strip = lip && solid_lips.at<uchar>(j - zone.y, i - zone.x) == 0 &&
                         near_lips.at<uchar>(j - zone.y, i - zone.x) != 0;
      if (lip && !strip) continue;
      // How much of the pixel is the opening's: a strip's all of it.
      const uchar coverage = strip ? 255 : orow[i];
      if (!coverage) continue;
      const size_t p = static_cast<size_t>(j) * w + i;
      const int32_t v0 = g.vertices[3 * p];
      const bool covered = g.triangle[p] >= 0;
      const FacePart part = covered ? part_of(v0) : FacePart::Face;
      const bool mouth_part = covered && (kMouthParts & part_bit(part));
      const float depth_behind = covered ? g.position[3 * p + 2] - lip_z : 1.0f;
      const float unshown = covered && !frame_shown.empty() ? 1.0f - std::clamp(frame_shown.at<float>(j, i), 0.0f, 1.0f) : 0.0f;
      const float alpha = std::max(mouth_alpha, unshown) * static_cast<float>(coverage) / 255.0f;
      if (!(alpha > 0.f)) continue;
      Eigen::Vector3f interior;
      if (use_exemplar && SampleMouthExemplar(*mouth, opening_px,
                                              Eigen::Vector2f(static_cast<float>(i), static_cast<float>(j)), &interior)) {
        interior *= exemplar_light;
        ++from_exemplar;
      } else if (strip) {
        strips.push_back({i, j, alpha});
        continue;
      } else if (mouth_part) {
        // Lit through the opening: the light from in front of the face, of which a point inside
        // gets the share the opening subtends and what the mouth's inside bounces
        // (MouthInteriorLight). Shaded at their own normals instead (up, down,
        // inwards: where the fit's light is an extrapolation) and darkened linearly with depth,
        // the tongue of a wide-open mouth drew at 2 % of the cheek's luminance, the cavity's own
        // colour: one flat dark gash with a band of teeth above it (d6 onto the webcam clip,
        // --mouth model, output frame 60), where a real open mouth's tongue shows at about a
        // third of the cheek (d12's frame 125) and only its rim and the throat are that dark.
        const float light = MouthInteriorLight(opening_radius_m, depth_behind);
        // The teeth's texture (teeth_texture.h): gaps, edges and darker corners on the band.
        const Eigen::Vector3f pattern = part == FacePart::Tongue ? Eigen::Vector3f::Ones() : in.teeth_pattern(p);
        // The teeth's biting edges face up or down, away from the opening, so they keep the fit's
        // light at their own normals where that is less: lit from in front, the lower teeth in a
        // parted mouth drew a row of white dashes along the lower lip (d14 on the webcam clip,
        // output frames 11-37). The model's tongue faces up where a real one in an open mouth
        // bulges toward the opening, so it is lit from in front.
        Eigen::Vector3f lit = front_lit(p);
        if (part != FacePart::Tongue)
          lit = lit.cwiseMin(shaded(p));
        // No darker than the cavity wall behind them.
        for (int c = 0; c < 3; ++c) interior[c] = std::max(light * pattern[c] * lit[c], cavity_rgb[c]);
      } else {
        interior = cavity_rgb;
      }
      const cv::Vec3f colour = display_bgr(interior);
      if (strip && !rim_gives_way(i, j, colour)) continue;
      // Under the softened layer's edge the face's rendering shows through: past the polygon,
      // for teeth that is their unshaded colour, which drew light specks along the opening's
      // edge. Where the layer takes such a pixel whole, the rendering under it is the
      // interior's colour too.
      if (mouth_part && alpha >= 1.0f && past_opening.at<uchar>(j - zone.y, i - zone.x))
        rendered.at<cv::Vec3f>(j, i) = colour;
      layer.at<cv::Vec3f>(j - zone.y, i - zone.x) = alpha * colour;
      layer_alpha.at<float>(j - zone.y, i - zone.x) = alpha;
      mark_drawn(i, j, coverage, alpha);
    }
  }
  // Each strip pixel: the mean colour of the interior drawn in its 5x5 neighbourhood (the
  // cavity's where there is none).
  const cv::Vec3f cavity_bgr = display_bgr(cavity_rgb);
  for (const Strip& s : strips) {
    const int li = s.i - zone.x, lj = s.j - zone.y;
    cv::Vec3f sum(0.f, 0.f, 0.f);
    float weight = 0.f;
    for (int dj = -2; dj <= 2; ++dj)
      for (int di = -2; di <= 2; ++di) {
        const int y = lj + dj, x = li + di;
        if (x < 0 || y < 0 || x >= zone.width || y >= zone.height) continue;
        const float a = layer_alpha.at<float>(y, x);
        if (!(a > 0.f)) continue;
        sum += layer.at<cv::Vec3f>(y, x);  // premultiplied: the alpha-weighted mean
        weight += a;
      }
    const cv::Vec3f colour = weight > 0.f ? cv::Vec3f(sum / weight) : cavity_bgr;
    if (!rim_gives_way(s.i, s.j, colour)) continue;
    layer.at<cv::Vec3f>(lj, li) = s.alpha * colour;
    layer_alpha.at<float>(lj, li) = s.alpha;
    mark_drawn(s.i, s.j, 255, s.alpha);
  }
  if (drawn > 0) {
    cv::GaussianBlur(layer, layer, cv::Size(0, 0), kInteriorSoftnessPx);
    cv::GaussianBlur(layer_alpha, layer_alpha, cv::Size(0, 0), kInteriorSoftnessPx);
    for (int j = 0; j < zone.height; ++j)
      for (int i = 0; i < zone.width; ++i) {
        const float a = layer_alpha.at<float>(j, i);
        if (!(a > 0.f)) continue;
        cv::Vec3f& px = rendered.at<cv::Vec3f>(j + zone.y, i + zone.x);
        px = layer.at<cv::Vec3f>(j, i) + (1.0f - a) * px;
      }
  }
  result.drawn = drawn > 0;
  result.from_exemplar = from_exemplar > 0;
  return result;
}

}  // namespace face_reenact::reenact::internal
