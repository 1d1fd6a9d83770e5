#pragma once
// Measures in JSON reports: JSON has no NaN or infinity, and a figure that could not be measured
// (no frame counted, no ground truth) is written as null rather than as a number.
#include <cmath>

#include <nlohmann/json.hpp>

namespace face_reenact {

inline nlohmann::json json_number(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

}  // namespace face_reenact
