#pragma once
// Strict JSON field access for the capture module's input files (recordings, synth scripts,
// identity files): every error names the file and the key path ("frames.jsonl line 3:
// ground_truth.euler[1]: expected a finite number"), unknown keys are refused, and numbers must
// be finite and in range.
#include <initializer_list>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace face_reenact::capture::json_checks {

// Throws face_reenact::Error("<where>: <path>: <message>").
[[noreturn]] void fail(const std::string& where, const std::string& path, const std::string& message);

// Parses text; a syntax error becomes an Error naming `where` and the byte offset.
nlohmann::json parse(const std::string& text, const std::string& where);

void require_object(const nlohmann::json& j, const std::string& where, const std::string& path);
// Refuses keys not in `allowed`.
void only_keys(const nlohmann::json& j, std::initializer_list<const char*> allowed, const std::string& where,
               const std::string& path);
void require_keys(const nlohmann::json& j, std::initializer_list<const char*> required, const std::string& where,
                  const std::string& path);
double number(const nlohmann::json& j, const std::string& where, const std::string& path, double lo, double hi);
int integer(const nlohmann::json& j, const std::string& where, const std::string& path, long lo, long hi);
std::string string(const nlohmann::json& j, const std::string& where, const std::string& path);
bool boolean(const nlohmann::json& j, const std::string& where, const std::string& path);
// An array of numbers; size in [min_size, max_size].
std::vector<double> numbers(const nlohmann::json& j, const std::string& where, const std::string& path, double lo,
                            double hi, size_t min_size, size_t max_size);

inline std::string join(const std::string& path, const std::string& key) { return path.empty() ? key : path + "." + key; }
inline std::string index(const std::string& path, size_t i) { return path + "[" + std::to_string(i) + "]"; }

}  // namespace face_reenact::capture::json_checks
