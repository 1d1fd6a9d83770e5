#include "face_reenact/model/makehuman_formats.h"

#include <charconv>
#include <cmath>
#include <cstdlib>

#include "face_reenact/common/error.h"

namespace face_reenact {
namespace {

// Walks text line by line and tokenises on blanks without allocating.
class LineCursor {
 public:
  explicit LineCursor(std::string_view text) : text_(text) {}
  bool next(std::string_view* line) {
    if (pos_ >= text_.size()) return false;
    size_t end = text_.find('\n', pos_);
    if (end == std::string_view::npos) end = text_.size();
    *line = text_.substr(pos_, end - pos_);
    if (!line->empty() && line->back() == '\r') line->remove_suffix(1);
    pos_ = end + 1;
    ++line_no_;
    return true;
  }
  int line_no() const { return line_no_; }

 private:
  std::string_view text_;
  size_t pos_ = 0;
  int line_no_ = 0;
};

void split_blanks(std::string_view line, std::vector<std::string_view>* tokens) {
  tokens->clear();
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
    size_t j = i;
    while (j < line.size() && line[j] != ' ' && line[j] != '\t') ++j;
    if (j > i) tokens->push_back(line.substr(i, j - i));
    i = j;
  }
}

[[noreturn]] void fail(const std::string& what, int line, const std::string& msg) {
  throw Error(what + ": line " + std::to_string(line) + ": " + msg);
}

bool parse_int(std::string_view s, int64_t* out) {
  auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), *out);
  return ec == std::errc() && p == s.data() + s.size();
}

bool parse_float(std::string_view s, float* out) {
  // std::from_chars for float is in libstdc++ 12 and accepts ".026" / "-.166".
  auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), *out);
  return ec == std::errc() && p == s.data() + s.size() && std::isfinite(*out);
}

std::string quote(std::string_view s) {
  std::string q(s.substr(0, 40));
  return "'" + q + (s.size() > 40 ? "...'" : "'");
}

}  // namespace

MorphTarget parse_morph_target(std::string_view text, int num_vertices, const std::string& what) {
  MorphTarget t;
  std::vector<char> seen(static_cast<size_t>(std::max(num_vertices, 0)), 0);
  LineCursor cur(text);
  std::string_view line;
  std::vector<std::string_view> tok;
  while (cur.next(&line)) {
    split_blanks(line, &tok);
    if (tok.empty() || tok[0].front() == '#') continue;
    if (tok.size() != 4) fail(what, cur.line_no(), "expected 'index dx dy dz', got " + quote(line));
    int64_t idx;
    if (!parse_int(tok[0], &idx)) fail(what, cur.line_no(), "bad vertex index " + quote(tok[0]));
    if (idx < 0 || idx >= num_vertices)
      fail(what, cur.line_no(), "vertex index " + std::to_string(idx) + " outside [0, " + std::to_string(num_vertices) + ")");
    if (seen[static_cast<size_t>(idx)]) fail(what, cur.line_no(), "vertex " + std::to_string(idx) + " repeated");
    seen[static_cast<size_t>(idx)] = 1;
    TargetOffset o;
    o.vertex = static_cast<int32_t>(idx);
    for (int k = 0; k < 3; ++k)
      if (!parse_float(tok[1 + k], &o.delta[k])) fail(what, cur.line_no(), "bad number " + quote(tok[1 + k]));
    t.offsets.push_back(o);
  }
  return t;
}

int BaseMesh::group_index(const std::string& name) const {
  for (size_t i = 0; i < group_names.size(); ++i)
    if (group_names[i] == name) return static_cast<int>(i);
  return -1;
}

BaseMesh parse_obj(std::string_view text, const std::string& what) {
  BaseMesh m;
  LineCursor cur(text);
  std::string_view line;
  std::vector<std::string_view> tok;
  int32_t group = -1;
  std::vector<ObjFace> faces;
  while (cur.next(&line)) {
    split_blanks(line, &tok);
    if (tok.empty() || tok[0].front() == '#') continue;
    const std::string_view key = tok[0];
    if (key == "v") {
      if (tok.size() < 4) fail(what, cur.line_no(), "vertex needs 3 coordinates");
      Eigen::Vector3f p;
      for (int k = 0; k < 3; ++k)
        if (!parse_float(tok[1 + k], &p[k])) fail(what, cur.line_no(), "bad coordinate " + quote(tok[1 + k]));
      m.positions.push_back(p);
    } else if (key == "vt") {
      if (tok.size() < 3) fail(what, cur.line_no(), "texture coordinate needs 2 values");
      std::array<float, 2> uv;
      for (int k = 0; k < 2; ++k)
        if (!parse_float(tok[1 + k], &uv[k])) fail(what, cur.line_no(), "bad texture coordinate " + quote(tok[1 + k]));
      m.uvs.push_back(uv);
    } else if (key == "g") {
      if (tok.size() < 2) fail(what, cur.line_no(), "group without a name");
      std::string name(tok[1]);
      group = m.group_index(name);
      if (group < 0) {
        group = static_cast<int32_t>(m.group_names.size());
        m.group_names.push_back(name);
      }
    } else if (key == "f") {
      if (tok.size() < 4) fail(what, cur.line_no(), "face with fewer than 3 corners");
      ObjFace f;
      f.group = group;
      bool with_uv = tok[1].find('/') != std::string_view::npos;
      for (size_t c = 1; c < tok.size(); ++c) {
        std::string_view t = tok[c];
        size_t slash = t.find('/');
        int64_t vi, ti = 0;
        if (!parse_int(t.substr(0, slash), &vi)) fail(what, cur.line_no(), "bad face index " + quote(t));
        if (with_uv) {
          if (slash == std::string_view::npos) fail(what, cur.line_no(), "mixed face corner formats");
          std::string_view rest = t.substr(slash + 1);
          size_t slash2 = rest.find('/');
          if (!parse_int(rest.substr(0, slash2), &ti)) fail(what, cur.line_no(), "bad texture index " + quote(t));
        }
        // Negative (relative) indices are legal OBJ but MakeHuman never writes them.
        if (vi < 1 || vi > static_cast<int64_t>(m.positions.size()))
          fail(what, cur.line_no(), "face refers to undefined vertex " + std::to_string(vi));
        if (with_uv && (ti < 1 || ti > static_cast<int64_t>(m.uvs.size())))
          fail(what, cur.line_no(), "face refers to undefined texture coordinate " + std::to_string(ti));
        f.vertices.push_back(static_cast<int32_t>(vi - 1));
        if (with_uv) f.uvs.push_back(static_cast<int32_t>(ti - 1));
      }
      faces.push_back(std::move(f));
    }
  }
  m.faces = std::move(faces);
  if (m.positions.empty()) throw Error(what + ": no vertices");
  return m;
}

MirrorTable parse_mirror_table(std::string_view text, int num_vertices, const std::string& what) {
  MirrorTable t;
  t.partner.assign(static_cast<size_t>(num_vertices), -1);
  t.side.assign(static_cast<size_t>(num_vertices), 0);
  LineCursor cur(text);
  std::string_view line;
  std::vector<std::string_view> tok;
  while (cur.next(&line)) {
    split_blanks(line, &tok);
    if (tok.empty() || tok[0].front() == '#') continue;
    if (tok.size() != 3) fail(what, cur.line_no(), "expected 'index partner side', got " + quote(line));
    int64_t a, b;
    if (!parse_int(tok[0], &a) || !parse_int(tok[1], &b)) fail(what, cur.line_no(), "bad index in " + quote(line));
    if (a < 0 || a >= num_vertices || b < 0 || b >= num_vertices)
      fail(what, cur.line_no(), "index outside [0, " + std::to_string(num_vertices) + ")");
    if (tok[2] != "l" && tok[2] != "r" && tok[2] != "m") fail(what, cur.line_no(), "side must be l, r or m");
    if (t.partner[static_cast<size_t>(a)] >= 0) fail(what, cur.line_no(), "vertex " + std::to_string(a) + " listed twice");
    t.partner[static_cast<size_t>(a)] = static_cast<int32_t>(b);
    t.side[static_cast<size_t>(a)] = tok[2][0];
  }
  for (int i = 0; i < num_vertices; ++i) {
    const int p = t.partner[static_cast<size_t>(i)];
    if (p < 0) throw Error(what + ": vertex " + std::to_string(i) + " has no entry");
    if (t.partner[static_cast<size_t>(p)] != i)
      throw Error(what + ": mirror map is not symmetric at vertex " + std::to_string(i));
    if ((p == i) != (t.side[static_cast<size_t>(i)] == 'm'))
      throw Error(what + ": vertex " + std::to_string(i) + " is its own mirror but not marked 'm' (or vice versa)");
  }
  return t;
}

}  // namespace face_reenact
