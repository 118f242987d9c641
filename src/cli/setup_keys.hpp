#pragma once
// The configuration as the library's set-up inputs, and the library's set-up
// errors as errors of configuration keys (private to otfp_app).
#include "otfp/run_setup.hpp"
#include "otfp/types.hpp"
#include "otfp_app/config.hpp"

namespace otfp::app::detail {

// The library's set-up inputs (run_setup.hpp) from the configuration; L is
// resolved by the caller (particles.length_L or the domain's).
RunSetupOptions run_setup_options(const Config& c, double length_L, bool bounded);

// An InvalidArgument of run_parameters() ("<field> = <value>: <rule>") as a
// ConfigError naming the configuration key of the field (c: the values to quote).
[[noreturn]] void throw_keyed(const InvalidArgument& e, const Config& c);

}  // namespace otfp::app::detail
