#include "face_reenact/model/macro_modifiers.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <nlohmann/json.hpp>
#include <set>

#include "face_reenact/common/error.h"

namespace face_reenact {
namespace {

double round4(double x) { return std::round(x * 1e4) / 1e4; }

struct Combination {
  const char* key;     // name in macro.json "combinations"
  const char* prefix;  // file name prefix under macrodetails/
};
constexpr Combination kHeadCombinations[] = {
    {"racegenderage", ""},
    {"genderagemuscleweight", "universal-"},
    {"genderagemuscleweightheight", "height/"},
    {"genderagemuscleweightproportions", "proportions/"},
};

}  // namespace

double makehuman_age_from_years(double years) {
  // MakeHuman's anchors: 1 y -> 0, 11 y -> 0.1875, 25 y -> 0.5, 90 y -> 1.
  if (years <= 1) return 0;
  if (years <= 11) return 0.1875 * (years - 1) / 10;
  if (years <= 25) return 0.1875 + 0.3125 * (years - 11) / 14;
  if (years <= 90) return 0.5 + 0.5 * (years - 25) / 65;
  return 1;
}

MacroRules MacroRules::parse(std::string_view json_text, const std::string& what) {
  nlohmann::json j = nlohmann::json::parse(json_text, nullptr, /*allow_exceptions=*/false);
  if (!j.is_object() || !j.contains("macrotargets") || !j["macrotargets"].is_object())
    throw Error(what + ": not a macro.json (no \"macrotargets\" object)");
  MacroRules rules;
  for (auto& [name, var] : j["macrotargets"].items()) {
    if (!var.is_object() || !var.contains("parts") || !var["parts"].is_array() || var["parts"].empty())
      throw Error(what + ": variable '" + name + "' has no parts");
    const auto& parts = var["parts"];
    std::vector<MacroPart> out;
    for (size_t i = 0; i < parts.size(); ++i) {
      const auto& p = parts[i];
      if (!p.is_object() || !p.contains("lowest") || !p.contains("highest") || !p["lowest"].is_number() ||
          !p["highest"].is_number() || !p.contains("low") || !p["low"].is_string() || !p.contains("high") ||
          !p["high"].is_string())
        throw Error(what + ": variable '" + name + "' part " + std::to_string(i) + " is malformed");
      MacroPart mp;
      mp.low = p["low"].get<std::string>();
      mp.high = p["high"].get<std::string>();
      mp.begin = i == 0 ? 0.0 : round4(0.5 * (parts[i - 1]["highest"].get<double>() + p["lowest"].get<double>()));
      mp.end = i + 1 == parts.size() ? 1.0
                                     : round4(0.5 * (p["highest"].get<double>() + parts[i + 1]["lowest"].get<double>()));
      if (!(mp.end > mp.begin)) throw Error(what + ": variable '" + name + "' has an empty or reversed part");
      if (!out.empty() && out.back().high != mp.low)
        throw Error(what + ": variable '" + name + "' parts do not chain (" + out.back().high + " vs " + mp.low + ")");
      out.push_back(mp);
    }
    rules.variables_[name] = std::move(out);
  }
  if (j.contains("combinations") && j["combinations"].is_object()) {
    for (auto& [name, list] : j["combinations"].items()) {
      if (!list.is_array()) throw Error(what + ": combination '" + name + "' is not a list");
      std::vector<std::string> vars;
      for (auto& v : list) {
        if (!v.is_string()) throw Error(what + ": combination '" + name + "' has a non-string entry");
        vars.push_back(v.get<std::string>());
      }
      rules.combinations_[name] = std::move(vars);
    }
  }
  return rules;
}

std::map<std::string, double> MacroRules::label_weights(const std::string& variable, double value) const {
  auto it = variables_.find(variable);
  if (it == variables_.end()) throw Error("macro.json has no variable '" + variable + "'");
  const auto& parts = it->second;
  value = std::clamp(value, 0.0, 1.0);
  size_t k = 0;
  while (k + 1 < parts.size() && value >= parts[k].end) ++k;
  const MacroPart& p = parts[k];
  const double t = std::clamp((value - p.begin) / (p.end - p.begin), 0.0, 1.0);
  std::map<std::string, double> w;
  if (!p.low.empty() && 1 - t > 0) w[p.low] += 1 - t;
  if (!p.high.empty() && t > 0) w[p.high] += t;
  return w;
}

std::vector<std::string> MacroRules::labels(const std::string& variable) const {
  auto it = variables_.find(variable);
  if (it == variables_.end()) throw Error("macro.json has no variable '" + variable + "'");
  std::vector<std::string> out;
  for (const auto& p : it->second)
    for (const auto* l : {&p.low, &p.high})
      if (!l->empty() && std::find(out.begin(), out.end(), *l) == out.end()) out.push_back(*l);
  return out;
}

namespace {

// Label weights of every variable a head combination can use.
std::map<std::string, std::map<std::string, double>> all_label_weights(const MacroRules& rules,
                                                                        const MacroParameters& p) {
  std::map<std::string, std::map<std::string, double>> w;
  w["gender"] = rules.label_weights("gender", p.gender);
  w["age"] = rules.label_weights("age", p.age);
  w["muscle"] = rules.label_weights("muscle", p.muscle);
  w["weight"] = rules.label_weights("weight", p.weight);
  w["height"] = rules.label_weights("height", p.height);
  w["proportions"] = rules.label_weights("proportions", p.proportions);
  const double a = std::max(0.0, p.african), s = std::max(0.0, p.asian), c = std::max(0.0, p.caucasian);
  const double sum = a + s + c;
  auto& race = w["race"];
  if (sum > 0) {
    if (a > 0) race["african"] = a / sum;
    if (s > 0) race["asian"] = s / sum;
    if (c > 0) race["caucasian"] = c / sum;
  } else {
    race = {{"african", 1.0 / 3}, {"asian", 1.0 / 3}, {"caucasian", 1.0 / 3}};
  }
  return w;
}

template <typename Fn>
void for_each_product(const std::vector<std::string>& vars,
                      const std::map<std::string, std::map<std::string, double>>& weights, Fn&& fn) {
  std::vector<std::pair<std::string, double>> chosen;
  std::function<void(size_t)> rec = [&](size_t i) {
    if (i == vars.size()) {
      std::string name;
      double w = 1;
      for (size_t k = 0; k < chosen.size(); ++k) {
        if (k) name += '-';
        name += chosen[k].first;
        w *= chosen[k].second;
      }
      fn(name, w);
      return;
    }
    auto it = weights.find(vars[i]);
    if (it == weights.end()) throw Error("macro combination uses unknown variable '" + vars[i] + "'");
    for (const auto& [label, w] : it->second) {
      chosen.emplace_back(label, w);
      rec(i + 1);
      chosen.pop_back();
    }
  };
  rec(0);
}

const std::vector<std::string>& combination_vars(const MacroRules& rules, const char* key) {
  auto it = rules.combinations().find(key);
  if (it == rules.combinations().end()) throw Error(std::string("macro.json has no combination '") + key + "'");
  return it->second;
}

}  // namespace

std::vector<WeightedTarget> macro_target_weights(const MacroRules& rules, const MacroParameters& p) {
  const auto w = all_label_weights(rules, p);
  std::vector<WeightedTarget> out;
  for (const auto& c : kHeadCombinations) {
    for_each_product(combination_vars(rules, c.key), w, [&](const std::string& name, double weight) {
      if (weight > 0) out.push_back({c.prefix + name, weight});
    });
  }
  return out;
}

std::vector<std::string> macro_target_names(const MacroRules& rules, double min_age, double max_age) {
  // Every label of every variable, except ages outside the range's parts.
  std::map<std::string, std::map<std::string, double>> all;
  for (const char* v : {"gender", "muscle", "weight", "height", "proportions"})
    for (const auto& l : rules.labels(v)) all[v][l] = 1;
  all["race"] = {{"african", 1}, {"asian", 1}, {"caucasian", 1}};
  std::set<std::string> ages;
  for (double a = min_age;; a = std::min(max_age, a + 0.01)) {
    for (const auto& [l, w] : rules.label_weights("age", a)) ages.insert(l);
    if (a >= max_age) break;
  }
  for (const auto& l : ages) all["age"][l] = 1;
  std::vector<std::string> names;
  for (const auto& c : kHeadCombinations)
    for_each_product(combination_vars(rules, c.key), all,
                     [&](const std::string& name, double) { names.push_back(c.prefix + name); });
  return names;
}

}  // namespace face_reenact
