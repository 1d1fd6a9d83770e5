#include "shape_predictor_cache.h"

#include <cmath>
#include <cstring>

#include "face_reenact/common/byte_io.h"
#include "face_reenact/common/checksum.h"
#include "face_reenact/common/error.h"

namespace face_reenact::landmarks::detail {
namespace {

constexpr char kMagic[8] = {'F', 'R', 'S', 'H', 'A', 'P', 'E', '\0'};
constexpr uint32_t kFormatVersion = 1;
constexpr size_t kMaxPathBytes = 4096;

bool all_finite(const std::vector<float>& values) {
  for (float v : values)
    if (!std::isfinite(v)) return false;
  return true;
}

struct CascadeShape {
  uint32_t features = 0, trees = 0, depth = 0;
};

// Bytes of one cascade's arrays; the counts are bounded first, so this cannot overflow.
uint64_t cascade_bytes(const CascadeShape& c, uint32_t num_parts) {
  const uint64_t splits = uint64_t(c.trees) * ((uint64_t(1) << c.depth) - 1);
  const uint64_t leaves = uint64_t(c.trees) << c.depth;
  return uint64_t(c.features) * 3 * 4 + splits * 3 * 4 + leaves * 2 * num_parts * 4;
}

// Why `tables` cannot be a cache file ("" when it can): the limits the parser enforces.
std::string check_tables(const ShapePredictorTables& t) {
  if (t.num_parts < 1 || t.num_parts > kMaxShapeParts) return "part count " + std::to_string(t.num_parts);
  if (t.initial_shape.size() != size_t(2 * t.num_parts)) return "initial shape size";
  if (!all_finite(t.initial_shape)) return "initial shape not finite";
  if (t.cascades.empty() || t.cascades.size() > size_t(kMaxCascades)) return "cascade count";
  uint64_t total = 0;
  for (const auto& c : t.cascades) {
    if (c.num_features() < 1 || c.num_features() > kMaxFeatures || c.deltas.size() != 2 * c.anchors.size())
      return "feature count";
    for (uint32_t a : c.anchors)
      if (a >= uint32_t(t.num_parts)) return "feature anchored to no part";
    if (c.num_trees < 1 || c.num_trees > kMaxTrees || c.depth < 1 || c.depth > kMaxTreeDepth) return "tree shape";
    const size_t splits = size_t(c.num_trees) * size_t(c.splits_per_tree());
    if (c.split_features.size() != 2 * splits || c.split_thresholds.size() != splits) return "split count";
    if (c.leaf_values.size() != size_t(c.num_trees) * size_t(c.leaves_per_tree()) * size_t(2 * t.num_parts))
      return "leaf count";
    for (uint32_t f : c.split_features)
      if (f >= uint32_t(c.num_features())) return "split feature out of range";
    if (!all_finite(c.deltas) || !all_finite(c.split_thresholds) || !all_finite(c.leaf_values))
      return "values not finite";
    total += cascade_bytes({uint32_t(c.num_features()), uint32_t(c.num_trees), uint32_t(c.depth)},
                           uint32_t(t.num_parts));
  }
  if (total > kMaxShapeCacheBytes) return "larger than " + std::to_string(kMaxShapeCacheBytes) + " bytes";
  return "";
}

}  // namespace

std::vector<uint8_t> serialize_shape_cache(const ShapeModelStamp& stamp, const ShapePredictorTables& tables) {
  if (const std::string why = check_tables(tables); !why.empty())
    throw Error("shape predictor cache: the model does not fit the cache format (" + why + ")");
  if (stamp.source_path.size() > kMaxPathBytes) throw Error("shape predictor cache: model path too long");
  ByteWriter w;
  w.bytes(std::span(reinterpret_cast<const uint8_t*>(kMagic), sizeof kMagic));
  w.u32(kFormatVersion);
  w.u32(stamp.dlib_version);
  w.u64(stamp.source_size);
  w.u64(uint64_t(stamp.source_mtime_ns));
  w.str(stamp.source_path);
  w.u32(uint32_t(tables.num_parts));
  w.u32(uint32_t(tables.cascades.size()));
  for (const auto& c : tables.cascades) {
    w.u32(uint32_t(c.num_features()));
    w.u32(uint32_t(c.num_trees));
    w.u32(uint32_t(c.depth));
  }
  const size_t checksum_at = w.size();
  w.u32(0);
  const size_t tables_at = w.size();
  w.f32_array(tables.initial_shape);
  for (const auto& c : tables.cascades) {
    w.u32_array(c.anchors);
    w.f32_array(c.deltas);
    w.u32_array(c.split_features);
    w.f32_array(c.split_thresholds);
    w.f32_array(c.leaf_values);
  }
  w.patch_u32(checksum_at, crc32(std::span(w.data()).subspan(tables_at)));
  return w.take();
}

bool parse_shape_cache(std::span<const uint8_t> bytes, ShapeModelStamp* stamp, ShapePredictorTables* tables,
                       std::string* why, bool verify_checksum) {
  auto fail = [why](const std::string& reason) {
    if (why) *why = reason;
    return false;
  };
  if (bytes.size() < sizeof kMagic || std::memcmp(bytes.data(), kMagic, sizeof kMagic) != 0)
    return fail("not a shape predictor cache");
  try {
    ByteReader r(bytes.subspan(sizeof kMagic), "shape predictor cache");
    if (const uint32_t version = r.u32(); version != kFormatVersion)
      return fail("cache format " + std::to_string(version));
    ShapeModelStamp s;
    s.dlib_version = r.u32();
    s.source_size = r.u64();
    s.source_mtime_ns = int64_t(r.u64());
    s.source_path = r.str(kMaxPathBytes);
    const uint32_t num_parts = r.u32();
    const uint32_t num_cascades = r.u32();
    if (num_parts < 1 || num_parts > uint32_t(kMaxShapeParts)) return fail("part count " + std::to_string(num_parts));
    if (num_cascades < 1 || num_cascades > uint32_t(kMaxCascades))
      return fail("cascade count " + std::to_string(num_cascades));
    std::vector<CascadeShape> shapes(num_cascades);
    uint64_t expected = uint64_t(num_parts) * 2 * 4;
    for (auto& c : shapes) {
      c.features = r.u32();
      c.trees = r.u32();
      c.depth = r.u32();
      if (c.features < 1 || c.features > uint32_t(kMaxFeatures) || c.trees < 1 || c.trees > uint32_t(kMaxTrees) ||
          c.depth < 1 || c.depth > uint32_t(kMaxTreeDepth))
        return fail("cascade of " + std::to_string(c.features) + " features, " + std::to_string(c.trees) +
                    " trees of depth " + std::to_string(c.depth));
      expected += cascade_bytes(c, num_parts);
      if (expected > kMaxShapeCacheBytes)
        return fail("declares more than " + std::to_string(kMaxShapeCacheBytes) + " bytes");
    }
    const uint32_t sum = r.u32();
    // Nothing is allocated before the counts add up to the bytes there are.
    if (expected != r.remaining())
      return fail("declares " + std::to_string(expected) + " bytes of tables, holds " + std::to_string(r.remaining()));
    if (verify_checksum && crc32(bytes.last(r.remaining())) != sum) return fail("checksum mismatch (damaged)");

    ShapePredictorTables t;
    t.num_parts = int(num_parts);
    r.f32_array(2 * size_t(num_parts), t.initial_shape);
    t.cascades.resize(num_cascades);
    for (size_t i = 0; i < num_cascades; ++i) {
      auto& c = t.cascades[i];
      c.num_trees = int(shapes[i].trees);
      c.depth = int(shapes[i].depth);
      const size_t splits = size_t(c.num_trees) * size_t(c.splits_per_tree());
      r.u32_array(shapes[i].features, c.anchors);
      r.f32_array(2 * size_t(shapes[i].features), c.deltas);
      r.u32_array(2 * splits, c.split_features);
      r.f32_array(splits, c.split_thresholds);
      r.f32_array(size_t(c.num_trees) * size_t(c.leaves_per_tree()) * 2 * num_parts, c.leaf_values);
    }
    if (const std::string reason = check_tables(t); !reason.empty()) return fail(reason);
    *stamp = std::move(s);
    *tables = std::move(t);
    return true;
  } catch (const Error& e) {
    return fail(e.what());
  }
}

std::string shape_cache_file(const std::string& cache_dir) { return cache_dir + "/dlib-shape-predictor.bin"; }

}  // namespace face_reenact::landmarks::detail
