#pragma once
// The pre-shared 32-byte key that authenticates and encrypts the expression stream, and its key
// file (docs/stream-protocol.md, "Key file"):
//
//   face-reenact-stream-key v1
//   <64 lower-case hex digits>
//
// A key file must be a regular file owned by the current user (or root) and not readable or
// writable by group or others, like ssh's private keys; anything else is refused with a message
// that says how to fix it.
#include <array>
#include <cstdint>
#include <string>

namespace face_reenact::stream {

inline constexpr size_t kKeySize = 32;

class StreamKey {
 public:
  StreamKey() = default;
  explicit StreamKey(const std::array<uint8_t, kKeySize>& bytes) : bytes_(bytes) {}
  StreamKey(const StreamKey&) = default;
  StreamKey& operator=(const StreamKey&) = default;
  ~StreamKey();  // wipes the key bytes

  // A fresh random key (libsodium's CSPRNG).
  static StreamKey generate();

  const std::array<uint8_t, kKeySize>& bytes() const { return bytes_; }
  // A short public identifier of the key (16 hex digits of a BLAKE2b hash) so two machines can
  // check they hold the same key without showing it.
  std::string fingerprint() const;

 private:
  std::array<uint8_t, kKeySize> bytes_{};
};

struct KeyFileOptions {
  bool overwrite = false;  // replace an existing file (atomically); otherwise refuse
};

// Writes `key` to `path` with mode 0600. Without overwrite the file is created with O_EXCL, so
// an existing key is never replaced; with it, a temporary file is renamed over the old one.
// Throws face_reenact::Error with the path and the reason.
void write_key_file(const std::string& path, const StreamKey& key, const KeyFileOptions& options = {});

// Reads a key file, refusing files that group/others can access, files owned by someone else,
// non-regular files, and malformed content. Throws face_reenact::Error.
StreamKey load_key_file(const std::string& path);

// The text of a key file for `key` (used by write_key_file; exposed for tests).
std::string format_key_file(const StreamKey& key);
// Parses key file text; throws face_reenact::Error naming `what`.
StreamKey parse_key_file(const std::string& text, const std::string& what);

}  // namespace face_reenact::stream
