#include "face_reenact/common/byte_io.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <system_error>

#include "face_reenact/common/error.h"

namespace face_reenact {

void ByteWriter::str(std::string_view s) {
  u32(static_cast<uint32_t>(s.size()));
  bytes_.insert(bytes_.end(), s.begin(), s.end());
}

void ByteWriter::f32_array(std::span<const float> v) {
  for (float x : v) f32(x);
}

void ByteWriter::i32_array(std::span<const int32_t> v) {
  for (int32_t x : v) i32(x);
}

void ByteWriter::patch_u32(size_t offset, uint32_t v) {
  if (offset + 4 > bytes_.size()) throw Error("ByteWriter::patch_u32 out of range");
  for (size_t i = 0; i < 4; ++i) bytes_[offset + i] = static_cast<uint8_t>(v >> (8 * i));
}

void ByteWriter::patch_u64(size_t offset, uint64_t v) {
  if (offset + 8 > bytes_.size()) throw Error("ByteWriter::patch_u64 out of range");
  for (size_t i = 0; i < 8; ++i) bytes_[offset + i] = static_cast<uint8_t>(v >> (8 * i));
}

void ByteReader::fail(const std::string& msg) const {
  throw Error(what_ + ": " + msg + " (at byte " + std::to_string(pos_) + ")");
}

void ByteReader::need(size_t n) const {
  if (n > data_.size() - pos_) fail("truncated: needs " + std::to_string(n) + " more bytes, " +
                                    std::to_string(data_.size() - pos_) + " left");
}

uint8_t ByteReader::u8() {
  need(1);
  return data_[pos_++];
}

float ByteReader::f32() {
  uint32_t u = u32();
  float v;
  std::memcpy(&v, &u, 4);
  return v;
}

double ByteReader::f64() {
  uint64_t u = u64();
  double v;
  std::memcpy(&v, &u, 8);
  return v;
}

std::span<const uint8_t> ByteReader::bytes(size_t n) {
  need(n);
  auto s = data_.subspan(pos_, n);
  pos_ += n;
  return s;
}

std::string ByteReader::str(size_t max_len) {
  uint32_t n = u32();
  if (n > max_len) fail("string length " + std::to_string(n) + " exceeds limit " + std::to_string(max_len));
  auto b = bytes(n);
  return std::string(b.begin(), b.end());
}

void ByteReader::f32_array(size_t n, std::vector<float>& out) {
  if (n > remaining() / 4) fail("array of " + std::to_string(n) + " floats does not fit");
  out.resize(n);
  for (size_t i = 0; i < n; ++i) out[i] = f32();
}

void ByteReader::i32_array(size_t n, std::vector<int32_t>& out) {
  if (n > remaining() / 4) fail("array of " + std::to_string(n) + " ints does not fit");
  out.resize(n);
  for (size_t i = 0; i < n; ++i) out[i] = i32();
}

void ByteReader::seek(size_t offset) {
  if (offset > data_.size()) fail("seek to " + std::to_string(offset) + " past the end");
  pos_ = offset;
}

void ByteReader::skip(size_t n) {
  need(n);
  pos_ += n;
}

std::vector<uint8_t> read_file_bytes(const std::string& path, size_t max_bytes) {
  std::error_code ec;
  auto size = std::filesystem::file_size(path, ec);
  if (ec) throw Error("cannot read '" + path + "': " + ec.message());
  if (size > max_bytes) throw Error("'" + path + "' is too large (" + std::to_string(size) + " bytes)");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open '" + path + "'");
  std::vector<uint8_t> bytes(size);
  in.read(reinterpret_cast<char*>(bytes.data()), static_cast<std::streamsize>(size));
  if (static_cast<size_t>(in.gcount()) != size) throw Error("short read from '" + path + "'");
  return bytes;
}

void write_file_atomic(const std::string& path, std::span<const uint8_t> bytes) {
  namespace fs = std::filesystem;
  fs::path target(path);
  if (target.has_parent_path()) {
    std::error_code ec;
    fs::create_directories(target.parent_path(), ec);
    if (ec) throw Error("cannot create folder '" + target.parent_path().string() + "': " + ec.message());
  }
  std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw Error("cannot write '" + tmp + "'");
    out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
    out.flush();
    if (!out) {
      out.close();
      std::remove(tmp.c_str());
      throw Error("write to '" + tmp + "' failed (disk full?)");
    }
  }
  std::error_code ec;
  fs::rename(tmp, target, ec);
  if (ec) {
    std::remove(tmp.c_str());
    throw Error("cannot move '" + tmp + "' to '" + path + "': " + ec.message());
  }
}

}  // namespace face_reenact
