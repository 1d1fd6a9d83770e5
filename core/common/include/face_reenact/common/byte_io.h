#pragma once
// Explicit little-endian serialisation used by every binary format of the project (model file,
// recordings, wire protocol). Readers never trust a length: every read is bounds-checked and
// fails with face_reenact::Error instead of reading past the buffer.
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace face_reenact {

class ByteWriter {
 public:
  void u8(uint8_t v) { bytes_.push_back(v); }
  void u16(uint16_t v) { put_le(v); }
  void u32(uint32_t v) { put_le(v); }
  void u64(uint64_t v) { put_le(v); }
  void i32(int32_t v) { put_le(static_cast<uint32_t>(v)); }
  void f32(float v) {
    uint32_t u;
    std::memcpy(&u, &v, 4);
    put_le(u);
  }
  void f64(double v) {
    uint64_t u;
    std::memcpy(&u, &v, 8);
    put_le(u);
  }
  void bytes(std::span<const uint8_t> b) { bytes_.insert(bytes_.end(), b.begin(), b.end()); }
  // A length-prefixed (u32) UTF-8 string.
  void str(std::string_view s);
  void f32_array(std::span<const float> v);
  void i32_array(std::span<const int32_t> v);
  void u32_array(std::span<const uint32_t> v);
  // Overwrites 4 bytes at `offset` (for patching sizes and checksums after the fact).
  void patch_u32(size_t offset, uint32_t v);
  void patch_u64(size_t offset, uint64_t v);

  size_t size() const { return bytes_.size(); }
  const std::vector<uint8_t>& data() const { return bytes_; }
  std::vector<uint8_t> take() { return std::move(bytes_); }

 private:
  template <typename T>
  void put_le(T v) {
    for (size_t i = 0; i < sizeof(T); ++i) bytes_.push_back(static_cast<uint8_t>(v >> (8 * i)));
  }
  std::vector<uint8_t> bytes_;
};

class ByteReader {
 public:
  // `what` names the thing being parsed, for error messages.
  ByteReader(std::span<const uint8_t> data, std::string what)
      : data_(data), what_(std::move(what)) {}

  uint8_t u8();
  uint16_t u16() { return get_le<uint16_t>(); }
  uint32_t u32() { return get_le<uint32_t>(); }
  uint64_t u64() { return get_le<uint64_t>(); }
  int32_t i32() { return static_cast<int32_t>(get_le<uint32_t>()); }
  float f32();
  double f64();
  std::span<const uint8_t> bytes(size_t n);
  // A u32 length-prefixed string of at most max_len bytes.
  std::string str(size_t max_len = 4096);
  // Reads n floats into out (n checked against what is left before any allocation).
  void f32_array(size_t n, std::vector<float>& out);
  void i32_array(size_t n, std::vector<int32_t>& out);
  void u32_array(size_t n, std::vector<uint32_t>& out);

  void seek(size_t offset);
  void skip(size_t n);
  size_t offset() const { return pos_; }
  size_t remaining() const { return data_.size() - pos_; }
  const std::string& what() const { return what_; }
  [[noreturn]] void fail(const std::string& msg) const;

 private:
  void need(size_t n) const;
  template <typename T>
  T get_le() {
    need(sizeof(T));
    T v = 0;
    for (size_t i = 0; i < sizeof(T); ++i) v |= static_cast<T>(static_cast<T>(data_[pos_ + i]) << (8 * i));
    pos_ += sizeof(T);
    return v;
  }
  std::span<const uint8_t> data_;
  size_t pos_ = 0;
  std::string what_;
};

// Whole-file helpers with clear errors (path in the message).
std::vector<uint8_t> read_file_bytes(const std::string& path, size_t max_bytes = size_t(1) << 31);
// Writes atomically: to a temporary file beside `path`, then rename, so a crash or a full disk
// never leaves a half-written file where a good one was.
void write_file_atomic(const std::string& path, std::span<const uint8_t> bytes);

}  // namespace face_reenact
