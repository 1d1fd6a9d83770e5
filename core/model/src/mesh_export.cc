#include "face_reenact/model/mesh_export.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

#include "face_reenact/common/paths.h"
#include "face_reenact/common/byte_io.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/srgb.h"

namespace face_reenact {
namespace {

struct Selection {
  std::vector<int32_t> old_to_new;  // -1 for dropped vertices
  std::vector<int32_t> kept_vertices;
  std::vector<int32_t> kept_triangles;
};

Selection select(const FaceModel& m, const std::vector<FacePart>& parts) {
  Selection s;
  const int n = m.num_vertices();
  std::vector<bool> keep(n, parts.empty());
  if (!parts.empty())
    for (int v = 0; v < n; ++v) keep[v] = std::find(parts.begin(), parts.end(), m.vertex_part[v]) != parts.end();
  s.old_to_new.assign(n, -1);
  for (int v = 0; v < n; ++v)
    if (keep[v]) {
      s.old_to_new[v] = static_cast<int32_t>(s.kept_vertices.size());
      s.kept_vertices.push_back(v);
    }
  for (int t = 0; t < m.num_triangles(); ++t) {
    const auto& tri = m.triangles[t];
    if (keep[tri[0]] && keep[tri[1]] && keep[tri[2]]) s.kept_triangles.push_back(t);
  }
  return s;
}

std::vector<uint8_t> to_bytes(const std::string& s) { return {s.begin(), s.end()}; }

std::vector<uint8_t> write_obj(const FaceModel& m, const MeshInstance& inst, const Selection& s) {
  std::ostringstream o;
  o << "# face-reenact model instance: " << s.kept_vertices.size() << " vertices, " << s.kept_triangles.size()
    << " triangles, metres\n";
  char line[160];
  for (int v : s.kept_vertices) {
    std::snprintf(line, sizeof line, "v %.6f %.6f %.6f %.4f %.4f %.4f\n", inst.positions[3 * v],
                  inst.positions[3 * v + 1], inst.positions[3 * v + 2], srgb_encode(inst.colours[3 * v]),
                  srgb_encode(inst.colours[3 * v + 1]), srgb_encode(inst.colours[3 * v + 2]));
    o << line;
  }
  for (int t : s.kept_triangles)
    for (int c = 0; c < 3; ++c) {
      const auto& uv = m.corner_uvs[3 * t + c];
      std::snprintf(line, sizeof line, "vt %.6f %.6f\n", uv[0], uv[1]);
      o << line;
    }
  int corner = 1;
  for (int t : s.kept_triangles) {
    const auto& tri = m.triangles[t];
    o << "f";
    for (int c = 0; c < 3; ++c) o << ' ' << s.old_to_new[tri[c]] + 1 << '/' << corner++;
    o << '\n';
  }
  return to_bytes(o.str());
}

std::vector<uint8_t> write_ply(const MeshInstance& inst, const FaceModel& m, const Selection& s) {
  std::ostringstream h;
  h << "ply\nformat binary_little_endian 1.0\ncomment face-reenact model instance, metres\n"
    << "element vertex " << s.kept_vertices.size()
    << "\nproperty float x\nproperty float y\nproperty float z\n"
    << "property uchar red\nproperty uchar green\nproperty uchar blue\n"
    << "element face " << s.kept_triangles.size() << "\nproperty list uchar int vertex_indices\nend_header\n";
  ByteWriter w;
  w.bytes(to_bytes(h.str()));
  for (int v : s.kept_vertices) {
    for (int k = 0; k < 3; ++k) w.f32(inst.positions[3 * v + k]);
    for (int k = 0; k < 3; ++k)
      w.u8(static_cast<uint8_t>(std::lround(255.f * srgb_encode(inst.colours[3 * v + k]))));
  }
  for (int t : s.kept_triangles) {
    w.u8(3);
    for (int c = 0; c < 3; ++c) w.i32(s.old_to_new[m.triangles[t][c]]);
  }
  return w.take();
}

}  // namespace

void export_mesh(const FaceModel& model, const MeshInstance& instance, const std::vector<FacePart>& parts,
                 const std::string& path) {
  const Eigen::Index n3 = 3 * model.num_vertices();
  if (instance.positions.size() != n3 || instance.colours.size() != n3)
    throw Error("mesh export: instance does not match the model's vertex count");
  if (!instance.positions.allFinite()) throw Error("mesh export: positions contain NaN or infinity");
  const std::string ext = lower_case_extension(path);
  Selection s = select(model, parts);
  if (s.kept_triangles.empty()) throw Error("mesh export: the selected parts contain no triangles");
  if (ext == ".obj")
    write_file_atomic(path, write_obj(model, instance, s));
  else if (ext == ".ply")
    write_file_atomic(path, write_ply(instance, model, s));
  else
    throw Error("mesh export: unknown format '" + ext + "' (use .obj or .ply)");
}

}  // namespace face_reenact
