// How file names are read: the one lower-case extension every reader and writer dispatches on.
#include "face_reenact/common/paths.h"

#include <gtest/gtest.h>

namespace face_reenact {
namespace {

TEST(Paths, AsciiLowerChangesOnlyAsciiLetters) {
  EXPECT_EQ(ascii_lower("YUY2"), "yuy2");
  EXPECT_EQ(ascii_lower("NVIDIA GeForce RTX 4090"), "nvidia geforce rtx 4090");
  EXPECT_EQ(ascii_lower(""), "");
  EXPECT_EQ(ascii_lower("caf\xC3\x89"), "caf\xC3\x89");  // UTF-8 bytes pass through unchanged
}

TEST(Paths, LowerCaseExtensionKeepsTheDotAndOnlyTheLastSuffix) {
  EXPECT_EQ(lower_case_extension("clip.MP4"), ".mp4");
  EXPECT_EQ(lower_case_extension("/data/take.1/face.Png"), ".png");
  EXPECT_EQ(lower_case_extension("archive.tar.GZ"), ".gz");
  EXPECT_EQ(lower_case_extension("/data/take.1/recording"), "");
  EXPECT_EQ(lower_case_extension(".hidden"), "");  // a dot file has no extension
  EXPECT_EQ(lower_case_extension(""), "");
}

}  // namespace
}  // namespace face_reenact
