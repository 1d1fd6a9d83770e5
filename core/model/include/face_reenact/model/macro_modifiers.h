#pragma once
// MakeHuman's macro modifiers (gender, age, muscle, weight, height, proportions, ethnicity) and
// the rule that turns their values into weights of the macrodetails/ targets, as written in
// macrodetails/macro.json:
//  - each variable has consecutive "parts"; inside a part the value interpolates linearly between
//    the part's low and high target label (an empty label means "no target"). The nominal part
//    boundaries are the midpoints of one part's "highest" and the next one's "lowest" (rounded to
//    1e-4: 0.1875 and 0.5 for age, 0.5 for the others); the first part starts at 0, the last
//    ends at 1. Age 0 / 0.1875 / 0.5 / 1 is 1 / 11 / 25 / 90 years.
//  - the three ethnicity weights are normalised to sum to 1.
//  - a "combination" (e.g. gender-age-muscle-weight) names targets by joining one label per
//    variable with '-'; the target's weight is the product of the label weights.
#include <map>
#include <string>
#include <string_view>
#include <vector>

namespace face_reenact {

struct MacroParameters {
  double gender = 0.5;  // 0 female .. 1 male
  double age = 0.5;     // 0 = 1 year, 0.1875 = 11, 0.5 = 25, 1 = 90 years
  double muscle = 0.5;
  double weight = 0.5;
  double height = 0.5;
  double proportions = 0.5;
  double african = 1.0 / 3, asian = 1.0 / 3, caucasian = 1.0 / 3;  // normalised before use
};

// MakeHuman's age scale: years -> value in [0,1] (piecewise linear through 1, 11, 25, 90 years).
double makehuman_age_from_years(double years);

struct MacroPart {
  double begin = 0, end = 1;  // nominal range
  std::string low, high;      // target labels ("" = none)
};

class MacroRules {
 public:
  // Parses macro.json; throws Error naming `what` on malformed content.
  static MacroRules parse(std::string_view json_text, const std::string& what);

  // Label -> weight for one variable at `value` (clamped to [0,1]); labels with weight 0 omitted.
  std::map<std::string, double> label_weights(const std::string& variable, double value) const;
  // Every label a variable can take (for enumerating targets).
  std::vector<std::string> labels(const std::string& variable) const;
  bool has_variable(const std::string& variable) const { return variables_.count(variable) != 0; }
  const std::map<std::string, std::vector<MacroPart>>& variables() const { return variables_; }
  const std::map<std::string, std::vector<std::string>>& combinations() const { return combinations_; }

 private:
  std::map<std::string, std::vector<MacroPart>> variables_;
  std::map<std::string, std::vector<std::string>> combinations_;
};

// A macrodetails target (path relative to targets/macrodetails/, without ".target.gz") and its
// weight for given parameters.
struct WeightedTarget {
  std::string name;
  double weight = 0;
};

// The combinations the head depends on and where MakeHuman keeps their targets:
//   racegenderage                   -> "<race>-<gender>-<age>"
//   genderagemuscleweight           -> "universal-<gender>-<age>-<muscle>-<weight>"
//   genderagemuscleweightheight     -> "height/<gender>-<age>-<muscle>-<weight>-<height>"
//   genderagemuscleweightproportions-> "proportions/<gender>-<age>-<muscle>-<weight>-<proportions>"
// (cup size and firmness only shape the breasts and are left out.)
// Returns every target with a nonzero weight.
std::vector<WeightedTarget> macro_target_weights(const MacroRules& rules, const MacroParameters& p);

// Every target name macro_target_weights can return for ages in [min_age, max_age].
std::vector<std::string> macro_target_names(const MacroRules& rules, double min_age, double max_age);

}  // namespace face_reenact
