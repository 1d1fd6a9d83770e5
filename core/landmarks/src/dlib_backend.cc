#include "dlib_backend.h"

#include <dlib/image_processing.h>
#include <dlib/image_processing/frontal_face_detector.h>
#include <dlib/opencv/cv_image.h>
#include <dlib/revision.h>

#include <malloc.h>
#include <pthread.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <future>
#include <map>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
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

// The predictor as the cache's tables (every model dlib's trainer writes), evaluated here, or
// dlib's own object (dlib's reader end to end, for the tests, or a layout the tables cannot hold).
struct ShapeModel::Predictor {
  struct Cascade {
    std::vector<unsigned long> anchors;           // dlib's types, for its feature extraction
    std::vector<dlib::vector<float, 2>> deltas;
    int num_trees = 0;
    int depth = 0;
    std::vector<uint32_t> split_features;         // idx1, idx2 per split, tree after tree
    std::vector<float> split_thresholds;
    std::vector<float> leaf_values;               // 2 * parts per leaf, tree after tree
  };
  bool tabled = false;
  dlib::matrix<float, 0, 1> initial_shape;
  std::vector<Cascade> cascades;
  dlib::shape_predictor sp;

  explicit Predictor(ShapePredictorTables t) : tabled(true) {
    initial_shape.set_size(long(t.initial_shape.size()));
    std::copy(t.initial_shape.begin(), t.initial_shape.end(), initial_shape.begin());
    cascades.resize(t.cascades.size());
    for (size_t i = 0; i < t.cascades.size(); ++i) {
      auto& from = t.cascades[i];
      auto& to = cascades[i];
      to.anchors.assign(from.anchors.begin(), from.anchors.end());
      to.deltas.resize(from.anchors.size());
      for (size_t j = 0; j < from.anchors.size(); ++j) to.deltas[j] = {from.deltas[2 * j], from.deltas[2 * j + 1]};
      to.num_trees = from.num_trees;
      to.depth = from.depth;
      to.split_features = std::move(from.split_features);
      to.split_thresholds = std::move(from.split_thresholds);
      to.leaf_values = std::move(from.leaf_values);
    }
  }
  Predictor() = default;

  // dlib's cascade (Kazemi and Sullivan's ensemble of regression trees) over the tables: dlib's
  // own feature extraction and transforms, and the same sums in the same order as its
  // shape_predictor::operator(), so the points are dlib's to the bit
  // (ShapeCacheTest.TheCopyIsDlibsPredictorAndABadCopyIsMadeAgain). What differs is memory:
  // dlib keeps each tree's leaves as separately allocated vectors and adds them through its
  // matrix expressions; here the leaves of a cascade are one array and the sum a plain loop.
  dlib::full_object_detection operator()(const dlib::cv_image<unsigned char>& img, const dlib::rectangle& rect) const {
    dlib::matrix<float, 0, 1> current = initial_shape;
    float* shape = &current(0);
    const size_t leaf_size = size_t(initial_shape.size());
    std::vector<float> features;
    std::vector<const float*> leaves;
    for (const Cascade& c : cascades) {
      dlib::impl::extract_feature_pixel_values(img, rect, current, initial_shape, c.anchors, c.deltas, features);
      // A cascade's trees all read the same features, so every tree's leaf is known before the
      // first is added: the leaves (4 MB of the 65 over a whole prediction, each where its tree
      // sends it) are fetched ahead of the sum, which otherwise waits on memory for most of its time.
      const unsigned splits = (1u << c.depth) - 1;
      leaves.resize(size_t(c.num_trees));
      for (int t = 0; t < c.num_trees; ++t) {
        const uint32_t* feature = &c.split_features[2 * size_t(t) * splits];
        const float* threshold = &c.split_thresholds[size_t(t) * splits];
        unsigned node = 0;
        while (node < splits)
          node = features[feature[2 * node]] - features[feature[2 * node + 1]] > threshold[node] ? 2 * node + 1
                                                                                                : 2 * node + 2;
        leaves[size_t(t)] = &c.leaf_values[(size_t(t) * (splits + 1) + (node - splits)) * leaf_size];
      }
      constexpr int kAhead = 6;
      for (int t = 0; t < c.num_trees; ++t) {
        if (t + kAhead < c.num_trees) {
          const char* next = reinterpret_cast<const char*>(leaves[size_t(t + kAhead)]);
          for (size_t b = 0; b < leaf_size * sizeof(float); b += 64) __builtin_prefetch(next + b);
        }
        const float* leaf = leaves[size_t(t)];
        for (size_t k = 0; k < leaf_size; ++k) shape[k] += leaf[k];
      }
    }
    const dlib::point_transform_affine to_image = dlib::impl::unnormalizing_tform(rect);
    std::vector<dlib::point> parts(leaf_size / 2);
    for (size_t i = 0; i < parts.size(); ++i) parts[i] = to_image(dlib::impl::location(current, i));
    return dlib::full_object_detection(rect, parts);
  }
  unsigned long num_parts() const { return tabled ? static_cast<unsigned long>(initial_shape.size() / 2) : sp.num_parts(); }
};

ShapeModel::~ShapeModel() = default;

void ShapeModel::Predict(const cv::Mat& gray, const Box& box, Shape68* points) const {
  const dlib::full_object_detection det =
      predictor_->tabled ? (*predictor_)(wrap(gray), to_dlib(box)) : predictor_->sp(wrap(gray), to_dlib(box));
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

// The cache copy's tables, or why it cannot be used.
bool read_cache_copy(const std::string& file, const ShapeModelStamp& stamp, ShapePredictorTables* tables,
                     std::string* why) {
  struct stat st {};
  if (::stat(file.c_str(), &st) != 0) {
    *why = "no cache copy yet";
    return false;
  }
  // Without $HOME the cache folder is under /tmp, where anyone may have left a file: only a copy
  // this user owns and that others cannot write is read. (Group write is allowed: Debian's user
  // private groups give users a umask of 002.)
  if (st.st_uid != ::geteuid() || (st.st_mode & S_IWOTH) != 0) {
    *why = "cache copy " + file + " is not this user's own (its owner or permissions), not read";
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

// The predictor from the cache copy; null, with the reason in `note`, where there is none to use.
std::unique_ptr<ShapeModel::Predictor> read_from_copy(const std::string& cache_file, const ShapeModelStamp& stamp,
                                                      std::string* note) {
  ShapePredictorTables tables;
  if (!read_cache_copy(cache_file, stamp, &tables, note)) return nullptr;
  return std::make_unique<ShapeModel::Predictor>(std::move(tables));
}

// The predictor from dlib's file, and its copy written to `cache_file` ("" for none) where the
// model can be kept as one; what went wrong with the copy is added to `note`.
std::unique_ptr<ShapeModel::Predictor> read_from_model_file(const std::string& path, const std::string& cache_file,
                                                            const ShapeModelStamp& stamp, std::string* note) {
  ShapePredictorTables tables;
  bool tabled;
  {
    const DlibPredictorParts parts = read_dlib_parts(path);
    tabled = to_tables(parts, &tables);
  }
  if (!tabled) {
    *note = "this model cannot be kept as a copy (not the layout dlib's trainer writes)";
    auto predictor = std::make_unique<ShapeModel::Predictor>();
    dlib::deserialize(path) >> predictor->sp;
    return predictor;
  }
  if (!cache_file.empty()) {
    try {
      write_file_atomic(cache_file, serialize_shape_cache(stamp, tables));
    } catch (const Error& e) {
      *note += std::string("; not written: ") + e.what();
    }
  }
  return std::make_unique<ShapeModel::Predictor>(std::move(tables));
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
  model->path_ = path;
  ShapeModelStamp stamp;
  const bool stamped = stamp_of(path, canonical, &stamp);
  const std::string cache_file =
      options.cache_dir.empty() || !stamped ? "" : shape_cache_file(options.cache_dir);

  std::vector<float> initial_shape;
  try {
    if (options.dlib_reader_only) {
      model->predictor_ = std::make_unique<ShapeModel::Predictor>();
      dlib::deserialize(path) >> model->predictor_->sp;
    } else if (cache_file.empty()) {
      model->cache_note_ = "no cache folder";
      model->predictor_ = read_from_model_file(path, "", stamp, &model->cache_note_);
    } else if ((model->predictor_ = read_from_copy(cache_file, stamp, &model->cache_note_))) {
      model->from_cache_ = true;
    } else {
      model->predictor_ = read_from_model_file(path, cache_file, stamp, &model->cache_note_);
    }
    if (model->predictor_->tabled) {
      initial_shape.assign(model->predictor_->initial_shape.begin(), model->predictor_->initial_shape.end());
    } else {  // dlib's own reader: the mean shape is the file's first matrix
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
  const unsigned long parts = model->predictor_->num_parts();
  if (parts != kNumLandmarks || initial_shape.size() != 2 * kNumLandmarks) {
    throw Error("shape predictor '" + path + "': has " + std::to_string(parts) + " points, expected 68 (iBUG layout)");
  }
  for (int i = 0; i < kNumLandmarks; ++i)
    model->mean_shape_[i] = Eigen::Vector2f(initial_shape[2 * i], initial_shape[2 * i + 1]);
#ifdef __GLIBC__
  // Reading dlib's file freed its trees as 120,000 small blocks, which glibc would otherwise keep
  // for the process (74 MB more held after the first read, measured on `landmarks`).
  malloc_trim(0);
#endif
  return model;
}

namespace {

using ModelRead = std::shared_future<std::shared_ptr<const ShapeModel>>;

// The process' models by canonical path: those in memory (weak: a model no detector holds is
// freed), and those a preload_shape_model() is reading, with its thread.
struct ShapeModelRegistry {
  std::mutex mutex;
  std::map<std::string, std::weak_ptr<const ShapeModel>> loaded;
  struct InFlight {
    ModelRead read;
    uint64_t id = 0;  // which read: only its own waiters take it off the list
  };
  std::map<std::string, InFlight> reading;
  uint64_t next_read_id = 0;
  // The reads' threads, joined once done (not holding the read's result: that would keep a model
  // its detectors let go of), and at exit.
  struct Reader {
    std::thread thread;
    std::shared_ptr<std::atomic<bool>> done;
  };
  std::vector<Reader> readers;

  static ShapeModelRegistry& Instance() {
    static ShapeModelRegistry registry;
    return registry;
  }
  // A read of `path` listed as in flight under `key` (the caller holds the mutex); the caller runs
  // the task, here or on a thread.
  std::packaged_task<std::shared_ptr<const ShapeModel>()> StartRead(const std::string& key, const std::string& path) {
    std::packaged_task<std::shared_ptr<const ShapeModel>()> task(
        [path] { return read_shape_model(path, {.cache_dir = user_cache_dir()}); });
    reading[key] = {task.get_future().share(), ++next_read_id};
    return task;
  }
  ~ShapeModelRegistry() {
    for (auto& reader : readers) reader.thread.join();
  }
};

std::string registry_key(const std::string& path) {
  std::error_code ec;
  return std::filesystem::weakly_canonical(path, ec).string();
}

}  // namespace

std::shared_ptr<const ShapeModel> load_shape_model(const std::string& path) {
  ShapeModelRegistry& r = ShapeModelRegistry::Instance();
  const std::string key = registry_key(path);
  std::unique_lock<std::mutex> lock(r.mutex);
  if (auto it = r.loaded.find(key); it != r.loaded.end()) {
    if (auto model = it->second.lock()) return model;
  }
  // A read in flight (a preload's, or another detector's on another thread) is waited for; else
  // this thread reads, listed as in flight so others wait for it. Without the lock either way:
  // another path's detector, or a preload, need not wait for this read.
  std::packaged_task<std::shared_ptr<const ShapeModel>()> own_read;
  if (!r.reading.count(key)) own_read = r.StartRead(key, path);
  const ShapeModelRegistry::InFlight in_flight = r.reading.at(key);
  lock.unlock();
  if (own_read.valid()) own_read();
  // Taken off the list once over (the first to get here): a preload then holds no reference, so
  // the model is freed like any other once its detectors are gone. A failed read throws to each
  // detector that waited for it, as it would have without the preload; the next one reads again.
  auto take_off_list = [&] {
    if (auto it = r.reading.find(key); it != r.reading.end() && it->second.id == in_flight.id) r.reading.erase(it);
  };
  std::shared_ptr<const ShapeModel> model;
  try {
    model = in_flight.read.get();
  } catch (...) {
    lock.lock();
    take_off_list();
    throw;
  }
  lock.lock();
  r.loaded[key] = model;
  take_off_list();
  return model;
}

std::shared_ptr<const ShapeModel> shape_model_in_memory(const std::string& path) {
  ShapeModelRegistry& r = ShapeModelRegistry::Instance();
  const std::string key = registry_key(path);
  std::lock_guard<std::mutex> lock(r.mutex);
  const auto it = r.loaded.find(key);
  return it == r.loaded.end() ? nullptr : it->second.lock();
}

void preload_shape_model(const std::string& path) {
  ShapeModelRegistry& r = ShapeModelRegistry::Instance();
  const std::string key = registry_key(path);
  std::lock_guard<std::mutex> lock(r.mutex);
  // Threads whose read is over (taken or not) are joined here, so a long-lived process (OBS,
  // its sources made again and again) keeps none.
  for (auto it = r.readers.begin(); it != r.readers.end();) {
    if (!it->done->load()) {
      ++it;
      continue;
    }
    it->thread.join();
    it = r.readers.erase(it);
  }
  if (r.reading.count(key)) return;
  if (auto it = r.loaded.find(key); it != r.loaded.end() && !it->second.expired()) return;
  std::packaged_task<std::shared_ptr<const ShapeModel>()> task = r.StartRead(key, path);
  auto done = std::make_shared<std::atomic<bool>>(false);
  std::thread thread([task = std::move(task), done]() mutable {
    pthread_setname_np(pthread_self(), "fr-shape-load");
    task();
    done->store(true);
  });
  r.readers.push_back({std::move(thread), std::move(done)});
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
