// `face-reenact devices` and `face-reenact bench render` end to end (env FR_CLI, FR_MODEL).
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "face_reenact/common/subprocess.h"

namespace face_reenact {
namespace {

std::string cli() {
  const char* p = std::getenv("FR_CLI");
  return p ? p : "";
}

// The JSON document in a command's output (stdout and stderr are merged).
nlohmann::json parse_json(const std::string& output) {
  const size_t start = output.find_first_of("[{");
  if (start == std::string::npos) throw std::runtime_error("no JSON in: " + output);
  return nlohmann::json::parse(output.substr(start));
}

class CliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (cli().empty() || !std::filesystem::exists(cli())) GTEST_FAIL() << "FR_CLI is not set or missing: run through ctest";
  }
};

TEST_F(CliTest, DevicesListsLavapipeAsJson) {
  const auto r = run_subprocess({cli(), "devices", "--json", "--device", "llvmpipe"});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto doc = parse_json(r.output);
  ASSERT_TRUE(doc.is_array());
  int selected = 0;
  for (const auto& d : doc) {
    EXPECT_TRUE(d.contains("name") && d.contains("type") && d.contains("api_version") && d.contains("heaps"));
    if (d["selected"].get<bool>()) {
      ++selected;
      EXPECT_EQ(d["type"], "cpu");
    }
  }
  EXPECT_EQ(selected, 1);
}

TEST_F(CliTest, DevicesTextMarksTheChoice) {
  const auto r = run_subprocess({cli(), "devices"});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("* ["), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("llvmpipe"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("RGB-D cameras on USB"), std::string::npos) << r.output;
}

// The RGB-D cameras alone (live/usb_cameras.h): a list, with the reason where the buses cannot be
// read (none here: no camera is plugged into the test machines).
TEST_F(CliTest, DevicesCamerasListsTheRgbdCamerasOnUsb) {
  const auto r = run_subprocess({cli(), "devices", "--cameras", "--json"});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto doc = parse_json(r.output);
  ASSERT_TRUE(doc.contains("cameras") && doc["cameras"].is_array()) << r.output;
  EXPECT_TRUE(doc.contains("error")) << r.output;
  for (const auto& c : doc["cameras"]) EXPECT_TRUE(c.contains("model") && c.contains("usb_id")) << r.output;
}

TEST_F(CliTest, DevicesWithAnUnknownSelectionSaysSo) {
  const auto r = run_subprocess({cli(), "devices", "--device", "no-such-device"});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("no device matches"), std::string::npos) << r.output;
}

TEST_F(CliTest, BenchRenderReportsEveryLevelForGpuAndCpu) {
  const char* model = std::getenv("FR_MODEL");
  ASSERT_TRUE(model && std::filesystem::exists(model)) << "face model missing: build it with `face-reenact model build`";
  const auto r = run_subprocess({cli(), "bench", "render", "--model", model, "--device", "llvmpipe", "--iterations", "2",
                                 "--json", "--validation"});
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output.find("[vulkan"), std::string::npos) << "validation messages: " << r.output;
  const auto doc = parse_json(r.output);
  ASSERT_EQ(doc["levels"].size(), 3u);
  const int widths[] = {640, 320, 160};
  for (int l = 0; l < 3; ++l) {
    const auto& level = doc["levels"][l];
    EXPECT_EQ(level["width"], widths[l]);
    EXPECT_GT(level["covered_pixels"].get<int>(), 0);
    EXPECT_GT(level["gpu"]["wall_ms"].get<double>(), 0.0);
    EXPECT_GE(level["gpu"]["raster_ms"].get<double>(), 0.0);
    EXPECT_GT(level["cpu"]["total_ms"].get<double>(), 0.0);
    EXPECT_GT(level["cpu"]["raster_geometry_ms"].get<double>(), 0.0);
    EXPECT_GT(level["gpu_cpu_ratio"].get<double>(), 0.0);
  }
}

TEST_F(CliTest, BenchRenderWithAMissingModelFailsClearly) {
  const auto r = run_subprocess({cli(), "bench", "render", "--model", "/nonexistent/face-model.frm", "--iterations", "1"});
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("error"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("/nonexistent/face-model.frm"), std::string::npos) << r.output;
}

TEST_F(CliTest, BenchRenderRejectsAnUnknownDevice) {
  const char* model = std::getenv("FR_MODEL");
  ASSERT_TRUE(model && std::filesystem::exists(model)) << "face model missing";
  const auto r = run_subprocess({cli(), "bench", "render", "--model", model, "--device", "no-such-gpu", "--iterations", "1"});
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("no-such-gpu"), std::string::npos) << r.output;
}

// A machine with the Vulkan loader but no driver (libvulkan1 only recommends one): the loader's
// bare VK_ERROR_INCOMPATIBLE_DRIVER becomes one sentence naming the package to install. The
// loader is pointed at a driver list that does not exist (VK_DRIVER_FILES, and its older name).
TEST_F(CliTest, NoVulkanDriverSaysWhichPackageToInstall) {
  const auto r = run_subprocess({"env", "VK_DRIVER_FILES=/nonexistent/icd.json", "VK_ICD_FILENAMES=/nonexistent/icd.json",
                                 cli(), "devices"});
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("no Vulkan driver is installed"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("apt-get install mesa-vulkan-drivers"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace face_reenact
