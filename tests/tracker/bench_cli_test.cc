// `face-reenact bench track` runs end to end and reports a sane table as JSON.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <nlohmann/json.hpp>
#include <string>

#include "tracker_test_support.h"

namespace {

using face_reenact::tracker::testing::run_shell_command;

// The CPU operators only (--vulkan none): the Vulkan strategies have their own test
// (VulkanTrackBenchCli), and on lavapipe they took 147 of this test's 148 s.
TEST(TrackerBenchCli, BenchTrackReportsBothCpuOperators) {
  const std::string model = face_reenact::tracker::testing::real_model_path();
  if (model.empty()) GTEST_SKIP() << "no face model built yet (FR_MODEL)";
  const char* cli = std::getenv("FR_CLI");
  ASSERT_NE(cli, nullptr);
  int status = -1;
  const std::string out = run_shell_command(std::string(cli) + " bench track --model " + model +
                                  " --frames 1 --width 320 --height 240 --vulkan none --json 2>&1",
                              &status);
  ASSERT_EQ(status, 0) << out;
  const auto doc = nlohmann::json::parse(out);
  EXPECT_EQ(doc["unknowns"], 85);
  for (const char* name : {"cpu_matrix_free", "cpu_assembled"}) {
    const auto& s = doc["solvers"][name];
    ASSERT_EQ(s["levels"].size(), 2u) << out;
    EXPECT_EQ(s["levels"][0]["level"], 2);
    EXPECT_GT(double(s["levels"][0]["residuals"]), 100.0);
    EXPECT_GT(double(s["levels"][1]["residuals"]), double(s["levels"][0]["residuals"]));
    EXPECT_GT(double(s["total_ms_per_frame"]), 0.0);
    EXPECT_LT(double(s["mean_final_energy"]), 1.0);
  }
  // With more than one CPU thread, matrix-free also runs on one thread: the same steps exactly.
  EXPECT_GE(int(doc["cpu_threads"]), 1);
  if (int(doc["cpu_threads"]) > 1) {
    ASSERT_TRUE(doc["solvers"].contains("cpu_matrix_free_1_thread")) << out;
    EXPECT_EQ(double(doc["solvers"]["cpu_matrix_free_1_thread"]["mean_final_energy"]),
              double(doc["solvers"]["cpu_matrix_free"]["mean_final_energy"]));
  }
}

TEST(TrackerBenchCli, BadArgumentsFailCleanly) {
  const char* cli = std::getenv("FR_CLI");
  ASSERT_NE(cli, nullptr);
  int status = -1;
  run_shell_command(std::string(cli) + " bench track --model /nonexistent/model.frm --frames 1 2>&1", &status);
  EXPECT_NE(status, 0);
  run_shell_command(std::string(cli) + " bench track --frames 0 2>&1", &status);
  EXPECT_NE(status, 0);
}

}  // namespace
