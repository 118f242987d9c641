#pragma once
// Internal: TOML values against the table of keys (config_table.hpp), shared
// by reading a configuration (config_read.cpp) and its --set overrides
// (config_overrides.cpp).
#include <string>
#include <toml++/toml.h>

#include "config_table.hpp"

namespace otfp::app::config_detail {

// A value as it was written, for messages: a float stays a float (3.0).
std::string format_node(const toml::node& n);
// A kind-checked number (an integer or a float) as a double.
double number_of(const toml::node& n);
// "must be an integer", "must be one of ...": what the key's kind allows.
std::string kind_rule(const Field& spec);
// Checks one value against its key's kind; `key` is the display name,
// `given` the value as the user wrote it (--set), if known.
void check_kind(const toml::node& n, const Field& spec, const std::string& key, const std::string& given = "");
// "unknown key" with the closest known key of the same table, if any is close.
std::string unknown_key_rule(const std::string& prefix, const std::string& key);

// Applies one --set assignment "key=value" to the parsed file (config_overrides.cpp).
void apply_override(toml::table& root, const std::string& assignment);

}  // namespace otfp::app::config_detail
