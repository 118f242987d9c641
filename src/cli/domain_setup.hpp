#pragma once
// Builds the Domain described by [domain] (private to otfp_app).
#include <functional>
#include <optional>
#include <string>

#include "otfp/geometry.hpp"
#include "otfp_app/config.hpp"

namespace otfp::app::detail {

struct BuiltDomain {
  DomainPtr domain;
  bool free_space = false;        // type = "free": no boundary, no barrier
  double length_L = 1.0;          // default L of b = sqrt(L dr)
  double min_extent = 0.0;        // smallest bounding-box edge over the used axes
};

// Throws ConfigError naming the offending key.
BuiltDomain build_domain(const Config& config);

// Patch id of a name, -1 if unknown.
int resolve_patch(const BuiltDomain& built, const std::string& name);

// "a, b, c": the patch names a configuration may use.
std::string patch_names(const BuiltDomain& built);

}  // namespace otfp::app::detail
