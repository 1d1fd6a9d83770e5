#include "face_reenact/common/checksum.h"

#include <sodium.h>
#include <zlib.h>

#include <fstream>
#include <vector>

#include "face_reenact/common/error.h"

namespace face_reenact {
namespace {

std::string to_hex(const unsigned char* digest, size_t n) {
  static const char* kHex = "0123456789abcdef";
  std::string s;
  s.reserve(2 * n);
  for (size_t i = 0; i < n; ++i) {
    s.push_back(kHex[digest[i] >> 4]);
    s.push_back(kHex[digest[i] & 15]);
  }
  return s;
}

void ensure_sodium() {
  if (sodium_init() < 0) throw Error("libsodium failed to initialise");
}

}  // namespace

uint32_t crc32(std::span<const uint8_t> bytes) {
  uLong c = ::crc32(0L, Z_NULL, 0);
  // zlib takes uInt lengths: feed large ranges in chunks.
  size_t off = 0;
  while (off < bytes.size()) {
    size_t n = std::min<size_t>(bytes.size() - off, 1u << 30);
    c = ::crc32(c, bytes.data() + off, static_cast<uInt>(n));
    off += n;
  }
  return static_cast<uint32_t>(c);
}

std::string sha256_hex(std::span<const uint8_t> bytes) {
  ensure_sodium();
  unsigned char digest[crypto_hash_sha256_BYTES];
  crypto_hash_sha256(digest, bytes.data(), bytes.size());
  return to_hex(digest, sizeof digest);
}

std::string sha256_file_hex(const std::string& path) {
  ensure_sodium();
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open '" + path + "' to hash it");
  crypto_hash_sha256_state st;
  crypto_hash_sha256_init(&st);
  std::vector<char> buf(1 << 20);
  while (in) {
    in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
    auto got = in.gcount();
    if (got > 0) crypto_hash_sha256_update(&st, reinterpret_cast<unsigned char*>(buf.data()),
                                           static_cast<unsigned long long>(got));
  }
  unsigned char digest[crypto_hash_sha256_BYTES];
  crypto_hash_sha256_final(&st, digest);
  return to_hex(digest, sizeof digest);
}

}  // namespace face_reenact
