// Runs a libFuzzer target's entry point in the normal test suite (no -DFR_FUZZ needed): every
// committed seed, then seeded random mutations of each (bit flips, truncation, extension), so
// the invariants the fuzz target checks are exercised on every build.
#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

namespace {

TEST(FuzzRegression, SeedsAndMutations) {
  const std::filesystem::path dir = FR_FUZZ_SEED_DIR;
  ASSERT_TRUE(std::filesystem::is_directory(dir)) << dir;
  std::vector<std::vector<uint8_t>> seeds;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    std::ifstream in(e.path(), std::ios::binary);
    seeds.emplace_back(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  ASSERT_FALSE(seeds.empty());
  std::mt19937 rng(20240601);
  size_t runs = 0;
  for (const auto& seed : seeds) {
    LLVMFuzzerTestOneInput(seed.data(), seed.size());
    for (int m = 0; m < 3000; ++m) {
      std::vector<uint8_t> x = seed;
      const int kind = static_cast<int>(rng() % 4);
      if (kind == 0 && !x.empty()) {
        x[rng() % x.size()] ^= static_cast<uint8_t>(1u << (rng() % 8));
      } else if (kind == 1 && !x.empty()) {
        x.resize(rng() % x.size());
      } else if (kind == 2) {
        x.resize(x.size() + 1 + rng() % 64, static_cast<uint8_t>(rng()));
      } else if (x.size() > 1) {
        for (int k = 0; k < 4; ++k) x[1 + rng() % (x.size() - 1)] = static_cast<uint8_t>(rng());
      }
      LLVMFuzzerTestOneInput(x.data(), x.size());
      ++runs;
    }
  }
  EXPECT_GT(runs, 0u);
}

}  // namespace
