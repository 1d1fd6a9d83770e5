#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "face_reenact/common/error.h"
#include "face_reenact/stream/stream_key.h"
#include "support/temp_dir.h"

namespace face_reenact::stream {
namespace {

namespace fs = std::filesystem;

class KeyFileTest : public ::testing::Test {
 protected:
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  void write_text(const std::string& p, const std::string& text, mode_t mode) {
    { std::ofstream(p, std::ios::binary) << text; }
    ::chmod(p.c_str(), mode);
  }
  static std::string error_of(const std::function<void()>& f) {
    try {
      f();
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  }
  const face_reenact::testing::TempDir tmp_{"fr-key-test"};
  const fs::path dir_ = tmp_.path();
};

TEST_F(KeyFileTest, WritesAPrivateFileThatLoadsBack) {
  const StreamKey key = StreamKey::generate();
  write_key_file(path("k"), key);
  struct stat st;
  ASSERT_EQ(::stat(path("k").c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  EXPECT_EQ(load_key_file(path("k")).bytes(), key.bytes());
  EXPECT_EQ(load_key_file(path("k")).fingerprint(), key.fingerprint());
  EXPECT_EQ(key.fingerprint().size(), 16u);
}

TEST_F(KeyFileTest, GeneratedKeysDiffer) {
  EXPECT_NE(StreamKey::generate().bytes(), StreamKey::generate().bytes());
  EXPECT_NE(StreamKey::generate().fingerprint(), StreamKey::generate().fingerprint());
}

TEST_F(KeyFileTest, NeverOverwritesWithoutForce) {
  const StreamKey first = StreamKey::generate();
  write_key_file(path("k"), first);
  const std::string msg = error_of([&] { write_key_file(path("k"), StreamKey::generate()); });
  EXPECT_NE(msg.find("already exists"), std::string::npos) << msg;
  EXPECT_EQ(load_key_file(path("k")).bytes(), first.bytes());  // untouched
  const StreamKey second = StreamKey::generate();
  write_key_file(path("k"), second, KeyFileOptions{true});
  EXPECT_EQ(load_key_file(path("k")).bytes(), second.bytes());
  struct stat st;
  ASSERT_EQ(::stat(path("k").c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  // No temporary files left behind.
  EXPECT_EQ(std::distance(fs::directory_iterator(dir_), fs::directory_iterator()), 1);
}

TEST_F(KeyFileTest, ForceReplacesAGroupReadableFileWithAPrivateOne) {
  write_text(path("k"), "old", 0644);
  write_key_file(path("k"), StreamKey::generate(), KeyFileOptions{true});
  struct stat st;
  ASSERT_EQ(::stat(path("k").c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
}

TEST_F(KeyFileTest, RefusesFilesOthersCanRead) {
  write_key_file(path("k"), StreamKey::generate());
  for (mode_t mode : {0644, 0640, 0604, 0660, 0606, 0610}) {
    ::chmod(path("k").c_str(), mode);
    const std::string msg = error_of([&] { load_key_file(path("k")); });
    EXPECT_NE(msg.find("permissions"), std::string::npos) << std::oct << mode << ": " << msg;
    EXPECT_NE(msg.find("chmod 600"), std::string::npos) << msg;
  }
  ::chmod(path("k").c_str(), 0400);
  EXPECT_NO_THROW(load_key_file(path("k")));
}

TEST_F(KeyFileTest, RefusesMalformedFiles) {
  const std::string good_hex(64, 'a');
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"", "missing header"},
      {"face-reenact-stream-key v1", "missing header"},
      {"some-other-format v1\n" + good_hex + "\n", "unrecognised header"},
      {"face-reenact-stream-key v2\n" + good_hex + "\n", "unrecognised header"},
      {"face-reenact-stream-key v1\n" + std::string(63, 'a') + "\n", "63 characters"},
      {"face-reenact-stream-key v1\n" + std::string(66, 'a') + "\n", "66 characters"},
      {"face-reenact-stream-key v1\n" + std::string(62, 'a') + "zz\n", "not hexadecimal"},
      {"face-reenact-stream-key v1\n" + std::string(5000, 'a'), "too large"},
  };
  int i = 0;
  for (const auto& [text, expected] : cases) {
    const std::string p = path("bad" + std::to_string(i++));
    write_text(p, text, 0600);
    const std::string msg = error_of([&] { load_key_file(p); });
    EXPECT_NE(msg.find(expected), std::string::npos) << "text '" << text.substr(0, 40) << "': " << msg;
  }
  // Windows line endings and a missing final newline are fine.
  write_text(path("crlf"), "face-reenact-stream-key v1\r\n" + good_hex + "\r\n", 0600);
  EXPECT_NO_THROW(load_key_file(path("crlf")));
  write_text(path("nonl"), "face-reenact-stream-key v1\n" + good_hex, 0600);
  EXPECT_NO_THROW(load_key_file(path("nonl")));
}

TEST_F(KeyFileTest, RefusesMissingFilesDirectoriesAndSymlinks) {
  EXPECT_NE(error_of([&] { load_key_file(path("absent")); }).find("cannot open"), std::string::npos);
  fs::create_directory(path("d"));
  ::chmod(path("d").c_str(), 0700);
  EXPECT_NE(error_of([&] { load_key_file(path("d")); }).find("not a regular file"), std::string::npos);
  write_key_file(path("k"), StreamKey::generate());
  fs::create_symlink(path("k"), path("link"));
  EXPECT_NE(error_of([&] { load_key_file(path("link")); }).find("symbolic link"), std::string::npos);
  // keygen refuses to write through a symlink (O_EXCL|O_NOFOLLOW)
  EXPECT_THROW(write_key_file(path("link"), StreamKey::generate()), Error);
}

TEST_F(KeyFileTest, UnwritableDirectoryGivesAClearError) {
  const std::string msg = error_of([&] { write_key_file(path("no/such/dir/k"), StreamKey::generate()); });
  EXPECT_NE(msg.find("cannot create key file"), std::string::npos) << msg;
}

}  // namespace
}  // namespace face_reenact::stream
