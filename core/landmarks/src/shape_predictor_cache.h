#pragma once
// A raw copy of dlib's 68-point shape predictor, kept in the user's cache folder so that a process
// starts in tens of milliseconds instead of the 0.7 s dlib's own reader takes (most of it decoding
// 16 million floats one portable byte at a time). The copy is made on this machine from the
// user's own model file on its first use: the model is never shipped (its training data's licence
// excludes commercial use). Nothing here includes dlib; dlib_backend.cc converts.
//
// The file: a header (magic, format version, the dlib version that wrote it, the model file's
// path, size and modification time, the counts, a checksum), then per cascade its features
// (anchor part and offset), its trees' splits and their leaves, little-endian (byte_io.h). The
// parser trusts nothing in it: counts are bounded and must add up to the file's size exactly
// before anything is allocated, the checksum must match, split indices must name a feature and
// anchors a part, every float must be finite. A file that fails any check is not used (and is
// written again from the model file).
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace face_reenact::landmarks::detail {

// Which model file a cache copy was made from, and by which dlib: a copy is used only where all of
// these still hold.
struct ShapeModelStamp {
  std::string source_path;    // canonical path of the .dat file
  uint64_t source_size = 0;   // bytes
  int64_t source_mtime_ns = 0;
  uint32_t dlib_version = 0;  // major * 10000 + minor * 100 + patch

  bool operator==(const ShapeModelStamp&) const = default;
};

// The shape predictor as plain arrays, as dlib keeps it (what dlib_backend.cc evaluates).
struct ShapePredictorTables {
  int num_parts = 0;
  std::vector<float> initial_shape;  // x, y per part, in the face box's unit square
  struct Cascade {
    // The pixels compared by this cascade's splits, as dlib keeps them: the part each is anchored
    // to, and x, y from that part of the initial shape (its unit square).
    std::vector<uint32_t> anchors;
    std::vector<float> deltas;
    int num_trees = 0;
    int depth = 0;                        // each tree: 2^depth leaves, 2^depth - 1 splits
    std::vector<uint32_t> split_features; // idx1, idx2 per split, tree after tree
    std::vector<float> split_thresholds;  // per split
    std::vector<float> leaf_values;       // 2 * num_parts per leaf, tree after tree

    int num_features() const { return static_cast<int>(anchors.size()); }
    int splits_per_tree() const { return (1 << depth) - 1; }
    int leaves_per_tree() const { return 1 << depth; }
  };
  std::vector<Cascade> cascades;
};

// Limits the parser enforces (dlib's 68-point model: 15 cascades of 500 trees of depth 4 over
// 500 features each; 65 MB).
inline constexpr int kMaxShapeParts = 1000;
inline constexpr int kMaxCascades = 100;
inline constexpr int kMaxFeatures = 100000;
inline constexpr int kMaxTrees = 100000;
inline constexpr int kMaxTreeDepth = 16;
inline constexpr uint64_t kMaxShapeCacheBytes = uint64_t(1) << 30;

// The cache file's bytes for `tables` made from the model `stamp` names. Throws face_reenact::Error
// for tables the parser would refuse (so a written file always reads back).
std::vector<uint8_t> serialize_shape_cache(const ShapeModelStamp& stamp, const ShapePredictorTables& tables);

// Parses a cache file's bytes into `stamp` and `tables`; false with `why` for anything that is not
// such a file, whole and consistent. `verify_checksum` false only for the fuzzer, whose mutations
// would otherwise nearly all stop at the checksum before the checks behind it.
bool parse_shape_cache(std::span<const uint8_t> bytes, ShapeModelStamp* stamp, ShapePredictorTables* tables,
                       std::string* why, bool verify_checksum = true);

// Where the copy is kept in `cache_dir`. One file for whichever model was read last (the stamp
// inside says which), so the folder never holds more than one copy (65 MB) however often the
// model moves.
std::string shape_cache_file(const std::string& cache_dir);

}  // namespace face_reenact::landmarks::detail
