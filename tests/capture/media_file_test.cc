// The media-file reader every video and still-image input goes through: clear errors naming
// the file, a written clip read back (size, frame rate, frame count, colours, end of file,
// rewind), the frame-rate fallback, pixel normalisation and still images.
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "capture_test_support.h"
#include "face_reenact/capture/media_file.h"
#include "face_reenact/common/error.h"

namespace face_reenact::capture {
namespace {
namespace fs = std::filesystem;
using testing::spit;
using testing::TempDir;

// Distinct colours (BGR) per frame, far enough apart that codec noise cannot confuse them and
// with unequal channels, so swapped channels would show.
const std::vector<cv::Scalar> kFrameColours = {
    {200, 40, 10}, {10, 200, 40}, {40, 10, 200}, {120, 120, 30}, {30, 90, 160}};
constexpr int kW = 64, kH = 48;
// MJPEG's quantisation and 4:2:0 chroma on flat colours stay well within this.
constexpr int kCodecTolerance = 12;

// Writes kFrameColours as an MJPG AVI; false when this OpenCV cannot write one.
bool write_clip(const fs::path& path, double fps) {
  cv::VideoWriter writer(path.string(), cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), fps, cv::Size(kW, kH));
  if (!writer.isOpened()) return false;
  for (const cv::Scalar& c : kFrameColours) writer.write(cv::Mat(kH, kW, CV_8UC3, c));
  return true;
}

void expect_colour(const cv::Mat& frame, const cv::Scalar& bgr) {
  ASSERT_EQ(frame.type(), CV_8UC3);
  ASSERT_EQ(frame.size(), cv::Size(kW, kH));
  const cv::Vec3b centre = frame.at<cv::Vec3b>(kH / 2, kW / 2);
  for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(centre[ch], bgr[ch], kCodecTolerance) << "channel " << ch;
}

TEST(CaptureVideoFileReaderTest, MissingFolderAndGarbageFilesAreClearErrors) {
  TempDir tmp;
  EXPECT_THROW_WITH(VideoFileReader(tmp / "absent.mp4"), "video '", "absent.mp4", "no such file");
  fs::create_directories(tmp / "clips.mp4");
  EXPECT_THROW_WITH(VideoFileReader(tmp / "clips.mp4"), "clips.mp4", "folder");
  EXPECT_THROW_WITH(VideoFileReader("/dev/null"), "/dev/null", "not a regular file");
  spit(tmp / "garbage.mp4", std::string(4096, 'x'));
  EXPECT_THROW_WITH(VideoFileReader(tmp / "garbage.mp4"), "garbage.mp4", "cannot open");
  spit(tmp / "notes.avi", "this is not a video at all");
  EXPECT_THROW_WITH(VideoFileReader(tmp / "notes.avi"), "notes.avi");
  spit(tmp / "empty.mp4", "");
  EXPECT_THROW_WITH(VideoFileReader(tmp / "empty.mp4"), "empty.mp4");
  // The errors are face_reenact::Error (not OpenCV's exceptions), so callers can catch one type.
  EXPECT_THROW(VideoFileReader(tmp / "garbage.mp4"), Error);
}

TEST(CaptureVideoFileReaderTest, TruncatedClipIsAnErrorOrEndsEarly) {
  TempDir tmp;
  const fs::path clip = tmp / "clip.avi";
  if (!write_clip(clip, 25)) GTEST_SKIP() << "OpenCV cannot write MJPG AVI here";
  const std::string bytes = testing::slurp(clip);
  // Only the header: nothing decodable.
  spit(tmp / "header_only.avi", bytes.substr(0, 200));
  EXPECT_THROW_WITH(VideoFileReader(tmp / "header_only.avi"), "header_only.avi");
  // Cut in the middle: whatever opens ends without a failure, with fewer frames.
  spit(tmp / "half.avi", bytes.substr(0, bytes.size() / 2));
  try {
    VideoFileReader half(tmp / "half.avi");
    cv::Mat frame;
    int frames = 0;
    while (half.read(&frame)) ++frames;
    EXPECT_LT(frames, static_cast<int>(kFrameColours.size()));
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("half.avi"), std::string::npos) << e.what();
  }
}

TEST(CaptureVideoFileReaderTest, WrittenClipReadsBackThenEndsAndRewinds) {
  TempDir tmp;
  const fs::path clip = tmp / "clip.avi";
  if (!write_clip(clip, 25)) GTEST_SKIP() << "OpenCV cannot write MJPG AVI here";
  VideoFileReader video(clip);
  EXPECT_EQ(video.path(), clip.string());
  EXPECT_EQ(video.width(), kW);
  EXPECT_EQ(video.height(), kH);
  EXPECT_DOUBLE_EQ(video.fps(), 25);
  EXPECT_EQ(video.frame_count(), static_cast<int64_t>(kFrameColours.size()));
  cv::Mat frame;
  for (size_t i = 0; i < kFrameColours.size(); ++i) {
    SCOPED_TRACE("frame " + std::to_string(i));
    EXPECT_EQ(video.frames_read(), static_cast<int64_t>(i));
    ASSERT_TRUE(video.read(&frame));
    expect_colour(frame, kFrameColours[i]);
  }
  EXPECT_FALSE(video.read(&frame));  // end of file, not an exception
  EXPECT_FALSE(video.read(&frame));  // and it stays there
  EXPECT_EQ(video.frames_read(), static_cast<int64_t>(kFrameColours.size()));

  video.rewind();
  EXPECT_EQ(video.frames_read(), 0);
  for (size_t i = 0; i < kFrameColours.size(); ++i) {
    SCOPED_TRACE("after rewind, frame " + std::to_string(i));
    ASSERT_TRUE(video.read(&frame));
    expect_colour(frame, kFrameColours[i]);
  }
  EXPECT_FALSE(video.read(&frame));

  // A file deleted before a rewind: the error names it and nothing more is read.
  fs::remove(clip);
  EXPECT_THROW_WITH(video.rewind(), "clip.avi", "no such file");
  EXPECT_FALSE(video.read(&frame));
}

TEST(CaptureVideoFileReaderTest, MovedReaderKeepsReading) {
  TempDir tmp;
  const fs::path clip = tmp / "clip.avi";
  if (!write_clip(clip, 25)) GTEST_SKIP() << "OpenCV cannot write MJPG AVI here";
  VideoFileReader first(clip);
  cv::Mat frame;
  ASSERT_TRUE(first.read(&frame));
  VideoFileReader second(std::move(first));
  ASSERT_TRUE(second.read(&frame));
  expect_colour(frame, kFrameColours[1]);
  EXPECT_EQ(second.frames_read(), 2);
}

TEST(CaptureVideoFileReaderTest, ImplausibleFrameRateFallsBack) {
  TempDir tmp;
  const fs::path clip = tmp / "fast.avi";
  if (!write_clip(clip, 1000)) GTEST_SKIP() << "OpenCV cannot write MJPG AVI here";
  {
    cv::VideoCapture probe(clip.string(), cv::CAP_FFMPEG);
    if (probe.get(cv::CAP_PROP_FPS) <= kMaxPlausibleFps) GTEST_SKIP() << "the container did not keep 1000 fps";
  }
  EXPECT_DOUBLE_EQ(VideoFileReader(clip).fps(), 30);  // the default fallback
  EXPECT_DOUBLE_EQ(VideoFileReader(clip, {.fallback_fps = 12.5}).fps(), 12.5);
}

TEST(CaptureMediaFileTest, ToBgr8ExpandsGreyDropsAlphaRejectsTheRest) {
  cv::Mat grey(2, 3, CV_8UC1, cv::Scalar(77));
  ASSERT_TRUE(to_bgr8(&grey));
  EXPECT_EQ(grey.type(), CV_8UC3);
  EXPECT_EQ(grey.at<cv::Vec3b>(1, 2), cv::Vec3b(77, 77, 77));
  cv::Mat bgra(2, 3, CV_8UC4, cv::Scalar(1, 2, 3, 4));
  ASSERT_TRUE(to_bgr8(&bgra));
  EXPECT_EQ(bgra.type(), CV_8UC3);
  EXPECT_EQ(bgra.at<cv::Vec3b>(0, 0), cv::Vec3b(1, 2, 3));
  cv::Mat bgr(2, 3, CV_8UC3, cv::Scalar(9, 8, 7));
  const uchar* pixels = bgr.data;
  ASSERT_TRUE(to_bgr8(&bgr));
  EXPECT_EQ(bgr.data, pixels);  // already BGR: untouched, not copied
  cv::Mat deep(2, 3, CV_16UC3, cv::Scalar(1000, 0, 0));
  EXPECT_FALSE(to_bgr8(&deep));
  EXPECT_EQ(deep.type(), CV_16UC3);
  cv::Mat two(2, 3, CV_8UC2);
  EXPECT_FALSE(to_bgr8(&two));
}

TEST(CaptureMediaFileTest, StillImagesByNameOrContent) {
  TempDir tmp;
  EXPECT_TRUE(has_still_image_extension("a/b/Photo.JPG"));
  EXPECT_TRUE(has_still_image_extension("x.webp"));
  EXPECT_FALSE(has_still_image_extension("clip.mp4"));
  EXPECT_FALSE(has_still_image_extension("png"));
  EXPECT_TRUE(is_still_image(tmp / "missing.png"));  // by name: its errors say "image"
  std::vector<uchar> png;
  cv::imencode(".png", cv::Mat(30, 40, CV_8UC1, cv::Scalar(90)), png);
  const fs::path unnamed = tmp / "picture";
  spit(unnamed, std::string(png.begin(), png.end()));
  EXPECT_TRUE(is_still_image(unnamed.string()));  // by content
  spit(tmp / "notes.mp4", "not an image");
  EXPECT_FALSE(is_still_image(tmp / "notes.mp4"));
  EXPECT_FALSE(is_still_image(tmp / "missing.mp4"));

  const cv::Mat grey = read_still_image(unnamed.string());
  EXPECT_EQ(grey.type(), CV_8UC3);
  EXPECT_EQ(grey.size(), cv::Size(40, 30));
  EXPECT_EQ(grey.at<cv::Vec3b>(5, 5), cv::Vec3b(90, 90, 90));
  const fs::path bgra = tmp / "alpha.png";
  ASSERT_TRUE(cv::imwrite(bgra.string(), cv::Mat(4, 4, CV_8UC4, cv::Scalar(10, 20, 30, 128))));
  EXPECT_EQ(read_still_image(bgra.string()).at<cv::Vec3b>(0, 0), cv::Vec3b(10, 20, 30));
}

TEST(CaptureMediaFileTest, BadStillImagesAreClearErrors) {
  TempDir tmp;
  EXPECT_THROW_WITH(read_still_image(tmp / "absent.png"), "image '", "absent.png", "no such file");
  std::vector<uchar> png;
  cv::imencode(".png", cv::Mat(64, 64, CV_8UC3, cv::Scalar(1, 2, 3)), png);
  spit(tmp / "broken.png", std::string(png.begin(), png.begin() + 40));  // signature, then cut
  EXPECT_THROW_WITH(read_still_image(tmp / "broken.png"), "broken.png", "cannot be decoded");
  spit(tmp / "text.jpg", "not a picture");
  EXPECT_THROW_WITH(read_still_image(tmp / "text.jpg"), "text.jpg", "cannot be decoded");
}

}  // namespace
}  // namespace face_reenact::capture
