#pragma once
// Each command group (model, landmarks, send/receive, render, ...) lives in its own
// *_commands.cc and registers itself here at static-initialisation time, so main.cc never
// changes when a group is added.
#include <CLI/CLI.hpp>
#include <functional>
#include <string>

namespace face_reenact::cli {

using CommandAdder = std::function<void(CLI::App& app)>;

// Returns true so it can initialise a namespace-scope constant.
bool register_commands(const char* group, CommandAdder adder);
void add_all_commands(CLI::App& app);

// Returns the subcommand `name` of `parent`, creating it on first use. Command groups that
// share a parent (e.g. every module adds its own `bench <stage>`) go through this.
CLI::App* get_or_add_subcommand(CLI::App& parent, const std::string& name, const std::string& description);

}  // namespace face_reenact::cli

#define FR_REGISTER_COMMANDS(group, fn) \
  static const bool fr_registered_##group = ::face_reenact::cli::register_commands(#group, fn)
