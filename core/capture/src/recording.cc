#include "face_reenact/capture/recording.h"

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "face_reenact/capture/json_checks.h"
#include "face_reenact/capture/media_file.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/common/error.h"
#include "face_reenact/model/face_model.h"

namespace face_reenact::capture {
namespace fs = std::filesystem;
namespace jc = json_checks;
using nlohmann::json;

namespace {

std::string frame_name(int index, const char* ext) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%06d.%s", index, ext);
  return buf;
}

json camera_to_json(const gpu::PinholeCamera& c) {
  return json{{"fx", c.fx}, {"fy", c.fy}, {"cx", c.cx}, {"cy", c.cy}, {"width", c.width}, {"height", c.height}};
}

gpu::PinholeCamera camera_from_json(const json& j, const std::string& where, const std::string& path) {
  jc::only_keys(j, {"fx", "fy", "cx", "cy", "width", "height"}, where, path);
  jc::require_keys(j, {"fx", "fy", "cx", "cy", "width", "height"}, where, path);
  gpu::PinholeCamera c;
  c.width = jc::integer(j["width"], where, jc::join(path, "width"), 1, 16384);
  c.height = jc::integer(j["height"], where, jc::join(path, "height"), 1, 16384);
  c.fx = static_cast<float>(jc::number(j["fx"], where, jc::join(path, "fx"), 1e-3, 1e6));
  c.fy = static_cast<float>(jc::number(j["fy"], where, jc::join(path, "fy"), 1e-3, 1e6));
  c.cx = static_cast<float>(jc::number(j["cx"], where, jc::join(path, "cx"), -c.width, 2.0 * c.width));
  c.cy = static_cast<float>(jc::number(j["cy"], where, jc::join(path, "cy"), -c.height, 2.0 * c.height));
  return c;
}

json vector_json(const Eigen::VectorXf& v) {
  json a = json::array();
  for (int i = 0; i < v.size(); ++i) a.push_back(v[i]);
  return a;
}

Eigen::VectorXf vector_from(const std::vector<double>& v) {
  Eigen::VectorXf out(static_cast<int>(v.size()));
  for (size_t i = 0; i < v.size(); ++i) out[static_cast<int>(i)] = static_cast<float>(v[i]);
  return out;
}

json ground_truth_json(const GroundTruth& t) {
  json g = json::object();
  if (t.params) {
    const auto& p = *t.params;
    json delta = json::object();
    const auto& names = arkit_blendshape_names();
    for (int i = 0; i < p.delta.size(); ++i) {
      if (i >= static_cast<int>(names.size())) throw Error("ground truth has more than 52 expression coefficients");
      delta[names[static_cast<size_t>(i)]] = p.delta[i];
    }
    json gamma = json::array();
    for (float x : p.gamma) gamma.push_back(x);
    g["params"] = json{{"alpha", vector_json(p.alpha)},
                       {"beta", vector_json(p.beta)},
                       {"delta", delta},
                       {"gamma", gamma},
                       {"euler", {p.euler.x(), p.euler.y(), p.euler.z()}},
                       {"translation", {p.translation.x(), p.translation.y(), p.translation.z()}}};
  }
  if (t.landmarks) {
    json l = json::array();
    for (const auto& o : *t.landmarks) l.push_back(json::array({o.pixel.x(), o.pixel.y(), o.visible}));
    g["landmarks"] = l;
  }
  return g;
}

GroundTruth ground_truth_from(const json& g, const std::string& where, const std::string& path) {
  jc::only_keys(g, {"params", "landmarks"}, where, path);
  GroundTruth t;
  if (g.contains("params")) {
    const std::string pp = jc::join(path, "params");
    const json& p = g["params"];
    jc::only_keys(p, {"alpha", "beta", "delta", "gamma", "euler", "translation"}, where, pp);
    jc::require_keys(p, {"alpha", "beta", "delta", "gamma", "euler", "translation"}, where, pp);
    gpu::FaceParameters f;
    f.alpha = vector_from(jc::numbers(p["alpha"], where, jc::join(pp, "alpha"), -1e3, 1e3, 0, 4096));
    f.beta = vector_from(jc::numbers(p["beta"], where, jc::join(pp, "beta"), -1e3, 1e3, 0, 4096));
    const json& d = p["delta"];
    const std::string dp = jc::join(pp, "delta");
    if (d.is_array()) {
      f.delta = vector_from(jc::numbers(d, where, dp, 0.0, 1.0, 0, 52));
    } else if (d.is_object()) {
      f.delta = Eigen::VectorXf::Zero(52);
      for (auto it = d.begin(); it != d.end(); ++it) {
        const int k = arkit_blendshape_index(it.key());
        if (k < 0) jc::fail(where, jc::join(dp, it.key()), "unknown ARKit blendshape name");
        f.delta[k] = static_cast<float>(jc::number(it.value(), where, jc::join(dp, it.key()), 0.0, 1.0));
      }
    } else {
      jc::fail(where, dp, "expected an object of ARKit name -> weight, or an array in ARKit order");
    }
    const auto gamma = jc::numbers(p["gamma"], where, jc::join(pp, "gamma"), -1e3, 1e3, 27, 27);
    for (int i = 0; i < 27; ++i) f.gamma[static_cast<size_t>(i)] = static_cast<float>(gamma[static_cast<size_t>(i)]);
    const auto e = jc::numbers(p["euler"], where, jc::join(pp, "euler"), -8.0, 8.0, 3, 3);
    const auto tr = jc::numbers(p["translation"], where, jc::join(pp, "translation"), -1e3, 1e3, 3, 3);
    f.euler = Eigen::Vector3f(float(e[0]), float(e[1]), float(e[2]));
    f.translation = Eigen::Vector3f(float(tr[0]), float(tr[1]), float(tr[2]));
    t.params = f;
  }
  if (g.contains("landmarks")) {
    const std::string lp = jc::join(path, "landmarks");
    const json& l = g["landmarks"];
    if (!l.is_array() || l.size() != kNumLandmarks)
      jc::fail(where, lp, "expected an array of 68 [u, v, visible] entries");
    std::array<LandmarkObservation, kNumLandmarks> out;
    for (size_t i = 0; i < kNumLandmarks; ++i) {
      const std::string ip = jc::index(lp, i);
      const json& e = l[i];
      if (!e.is_array() || e.size() != 3) jc::fail(where, ip, "expected [u, v, visible]");
      out[i].pixel = Eigen::Vector2f(static_cast<float>(jc::number(e[0], where, jc::index(ip, 0), -1e6, 1e6)),
                                     static_cast<float>(jc::number(e[1], where, jc::index(ip, 1), -1e6, 1e6)));
      out[i].visible = jc::boolean(e[2], where, jc::index(ip, 2));
    }
    t.landmarks = out;
  }
  return t;
}

std::string read_text_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open '" + path + "'");
  std::ostringstream s;
  s << in.rdbuf();
  if (in.bad()) throw Error("cannot read '" + path + "'");
  return s.str();
}

void write_text_file(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw Error("cannot create '" + path + "'");
  out << text;
  out.flush();
  if (!out) throw Error("cannot write '" + path + "' (disk full?)");
}

// A path inside the recording folder: relative, no "..".
std::string checked_member(const std::string& name, const std::string& where, const std::string& path) {
  if (name.empty() || name.front() == '/' || name.find("..") != std::string::npos || name.find('\\') != std::string::npos)
    jc::fail(where, path, "'" + name + "' is not a plain relative file name inside the recording");
  return name;
}

}  // namespace

bool RecordingInfo::IsValid(std::string* why) const {
  std::string w;
  if (!camera.IsValid(&w)) return fail_why(why, "camera: " + w);
  if (!(fps > 0 && fps <= 1000)) return fail_why(why, "fps must be in (0, 1000]");
  if (!(depth_scale > 0 && depth_scale <= 1)) return fail_why(why, "depth_scale must be in (0, 1] metres per unit");
  if (frame_count < -1) return fail_why(why, "frame_count must be >= -1");
  return true;
}

bool RecordingWriter::Options::IsValid(std::string* why) const {
  if (png_compression < 0 || png_compression > 9) return fail_why(why, "png_compression must be in 0..9");
  return true;
}

RecordingWriter::RecordingWriter(const std::string& dir, const RecordingInfo& info, const Options& options)
    : info_(info), options_(options) {
  std::string why;
  if (!info.IsValid(&why)) throw Error("recording '" + dir + "': invalid info: " + why);
  if (!options.IsValid(&why)) throw Error("recording writer: " + why);
  if (dir.empty()) throw Error("recording: empty output folder name");
  fs::path target = fs::path(dir).lexically_normal();
  if (target.filename().empty()) target = target.parent_path();
  dir_ = target.string();
  const fs::path parent = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(parent, ec)) throw Error("cannot write recording '" + dir_ + "': folder '" + parent.string() + "' does not exist");
  if (fs::exists(target, ec) && !options.overwrite)
    throw Error("cannot write recording '" + dir_ + "': it already exists (remove it or allow overwriting)");
  if (fs::exists(target, ec) && !fs::is_directory(target, ec))
    throw Error("cannot write recording '" + dir_ + "': a file of that name exists");
  if (::access(parent.c_str(), W_OK) != 0)
    throw Error("cannot write recording '" + dir_ + "': folder '" + parent.string() + "' is not writable");
  partial_dir_ = dir_ + ".partial-" + std::to_string(::getpid());
  fs::remove_all(partial_dir_, ec);
  if (!fs::create_directory(partial_dir_, ec) || !fs::create_directory(fs::path(partial_dir_) / "color", ec) ||
      (info_.has_depth && !fs::create_directory(fs::path(partial_dir_) / "depth", ec)))
    throw Error("cannot create folder '" + partial_dir_ + "': " + ec.message());
}

RecordingWriter::~RecordingWriter() {
  if (!finished_ && !partial_dir_.empty()) {
    std::error_code ec;
    fs::remove_all(partial_dir_, ec);  // best effort; the folder never looks complete anyway
  }
}

void RecordingWriter::write(const RgbdFrame& frame) {
  if (finished_) throw Error("recording '" + dir_ + "': write() after finish()");
  const int index = frames_written();
  const std::string what = "recording '" + dir_ + "' frame " + std::to_string(index);
  if (frame.index != index) throw Error(what + ": frame index " + std::to_string(frame.index) + " out of order");
  const cv::Size size(info_.camera.width, info_.camera.height);
  if (frame.color.type() != CV_8UC3 || frame.color.size() != size)
    throw Error(what + ": colour must be 8-bit BGR of " + std::to_string(size.width) + "x" + std::to_string(size.height));
  if (!std::isfinite(frame.timestamp_s)) throw Error(what + ": timestamp is not finite");
  std::string why;
  if (frame.ground_truth.params && !frame.ground_truth.params->IsValid(&why, 4096, 52, 4096))
    throw Error(what + ": invalid ground truth: " + why);
  const std::vector<int> png{cv::IMWRITE_PNG_COMPRESSION, options_.png_compression};
  const std::string color_name = "color/" + frame_name(index, "png");
  if (!cv::imwrite((fs::path(partial_dir_) / color_name).string(), frame.color, png))
    throw Error(what + ": cannot write " + color_name);
  json line{{"index", index}, {"timestamp", frame.timestamp_s}, {"color", color_name}};
  if (info_.has_depth) {
    if (frame.depth.type() != CV_32FC1 || frame.depth.size() != size)
      throw Error(what + ": depth must be 32-bit float metres of the colour image's size");
    cv::Mat units(size, CV_16UC1);
    const double inv = 1.0 / info_.depth_scale;
    for (int y = 0; y < size.height; ++y) {
      const float* src = frame.depth.ptr<float>(y);
      uint16_t* dst = units.ptr<uint16_t>(y);
      for (int x = 0; x < size.width; ++x) {
        const double u = std::isfinite(src[x]) && src[x] > 0 ? std::round(src[x] * inv) : 0.0;
        dst[x] = u >= 1 && u <= 65535 ? static_cast<uint16_t>(u) : 0;
      }
    }
    const std::string depth_name = "depth/" + frame_name(index, "png");
    if (!cv::imwrite((fs::path(partial_dir_) / depth_name).string(), units, png))
      throw Error(what + ": cannot write " + depth_name);
    line["depth"] = depth_name;
  }
  if (frame.ground_truth.params || frame.ground_truth.landmarks) line["ground_truth"] = ground_truth_json(frame.ground_truth);
  frame_lines_.push_back(line.dump());
}

std::string RecordingWriter::finish() {
  if (finished_) return dir_;
  std::string lines;
  for (const auto& l : frame_lines_) lines += l + "\n";
  write_text_file((fs::path(partial_dir_) / "frames.jsonl").string(), lines);
  json header{{"format", kRecordingFormatName},
              {"version", kRecordingFormatVersion},
              {"camera", camera_to_json(info_.camera)},
              {"depth_scale", info_.depth_scale},
              {"fps", info_.fps},
              {"frame_count", frames_written()},
              {"has_depth", info_.has_depth},
              {"source", info_.source},
              {"generator", info_.generator}};
  // recording.json last: a folder without it is not a recording.
  write_text_file((fs::path(partial_dir_) / "recording.json").string(), header.dump(2) + "\n");
  std::error_code ec;
  std::string old;
  if (fs::exists(dir_, ec)) {
    old = dir_ + ".old-" + std::to_string(::getpid());
    fs::rename(dir_, old, ec);
    if (ec) throw Error("cannot replace '" + dir_ + "': " + ec.message() + " (the new recording is in '" + partial_dir_ + "')");
  }
  fs::rename(partial_dir_, dir_, ec);
  if (ec) throw Error("cannot move '" + partial_dir_ + "' to '" + dir_ + "': " + ec.message());
  if (!old.empty()) fs::remove_all(old, ec);
  finished_ = true;
  return dir_;
}

RecordingReader::RecordingReader(const std::string& dir) : dir_(dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) throw Error("recording '" + dir + "': not a folder");
  const std::string header_path = (fs::path(dir) / "recording.json").string();
  if (!fs::exists(header_path, ec))
    throw Error("recording '" + dir + "': no recording.json (not a recording, or an incomplete one)");
  const json h = jc::parse(read_text_file(header_path), header_path);
  jc::only_keys(h, {"format", "version", "camera", "depth_scale", "fps", "frame_count", "has_depth", "source", "generator"},
                header_path, "");
  jc::require_keys(h, {"format", "version", "camera", "depth_scale", "fps", "frame_count", "has_depth"}, header_path, "");
  if (jc::string(h["format"], header_path, "format") != kRecordingFormatName)
    jc::fail(header_path, "format", std::string("expected \"") + kRecordingFormatName + "\"");
  const int version = jc::integer(h["version"], header_path, "version", 1, 1000000);
  if (version != kRecordingFormatVersion)
    jc::fail(header_path, "version", "unsupported version " + std::to_string(version) + " (this program reads " +
                                         std::to_string(kRecordingFormatVersion) + ")");
  info_.camera = camera_from_json(h["camera"], header_path, "camera");
  info_.depth_scale = jc::number(h["depth_scale"], header_path, "depth_scale", 1e-6, 1.0);
  info_.fps = jc::number(h["fps"], header_path, "fps", 1e-3, 1000.0);
  info_.frame_count = jc::integer(h["frame_count"], header_path, "frame_count", 0, 100000000);
  info_.has_depth = jc::boolean(h["has_depth"], header_path, "has_depth");
  if (h.contains("source")) info_.source = jc::string(h["source"], header_path, "source");
  if (h.contains("generator")) info_.generator = jc::string(h["generator"], header_path, "generator");

  const std::string frames_path = (fs::path(dir) / "frames.jsonl").string();
  if (!fs::exists(frames_path, ec)) throw Error("recording '" + dir + "': frames.jsonl is missing");
  std::istringstream lines(read_text_file(frames_path));
  std::string line;
  int line_no = 0;
  while (std::getline(lines, line)) {
    ++line_no;
    if (line.empty()) continue;
    const std::string where = frames_path + " line " + std::to_string(line_no);
    const json f = jc::parse(line, where);
    jc::only_keys(f, {"index", "timestamp", "color", "depth", "ground_truth"}, where, "");
    jc::require_keys(f, {"index", "timestamp", "color"}, where, "");
    const int index = jc::integer(f["index"], where, "index", 0, 100000000);
    if (index != static_cast<int>(frames_.size()))
      jc::fail(where, "index", "expected frame " + std::to_string(frames_.size()) + ", got " + std::to_string(index) +
                                   " (a missing or repeated frame)");
    FrameEntry e;
    e.timestamp_s = jc::number(f["timestamp"], where, "timestamp", 0.0, 1e9);
    if (!frames_.empty() && e.timestamp_s < frames_.back().timestamp_s)
      jc::fail(where, "timestamp", "timestamps must not decrease");
    e.color_file = checked_member(jc::string(f["color"], where, "color"), where, "color");
    if (info_.has_depth) {
      if (!f.contains("depth")) jc::fail(where, "depth", "missing (the recording has depth)");
      e.depth_file = checked_member(jc::string(f["depth"], where, "depth"), where, "depth");
    } else if (f.contains("depth")) {
      jc::fail(where, "depth", "present although recording.json says has_depth: false");
    }
    for (const auto* file : {&e.color_file, &e.depth_file})
      if (!file->empty() && !fs::is_regular_file(fs::path(dir) / *file, ec))
        throw Error(where + ": frame " + std::to_string(index) + ": file '" + (fs::path(dir) / *file).string() + "' is missing");
    if (f.contains("ground_truth")) e.ground_truth = ground_truth_from(f["ground_truth"], where, "ground_truth");
    frames_.push_back(std::move(e));
  }
  if (static_cast<int>(frames_.size()) != info_.frame_count)
    throw Error("recording '" + dir + "': recording.json says " + std::to_string(info_.frame_count) +
                " frames but frames.jsonl lists " + std::to_string(frames_.size()));
}

RgbdFrame RecordingReader::read(int index) const {
  if (index < 0 || index >= frame_count())
    throw Error("recording '" + dir_ + "': no frame " + std::to_string(index) + " (it has " + std::to_string(frame_count()) + ")");
  const FrameEntry& e = frames_[static_cast<size_t>(index)];
  const cv::Size size(info_.camera.width, info_.camera.height);
  RgbdFrame frame;
  frame.index = index;
  frame.timestamp_s = e.timestamp_s;
  frame.camera = info_.camera;
  frame.ground_truth = e.ground_truth;
  const std::string what = "recording '" + dir_ + "' frame " + std::to_string(index);
  const std::string color_path = (fs::path(dir_) / e.color_file).string();
  cv::Mat color = cv::imread(color_path, cv::IMREAD_UNCHANGED);
  if (color.empty()) throw Error(what + ": cannot decode colour image '" + color_path + "' (truncated or not a PNG?)");
  if (color.depth() != CV_8U)
    throw Error(what + ": colour image '" + color_path + "' must have 8 bits per channel");
  if (!to_bgr8(&color)) throw Error(what + ": colour image '" + color_path + "' has an unsupported channel count");
  if (color.size() != size)
    throw Error(what + ": colour image '" + color_path + "' is " + std::to_string(color.cols) + "x" + std::to_string(color.rows) +
                ", recording.json says " + std::to_string(size.width) + "x" + std::to_string(size.height));
  frame.color = color;
  if (info_.has_depth) {
    const std::string depth_path = (fs::path(dir_) / e.depth_file).string();
    cv::Mat units = cv::imread(depth_path, cv::IMREAD_UNCHANGED);
    if (units.empty()) throw Error(what + ": cannot decode depth image '" + depth_path + "' (truncated or not a PNG?)");
    if (units.type() != CV_16UC1)
      throw Error(what + ": depth image '" + depth_path + "' must be a 16-bit single-channel PNG (got " +
                  std::to_string(8 * static_cast<int>(units.elemSize1())) + "-bit, " + std::to_string(units.channels()) +
                  " channel(s))");
    if (units.size() != size)
      throw Error(what + ": depth image '" + depth_path + "' is " + std::to_string(units.cols) + "x" +
                  std::to_string(units.rows) + ", recording.json says " + std::to_string(size.width) + "x" +
                  std::to_string(size.height));
    units.convertTo(frame.depth, CV_32FC1, info_.depth_scale);
  }
  return frame;
}

bool RecordingReader::read_next(RgbdFrame* frame) {
  if (next_ >= frame_count()) return false;
  *frame = read(next_++);
  return true;
}

gpu::PinholeCamera camera_from_fov(int width, int height, double horizontal_fov_deg) {
  if (width <= 0 || height <= 0 || !(horizontal_fov_deg > 1 && horizontal_fov_deg < 179))
    throw Error("camera_from_fov: invalid size or field of view");
  gpu::PinholeCamera c;
  c.width = width;
  c.height = height;
  c.fx = c.fy = static_cast<float>(0.5 * width / std::tan(0.5 * horizontal_fov_deg * M_PI / 180.0));
  c.cx = 0.5f * static_cast<float>(width) - 0.5f;
  c.cy = 0.5f * static_cast<float>(height) - 0.5f;
  return c;
}

bool VideoReader::Options::IsValid(std::string* why) const {
  if (!(horizontal_fov_deg > 1 && horizontal_fov_deg < 179)) return fail_why(why, "horizontal_fov_deg must be in (1, 179)");
  if (intrinsics && !(intrinsics->fx > 0 && intrinsics->fy > 0 && std::isfinite(intrinsics->fx) && std::isfinite(intrinsics->fy) &&
                      std::isfinite(intrinsics->cx) && std::isfinite(intrinsics->cy)))
    return fail_why(why, "intrinsics need fx, fy > 0 and finite cx, cy");
  return true;
}

HeldFrameSource::HeldFrameSource(RgbdFrame frame, RecordingInfo info, int frames, double fps)
    : frame_(std::move(frame)), info_(std::move(info)) {
  if (frames < 1) throw Error("a held frame needs at least one frame to show");
  if (!(fps > 0 && fps <= 1000)) throw Error("a held frame needs a frame rate in (0, 1000]");
  if (frame_.color.empty()) throw Error("a held frame needs a colour image");
  info_.fps = fps;
  info_.frame_count = frames;
}

bool HeldFrameSource::read_next(RgbdFrame* frame) {
  if (next_ >= info_.frame_count) return false;
  *frame = frame_;
  frame->color = frame_.color.clone();
  if (!frame_.depth.empty()) frame->depth = frame_.depth.clone();
  frame->index = next_;
  frame->timestamp_s = next_ / info_.fps;
  ++next_;
  return true;
}

VideoReader::VideoReader(const std::string& path, const Options& options) : path_(path) {
  std::string why;
  if (!options.IsValid(&why)) throw Error("video '" + path + "': " + why);
  video_ = std::make_unique<VideoFileReader>(path);
  info_.camera = camera_from_fov(video_->width(), video_->height(), options.horizontal_fov_deg);
  if (options.intrinsics) {
    info_.camera.fx = static_cast<float>(options.intrinsics->fx);
    info_.camera.fy = static_cast<float>(options.intrinsics->fy);
    info_.camera.cx = static_cast<float>(options.intrinsics->cx);
    info_.camera.cy = static_cast<float>(options.intrinsics->cy);
  }
  info_.fps = video_->fps();
  // The container's estimate (-1: unknown); below 1e9, so it fits.
  info_.frame_count = static_cast<int>(video_->frame_count());
  info_.has_depth = false;
  info_.source = path;
  info_.generator = "video file";
}

VideoReader::~VideoReader() = default;

bool VideoReader::read_next(RgbdFrame* frame) {
  const int index = static_cast<int>(video_->frames_read());
  cv::Mat image;
  if (!video_->read(&image)) return false;
  // The camera (intrinsics, and every consumer's buffers) is sized by the first frame.
  if (image.cols != info_.camera.width || image.rows != info_.camera.height)
    throw Error("video '" + path_ + "': frame " + std::to_string(index) + " changes size");
  *frame = RgbdFrame();
  frame->index = index;
  frame->timestamp_s = index / info_.fps;  // container timestamps are unreliable across backends
  frame->color = image;
  frame->camera = info_.camera;
  return true;
}

std::unique_ptr<FrameSource> open_frame_source(const std::string& path, const VideoReader::Options& video_options) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) return std::make_unique<RecordingReader>(path);
  if (!fs::exists(path, ec)) throw Error("'" + path + "': no such file or folder");
  if (lower_case_extension(path) == ".oni")
    throw Error("'" + path + "': an OpenNI recording: the commands and the live inputs read it as openni:" + path +
                " (through OpenNI2)");
  return std::make_unique<VideoReader>(path, video_options);
}

std::string ground_truth_to_json(const GroundTruth& truth) { return ground_truth_json(truth).dump(); }

GroundTruth ground_truth_from_json(const std::string& json_text, const std::string& what) {
  return ground_truth_from(jc::parse(json_text, what), what, "");
}

}  // namespace face_reenact::capture
