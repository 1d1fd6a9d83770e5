#include "face_reenact/common/byte_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <thread>
#include <vector>

#include "face_reenact/common/error.h"
#include "support/temp_dir.h"

namespace face_reenact {
namespace {

TEST(ByteIo, RoundTripsEveryTypeLittleEndian) {
  ByteWriter w;
  w.u8(0xAB);
  w.u16(0x1234);
  w.u32(0xDEADBEEF);
  w.u64(0x0102030405060708ull);
  w.i32(-7);
  w.f32(1.5f);
  w.f64(-2.25);
  w.str("héllo");
  const auto& b = w.data();
  // Explicit byte order: least significant byte first.
  EXPECT_EQ(b[1], 0x34);
  EXPECT_EQ(b[2], 0x12);
  EXPECT_EQ(b[3], 0xEF);

  ByteReader r(b, "test");
  EXPECT_EQ(r.u8(), 0xAB);
  EXPECT_EQ(r.u16(), 0x1234);
  EXPECT_EQ(r.u32(), 0xDEADBEEFu);
  EXPECT_EQ(r.u64(), 0x0102030405060708ull);
  EXPECT_EQ(r.i32(), -7);
  EXPECT_EQ(r.f32(), 1.5f);
  EXPECT_EQ(r.f64(), -2.25);
  EXPECT_EQ(r.str(), "héllo");
  EXPECT_EQ(r.remaining(), 0u);
}

// Arrays go in one copy on little-endian machines: still least significant byte first, and
// element for element what the scalar writers write.
TEST(ByteIo, ArraysAreLittleEndianLikeTheirElements) {
  const std::vector<float> f{1.5f, -0.0f, std::numeric_limits<float>::infinity(), 3.25e-5f};
  const std::vector<int32_t> i{-7, 0, 1 << 30};
  const std::vector<uint32_t> u{0xDEADBEEFu, 1u};
  ByteWriter arrays, scalars;
  arrays.f32_array(f);
  arrays.i32_array(i);
  arrays.u32_array(u);
  for (float x : f) scalars.f32(x);
  for (int32_t x : i) scalars.i32(x);
  for (uint32_t x : u) scalars.u32(x);
  EXPECT_EQ(arrays.data(), scalars.data());
  EXPECT_EQ(arrays.data()[4 * 7], 0xEF);

  ByteReader r(arrays.data(), "arrays");
  std::vector<float> f2;
  std::vector<int32_t> i2;
  std::vector<uint32_t> u2;
  r.f32_array(f.size(), f2);
  r.i32_array(i.size(), i2);
  r.u32_array(u.size(), u2);
  EXPECT_EQ(f2, f);
  EXPECT_TRUE(std::signbit(f2[1]));
  EXPECT_EQ(i2, i);
  EXPECT_EQ(u2, u);
  EXPECT_EQ(r.remaining(), 0u);
  EXPECT_THROW(r.u32_array(1, u2), Error);
}

TEST(ByteIo, TruncatedReadsThrowWithContext) {
  ByteWriter w;
  w.u16(1);
  ByteReader r(w.data(), "my thing");
  try {
    r.u32();
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("my thing"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos);
  }
}

TEST(ByteIo, HugeLengthsAreRejectedBeforeAllocating) {
  ByteWriter w;
  w.u32(0xFFFFFFFFu);  // a forged string length
  ByteReader r(w.data(), "forged");
  EXPECT_THROW(r.str(), Error);
  ByteReader r2(w.data(), "forged");
  std::vector<float> out;
  EXPECT_THROW(r2.f32_array(size_t(1) << 40, out), Error);
  EXPECT_TRUE(out.empty());
}

TEST(ByteIo, SeekAndSkipAreBounded) {
  std::vector<uint8_t> b(8, 0);
  ByteReader r(b, "b");
  EXPECT_NO_THROW(r.seek(8));
  EXPECT_THROW(r.seek(9), Error);
  r.seek(4);
  EXPECT_THROW(r.skip(5), Error);
}

TEST(ByteIo, AtomicWriteReplacesAndReadsBack) {
  const face_reenact::testing::TempDir tmp("fr-byte-io");
  const std::filesystem::path dir = tmp.path();
  auto path = (dir / "sub" / "file.bin").string();
  std::vector<uint8_t> a{1, 2, 3}, b{4, 5};
  write_file_atomic(path, a);
  EXPECT_EQ(read_file_bytes(path), a);
  write_file_atomic(path, b);
  EXPECT_EQ(read_file_bytes(path), b);
  EXPECT_THROW(read_file_bytes((dir / "missing").string()), Error);
  EXPECT_THROW(write_file_atomic("/proc/definitely/not/writable", a), Error);

  // Writers of the same file at once (test processes filling one cache) each rename a whole file
  // of their own: what is left is one of them, and no temporary file.
  std::vector<uint8_t> big_a(1 << 20, 0xAA), big_b(1 << 20, 0xBB);
  std::thread other([&] {
    for (int k = 0; k < 20; ++k) write_file_atomic(path, big_b);
  });
  for (int k = 0; k < 20; ++k) write_file_atomic(path, big_a);
  other.join();
  const std::vector<uint8_t> left = read_file_bytes(path);
  EXPECT_TRUE(left == big_a || left == big_b);
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir / "sub")) files += entry.is_regular_file();
  EXPECT_EQ(files, 1) << "a temporary file was left beside " << path;
}

}  // namespace
}  // namespace face_reenact
