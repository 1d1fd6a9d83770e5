// The raw copy of dlib's shape predictor in the user's cache folder (shape_predictor_cache.h):
// the format refuses every damaged or forged file with a reason, and a predictor read from a copy
// is dlib's own (the same points, bit for bit, on photos and on noise, in any box).
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>

#include "dlib_backend.h"
#include "face_reenact/common/error.h"
#include "landmark_internal.h"
#include "shape_predictor_cache.h"
#include "support/temp_dir.h"
#include "test_data.h"

namespace face_reenact::landmarks {
namespace {

using detail::parse_shape_cache;
using detail::serialize_shape_cache;
using detail::ShapeModelStamp;
using detail::ShapePredictorTables;

// A small predictor of 3 parts, 2 cascades with trees of depth 2, values that are not all alike.
ShapePredictorTables small_tables() {
  ShapePredictorTables t;
  t.num_parts = 3;
  t.initial_shape = {0.2f, 0.3f, 0.8f, 0.3f, 0.5f, 0.7f};
  for (int c = 0; c < 2; ++c) {
    ShapePredictorTables::Cascade k;
    k.num_trees = 3;
    k.depth = 2;
    for (uint32_t f = 0; f < 5; ++f) {
      k.anchors.push_back(f % 3);
      k.deltas.push_back(0.01f * float(f + c));
      k.deltas.push_back(-0.02f * float(f));
    }
    for (int s = 0; s < k.num_trees * k.splits_per_tree(); ++s) {
      k.split_features.push_back(uint32_t(s % 5));
      k.split_features.push_back(uint32_t((s + 2) % 5));
      k.split_thresholds.push_back(float(s) - 4.5f);
    }
    for (int v = 0; v < k.num_trees * k.leaves_per_tree() * 2 * t.num_parts; ++v)
      k.leaf_values.push_back(0.001f * float(v - 20 + c));
    t.cascades.push_back(std::move(k));
  }
  return t;
}

ShapeModelStamp small_stamp() {
  return {"/usr/share/dlib/shape_predictor_68_face_landmarks.dat", 99693937, 1545350400000000000, 192400};
}

// The fuzzer's seed is this small predictor as the writer writes it today: a change of the format
// must come with a new seed, or the fuzzer would start from a file the parser refuses.
TEST(ShapeCacheFormatTest, TheFuzzersSeedIsTheWritersOutput) {
  const std::vector<uint8_t> written = serialize_shape_cache(small_stamp(), small_tables());
  if (std::getenv("FR_WRITE_SHAPE_CACHE_SEED"))
    std::ofstream(FR_SHAPE_CACHE_SEED, std::ios::binary)
        .write(reinterpret_cast<const char*>(written.data()), std::streamsize(written.size()));
  std::ifstream in(FR_SHAPE_CACHE_SEED, std::ios::binary);
  const std::vector<uint8_t> seed((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_TRUE(seed == written) << FR_SHAPE_CACHE_SEED
                               << " is not the writer's output: run this test with FR_WRITE_SHAPE_CACHE_SEED=1";
}

TEST(ShapeCacheFormatTest, RoundTripsAndRefusesEveryDamageWithAReason) {
  const ShapePredictorTables t = small_tables();
  const std::vector<uint8_t> bytes = serialize_shape_cache(small_stamp(), t);
  ShapeModelStamp stamp;
  ShapePredictorTables back;
  std::string why;
  ASSERT_TRUE(parse_shape_cache(bytes, &stamp, &back, &why)) << why;
  EXPECT_EQ(stamp, small_stamp());
  EXPECT_EQ(back.initial_shape, t.initial_shape);
  ASSERT_EQ(back.cascades.size(), 2u);
  EXPECT_EQ(back.cascades[1].anchors, t.cascades[1].anchors);
  EXPECT_EQ(back.cascades[1].deltas, t.cascades[1].deltas);
  EXPECT_EQ(back.cascades[1].split_features, t.cascades[1].split_features);
  EXPECT_EQ(back.cascades[1].split_thresholds, t.cascades[1].split_thresholds);
  EXPECT_EQ(back.cascades[1].leaf_values, t.cascades[1].leaf_values);

  auto refused = [&](std::vector<uint8_t> b, const std::string& reason) {
    std::string w;
    ShapeModelStamp s;
    ShapePredictorTables x;
    EXPECT_FALSE(parse_shape_cache(b, &s, &x, &w)) << "accepted: " << reason;
    EXPECT_NE(w.find(reason), std::string::npos) << w;
  };
  refused({}, "not a shape predictor cache");
  refused(std::vector<uint8_t>(bytes.begin(), bytes.begin() + 30), "truncated");
  refused(std::vector<uint8_t>(bytes.begin(), bytes.end() - 1), "declares");
  std::vector<uint8_t> longer = bytes;
  longer.push_back(0);
  refused(longer, "declares");
  // Any flipped bit in the tables, even one that leaves a finite float.
  std::vector<uint8_t> flipped = bytes;
  flipped[flipped.size() - 3] ^= 0x01;
  refused(flipped, "checksum");
  std::vector<uint8_t> version = bytes;
  version[8] = 9;
  refused(version, "cache format");

  // Tables the writer refuses, so that it never writes what the parser would refuse.
  auto unwritable = [&](auto change, const std::string& reason) {
    ShapePredictorTables bad = small_tables();
    change(bad);
    try {
      serialize_shape_cache(small_stamp(), bad);
      ADD_FAILURE() << "written: " << reason;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(reason), std::string::npos) << e.what();
    }
  };
  unwritable([](ShapePredictorTables& b) { b.cascades[0].split_features[3] = 5; }, "split feature out of range");
  unwritable([](ShapePredictorTables& b) { b.cascades[1].anchors[0] = 3; }, "anchored to no part");
  unwritable([](ShapePredictorTables& b) { b.cascades[0].leaf_values[7] = std::nanf(""); }, "not finite");
  unwritable([](ShapePredictorTables& b) { b.cascades[0].leaf_values.pop_back(); }, "leaf count");
  unwritable([](ShapePredictorTables& b) { b.initial_shape.push_back(0); }, "initial shape");
}

// A forged header that declares huge counts is refused on the counts, before anything of that
// size is allocated (the fuzzer, shape_cache_fuzzer.cc, runs this under ASan's allocation limit).
TEST(ShapeCacheFormatTest, ForgedCountsAreRefusedBeforeAllocating) {
  std::vector<uint8_t> bytes = serialize_shape_cache(small_stamp(), small_tables());
  // The first cascade's tree count follows the header's path, part and cascade counts.
  const size_t path_end = 8 + 4 + 4 + 8 + 8 + 4 + small_stamp().source_path.size();
  const size_t trees_at = path_end + 4 + 4 + 4;
  uint32_t trees = 100000;
  std::memcpy(bytes.data() + trees_at, &trees, 4);
  ShapeModelStamp s;
  ShapePredictorTables t;
  std::string why;
  EXPECT_FALSE(parse_shape_cache(bytes, &s, &t, &why));
  EXPECT_NE(why.find("declares"), std::string::npos) << why;
  uint32_t depth = 40;
  std::memcpy(bytes.data() + trees_at + 4, &depth, 4);
  EXPECT_FALSE(parse_shape_cache(bytes, &s, &t, &why));
  EXPECT_NE(why.find("depth 40"), std::string::npos) << why;
}

// Points of both predictors on `gray`, in several boxes (a face's, shifted, tiny, off the image).
void expect_same_points(const detail::ShapeModel& a, const detail::ShapeModel& b, const cv::Mat& gray) {
  const std::vector<Box> boxes = {{0.3f * float(gray.cols), 0.25f * float(gray.rows), 0.4f * float(gray.cols), 0.45f * float(gray.rows)},
                                  {10, 5, 90, 90},
                                  {2, 3, 7, 9},
                                  {float(gray.cols) - 40, float(gray.rows) - 30, 120, 100}};
  for (const Box& box : boxes) {
    Shape68 pa, pb;
    a.Predict(gray, box, &pa);
    b.Predict(gray, box, &pb);
    for (int i = 0; i < kNumLandmarks; ++i) ASSERT_EQ(pa[i], pb[i]) << "point " << i << " in box " << box.x << "," << box.y;
  }
}

// dlib's model read through a copy: written on the first read, used on the next, and the same
// predictor as dlib's own reader gives. A damaged, stale or unwritable copy falls back to the
// model file and says why; the damaged one is written again.
TEST(ShapeCacheTest, TheCopyIsDlibsPredictorAndABadCopyIsMadeAgain) {
  FR_REQUIRE_MODEL();
  const std::string model = internal::default_shape_predictor_path();
  const testing::TempDir dir("fr-shape-cache-test");
  const std::string cache_dir = dir / "cache";
  const detail::ShapeModelReadOptions through_cache{.cache_dir = cache_dir};

  auto first = detail::read_shape_model(model, through_cache);
  EXPECT_FALSE(first->from_cache());
  EXPECT_EQ(first->cache_note(), "no cache copy yet");
  const std::string file = detail::shape_cache_file(cache_dir);
  ASSERT_TRUE(std::filesystem::exists(file));
  auto second = detail::read_shape_model(model, through_cache);
  EXPECT_TRUE(second->from_cache()) << second->cache_note();
  EXPECT_EQ(second->cache_note(), "");
  auto dlibs = detail::read_shape_model(model, {.dlib_reader_only = true});
  EXPECT_FALSE(dlibs->from_cache());
  EXPECT_EQ(second->mean_shape(), dlibs->mean_shape());

  cv::Mat noise(240, 320, CV_8UC1);
  cv::randu(noise, 0, 256);
  expect_same_points(*second, *dlibs, noise);
  expect_same_points(*first, *dlibs, noise);
  if (const std::string photo = test::shared_path("faces-68/lfpw/image_0001.png"); !photo.empty())
    expect_same_points(*second, *dlibs, cv::imread(photo, cv::IMREAD_GRAYSCALE));

  // Damaged on disk: refused, read from the model, written again.
  {
    std::fstream f(file, std::ios::binary | std::ios::in | std::ios::out);
    f.seekp(-1000, std::ios::end);
    f.put('\x7f');
  }
  auto damaged = detail::read_shape_model(model, through_cache);
  EXPECT_FALSE(damaged->from_cache());
  EXPECT_NE(damaged->cache_note().find("checksum"), std::string::npos) << damaged->cache_note();
  expect_same_points(*damaged, *dlibs, noise);
  EXPECT_TRUE(detail::read_shape_model(model, through_cache)->from_cache());

  // A copy of another version of the model file (its size differs): not used.
  {
    std::ifstream in(file, std::ios::binary);
    std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    ShapeModelStamp stamp;
    ShapePredictorTables tables;
    std::string why;
    ASSERT_TRUE(parse_shape_cache(bytes, &stamp, &tables, &why)) << why;
    stamp.source_size += 1;
    const std::vector<uint8_t> stale = serialize_shape_cache(stamp, tables);
    std::ofstream(file, std::ios::binary | std::ios::trunc).write(reinterpret_cast<const char*>(stale.data()),
                                                                   std::streamsize(stale.size()));
  }
  auto restamped = detail::read_shape_model(model, through_cache);
  EXPECT_FALSE(restamped->from_cache());
  EXPECT_NE(restamped->cache_note().find("another model file"), std::string::npos) << restamped->cache_note();

  // A copy that anyone may change (world-writable, as a file planted in a shared /tmp folder could
  // be): not read, and written again by this user.
  std::filesystem::permissions(file, std::filesystem::perms::others_write, std::filesystem::perm_options::add);
  auto foreign = detail::read_shape_model(model, through_cache);
  EXPECT_FALSE(foreign->from_cache());
  EXPECT_NE(foreign->cache_note().find("not this user's own"), std::string::npos) << foreign->cache_note();
  EXPECT_TRUE(detail::read_shape_model(model, through_cache)->from_cache());

  // A cache folder that cannot be made (a file in its place): the model still loads.
  const std::string blocked = dir / "blocked";
  std::ofstream(blocked) << "a file";
  auto unwritable = detail::read_shape_model(model, {.cache_dir = blocked + "/cache"});
  EXPECT_FALSE(unwritable->from_cache());
  EXPECT_NE(unwritable->cache_note().find("cannot create"), std::string::npos) << unwritable->cache_note();
  expect_same_points(*unwritable, *dlibs, noise);
}

}  // namespace
}  // namespace face_reenact::landmarks
