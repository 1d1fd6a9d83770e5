#include "face_reenact/model/model_file.h"

#include <gtest/gtest.h>

#include <filesystem>

#include "face_reenact/common/error.h"
#include "small_test_model.h"
#include "support/temp_dir.h"

namespace face_reenact {
namespace {

using testing::make_small_model;

void expect_same(const FaceModel& a, const FaceModel& b) {
  EXPECT_EQ(a.triangles, b.triangles);
  EXPECT_EQ(a.corner_uvs, b.corner_uvs);
  EXPECT_EQ(a.vertex_part, b.vertex_part);
  EXPECT_EQ(a.mirror_vertex, b.mirror_vertex);
  EXPECT_EQ(a.base_vertex, b.base_vertex);
  EXPECT_EQ(a.mean_shape, b.mean_shape);
  EXPECT_EQ(a.identity_basis, b.identity_basis);
  EXPECT_EQ(a.identity_sigma, b.identity_sigma);
  EXPECT_EQ(a.expression_basis, b.expression_basis);
  EXPECT_EQ(a.expression_names, b.expression_names);
  EXPECT_EQ(a.mean_albedo, b.mean_albedo);
  EXPECT_EQ(a.albedo_basis, b.albedo_basis);
  EXPECT_EQ(a.albedo_sigma, b.albedo_sigma);
  EXPECT_EQ(a.albedo_names, b.albedo_names);
  ASSERT_EQ(a.landmarks.size(), b.landmarks.size());
  for (size_t i = 0; i < a.landmarks.size(); ++i) {
    EXPECT_EQ(a.landmarks[i].ibug_index, b.landmarks[i].ibug_index);
    EXPECT_EQ(a.landmarks[i].vertex, b.landmarks[i].vertex);
    EXPECT_EQ(a.landmarks[i].flags, b.landmarks[i].flags);
  }
  EXPECT_EQ(a.units, b.units);
  EXPECT_EQ(a.source, b.source);
  EXPECT_EQ(a.source_sha256, b.source_sha256);
  EXPECT_EQ(a.identity_samples, b.identity_samples);
  EXPECT_EQ(a.build_seed, b.build_seed);
  EXPECT_FLOAT_EQ(a.identity_explained_variance, b.identity_explained_variance);
}

std::string error_of(std::span<const uint8_t> bytes) {
  try {
    parse_face_model(bytes, "test");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(ModelFile, RoundTripInMemoryAndOnDisk) {
  FaceModel m = make_small_model(1);
  auto bytes = serialize_face_model(m);
  expect_same(m, parse_face_model(bytes));

  const ::face_reenact::testing::TempDir dir("fr-model-file-test");
  const std::string path = dir / "model.frm";
  save_face_model(m, path);
  expect_same(m, load_face_model(path));
}

TEST(ModelFile, HeaderIsDocumentedLayout) {
  auto bytes = serialize_face_model(make_small_model(2));
  ASSERT_GT(bytes.size(), 20u);
  EXPECT_EQ(std::string(bytes.begin(), bytes.begin() + 7), "FRMODEL");
  EXPECT_EQ(bytes[7], 0);
  EXPECT_EQ(bytes[8], kFaceModelFormatVersion);  // little-endian u32
  EXPECT_EQ(bytes[12], 0x04);                   // byte-order marker 0x01020304, LE
  EXPECT_EQ(bytes[15], 0x01);
}

TEST(ModelFile, RejectsWrongMagic) {
  auto bytes = serialize_face_model(make_small_model(3));
  bytes[0] = 'X';
  EXPECT_NE(error_of(bytes).find("wrong magic"), std::string::npos);
}

TEST(ModelFile, RejectsWrongVersion) {
  auto bytes = serialize_face_model(make_small_model(3));
  bytes[8] = 99;
  EXPECT_NE(error_of(bytes).find("version 99"), std::string::npos);
}

TEST(ModelFile, RejectsEveryTruncation) {
  auto bytes = serialize_face_model(make_small_model(4));
  for (size_t len = 0; len < bytes.size(); len += std::max<size_t>(1, bytes.size() / 97)) {
    std::span<const uint8_t> cut(bytes.data(), len);
    EXPECT_FALSE(error_of(cut).empty()) << "truncated at " << len << " was accepted";
  }
}

TEST(ModelFile, DetectsCorruptionAnywhere) {
  const auto good = serialize_face_model(make_small_model(5));
  // Flipping a bit anywhere in the header, the table or a section is caught by a CRC or a
  // structural check. Only the zero padding that aligns sections to 8 bytes is unchecked.
  int undetected = 0;
  for (size_t i = 0; i < good.size(); ++i) {
    auto bytes = good;
    bytes[i] ^= 0x10;
    if (error_of(bytes).empty()) {
      ++undetected;
      EXPECT_EQ(good[i], 0) << "byte " << i << " (not padding) flipped without an error";
    }
  }
  EXPECT_LT(undetected, 8 * 7) << "more unchecked bytes than the alignment padding allows";
}

TEST(ModelFile, CorruptionMessageNamesTheSection) {
  auto bytes = serialize_face_model(make_small_model(6));
  bytes[bytes.size() - 5] ^= 0xFF;  // inside the last section (landmarks)
  EXPECT_NE(error_of(bytes).find("LMKS"), std::string::npos) << error_of(bytes);
}

TEST(ModelFile, RefusesToSaveInvalidModels) {
  FaceModel m = make_small_model(7);
  m.triangles[0][1] = 10000;
  EXPECT_THROW(serialize_face_model(m), Error);
  m = make_small_model(7);
  m.mean_shape[0] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(serialize_face_model(m), Error);
}

TEST(ModelFile, MissingFileIsAClearError) {
  try {
    load_face_model("/nonexistent/face-model.frm");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/face-model.frm"), std::string::npos);
  }
}

TEST(FaceModel, ShapeIsEquationOne) {
  FaceModel m = make_small_model(8);
  Eigen::VectorXf alpha = Eigen::VectorXf::Random(m.num_identity());
  Eigen::VectorXf delta = Eigen::VectorXf::Random(52);
  Eigen::VectorXf expected = m.mean_shape + m.identity_basis * alpha + m.expression_basis * delta;
  EXPECT_TRUE(m.shape(alpha, delta).isApprox(expected));
  // Shorter coefficient vectors mean trailing zeros.
  Eigen::VectorXf a2 = alpha.head(2);
  EXPECT_TRUE(m.shape(a2, {}).isApprox(m.mean_shape + m.identity_basis.leftCols(2) * a2));
  Eigen::VectorXf beta = Eigen::VectorXf::Random(m.num_albedo());
  EXPECT_TRUE(m.albedo(beta).isApprox(m.mean_albedo + m.albedo_basis * beta));
}

TEST(FaceModel, ArkitNamesAreUniqueAndIndexed) {
  const auto& names = arkit_blendshape_names();
  for (size_t i = 0; i < names.size(); ++i) EXPECT_EQ(arkit_blendshape_index(names[i]), int(i));
  EXPECT_EQ(arkit_blendshape_index("jawOpen"), 17);
  EXPECT_EQ(arkit_blendshape_index("notAShape"), -1);
}

}  // namespace
}  // namespace face_reenact
