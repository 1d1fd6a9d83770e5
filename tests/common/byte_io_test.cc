#include "face_reenact/common/byte_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>

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
  EXPECT_FALSE(std::filesystem::exists(path + ".tmp"));
  EXPECT_THROW(read_file_bytes((dir / "missing").string()), Error);
  EXPECT_THROW(write_file_atomic("/proc/definitely/not/writable", a), Error);
}

}  // namespace
}  // namespace face_reenact
