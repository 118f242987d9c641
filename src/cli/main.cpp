#include <iostream>

#include "otfp_app/cli.hpp"

int main(int argc, char** argv) { return otfp::app::cli_main(argc, argv, std::cout, std::cerr); }
