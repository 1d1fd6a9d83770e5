#include "command_registry.h"

#include <map>
#include <string>

namespace face_reenact::cli {
namespace {
// Ordered by group name so `--help` lists groups in a stable order.
std::map<std::string, CommandAdder>& registry() {
  static std::map<std::string, CommandAdder> r;
  return r;
}
}  // namespace

bool register_commands(const char* group, CommandAdder adder) {
  registry()[group] = std::move(adder);
  return true;
}

void add_all_commands(CLI::App& app) {
  for (auto& [name, adder] : registry()) adder(app);
}

}  // namespace face_reenact::cli
