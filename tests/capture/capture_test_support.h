#pragma once
// Temporary folders and file helpers for the capture tests.
#include <gtest/gtest.h>
#include <stdlib.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "support/temp_dir.h"

namespace face_reenact::capture::testing {

using ::face_reenact::testing::TempDir;  // support/temp_dir.h

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
