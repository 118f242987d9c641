#pragma once
// The `otfp` command line: `otfp run CONFIG --out DIR [--set k=v ...] [--quiet]`,
// `otfp run --resume DIR [--set run.t_end=...]`, `otfp check CONFIG [--set k=v ...]`
// and `otfp sweep`. Exit codes: 0 success, 1 the run failed (files kept), 2 bad
// command line or configuration (nothing written), 3 interrupted by
// SIGINT/SIGTERM (checkpoint written).
#include <ostream>

namespace otfp::app {

int cli_main(int argc, const char* const* argv, std::ostream& out, std::ostream& err);

}  // namespace otfp::app
