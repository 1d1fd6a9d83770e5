#include "face_reenact/stream/stream_key.h"

#include <fcntl.h>
#include <sodium.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <string_view>

#include "face_reenact/common/error.h"

namespace face_reenact::stream {
namespace {

constexpr std::string_view kKeyFileHeader = "face-reenact-stream-key v1";
constexpr size_t kMaxKeyFileSize = 4096;

void ensure_sodium() {
  if (sodium_init() < 0) throw Error("libsodium failed to initialise");
}


// Closes a descriptor on scope exit.
struct FdCloser {
  int fd = -1;
  ~FdCloser() {
    if (fd >= 0) ::close(fd);
  }
};

void write_all(int fd, const std::string& text, const std::string& path) {
  size_t done = 0;
  while (done < text.size()) {
    ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw Error("key file '" + path + "': write failed: " + errno_text(errno));
    }
    done += static_cast<size_t>(n);
  }
  if (::fsync(fd) != 0) throw Error("key file '" + path + "': fsync failed: " + errno_text(errno));
}

}  // namespace

StreamKey::~StreamKey() { sodium_memzero(bytes_.data(), bytes_.size()); }

StreamKey StreamKey::generate() {
  ensure_sodium();
  std::array<uint8_t, kKeySize> bytes;
  randombytes_buf(bytes.data(), bytes.size());
  StreamKey key(bytes);
  sodium_memzero(bytes.data(), bytes.size());
  return key;
}

std::string StreamKey::fingerprint() const {
  ensure_sodium();
  // Keyed with a fixed context string so the fingerprint is not a plain hash of the key.
  static constexpr char kContext[] = "face-reenact key fingerprint";
  unsigned char digest[8];
  crypto_generichash(digest, sizeof(digest), bytes_.data(), bytes_.size(),
                     reinterpret_cast<const unsigned char*>(kContext), sizeof(kContext) - 1);
  char hex[2 * sizeof(digest) + 1];
  sodium_bin2hex(hex, sizeof(hex), digest, sizeof(digest));
  return hex;
}

std::string format_key_file(const StreamKey& key) {
  ensure_sodium();
  char hex[2 * kKeySize + 1];
  sodium_bin2hex(hex, sizeof(hex), key.bytes().data(), kKeySize);
  std::string text = std::string(kKeyFileHeader) + "\n" + hex + "\n";
  sodium_memzero(hex, sizeof(hex));
  return text;
}

StreamKey parse_key_file(const std::string& text, const std::string& what) {
  ensure_sodium();
  auto bad = [&](const std::string& why) {
    return Error("key file '" + what + "': " + why + " (expected the two lines written by "
                 "`face-reenact keygen`: '" + std::string(kKeyFileHeader) + "' and 64 hex digits)");
  };
  if (text.size() > kMaxKeyFileSize) throw bad("file is too large to be a key file");
  const size_t eol = text.find('\n');
  if (eol == std::string::npos) throw bad("missing header line");
  std::string_view header(text.data(), eol);
  if (!header.empty() && header.back() == '\r') header.remove_suffix(1);
  if (header != kKeyFileHeader) throw bad("unrecognised header line");
  std::string_view body(text.data() + eol + 1, text.size() - eol - 1);
  while (!body.empty() && (body.back() == '\n' || body.back() == '\r' || body.back() == ' '))
    body.remove_suffix(1);
  if (body.size() != 2 * kKeySize)
    throw bad("key line has " + std::to_string(body.size()) + " characters, not " +
              std::to_string(2 * kKeySize));
  std::array<uint8_t, kKeySize> bytes;
  size_t decoded = 0;
  if (sodium_hex2bin(bytes.data(), bytes.size(), body.data(), body.size(), nullptr, &decoded,
                     nullptr) != 0 ||
      decoded != kKeySize)
    throw bad("key line is not hexadecimal");
  StreamKey key(bytes);
  sodium_memzero(bytes.data(), bytes.size());
  return key;
}

void write_key_file(const std::string& path, const StreamKey& key, const KeyFileOptions& options) {
  const std::string text = format_key_file(key);
  if (!options.overwrite) {
    FdCloser f{::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0600)};
    if (f.fd < 0) {
      if (errno == EEXIST)
        throw Error("key file '" + path + "' already exists; refusing to overwrite a key (use --force)");
      throw Error("cannot create key file '" + path + "': " + errno_text(errno));
    }
    // The umask can only remove bits, but be explicit: the key is for its owner only.
    if (::fchmod(f.fd, 0600) != 0)
      throw Error("key file '" + path + "': chmod failed: " + errno_text(errno));
    write_all(f.fd, text, path);
    return;
  }
  // Replace atomically: a new private file beside the old one, then rename over it.
  const std::filesystem::path target(path);
  std::string tmp = (target.parent_path() / ("." + target.filename().string() + ".tmp-XXXXXX")).string();
  if (target.parent_path().empty()) tmp = "." + target.filename().string() + ".tmp-XXXXXX";
  FdCloser f{::mkostemp(tmp.data(), O_CLOEXEC)};  // mkostemp creates with mode 0600 and O_EXCL
  if (f.fd < 0) throw Error("cannot create a temporary key file beside '" + path + "': " + errno_text(errno));
  try {
    if (::fchmod(f.fd, 0600) != 0) throw Error("key file '" + path + "': chmod failed: " + errno_text(errno));
    write_all(f.fd, text, path);
    if (::rename(tmp.c_str(), path.c_str()) != 0)
      throw Error("cannot replace key file '" + path + "': " + errno_text(errno));
  } catch (...) {
    ::unlink(tmp.c_str());
    throw;
  }
}

StreamKey load_key_file(const std::string& path) {
  FdCloser f{::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK)};
  if (f.fd < 0) {
    if (errno == ELOOP) throw Error("key file '" + path + "' is a symbolic link; refusing it");
    throw Error("cannot open key file '" + path + "': " + errno_text(errno));
  }
  struct stat st;
  if (::fstat(f.fd, &st) != 0) throw Error("cannot stat key file '" + path + "': " + errno_text(errno));
  if (!S_ISREG(st.st_mode)) throw Error("key file '" + path + "' is not a regular file");
  const uid_t me = ::geteuid();
  if (st.st_uid != me && st.st_uid != 0)
    throw Error("key file '" + path + "' is owned by uid " + std::to_string(st.st_uid) +
                ", not by you (uid " + std::to_string(me) + "); refusing it");
  if ((st.st_mode & 077) != 0) {
    char mode[8];
    std::snprintf(mode, sizeof(mode), "%04o", static_cast<unsigned>(st.st_mode & 07777));
    throw Error("key file '" + path + "' has permissions " + mode +
                ": it is accessible by group or others, so the key may be known to them; "
                "refusing it (run: chmod 600 '" + path + "', and consider a new key)");
  }
  if (st.st_size > static_cast<off_t>(kMaxKeyFileSize))
    throw Error("key file '" + path + "': file is too large to be a key file");
  std::string text(static_cast<size_t>(st.st_size), '\0');
  size_t done = 0;
  while (done < text.size()) {
    ssize_t n = ::read(f.fd, text.data() + done, text.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw Error("cannot read key file '" + path + "': " + errno_text(errno));
    }
    if (n == 0) break;
    done += static_cast<size_t>(n);
  }
  text.resize(done);
  try {
    StreamKey key = parse_key_file(text, path);
    sodium_memzero(text.data(), text.size());
    return key;
  } catch (...) {
    sodium_memzero(text.data(), text.size());
    throw;
  }
}

}  // namespace face_reenact::stream
