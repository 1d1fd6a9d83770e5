#include "face_reenact/model/makehuman_formats.h"

#include <gtest/gtest.h>

#include "face_reenact/common/error.h"

namespace face_reenact {
namespace {

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(MorphTarget, ParsesOffsetsCommentsBlankLinesAndCrLf) {
  const std::string text = "# a comment\n0 .026 .154 -.166\r\n\n  5\t-1.5 0 2e-3\n# end\n";
  MorphTarget t = parse_morph_target(text, 10, "t");
  ASSERT_EQ(t.offsets.size(), 2u);
  EXPECT_EQ(t.offsets[0].vertex, 0);
  EXPECT_FLOAT_EQ(t.offsets[0].delta.x(), 0.026f);
  EXPECT_FLOAT_EQ(t.offsets[0].delta.z(), -0.166f);
  EXPECT_EQ(t.offsets[1].vertex, 5);
  EXPECT_FLOAT_EQ(t.offsets[1].delta.x(), -1.5f);
  EXPECT_FLOAT_EQ(t.offsets[1].delta.z(), 0.002f);
  EXPECT_TRUE(parse_morph_target("", 10, "t").offsets.empty());
}

TEST(MorphTarget, RejectsMalformedLinesWithLineNumbers) {
  EXPECT_NE(error_of([] { parse_morph_target("0 1 2\n", 10, "x.target"); }).find("x.target: line 1"), std::string::npos);
  EXPECT_NE(error_of([] { parse_morph_target("0 1 2 3\n1 1 2 3 4\n", 10, "t"); }).find("line 2"), std::string::npos);
  EXPECT_NE(error_of([] { parse_morph_target("a 1 2 3\n", 10, "t"); }).find("bad vertex index"), std::string::npos);
  EXPECT_NE(error_of([] { parse_morph_target("1.5 1 2 3\n", 10, "t"); }).find("bad vertex index"), std::string::npos);
  EXPECT_NE(error_of([] { parse_morph_target("1 1 x 3\n", 10, "t"); }).find("bad number"), std::string::npos);
  EXPECT_NE(error_of([] { parse_morph_target("1 1 nan 3\n", 10, "t"); }).find("bad number"), std::string::npos);
  EXPECT_NE(error_of([] { parse_morph_target("1 1 inf 3\n", 10, "t"); }).find("bad number"), std::string::npos);
  EXPECT_NE(error_of([] { parse_morph_target("10 1 2 3\n", 10, "t"); }).find("outside"), std::string::npos);
  EXPECT_NE(error_of([] { parse_morph_target("-1 1 2 3\n", 10, "t"); }).find("outside"), std::string::npos);
  EXPECT_NE(error_of([] { parse_morph_target("3 1 2 3\n3 0 0 0\n", 10, "t"); }).find("repeated"), std::string::npos);
  EXPECT_NE(error_of([] { parse_morph_target("99999999999999999999 1 2 3\n", 10, "t"); }).find("bad vertex index"),
            std::string::npos);
}

TEST(Obj, ParsesVerticesUvsGroupsAndFaces) {
  const std::string text =
      "# comment\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
      "g body\ns off\nf 1/1 2/2 3/3 4/4\ng helper\nf 1/1 3/3 4/4\ng body\nf 2/2 3/3 4/4\n";
  BaseMesh m = parse_obj(text, "obj");
  ASSERT_EQ(m.positions.size(), 4u);
  ASSERT_EQ(m.uvs.size(), 4u);
  ASSERT_EQ(m.faces.size(), 3u);
  ASSERT_EQ(m.group_names.size(), 2u);
  EXPECT_EQ(m.group_index("body"), 0);
  EXPECT_EQ(m.group_index("helper"), 1);
  EXPECT_EQ(m.group_index("nope"), -1);
  EXPECT_EQ(m.faces[0].vertices, (std::vector<int32_t>{0, 1, 2, 3}));
  EXPECT_EQ(m.faces[0].uvs, (std::vector<int32_t>{0, 1, 2, 3}));
  EXPECT_EQ(m.faces[1].group, 1);
  EXPECT_EQ(m.faces[2].group, 0);
  EXPECT_FLOAT_EQ(m.positions[2].y(), 1.f);
}

TEST(Obj, RejectsBadInput) {
  EXPECT_NE(error_of([] { parse_obj("", "o"); }).find("no vertices"), std::string::npos);
  EXPECT_NE(error_of([] { parse_obj("v 0 0\n", "o"); }).find("3 coordinates"), std::string::npos);
  EXPECT_NE(error_of([] { parse_obj("v 0 0 0\nv 1 0 0\nf 1 2 3\n", "o"); }).find("undefined vertex 3"),
            std::string::npos);
  EXPECT_NE(error_of([] { parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n", "o"); })
                .find("undefined texture coordinate"),
            std::string::npos);
  EXPECT_NE(error_of([] { parse_obj("v 0 0 0\nv 1 0 0\nf 1 2\n", "o"); }).find("fewer than 3"), std::string::npos);
  EXPECT_NE(error_of([] { parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2 3\n", "o"); }).find("mixed"),
            std::string::npos);
  EXPECT_NE(error_of([] { parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "o"); }).find("undefined vertex 0"),
            std::string::npos);
}

TEST(MirrorTable, ParsesSidesAndChecksInvolution) {
  MirrorTable t = parse_mirror_table("0 2 r\n1 1 m\n2 0 l\n", 3, "mirror");
  EXPECT_EQ(t.partner, (std::vector<int32_t>{2, 1, 0}));
  EXPECT_EQ(t.side, (std::vector<char>{'r', 'm', 'l'}));
  EXPECT_NE(error_of([] { parse_mirror_table("0 2 r\n1 1 m\n2 1 l\n", 3, "m"); }).find("not symmetric"),
            std::string::npos);
  EXPECT_NE(error_of([] { parse_mirror_table("0 2 r\n2 0 l\n", 3, "m"); }).find("vertex 1 has no entry"),
            std::string::npos);
  EXPECT_NE(error_of([] { parse_mirror_table("0 2 r\n1 1 m\n2 0 x\n", 3, "m"); }).find("side"), std::string::npos);
  EXPECT_NE(error_of([] { parse_mirror_table("0 2 r\n1 1 r\n2 0 l\n", 3, "m"); }).find("own mirror"),
            std::string::npos);
  EXPECT_NE(error_of([] { parse_mirror_table("0 5 r\n", 3, "m"); }).find("outside"), std::string::npos);
  EXPECT_NE(error_of([] { parse_mirror_table("0 2 r\n0 2 r\n", 3, "m"); }).find("listed twice"), std::string::npos);
}

}  // namespace
}  // namespace face_reenact
