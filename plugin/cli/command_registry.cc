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

CLI::App* get_or_add_subcommand(CLI::App& parent, const std::string& name, const std::string& description) {
  for (CLI::App* sub : parent.get_subcommands([](CLI::App*) { return true; }))
    if (sub->get_name() == name) return sub;
  CLI::App* sub = parent.add_subcommand(name, description);
  sub->require_subcommand(1);
  return sub;
}

}  // namespace face_reenact::cli
