#pragma once
// Temporary folders and file helpers for the capture tests.
#include <gtest/gtest.h>
#include <stdlib.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace face_reenact::capture::testing {

class TempDir {
 public:
  TempDir() {
    std::string pattern = (std::filesystem::temp_directory_path() / "fr-capture-test-XXXXXX").string();
    if (!mkdtemp(pattern.data())) throw std::runtime_error("mkdtemp failed");
    path_ = pattern;
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  std::string operator/(const std::string& name) const { return (std::filesystem::path(path_) / name).string(); }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

inline std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

inline void spit(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
}

// Replaces the first occurrence of `from` in a file; fails the test if absent.
inline void replace_in_file(const std::string& path, const std::string& from, const std::string& to) {
  std::string text = slurp(path);
  const size_t at = text.find(from);
  ASSERT_NE(at, std::string::npos) << "'" << from << "' not in " << path;
  text.replace(at, from.size(), to);
  spit(path, text);
}

// Expects `statement` to throw an exception whose message contains every one of `parts`.
#define EXPECT_THROW_WITH(statement, ...)                                                          \
  do {                                                                                             \
    bool thrown_ = false;                                                                          \
    try {                                                                                          \
      statement;                                                                                   \
    } catch (const std::exception& e_) {                                                           \
      thrown_ = true;                                                                              \
      for (const char* part_ : {__VA_ARGS__})                                                      \
        EXPECT_NE(std::string(e_.what()).find(part_), std::string::npos)                           \
            << "message '" << e_.what() << "' lacks '" << part_ << "'";                           \
    }                                                                                              \
    EXPECT_TRUE(thrown_) << #statement " did not throw";                                           \
  } while (0)

}  // namespace face_reenact::capture::testing
