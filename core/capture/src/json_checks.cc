#include "face_reenact/capture/json_checks.h"

#include <cmath>

#include "face_reenact/common/error.h"

namespace face_reenact::capture::json_checks {

void fail(const std::string& where, const std::string& path, const std::string& message) {
  throw Error(where + ": " + (path.empty() ? std::string("(top level)") : path) + ": " + message);
}

nlohmann::json parse(const std::string& text, const std::string& where) {
  try {
    return nlohmann::json::parse(text);
  } catch (const nlohmann::json::parse_error& e) {
    throw Error(where + ": invalid JSON at byte " + std::to_string(e.byte) +
                " (NaN and Infinity are not JSON numbers): " + e.what());
  }
}

static const char* type_name(const nlohmann::json& j) { return j.type_name(); }

void require_object(const nlohmann::json& j, const std::string& where, const std::string& path) {
  if (!j.is_object()) fail(where, path, std::string("expected an object, got ") + type_name(j));
}

void only_keys(const nlohmann::json& j, std::initializer_list<const char*> allowed, const std::string& where,
               const std::string& path) {
  require_object(j, where, path);
  for (auto it = j.begin(); it != j.end(); ++it) {
    bool known = false;
    for (const char* a : allowed) known = known || it.key() == a;
    if (!known) {
      std::string list;
      for (const char* a : allowed) list += std::string(list.empty() ? "" : ", ") + a;
      fail(where, join(path, it.key()), "unknown key (allowed: " + list + ")");
    }
  }
}

void require_keys(const nlohmann::json& j, std::initializer_list<const char*> required, const std::string& where,
                  const std::string& path) {
  require_object(j, where, path);
  for (const char* k : required)
    if (!j.contains(k)) fail(where, join(path, k), "missing");
}

double number(const nlohmann::json& j, const std::string& where, const std::string& path, double lo, double hi) {
  if (j.is_null()) fail(where, path, "expected a finite number, got null (NaN or infinity written as null?)");
  if (!j.is_number()) fail(where, path, std::string("expected a number, got ") + type_name(j));
  const double v = j.get<double>();
  if (!std::isfinite(v)) fail(where, path, "expected a finite number");
  if (v < lo || v > hi)
    fail(where, path, "value " + nlohmann::json(v).dump() + " out of range [" + nlohmann::json(lo).dump() + ", " +
                          nlohmann::json(hi).dump() + "]");
  return v;
}

int integer(const nlohmann::json& j, const std::string& where, const std::string& path, long lo, long hi) {
  if (!j.is_number_integer()) fail(where, path, std::string("expected an integer, got ") + type_name(j));
  const long long v = j.get<long long>();
  if (v < lo || v > hi)
    fail(where, path, "value " + std::to_string(v) + " out of range [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
  return static_cast<int>(v);
}

std::string string(const nlohmann::json& j, const std::string& where, const std::string& path) {
  if (!j.is_string()) fail(where, path, std::string("expected a string, got ") + type_name(j));
  return j.get<std::string>();
}

bool boolean(const nlohmann::json& j, const std::string& where, const std::string& path) {
  if (!j.is_boolean()) fail(where, path, std::string("expected true or false, got ") + type_name(j));
  return j.get<bool>();
}

std::vector<double> numbers(const nlohmann::json& j, const std::string& where, const std::string& path, double lo,
                            double hi, size_t min_size, size_t max_size) {
  if (!j.is_array()) fail(where, path, std::string("expected an array, got ") + type_name(j));
  if (j.size() < min_size || j.size() > max_size)
    fail(where, path,
         "expected " + (min_size == max_size ? std::to_string(min_size)
                                             : std::to_string(min_size) + " to " + std::to_string(max_size)) +
             " numbers, got " + std::to_string(j.size()));
  std::vector<double> out;
  out.reserve(j.size());
  for (size_t i = 0; i < j.size(); ++i) out.push_back(number(j[i], where, index(path, i), lo, hi));
  return out;
}

}  // namespace face_reenact::capture::json_checks
