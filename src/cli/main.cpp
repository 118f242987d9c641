#include <csignal>
#include <iostream>

#include "otfp_app/cli.hpp"

int main(int argc, char** argv) {
  // A file-size limit (ulimit -f) is a write error to report, like a full disk, not a reason to die.
  std::signal(SIGXFSZ, SIG_IGN);
  return otfp::app::cli_main(argc, argv, std::cout, std::cerr);
}
