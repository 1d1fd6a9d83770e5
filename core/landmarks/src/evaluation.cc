#include "face_reenact/landmarks/evaluation.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numeric>
#include <sstream>
#include <time.h>

#include "face_reenact/capture/media_file.h"
#include "face_reenact/common/error.h"
#include "face_reenact/landmarks/frame_source.h"

namespace face_reenact::landmarks {
namespace fs = std::filesystem;

Shape68 parse_pts(const std::string& text, const std::string& what) {
  std::istringstream in(text);
  std::string line;
  int line_no = 0;
  int n_points = -1;
  bool in_block = false;
  int count = 0;
  Shape68 shape{};
  auto fail = [&](const std::string& m) -> Error {
    return Error(what + ": line " + std::to_string(line_no) + ": " + m);
  };
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const auto first = line.find_first_not_of(" \t");
    if (first == std::string::npos) continue;
    line = line.substr(first);
    if (!in_block) {
      if (line.rfind("version", 0) == 0) continue;
      if (line.rfind("n_points", 0) == 0) {
        const auto colon = line.find(':');
        if (colon == std::string::npos) throw fail("malformed n_points line");
        try {
          n_points = std::stoi(line.substr(colon + 1));
        } catch (const std::exception&) {
          throw fail("malformed n_points line");
        }
        if (n_points != kNumLandmarks) throw fail("n_points is " + std::to_string(n_points) + ", expected 68");
        continue;
      }
      if (line[0] == '{') {
        in_block = true;
        continue;
      }
      throw fail("unexpected '" + line.substr(0, 40) + "' before '{'");
    }
    if (line[0] == '}') {
      if (count != kNumLandmarks) throw fail("block has " + std::to_string(count) + " points, expected 68");
      return shape;
    }
    if (count >= kNumLandmarks) throw fail("more than 68 points");
    std::istringstream xy(line);
    double x = 0, y = 0;
    if (!(xy >> x >> y) || !std::isfinite(x) || !std::isfinite(y)) throw fail("expected 'x y'");
    // Pixel coordinates; anything beyond this is no image (and would overflow the float).
    constexpr double kMaxCoordinate = 1e7;
    if (std::abs(x) > kMaxCoordinate || std::abs(y) > kMaxCoordinate) throw fail("coordinate out of range");
    // 300-W coordinates are 1-based (Matlab convention).
    shape[size_t(count++)] = Eigen::Vector2f(float(x - 1.0), float(y - 1.0));
  }
  throw fail(in_block ? "missing '}'" : "missing '{'");
}

Shape68 read_pts(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("annotation '" + path + "': cannot be opened");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (text.size() > (1 << 20)) throw Error("annotation '" + path + "': too large for a .pts file");
  return parse_pts(text, "annotation '" + path + "'");
}

float nme_outer_eye(const Shape68& predicted, const Shape68& truth) {
  std::array<bool, kNumLandmarks> all;
  all.fill(true);
  return nme_outer_eye(predicted, truth, all);
}

float nme_outer_eye(const Shape68& predicted, const Shape68& truth, const std::array<bool, kNumLandmarks>& use) {
  const float norm = outer_eye_distance(truth);
  if (!(norm > 0)) return std::numeric_limits<float>::infinity();
  double sum = 0;
  int used = 0;
  for (int i = 0; i < kNumLandmarks; ++i) {
    if (!use[size_t(i)]) continue;
    sum += (predicted[size_t(i)] - truth[size_t(i)]).norm();
    ++used;
  }
  if (used == 0) return std::numeric_limits<float>::infinity();
  return float(sum / used / norm);
}

nlohmann::json to_json(const LandmarkResult& r) {
  nlohmann::json j;
  j["status"] = status_name(r.status);
  j["reason"] = r.reason;
  j["source"] = source_name(r.source);
  j["faces_found"] = r.faces_found;
  if (!r.has_landmarks) return j;
  j["score"] = r.score;
  j["detector_score"] = r.detector_score;
  j["shape_residual"] = r.shape_residual;
  j["face_box"] = {r.face_box.x, r.face_box.y, r.face_box.width, r.face_box.height};
  nlohmann::json points = nlohmann::json::array(), conf = nlohmann::json::array(), vis = nlohmann::json::array();
  for (int i = 0; i < kNumLandmarks; ++i) {
    points.push_back({r.points[size_t(i)].x(), r.points[size_t(i)].y()});
    conf.push_back(r.confidence[size_t(i)]);
    vis.push_back(r.visible[size_t(i)]);
  }
  j["points"] = std::move(points);
  j["confidence"] = std::move(conf);
  j["visible"] = std::move(vis);
  j["silhouette"] = "0-16";
  return j;
}

namespace {

std::vector<double> ranks(const std::vector<double>& v) {
  std::vector<size_t> order(v.size());
  std::iota(order.begin(), order.end(), size_t(0));
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return v[a] < v[b]; });
  std::vector<double> r(v.size());
  for (size_t i = 0; i < order.size();) {
    size_t j = i;
    while (j + 1 < order.size() && v[order[j + 1]] == v[order[i]]) ++j;
    const double avg = 0.5 * double(i + j);
    for (size_t k = i; k <= j; ++k) r[order[k]] = avg;
    i = j + 1;
  }
  return r;
}

double pearson(const std::vector<double>& a, const std::vector<double>& b) {
  const size_t n = a.size();
  if (n < 2) return 0;
  const double ma = std::accumulate(a.begin(), a.end(), 0.0) / double(n);
  const double mb = std::accumulate(b.begin(), b.end(), 0.0) / double(n);
  double sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < n; ++i) {
    sab += (a[i] - ma) * (b[i] - mb);
    saa += (a[i] - ma) * (a[i] - ma);
    sbb += (b[i] - mb) * (b[i] - mb);
  }
  return saa > 0 && sbb > 0 ? sab / std::sqrt(saa * sbb) : 0;
}

double thread_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return double(ts.tv_sec) * 1e3 + double(ts.tv_nsec) * 1e-6;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t idx = std::min(v.size() - 1, size_t(std::ceil(q * double(v.size()))) - (q > 0 ? 1 : 0));
  return v[idx];
}

}  // namespace

std::vector<std::string> list_annotated_images(const std::string& folder) {
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) throw Error("evaluation folder '" + folder + "': not a folder");
  std::vector<std::string> images;
  for (fs::recursive_directory_iterator it(folder, fs::directory_options::skip_permission_denied, ec), end;
       !ec && it != end; it.increment(ec)) {
    if (!it->is_regular_file(ec)) continue;
    const std::string p = it->path().string();
    if (!capture::has_still_image_extension(p)) continue;
    if (fs::is_regular_file(annotation_path(p), ec)) images.push_back(p);
  }
  std::sort(images.begin(), images.end());
  if (images.empty()) throw Error("evaluation folder '" + folder + "': no image with a .pts annotation beside it");
  return images;
}

std::string annotation_path(const std::string& image_path) {
  return fs::path(image_path).replace_extension(".pts").string();
}

TrackingHint annotated_face_hint(const Shape68& truth) {
  TrackingHint hint;
  Eigen::Vector2f lo = truth[0], hi = truth[0];
  for (const auto& p : truth) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  hint.previous_box = Box{lo.x(), lo.y(), hi.x() - lo.x(), hi.y() - lo.y()};
  return hint;
}

EvalReport evaluate_annotated_folder(const std::string& folder, LandmarkDetector* detector) {
  EvalAccumulator accumulator(folder, "image");
  for (const std::string& path : list_annotated_images(folder)) {
    EvalImage e;
    e.path = path;
    const Shape68 truth = read_pts(annotation_path(path));
    Image image;
    try {
      image = load_image(path);
    } catch (const Error& err) {
      e.status = DetectionStatus::kInvalidInput;
      e.reason = err.what();
      accumulator.AddUnreadable(std::move(e));
      continue;
    }
    const auto t0 = std::chrono::steady_clock::now();
    // 300-W protocol: when the photo shows several people, score the face that was annotated.
    const LandmarkResult r = detector->Detect(image.view(), annotated_face_hint(truth));
    e.milliseconds = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    accumulator.Add(std::move(e), r, truth);
  }
  return accumulator.Finish();
}

EvalAccumulator::EvalAccumulator(std::string folder, std::string unit) {
  report_.folder = std::move(folder);
  report_.unit = std::move(unit);
}

void EvalAccumulator::AddUnreadable(EvalImage e) {
  e.has_landmarks = false;
  ++report_.images;
  ++report_.no_face;
  report_.per_image.push_back(std::move(e));
}

void EvalAccumulator::Add(EvalImage e, const LandmarkResult& r, const Shape68& truth,
                          const std::array<bool, kNumLandmarks>* use) {
  std::array<bool, kNumLandmarks> all;
  all.fill(true);
  const std::array<bool, kNumLandmarks>& mask = use ? *use : all;
  e.status = r.status;
  e.reason = r.reason;
  e.faces_found = r.faces_found;
  e.has_landmarks = r.has_landmarks;
  ++report_.images;
  if (!r.has_landmarks) {
    ++report_.no_face;
  } else {
    e.nme = nme_outer_eye(r.points, truth, mask);
    // A frame with no usable ground-truth point is not scored (NME is infinite); it counts as
    // a failure so it cannot hide.
    if (std::isfinite(e.nme)) nmes_.push_back(e.nme);
    if (!(e.nme <= 0.1f)) ++report_.failures;
    const float iod = outer_eye_distance(truth);
    double sum_conf = 0;
    for (int i = 0; i < kNumLandmarks; ++i) {
      sum_conf += r.confidence[size_t(i)];
      if (!mask[size_t(i)] || !(iod > 0)) continue;
      point_conf_.push_back(r.confidence[size_t(i)]);
      point_err_.push_back((r.points[size_t(i)] - truth[size_t(i)]).norm() / iod);
    }
    e.mean_confidence = float(sum_conf / kNumLandmarks);
  }
  report_.per_image.push_back(std::move(e));
}

EvalReport EvalAccumulator::Finish() const {
  EvalReport report = report_;
  if (!nmes_.empty()) {
    report.mean_nme = std::accumulate(nmes_.begin(), nmes_.end(), 0.0) / double(nmes_.size());
    report.median_nme = percentile(nmes_, 0.5);
  }
  if (!point_conf_.empty()) {
    // Split at the median confidence (ties broken by rank so both halves are non-empty).
    const std::vector<double> conf_rank = ranks(point_conf_);
    const double mid = 0.5 * double(point_conf_.size() - 1);
    double hi = 0, lo = 0;
    int nh = 0, nl = 0;
    for (size_t i = 0; i < point_conf_.size(); ++i) {
      if (conf_rank[i] > mid) {
        hi += point_err_[i];
        ++nh;
      } else {
        lo += point_err_[i];
        ++nl;
      }
    }
    report.point_error_high_confidence = nh ? hi / nh : 0;
    report.point_error_low_confidence = nl ? lo / nl : 0;
    report.confidence_error_correlation = pearson(conf_rank, ranks(point_err_));
  }
  return report;
}

nlohmann::json EvalReport::ToJson() const {
  nlohmann::json j;
  j["folder"] = folder;
  j["unit"] = unit;
  j["images"] = images;
  if (unit == "frame") j["frames"] = images;
  j["mean_nme"] = mean_nme;
  j["median_nme"] = median_nme;
  j["no_face"] = no_face;
  j["failures_over_0.1"] = failures;
  j["point_error_high_confidence"] = point_error_high_confidence;
  j["point_error_low_confidence"] = point_error_low_confidence;
  j["confidence_error_spearman"] = confidence_error_correlation;
  nlohmann::json list = nlohmann::json::array();
  for (const EvalImage& e : per_image) {
    nlohmann::json i;
    i["path"] = e.path;
    if (e.index >= 0) i["index"] = e.index;
    i["status"] = status_name(e.status);
    i["reason"] = e.reason;
    i["faces_found"] = e.faces_found;
    i["ms"] = e.milliseconds;
    if (e.has_landmarks) {
      i["nme"] = e.nme;
      i["mean_confidence"] = e.mean_confidence;
    } else {
      i["nme"] = nullptr;
    }
    list.push_back(std::move(i));
  }
  j["per_image"] = std::move(list);
  return j;
}

// ---------------------------------------------------------------- video

void measure_jitter(const std::vector<LandmarkResult>& seq, double* raw, double* compensated) {
  // Rigid points: eye corners and lids, nose bridge and base.
  static constexpr int kStable[] = {27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 39, 42, 45};
  constexpr int n = int(sizeof(kStable) / sizeof(kStable[0]));
  double sum_raw = 0, sum_comp = 0;
  int pairs = 0;
  for (size_t t = 1; t < seq.size(); ++t) {
    const LandmarkResult& a = seq[t - 1];
    const LandmarkResult& b = seq[t];
    if (!a.has_landmarks || !b.has_landmarks) continue;
    const float iod = outer_eye_distance(b.points);
    if (!(iod > 1.f)) continue;
    Eigen::Vector2f ca = Eigen::Vector2f::Zero(), cb = Eigen::Vector2f::Zero();
    for (int i : kStable) {
      ca += a.points[size_t(i)];
      cb += b.points[size_t(i)];
    }
    ca /= float(n);
    cb /= float(n);
    double saa = 0, sdot = 0, scross = 0, d_raw = 0;
    for (int i : kStable) {
      const Eigen::Vector2f pa = a.points[size_t(i)] - ca, pb = b.points[size_t(i)] - cb;
      saa += pa.squaredNorm();
      sdot += pa.dot(pb);
      scross += pa.x() * pb.y() - pa.y() * pb.x();
      d_raw += (b.points[size_t(i)] - a.points[size_t(i)]).norm();
    }
    const double c = saa > 0 ? sdot / saa : 1, s = saa > 0 ? scross / saa : 0;
    double d_comp = 0;
    for (int i : kStable) {
      const Eigen::Vector2f pa = a.points[size_t(i)] - ca, pb = b.points[size_t(i)] - cb;
      d_comp += std::hypot(c * pa.x() - s * pa.y() - pb.x(), s * pa.x() + c * pa.y() - pb.y());
    }
    sum_raw += d_raw / n / iod;
    sum_comp += d_comp / n / iod;
    ++pairs;
  }
  if (raw) *raw = pairs ? sum_raw / pairs : 0;
  if (compensated) *compensated = pairs ? sum_comp / pairs : 0;
}

VideoModeReport run_video_mode(const std::string& path, const TrackerOptions& options, const std::string& mode,
                               int max_frames, int* width, int* height, double* fps) {
  std::unique_ptr<FrameSource> source = open_frame_source(path);
  LandmarkTracker tracker(options);
  VideoModeReport rep;
  rep.mode = mode;
  std::vector<LandmarkResult> seq;
  std::vector<double> ms, cpu_ms;
  Frame frame;
  while ((max_frames <= 0 || rep.frames < max_frames) && source->Next(&frame)) {
    if (width) *width = frame.image.width;
    if (height) *height = frame.image.height;
    const double c0 = thread_cpu_ms();
    const auto t0 = std::chrono::steady_clock::now();
    LandmarkResult r = tracker.Track(frame.image.view(), frame.timestamp_s);
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    cpu_ms.push_back(thread_cpu_ms() - c0);
    ++rep.frames;
    if (r.has_landmarks) ++rep.frames_with_landmarks;
    rep.boxes.push_back(r.has_landmarks ? r.face_box : Box{});
    seq.push_back(std::move(r));
  }
  if (fps) *fps = source->fps();
  if (rep.frames == 0) throw Error("video '" + path + "': no frame could be decoded");
  measure_jitter(seq, &rep.jitter_raw, &rep.jitter_motion_compensated);
  rep.ms_mean = std::accumulate(ms.begin(), ms.end(), 0.0) / double(ms.size());
  rep.ms_p95 = percentile(ms, 0.95);
  rep.ms_max = *std::max_element(ms.begin(), ms.end());
  rep.cpu_ms_mean = std::accumulate(cpu_ms.begin(), cpu_ms.end(), 0.0) / double(cpu_ms.size());
  rep.cpu_ms_p95 = percentile(cpu_ms, 0.95);
  rep.summary = tracker.summary();
  return rep;
}

VideoReport video_report(const std::string& path, const TrackerOptions& base, int max_frames) {
  VideoReport report;
  report.path = path;
  TrackerOptions tracking = base;
  tracking.detect_every_frame = false;
  tracking.smoothing.enabled = false;
  report.modes.push_back(run_video_mode(path, tracking, "tracking", max_frames, &report.width, &report.height, &report.fps));
  TrackerOptions smoothed = tracking;
  smoothed.smoothing.enabled = true;
  report.modes.push_back(run_video_mode(path, smoothed, "tracking+smoothing", max_frames));
  TrackerOptions every = tracking;
  every.detect_every_frame = true;
  report.modes.push_back(run_video_mode(path, every, "detect_every_frame", max_frames));
  return report;
}

nlohmann::json VideoReport::ToJson(bool include_boxes) const {
  nlohmann::json j;
  j["video"] = path;
  j["width"] = width;
  j["height"] = height;
  j["fps"] = fps;
  nlohmann::json modes_json = nlohmann::json::array();
  for (const VideoModeReport& m : modes) {
    nlohmann::json mj;
    mj["mode"] = m.mode;
    mj["frames"] = m.frames;
    mj["frames_with_landmarks"] = m.frames_with_landmarks;
    mj["jitter_raw"] = m.jitter_raw;
    mj["jitter_motion_compensated"] = m.jitter_motion_compensated;
    mj["ms_mean"] = m.ms_mean;
    mj["ms_p95"] = m.ms_p95;
    mj["ms_max"] = m.ms_max;
    mj["cpu_ms_mean"] = m.cpu_ms_mean;
    mj["cpu_ms_p95"] = m.cpu_ms_p95;
    mj["full_searches"] = m.summary.full_searches;
    mj["band_searches"] = m.summary.band_searches;
    mj["band_misses"] = m.summary.band_misses;
    mj["tracked_frames"] = m.summary.tracked_frames;
    mj["losses"] = m.summary.losses;
    mj["summary"] = m.summary.BriefReport();
    if (include_boxes) {
      nlohmann::json boxes = nlohmann::json::array();
      for (const Box& b : m.boxes) boxes.push_back({b.x, b.y, b.width, b.height});
      mj["boxes"] = std::move(boxes);
    }
    modes_json.push_back(std::move(mj));
  }
  j["modes"] = std::move(modes_json);
  return j;
}

}  // namespace face_reenact::landmarks
