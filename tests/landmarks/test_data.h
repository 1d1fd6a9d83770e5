#pragma once
// Shared fixtures for the landmark tests: real data from FR_SHARED_DATA (tests skip with a
// clear message without it) and one detector per process (the model takes ~0.5 s to load).
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <memory>
#include <string>
#include <vector>
#include <unistd.h>

#include "face_reenact/landmarks/frame_source.h"
#include "face_reenact/landmarks/landmark_detector.h"
#include "support/temp_dir.h"

namespace face_reenact::landmarks::test {

inline std::string shared_data() {
  const char* d = std::getenv("FR_SHARED_DATA");
  return d ? d : "";
}

// Path under FR_SHARED_DATA, or "" when it is not there.
inline std::string shared_path(const std::string& relative) {
  const std::string root = shared_data();
  if (root.empty()) return "";
  const std::string p = root + "/" + relative;
  return std::filesystem::exists(p) ? p : "";
}

#define FR_REQUIRE_SHARED(var, relative)                                                              \
  const std::string var = ::face_reenact::landmarks::test::shared_path(relative);                     \
  if (var.empty()) GTEST_SKIP() << "real test data '" << (relative)                                   \
                                << "' not found: set FR_SHARED_DATA to the shared data folder"

inline std::string read_text(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// A fresh temporary folder, removed with its contents when the test process exits.
inline std::filesystem::path temp_dir(const std::string& name) {
  static std::vector<std::unique_ptr<::face_reenact::testing::TempDir>> dirs;
  dirs.push_back(std::make_unique<::face_reenact::testing::TempDir>(name));
  return dirs.back()->path();
}

inline bool model_available() {
  return std::filesystem::exists("/usr/share/dlib/shape_predictor_68_face_landmarks.dat") ||
         std::getenv("FACE_REENACT_SHAPE_PREDICTOR") != nullptr;
}

#define FR_REQUIRE_MODEL()                                                                            \
  if (!::face_reenact::landmarks::test::model_available())                                           \
  GTEST_SKIP() << "dlib shape predictor not installed (apt-get install libdlib-data)"

inline LandmarkDetector& shared_detector() {
  static LandmarkDetector detector;
  return detector;
}

}  // namespace face_reenact::landmarks::test
