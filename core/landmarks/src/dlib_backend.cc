#include "dlib_backend.h"

#include <dlib/image_processing.h>
#include <dlib/image_processing/frontal_face_detector.h>
#include <dlib/opencv/cv_image.h>
#include <dlib/revision.h>

#include <malloc.h>
#include <sys/stat.h>

#include <bit>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#include "face_reenact/common/byte_io.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "shape_predictor_cache.h"

namespace face_reenact::landmarks::detail {
namespace {

dlib::rectangle to_dlib(const Box& box) {
  const long left = std::lround(box.x);
  const long top = std::lround(box.y);
  const long right = std::lround(box.x + box.width) - 1;
  const long bottom = std::lround(box.y + box.height) - 1;
  return dlib::rectangle(left, top, std::max(left, right), std::max(top, bottom));
}

Box from_dlib(const dlib::rectangle& r) {
  return Box{float(r.left()), float(r.top()), float(r.width()), float(r.height())};
}

// dlib wraps a cv::Mat without copying; cv_image needs a non-const Mat header.
dlib::cv_image<unsigned char> wrap(const cv::Mat& gray) {
  return dlib::cv_image<unsigned char>(const_cast<cv::Mat&>(gray));  // NOLINT: read-only use
}

}  // namespace

struct ShapeModel::Predictor {
  dlib::shape_predictor sp;
};

ShapeModel::~ShapeModel() = default;

void ShapeModel::Predict(const cv::Mat& gray, const Box& box, Shape68* points) const {
  const dlib::full_object_detection det = predictor_->sp(wrap(gray), to_dlib(box));
  for (int i = 0; i < kNumLandmarks; ++i) {
    const dlib::point& p = det.part(static_cast<unsigned long>(i));
    (*points)[i] = Eigen::Vector2f(float(p.x()), float(p.y()));
  }
}

namespace {

constexpr uint32_t kDlibVersion = DLIB_MAJOR_VERSION * 10000 + DLIB_MINOR_VERSION * 100 + DLIB_PATCH_VERSION;

// dlib's serialisation of a shape_predictor, member by member (its `serialize` writes a version,
// then these four).
struct DlibPredictorParts {
  dlib::matrix<float, 0, 1> initial_shape;
  std::vector<std::vector<dlib::impl::regression_tree>> forests;
  std::vector<std::vector<unsigned long>> anchor_idx;
  std::vector<std::vector<dlib::vector<float, 2>>> deltas;
};

DlibPredictorParts read_dlib_parts(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("shape predictor '" + path + "': cannot be opened");
  int version = 0;
  dlib::deserialize(version, in);
  if (version != 1) throw dlib::serialization_error("unexpected version " + std::to_string(version));
  DlibPredictorParts p;
  dlib::deserialize(p.initial_shape, in);
  dlib::deserialize(p.forests, in);
  dlib::deserialize(p.anchor_idx, in);
  dlib::deserialize(p.deltas, in);
  return p;
}

// The parts as the cache's tables; false where they do not have the shape dlib's trainer gives
// them (full trees of one depth per cascade, one anchor and offset per feature).
bool to_tables(const DlibPredictorParts& p, ShapePredictorTables* t) {
  const long parts = p.initial_shape.size() / 2;
  if (p.initial_shape.size() % 2 != 0 || p.forests.size() != p.anchor_idx.size() || p.forests.size() != p.deltas.size())
    return false;
  t->num_parts = int(parts);
  t->initial_shape.assign(p.initial_shape.begin(), p.initial_shape.end());
  t->cascades.resize(p.forests.size());
  for (size_t i = 0; i < p.forests.size(); ++i) {
    auto& c = t->cascades[i];
    const auto& forest = p.forests[i];
    if (forest.empty() || p.anchor_idx[i].size() != p.deltas[i].size()) return false;
    const size_t leaves = forest[0].leaf_values.size();
    if (leaves < 2 || (leaves & (leaves - 1)) != 0) return false;
    c.depth = std::countr_zero(leaves);
    c.num_trees = int(forest.size());
    for (size_t j = 0; j < p.anchor_idx[i].size(); ++j) {
      c.anchors.push_back(uint32_t(p.anchor_idx[i][j]));
      c.deltas.push_back(p.deltas[i][j].x());
      c.deltas.push_back(p.deltas[i][j].y());
    }
    for (const auto& tree : forest) {
      if (tree.leaf_values.size() != leaves || tree.splits.size() != leaves - 1) return false;
      for (const auto& split : tree.splits) {
        c.split_features.push_back(uint32_t(split.idx1));
        c.split_features.push_back(uint32_t(split.idx2));
        c.split_thresholds.push_back(split.thresh);
      }
      for (const auto& leaf : tree.leaf_values) {
        if (leaf.size() != 2 * parts) return false;
        c.leaf_values.insert(c.leaf_values.end(), leaf.begin(), leaf.end());
      }
    }
  }
  return true;
}

bool stamp_of(const std::string& path, const std::string& canonical, ShapeModelStamp* stamp) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return false;
  stamp->source_path = canonical;
  stamp->source_size = uint64_t(st.st_size);
  stamp->source_mtime_ns = int64_t(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
  stamp->dlib_version = kDlibVersion;
  return true;
}

// dlib's public constructor takes each feature's position and finds its anchor (the nearest part)
// and offset again, so a predictor built from the tables is dlib's own only where that gives back
// the stored anchor and offset bit for bit. Checked before a copy is written and when one is read.
bool encoding_round_trips(const ShapePredictorTables& t, std::vector<std::vector<dlib::vector<float, 2>>>* positions) {
  dlib::matrix<float, 0, 1> initial_shape(long(t.initial_shape.size()));
  std::copy(t.initial_shape.begin(), t.initial_shape.end(), initial_shape.begin());
  positions->assign(t.cascades.size(), {});
  for (size_t i = 0; i < t.cascades.size(); ++i) {
    const auto& c = t.cascades[i];
    auto& pos = (*positions)[i];
    pos.resize(c.anchors.size());
    for (size_t j = 0; j < c.anchors.size(); ++j)
      pos[j] = dlib::impl::location(initial_shape, c.anchors[j]) + dlib::vector<float, 2>(c.deltas[2 * j], c.deltas[2 * j + 1]);
    std::vector<unsigned long> anchors;
    std::vector<dlib::vector<float, 2>> deltas;
    dlib::impl::create_shape_relative_encoding(initial_shape, pos, anchors, deltas);
    for (size_t j = 0; j < c.anchors.size(); ++j) {
      if (anchors[j] != c.anchors[j] || std::bit_cast<uint32_t>(deltas[j].x()) != std::bit_cast<uint32_t>(c.deltas[2 * j]) ||
          std::bit_cast<uint32_t>(deltas[j].y()) != std::bit_cast<uint32_t>(c.deltas[2 * j + 1]))
        return false;
    }
  }
  return true;
}

// dlib's predictor from the tables (whose encoding round-trips), through its public constructor.
// The tables are consumed cascade by cascade, so that the leaves (65 MB for dlib's model) are held
// at most twice at a time: as dlib's trees and as the predictor's copy of them.
void build_predictor(ShapePredictorTables t, const std::vector<std::vector<dlib::vector<float, 2>>>& positions,
                     dlib::shape_predictor* sp) {
  dlib::matrix<float, 0, 1> initial_shape(long(t.initial_shape.size()));
  std::copy(t.initial_shape.begin(), t.initial_shape.end(), initial_shape.begin());
  std::vector<std::vector<dlib::impl::regression_tree>> forests(t.cascades.size());
  const long leaf_size = 2L * t.num_parts;
  for (size_t i = 0; i < t.cascades.size(); ++i) {
    auto& c = t.cascades[i];
    auto& forest = forests[i];
    forest.resize(size_t(c.num_trees));
    const float* leaf = c.leaf_values.data();
    for (int k = 0; k < c.num_trees; ++k) {
      auto& tree = forest[size_t(k)];
      tree.splits.resize(size_t(c.splits_per_tree()));
      for (int s = 0; s < c.splits_per_tree(); ++s) {
        const size_t at = size_t(k) * size_t(c.splits_per_tree()) + size_t(s);
        tree.splits[size_t(s)] = {c.split_features[2 * at], c.split_features[2 * at + 1], c.split_thresholds[at]};
      }
      tree.leaf_values.resize(size_t(c.leaves_per_tree()));
      for (auto& value : tree.leaf_values) {
        value.set_size(leaf_size);
        std::copy(leaf, leaf + leaf_size, value.begin());
        leaf += leaf_size;
      }
    }
    std::vector<float>().swap(c.leaf_values);
  }
  *sp = dlib::shape_predictor(initial_shape, forests, positions);
}

// The cache copy's tables, or why it cannot be used ("" and true when it can).
bool read_cache_copy(const std::string& file, const ShapeModelStamp& stamp, ShapePredictorTables* tables,
                     std::string* why) {
  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) {
    *why = "no cache copy yet";
    return false;
  }
  std::vector<uint8_t> bytes;
  try {
    bytes = read_file_bytes(file, kMaxShapeCacheBytes + (1 << 20));
  } catch (const Error& e) {
    *why = e.what();
    return false;
  }
  ShapeModelStamp cached;
  std::string reason;
  if (!parse_shape_cache(bytes, &cached, tables, &reason)) {
    *why = "cache copy " + file + " refused (" + reason + ")";
    return false;
  }
  if (cached != stamp) {
    *why = "cache copy " + file + " is of another model file or dlib";
    return false;
  }
  return true;
}

// The predictor from the cache copy; false, with the reason in `note`, where there is none to use.
bool read_from_copy(const std::string& cache_file, const ShapeModelStamp& stamp, dlib::shape_predictor* sp,
                    std::vector<float>* initial_shape, std::string* note) {
  ShapePredictorTables tables;
  if (!read_cache_copy(cache_file, stamp, &tables, note)) return false;
  std::vector<std::vector<dlib::vector<float, 2>>> positions;
  if (!encoding_round_trips(tables, &positions)) {
    *note = "cache copy " + cache_file + " does not rebuild dlib's predictor exactly";
    return false;
  }
  *initial_shape = tables.initial_shape;
  build_predictor(std::move(tables), positions, sp);
  return true;
}

// The predictor from dlib's file, and its copy written to `cache_file` ("" for none) where the
// model can be kept as one; what went wrong with the copy is added to `note`. `initial_shape` is
// left empty where dlib's own reader had to read the model.
void read_from_model_file(const std::string& path, const std::string& cache_file, const ShapeModelStamp& stamp,
                          dlib::shape_predictor* sp, std::vector<float>* initial_shape, std::string* note) {
  ShapePredictorTables tables;
  std::vector<std::vector<dlib::vector<float, 2>>> positions;
  bool tabled;
  {
    const DlibPredictorParts parts = read_dlib_parts(path);
    tabled = to_tables(parts, &tables) && encoding_round_trips(tables, &positions);
  }
  if (!tabled) {
    *note = "this model cannot be kept as a copy (not the layout dlib's trainer writes)";
    dlib::deserialize(path) >> *sp;
    return;
  }
  if (!cache_file.empty()) {
    try {
      write_file_atomic(cache_file, serialize_shape_cache(stamp, tables));
    } catch (const Error& e) {
      *note += std::string("; not written: ") + e.what();
    }
  }
  *initial_shape = tables.initial_shape;
  build_predictor(std::move(tables), positions, sp);
}

}  // namespace

std::shared_ptr<const ShapeModel> read_shape_model(const std::string& path, const ShapeModelReadOptions& options) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw Error("shape predictor '" + path +
                "': file not found (install libdlib-data or set FACE_REENACT_SHAPE_PREDICTOR)");
  }
  const std::string canonical = std::filesystem::weakly_canonical(path, ec).string();
  std::shared_ptr<ShapeModel> model(new ShapeModel());
  model->predictor_ = std::make_unique<ShapeModel::Predictor>();
  model->path_ = path;
  ShapeModelStamp stamp;
  const bool stamped = stamp_of(path, canonical, &stamp);
  const std::string cache_file =
      options.cache_dir.empty() || !stamped ? "" : shape_cache_file(options.cache_dir);

  dlib::shape_predictor& sp = model->predictor_->sp;
  std::vector<float> initial_shape;
  try {
    if (options.dlib_reader_only) {
      dlib::deserialize(path) >> sp;
    } else if (cache_file.empty()) {
      model->cache_note_ = "no cache folder";
      read_from_model_file(path, "", stamp, &sp, &initial_shape, &model->cache_note_);
    } else if (read_from_copy(cache_file, stamp, &sp, &initial_shape, &model->cache_note_)) {
      model->from_cache_ = true;
    } else {
      read_from_model_file(path, cache_file, stamp, &sp, &initial_shape, &model->cache_note_);
    }
    if (initial_shape.empty()) {  // dlib's own reader: the mean shape is the file's first matrix
      std::ifstream in(path, std::ios::binary);
      int version = 0;
      dlib::matrix<float, 0, 1> mean;
      dlib::deserialize(version, in);
      dlib::deserialize(mean, in);
      initial_shape.assign(mean.begin(), mean.end());
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error("shape predictor '" + path + "': not a dlib shape predictor (" + std::string(e.what()).substr(0, 200) +
                ")");
  }
  if (sp.num_parts() != kNumLandmarks || initial_shape.size() != 2 * kNumLandmarks) {
    throw Error("shape predictor '" + path + "': has " + std::to_string(sp.num_parts()) +
                " points, expected 68 (iBUG layout)");
  }
  for (int i = 0; i < kNumLandmarks; ++i)
    model->mean_shape_[i] = Eigen::Vector2f(initial_shape[2 * i], initial_shape[2 * i + 1]);
#ifdef __GLIBC__
  // The tables and dlib's trees were freed as 120,000 small blocks that glibc keeps for the
  // process: returned, the process holds what dlib's own reader left (152 MB for `landmarks` on a
  // photo, against 226 MB without this).
  malloc_trim(0);
#endif
  return model;
}

std::shared_ptr<const ShapeModel> load_shape_model(const std::string& path) {
  static std::mutex mutex;
  static std::map<std::string, std::weak_ptr<const ShapeModel>> cache;
  std::error_code ec;
  const std::string key = std::filesystem::weakly_canonical(path, ec).string();
  std::lock_guard<std::mutex> lock(mutex);
  if (auto it = cache.find(key); it != cache.end()) {
    if (auto model = it->second.lock()) return model;
  }
  auto model = read_shape_model(path, {.cache_dir = user_cache_dir()});
  cache[key] = model;
  return model;
}

// Written at build time by fr_embed_face_detector (embedded_face_detector.cc in the build tree).
extern const unsigned char kFrontalFaceDetector[];
extern const std::size_t kFrontalFaceDetectorSize;

std::string EmbeddedFaceDetectorSerialization() {
  return std::string(reinterpret_cast<const char*>(kFrontalFaceDetector), kFrontalFaceDetectorSize);
}

std::string DecodedFaceDetectorSerialization() {
  std::ostringstream out;
  dlib::serialize(dlib::get_frontal_face_detector(), out);
  return out.str();
}

struct HogFaceDetector::Impl {
  // Read once from the serialisation embedded at build time (2 ms; dlib's own decoding of its
  // built-in model took about 350 ms of every process start), and copied for each detector.
  static const dlib::frontal_face_detector& prototype() {
    static const dlib::frontal_face_detector d = [] {
      dlib::frontal_face_detector detector;
      std::istringstream in(EmbeddedFaceDetectorSerialization());
      dlib::deserialize(detector, in);
      return detector;
    }();
    return d;
  }
  dlib::frontal_face_detector detector = prototype();
};

HogFaceDetector::HogFaceDetector() : impl_(std::make_unique<Impl>()) {}
HogFaceDetector::~HogFaceDetector() = default;

std::vector<FaceCandidate> HogFaceDetector::Detect(const cv::Mat& gray, double adjust_threshold) {
  std::vector<FaceCandidate> faces;
  // The HOG scanner needs at least its 80x80 window.
  if (gray.empty() || gray.cols < 80 || gray.rows < 80) return faces;
  std::vector<dlib::rect_detection> detections;
  impl_->detector(wrap(gray), detections, adjust_threshold);
  faces.reserve(detections.size());
  for (const auto& d : detections) {
    faces.push_back(FaceCandidate{from_dlib(d.rect), float(d.detection_confidence)});
  }
  return faces;
}

}  // namespace face_reenact::landmarks::detail
