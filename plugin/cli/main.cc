// face-reenact: the command-line front-end. Subcommands are added by the *_commands.cc files.
#include <cstdio>
#include <exception>

#include "command_registry.h"
#include "face_reenact/common/error.h"

int main(int argc, char** argv) {
  CLI::App app{"face-reenact: real-time facial reenactment (Thies et al. 2015)", "face-reenact"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "face-reenact " FR_VERSION);
  face_reenact::cli::add_all_commands(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const face_reenact::Error& e) {
    std::fprintf(stderr, "face-reenact: error: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "face-reenact: internal error: %s\n", e.what());
    return 2;
  }
  return 0;
}
