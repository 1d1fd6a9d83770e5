// Tests of the compositor's pixel helpers (core/reenact/src/image_sampling.h).
#include <gtest/gtest.h>

#include <vector>

#include "face_reenact/gpu/cpu_renderer.h"
#include "image_sampling.h"
#include "test_meshes.h"

namespace face_reenact::reenact::internal {
namespace {

// covered_rect by brute force: every pixel of the buffer looked at.
cv::Rect covered_by_scanning_every_pixel(const gpu::GBuffer& g, int margin) {
  cv::Rect box;
  for (int j = 0; j < g.height; ++j)
    for (int i = 0; i < g.width; ++i)
      if (g.covered(i, j)) box |= cv::Rect(i, j, 1, 1);
  if (box.empty()) return box;
  return grown_within(box, margin, g.width, g.height);
}

// covered_rect scans only the rectangle the CPU rasteriser says it drew (GBuffer::drawn).
// Drawn into one kept buffer, a sphere that moves about, half leaves the image, leaves it and
// comes back has the rectangle every pixel's scan finds; so has a buffer whose trace Resize
// forgot, with a pixel written outside the last draw's rectangle.
TEST(ImageSampling, TheCoveredRectangleIsEveryPixelsScanWithinTheRastersTrace) {
  const gpu::RenderModel sphere = gpu::testing::make_icosphere(0.1f, 3);
  const gpu::CpuRenderer cpu(sphere);
  const gpu::PinholeCamera camera;  // 640x480
  gpu::GBuffer g;
  int drawn = 0;
  for (const Eigen::Vector3f& at : {Eigen::Vector3f(0.f, 0.f, 0.6f), Eigen::Vector3f(0.25f, -0.1f, 0.6f),
                                    Eigen::Vector3f(-0.35f, 0.2f, 0.7f), Eigen::Vector3f(5.f, 0.f, 0.6f),
                                    Eigen::Vector3f(0.02f, 0.05f, 0.4f)}) {
    gpu::FaceParameters p = gpu::frontal_pose(0.6f);
    p.translation = at;
    cpu.rasterize(cpu.evaluate(p), camera, gpu::RenderOptions{}, &g, 2);
    ASSERT_EQ(g.drawn.triangle_data, g.triangle.data());
    for (int margin : {0, 2, 9}) {
      const cv::Rect expected = covered_by_scanning_every_pixel(g, margin);
      EXPECT_EQ(covered_rect(g, margin), expected) << "sphere at " << at.transpose() << ", margin " << margin;
    }
    drawn += g.covered_count() > 0 ? 1 : 0;
  }
  EXPECT_EQ(drawn, 4);  // all but the sphere off the image
  EXPECT_TRUE(covered_rect(g, 0).width > 0);
  // No trace: every row is scanned.
  g.Resize(g.width, g.height);
  g.triangle[static_cast<size_t>(470) * g.width + 630] = 0;
  EXPECT_EQ(covered_rect(g, 1), cv::Rect(629, 469, 3, 3));
}

}  // namespace
}  // namespace face_reenact::reenact::internal
