#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "face_reenact/common/error.h"
#include "face_reenact/landmarks/evaluation.h"

namespace face_reenact::landmarks {
namespace {

std::string make_pts(int n, bool close = true, const std::string& header = "version: 1\nn_points: 68\n") {
  std::string s = header + "{\n";
  for (int i = 0; i < n; ++i) s += std::to_string(i + 1) + ".5 " + std::to_string(2 * i + 1) + "\n";
  if (close) s += "}\n";
  return s;
}

TEST(PtsTest, ParsesAndConvertsToZeroBased) {
  const Shape68 s = parse_pts(make_pts(68), "test");
  EXPECT_FLOAT_EQ(s[0].x(), 0.5f);
  EXPECT_FLOAT_EQ(s[0].y(), 0.f);
  EXPECT_FLOAT_EQ(s[67].x(), 67.5f);
  EXPECT_FLOAT_EQ(s[67].y(), 134.f);
}

TEST(PtsTest, AcceptsCrlfAndExtraSpaces) {
  std::string text = "version: 1\r\nn_points:  68\r\n{\r\n";
  for (int i = 0; i < 68; ++i) text += "  10 20 \r\n";
  text += "}\r\n";
  const Shape68 s = parse_pts(text, "crlf");
  EXPECT_FLOAT_EQ(s[10].x(), 9.f);
}

TEST(PtsTest, RejectsMalformedFilesWithClearErrors) {
  auto expect_error = [](const std::string& text, const std::string& fragment) {
    try {
      parse_pts(text, "file.pts");
      ADD_FAILURE() << "accepted: " << text.substr(0, 60);
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("file.pts"), std::string::npos) << e.what();
    }
  };
  expect_error(make_pts(67), "67 points");
  expect_error(make_pts(69), "more than 68");
  expect_error(make_pts(68, false), "missing '}'");
  expect_error("version: 1\nn_points: 5\n{\n}\n", "expected 68");
  expect_error("version: 1\nn_points: 68\n", "missing '{'");
  expect_error("hello\n", "unexpected");
  expect_error("version: 1\nn_points: 68\n{\n1 nan\n", "expected 'x y'");
  expect_error("version: 1\nn_points: 68\n{\n1\n", "expected 'x y'");
  expect_error("", "missing '{'");
  // Finite as a double but infinite as a float (found by the fuzzer).
  expect_error("version: 1\nn_points: 68\n{\n1e300 5\n", "out of range");
}

TEST(PtsTest, MissingFileIsAnError) { EXPECT_THROW(read_pts("/nonexistent/x.pts"), Error); }

TEST(NmeTest, NormalisedByOuterEyeCorners) {
  Shape68 truth;
  for (int i = 0; i < kNumLandmarks; ++i) truth[size_t(i)] = Eigen::Vector2f(float(i), float(i % 7));
  truth[36] = {100, 50};
  truth[45] = {200, 50};
  EXPECT_FLOAT_EQ(nme_outer_eye(truth, truth), 0.f);
  Shape68 shifted = truth;
  for (auto& p : shifted) p += Eigen::Vector2f(6, 8);  // 10 px = 0.1 of the 100 px eye distance
  EXPECT_NEAR(nme_outer_eye(shifted, truth), 0.1f, 1e-5f);
  Shape68 degenerate = truth;
  degenerate[45] = degenerate[36];
  EXPECT_TRUE(std::isinf(nme_outer_eye(truth, degenerate)));
}

}  // namespace
}  // namespace face_reenact::landmarks
