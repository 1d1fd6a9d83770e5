#include "face_reenact/common/byte_io.h"

#include <unistd.h>

#include <atomic>
#include <bit>
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

// Arrays in one copy where the machine is little-endian (every machine this runs on; the
// element-wise path stays for the others): 16 million floats take ~10 ms instead of ~100.
template <typename T>
void put_array_le(std::vector<uint8_t>& out, std::span<const T> v) {
  static_assert(sizeof(T) == 4);
  if constexpr (std::endian::native == std::endian::little) {
    const auto* p = reinterpret_cast<const uint8_t*>(v.data());
    out.insert(out.end(), p, p + v.size_bytes());
  } else {
    for (T x : v) {
      uint32_t u;
      std::memcpy(&u, &x, 4);
      for (int i = 0; i < 4; ++i) out.push_back(static_cast<uint8_t>(u >> (8 * i)));
    }
  }
}

template <typename T>
void get_array_le(std::span<const uint8_t> in, std::vector<T>& out) {
  static_assert(sizeof(T) == 4);
  out.resize(in.size() / 4);
  if constexpr (std::endian::native == std::endian::little) {
    std::memcpy(out.data(), in.data(), in.size());
  } else {
    for (size_t i = 0; i < out.size(); ++i) {
      uint32_t u = 0;
      for (int b = 0; b < 4; ++b) u |= uint32_t(in[4 * i + b]) << (8 * b);
      std::memcpy(&out[i], &u, 4);
    }
  }
}

void ByteWriter::f32_array(std::span<const float> v) { put_array_le(bytes_, v); }
void ByteWriter::i32_array(std::span<const int32_t> v) { put_array_le(bytes_, v); }
void ByteWriter::u32_array(std::span<const uint32_t> v) { put_array_le(bytes_, v); }

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
  get_array_le(bytes(4 * n), out);
}

void ByteReader::i32_array(size_t n, std::vector<int32_t>& out) {
  if (n > remaining() / 4) fail("array of " + std::to_string(n) + " ints does not fit");
  get_array_le(bytes(4 * n), out);
}

void ByteReader::u32_array(size_t n, std::vector<uint32_t>& out) {
  if (n > remaining() / 4) fail("array of " + std::to_string(n) + " ints does not fit");
  get_array_le(bytes(4 * n), out);
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
  // A name of this process and call, so that two processes writing the same file at once (test
  // processes filling one cache) each rename a whole file of their own.
  static std::atomic<uint64_t> calls{0};
  const std::string tmp = path + ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(calls++);
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
