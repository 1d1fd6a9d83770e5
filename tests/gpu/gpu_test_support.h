#pragma once
// Shared by the GPU tests: one Vulkan context on lavapipe (the CPU device, so no test needs a
// real GPU) with validation on, and a fixture that fails a test on any validation message.
#include <gtest/gtest.h>

#include <memory>

#include "face_reenact/gpu/context.h"

namespace face_reenact::gpu::testing {

inline Context& lavapipe_context() {
  static std::unique_ptr<Context> context = [] {
    Context::Options o;
    o.device = "llvmpipe";
    o.enable_validation = true;
    o.synchronization_validation = true;
    return std::make_unique<Context>(o);
  }();
  return *context;
}

class ValidatedGpuTest : public ::testing::Test {
 protected:
  void SetUp() override { lavapipe_context().reset_validation_stats(); }
  void TearDown() override {
    const ValidationStats s = lavapipe_context().validation_stats();
    EXPECT_EQ(s.errors, 0u) << "Vulkan validation errors; last: " << s.last_message;
    EXPECT_EQ(s.warnings, 0u) << "Vulkan validation warnings; last: " << s.last_message;
  }
  Context& context() { return lavapipe_context(); }
};

}  // namespace face_reenact::gpu::testing
