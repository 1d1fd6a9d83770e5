#pragma once
// Hashes used by file formats (CRC-32 per section) and by supply-chain checks (SHA-256 of the
// pinned face-data wheel).
#include <cstdint>
#include <span>
#include <string>

namespace face_reenact {

uint32_t crc32(std::span<const uint8_t> bytes);
// Lower-case hex SHA-256 of a byte range / of a file's content.
std::string sha256_hex(std::span<const uint8_t> bytes);
std::string sha256_file_hex(const std::string& path);

}  // namespace face_reenact
