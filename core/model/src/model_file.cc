#include "face_reenact/model/model_file.h"

#include <bit>
#include <cstring>
#include <map>
#include <nlohmann/json.hpp>

#include "face_reenact/common/byte_io.h"
#include "face_reenact/common/checksum.h"
#include "face_reenact/common/error.h"

namespace face_reenact {
namespace {

// Layout (all little-endian), see docs/face-model-format.md:
//   0  char[8]  magic "FRMODEL\0"
//   8  u32      format version
//  12  u32      byte-order marker 0x01020304 (reads 0x04030201 on a big-endian writer's file)
//  16  u32      section count S
//  20  S x { char[4] tag, u32 reserved(0), u64 offset, u64 size, u32 crc32, u32 reserved(0) }
//  ..  u32      CRC-32 of bytes [0, 20 + 32 S)
//  then the sections, each 8-byte aligned.
constexpr char kMagic[8] = {'F', 'R', 'M', 'O', 'D', 'E', 'L', '\0'};
constexpr uint32_t kByteOrderMarker = 0x01020304u;
constexpr size_t kSectionEntryBytes = 32;
constexpr uint32_t kMaxSections = 64;
// Bounds that keep a forged header from asking for absurd allocations.
constexpr uint64_t kMaxVertices = 1u << 22;
constexpr uint64_t kMaxTriangles = 1u << 23;
constexpr uint64_t kMaxComponents = 4096;

using Tag = std::array<char, 4>;
constexpr Tag kMeta{'M', 'E', 'T', 'A'}, kVert{'V', 'E', 'R', 'T'}, kTris{'T', 'R', 'I', 'S'},
    kIden{'I', 'D', 'E', 'N'}, kExpr{'E', 'X', 'P', 'R'}, kAlbd{'A', 'L', 'B', 'D'},
    kLmks{'L', 'M', 'K', 'S'};

std::string tag_str(const Tag& t) { return std::string(t.data(), 4); }

void write_matrix(ByteWriter& w, const Eigen::MatrixXf& m) {
  // Column-major, one basis vector after another.
  w.f32_array(std::span<const float>(m.data(), static_cast<size_t>(m.size())));
}

void write_vector(ByteWriter& w, const Eigen::VectorXf& v) {
  w.f32_array(std::span<const float>(v.data(), static_cast<size_t>(v.size())));
}

void read_floats(ByteReader& r, float* dst, size_t n) {
  if (n > r.remaining() / 4) r.fail("float array of " + std::to_string(n) + " does not fit");
  auto b = r.bytes(4 * n);
  if constexpr (std::endian::native == std::endian::little) {
    std::memcpy(dst, b.data(), b.size());
  } else {
    for (size_t i = 0; i < n; ++i) {
      uint32_t u = uint32_t(b[4 * i]) | uint32_t(b[4 * i + 1]) << 8 | uint32_t(b[4 * i + 2]) << 16 |
                   uint32_t(b[4 * i + 3]) << 24;
      std::memcpy(dst + i, &u, 4);
    }
  }
}

Eigen::MatrixXf read_matrix(ByteReader& r, uint64_t rows, uint64_t cols) {
  if (cols != 0 && rows > (r.remaining() / 4) / cols) r.fail("matrix does not fit in its section");
  Eigen::MatrixXf m(static_cast<Eigen::Index>(rows), static_cast<Eigen::Index>(cols));
  read_floats(r, m.data(), static_cast<size_t>(rows * cols));
  return m;
}

Eigen::VectorXf read_vector(ByteReader& r, uint64_t n) {
  if (n > r.remaining() / 4) r.fail("vector does not fit in its section");
  Eigen::VectorXf v(static_cast<Eigen::Index>(n));
  read_floats(r, v.data(), static_cast<size_t>(n));
  return v;
}

std::vector<std::string> read_names(ByteReader& r, uint64_t n) {
  std::vector<std::string> names;
  for (uint64_t i = 0; i < n; ++i) names.push_back(r.str(256));
  return names;
}

void check_count(const ByteReader& r, uint64_t n, uint64_t max, const char* what) {
  if (n > max) r.fail(std::string(what) + " count " + std::to_string(n) + " exceeds the limit " + std::to_string(max));
}

}  // namespace

std::vector<uint8_t> serialize_face_model(const FaceModel& m) {
  std::string why;
  if (!m.IsValid(&why)) throw Error("refusing to save an invalid face model: " + why);
  const uint32_t n = static_cast<uint32_t>(m.num_vertices());
  std::vector<std::pair<Tag, std::vector<uint8_t>>> sections;

  {  // META: provenance as JSON, for people and tools.
    nlohmann::json j = {{"units", m.units},
                        {"source", m.source},
                        {"source_sha256", m.source_sha256},
                        {"identity_samples", m.identity_samples},
                        {"build_seed", m.build_seed},
                        {"identity_explained_variance", m.identity_explained_variance},
                        {"builder", m.builder},
                        {"build_options", m.build_options}};
    ByteWriter w;
    w.str(j.dump());
    sections.push_back({kMeta, w.take()});
  }
  {  // VERT: N, per-vertex part / mirror / base index, mean shape, mean albedo.
    ByteWriter w;
    w.u32(n);
    for (auto p : m.vertex_part) w.u8(static_cast<uint8_t>(p));
    while (w.size() % 4) w.u8(0);
    w.i32_array(m.mirror_vertex);
    w.i32_array(m.base_vertex);
    write_vector(w, m.mean_shape);
    write_vector(w, m.mean_albedo);
    sections.push_back({kVert, w.take()});
  }
  {  // TRIS: T, indices, corner UVs.
    ByteWriter w;
    w.u32(static_cast<uint32_t>(m.triangles.size()));
    for (auto& t : m.triangles)
      for (int v : t) w.i32(v);
    for (auto& uv : m.corner_uvs) {
      w.f32(uv[0]);
      w.f32(uv[1]);
    }
    sections.push_back({kTris, w.take()});
  }
  {  // IDEN: K, explained variance, sigma, basis.
    ByteWriter w;
    w.u32(static_cast<uint32_t>(m.num_identity()));
    write_vector(w, m.identity_sigma);
    write_matrix(w, m.identity_basis);
    sections.push_back({kIden, w.take()});
  }
  {  // EXPR: K, names, basis.
    ByteWriter w;
    w.u32(static_cast<uint32_t>(m.num_expression()));
    for (auto& s : m.expression_names) w.str(s);
    write_matrix(w, m.expression_basis);
    sections.push_back({kExpr, w.take()});
  }
  {  // ALBD: K, names, sigma, basis.
    ByteWriter w;
    w.u32(static_cast<uint32_t>(m.num_albedo()));
    for (auto& s : m.albedo_names) w.str(s);
    write_vector(w, m.albedo_sigma);
    write_matrix(w, m.albedo_basis);
    sections.push_back({kAlbd, w.take()});
  }
  {  // LMKS: count, (ibug, vertex, flags).
    ByteWriter w;
    w.u32(static_cast<uint32_t>(m.landmarks.size()));
    for (auto& l : m.landmarks) {
      w.i32(l.ibug_index);
      w.i32(l.vertex);
      w.u32(l.flags);
    }
    sections.push_back({kLmks, w.take()});
  }

  ByteWriter out;
  out.bytes(std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(kMagic), 8));
  out.u32(kFaceModelFormatVersion);
  out.u32(kByteOrderMarker);
  out.u32(static_cast<uint32_t>(sections.size()));
  const size_t table_end = 20 + kSectionEntryBytes * sections.size();
  uint64_t offset = (table_end + 4 + 7) & ~uint64_t(7);
  for (auto& [tag, bytes] : sections) {
    out.bytes(std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(tag.data()), 4));
    out.u32(0);
    out.u64(offset);
    out.u64(bytes.size());
    out.u32(crc32(bytes));
    out.u32(0);
    offset = (offset + bytes.size() + 7) & ~uint64_t(7);
  }
  out.u32(crc32(std::span<const uint8_t>(out.data().data(), table_end)));
  for (auto& [tag, bytes] : sections) {
    while (out.size() % 8) out.u8(0);
    out.bytes(bytes);
  }
  return out.take();
}

FaceModel parse_face_model(std::span<const uint8_t> bytes, const std::string& what) {
  ByteReader hdr(bytes, what);
  auto magic = hdr.bytes(8);
  if (std::memcmp(magic.data(), kMagic, 8) != 0) hdr.fail("not a face-reenact model file (wrong magic)");
  const uint32_t version = hdr.u32();
  const uint32_t marker = hdr.u32();
  if (marker != kByteOrderMarker) hdr.fail("unsupported byte order marker");
  if (version != kFaceModelFormatVersion)
    hdr.fail("format version " + std::to_string(version) + " is not supported (this program reads version " +
             std::to_string(kFaceModelFormatVersion) + "); rebuild it with 'face-reenact model build'");
  const uint32_t count = hdr.u32();
  if (count > kMaxSections) hdr.fail("implausible section count " + std::to_string(count));
  struct Entry {
    uint64_t offset, size;
    uint32_t crc;
  };
  std::map<std::string, Entry> table;
  for (uint32_t i = 0; i < count; ++i) {
    auto t = hdr.bytes(4);
    Tag tag{char(t[0]), char(t[1]), char(t[2]), char(t[3])};
    hdr.u32();
    Entry e{hdr.u64(), hdr.u64(), hdr.u32()};
    hdr.u32();
    if (e.offset > bytes.size() || e.size > bytes.size() - e.offset)
      hdr.fail("section " + tag_str(tag) + " lies beyond the end of the file (truncated?)");
    table[tag_str(tag)] = e;
  }
  const size_t table_end = hdr.offset();
  const uint32_t header_crc = hdr.u32();
  if (header_crc != crc32(bytes.subspan(0, table_end))) hdr.fail("header checksum mismatch (corrupt file)");

  auto section = [&](const Tag& tag) {
    auto it = table.find(tag_str(tag));
    if (it == table.end()) hdr.fail("missing section " + tag_str(tag));
    auto s = bytes.subspan(it->second.offset, it->second.size);
    if (crc32(s) != it->second.crc) hdr.fail("section " + tag_str(tag) + " checksum mismatch (corrupt file)");
    return ByteReader(s, what + " section " + tag_str(tag));
  };

  FaceModel m;
  {
    auto r = section(kMeta);
    nlohmann::json j = nlohmann::json::parse(r.str(1 << 20), nullptr, /*allow_exceptions=*/false);
    if (!j.is_object()) r.fail("metadata is not a JSON object");
    m.units = j.value("units", "");
    m.source = j.value("source", "");
    m.source_sha256 = j.value("source_sha256", "");
    m.identity_samples = j.value("identity_samples", uint64_t(0));
    m.build_seed = j.value("build_seed", uint64_t(0));
    m.identity_explained_variance = j.value("identity_explained_variance", 0.f);
    m.builder = j.value("builder", "");
    m.build_options = j.value("build_options", "");
    if (m.units != "metres") r.fail("unsupported units '" + m.units + "'");
  }
  uint32_t n;
  {
    auto r = section(kVert);
    n = r.u32();
    check_count(r, n, kMaxVertices, "vertex");
    auto parts = r.bytes(n);
    m.vertex_part.resize(n);
    for (uint32_t i = 0; i < n; ++i) {
      if (parts[i] >= kNumFaceParts) r.fail("unknown vertex part " + std::to_string(parts[i]));
      m.vertex_part[i] = static_cast<FacePart>(parts[i]);
    }
    r.skip((4 - (4 + n) % 4) % 4);
    r.i32_array(n, m.mirror_vertex);
    r.i32_array(n, m.base_vertex);
    m.mean_shape = read_vector(r, 3ull * n);
    m.mean_albedo = read_vector(r, 3ull * n);
  }
  {
    auto r = section(kTris);
    uint32_t t = r.u32();
    check_count(r, t, kMaxTriangles, "triangle");
    if (t > r.remaining() / 36) r.fail("triangle data truncated");
    m.triangles.resize(t);
    for (auto& tri : m.triangles)
      for (auto& v : tri) v = r.i32();
    m.corner_uvs.resize(3ull * t);
    for (auto& uv : m.corner_uvs) {
      uv[0] = r.f32();
      uv[1] = r.f32();
    }
  }
  {
    auto r = section(kIden);
    uint32_t k = r.u32();
    check_count(r, k, kMaxComponents, "identity component");
    m.identity_sigma = read_vector(r, k);
    m.identity_basis = read_matrix(r, 3ull * n, k);
  }
  {
    auto r = section(kExpr);
    uint32_t k = r.u32();
    check_count(r, k, kMaxComponents, "expression component");
    m.expression_names = read_names(r, k);
    m.expression_basis = read_matrix(r, 3ull * n, k);
  }
  {
    auto r = section(kAlbd);
    uint32_t k = r.u32();
    check_count(r, k, kMaxComponents, "albedo component");
    m.albedo_names = read_names(r, k);
    m.albedo_sigma = read_vector(r, k);
    m.albedo_basis = read_matrix(r, 3ull * n, k);
  }
  {
    auto r = section(kLmks);
    uint32_t k = r.u32();
    check_count(r, k, 68, "landmark");
    for (uint32_t i = 0; i < k; ++i) {
      ModelLandmark l;
      l.ibug_index = r.i32();
      l.vertex = r.i32();
      uint32_t flags = r.u32();
      if (flags > 3) r.fail("unknown landmark flags");
      l.flags = static_cast<uint8_t>(flags);
      m.landmarks.push_back(l);
    }
  }
  std::string why;
  if (!m.IsValid(&why)) throw Error(what + ": inconsistent model: " + why);
  return m;
}

void save_face_model(const FaceModel& model, const std::string& path) {
  write_file_atomic(path, serialize_face_model(model));
}

FaceModel load_face_model(const std::string& path) {
  return parse_face_model(read_file_bytes(path), "face model '" + path + "'");
}

}  // namespace face_reenact
