#pragma once
// Internal to the configuration of the command-line tool: the table of keys
// (config_table.cpp) that reading a TOML file (config_read.cpp), the --set
// overrides (config_overrides.cpp), validation (config_validate.cpp),
// to_toml, config_to_json and schema() all iterate, and how values are shown
// in ConfigError messages.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <variant>
#include <vector>

#include <fmt/format.h>

#include "otfp_app/config.hpp"

namespace otfp::app::config_detail {

// ------------------------------------------------------------------ values

enum class Kind { Int, Float, String, Point };

// The value of one key: absent (an optional key not given), an integer, a
// number, a string or a point.
using Value = std::variant<std::monostate, std::int64_t, double, std::string, Vec3>;

// Values in messages: numbers as fmt prints them ("nan", "inf"), points as
// [x, y, z], strings quoted and escaped.
std::string format_double(double v);
std::string shown(double v);
std::string shown(const Vec3& v);
std::string shown(const Value& v);
// Control characters as escapes (\n, \t, \r, \xHH), so that an echoed value
// keeps an error message on one line and shows what was given.
std::string escaped(const std::string& s);
bool has_control_character(const std::string& s);
std::string quoted(const std::string& s);
std::string join(const std::vector<std::string>& v, const char* sep = ", ");

// ------------------------------------------------------------------ rules

// The range rule of one key: lo < v (or <=) and v < hi (or <=). The message
// names the side that is broken ("must be > 0", "must be <= 1000") unless
// `text` is the message for either side; `above` replaces the upper one.
struct Rule {
  double lo = -std::numeric_limits<double>::infinity();
  double hi = std::numeric_limits<double>::infinity();
  bool lo_open = false, hi_open = false;
  std::string text;
  std::string above;
  std::string doc;                          // short form (docs/configuration.md); generated when empty
  std::function<bool(const Config&)> when;  // the rule holds only where this is true (default: always)

  bool has_lo() const { return std::isfinite(lo); }
  bool has_hi() const { return std::isfinite(hi); }
  bool empty() const { return !has_lo() && !has_hi(); }
  std::string lower_message() const { return fmt::format("must be {} {}", lo_open ? ">" : ">=", format_double(lo)); }
  std::string upper_message() const {
    return above.empty() ? fmt::format("must be {} {}", hi_open ? "<" : "<=", format_double(hi)) : above;
  }
  std::string short_form() const {
    if (!doc.empty()) return doc;
    if (has_lo() && has_hi())
      return fmt::format("in {}{}, {}{}", lo_open ? "(" : "[", format_double(lo), format_double(hi), hi_open ? ")" : "]");
    if (has_lo()) return fmt::format("{} {}", lo_open ? ">" : ">=", format_double(lo));
    if (has_hi()) return fmt::format("{} {}", hi_open ? "<" : "<=", format_double(hi));
    return "";
  }
  // "" if x obeys the rule, else the message.
  std::string broken_by(double x) const {
    const bool low = has_lo() && !(lo_open ? x > lo : x >= lo);
    const bool high = has_hi() && !(hi_open ? x < hi : x <= hi);
    if (!low && !high) return "";
    if (!text.empty()) return text;
    return low ? lower_message() : upper_message();
  }
};

// ------------------------------------------------------------------ the table

// Where a key's member lives: a section of Config, or entry i of an array of tables.
enum class Scope { Section, SubPatch, Boundary };

// One key: its path, kind, member of Config, default, choices and rule.
struct Field {
  std::string path;     // "run.dim", "boundary[].kind", "domain.subpatch[].name"
  std::string section;  // "run", "boundary", "domain" (subpatches: the domain's array "subpatch")
  std::string key;      // "dim", "kind", "name"
  Scope scope = Scope::Section;
  Kind kind = Kind::Float;
  bool optional = false;             // a std::optional member: absent unless given
  std::string required;              // array keys that must be given: the rule shown when missing
  std::vector<std::string> choices;  // allowed strings (empty: any)
  Rule rule;
  Value fallback;  // the member's in-class default
  std::function<Value(const Config&, std::size_t)> get;
  std::function<void(Config&, std::size_t, const Value&, const std::string&)> set;
  std::function<bool(const Config&, std::size_t)> in_toml;  // to_toml writes the key only where true (default: always)

  Field& with(Rule r) {
    rule = std::move(r);
    return *this;
  }
  Field& one_of(std::vector<std::string> c) {
    choices = std::move(c);
    return *this;
  }
  Field& needed(std::string rule_when_missing) {
    required = std::move(rule_when_missing);
    optional = false;  // absent until given, but never left out
    return *this;
  }
  Field& written_if(std::function<bool(const Config&, std::size_t)> f) {
    in_toml = std::move(f);
    return *this;
  }
};

// Every key (config_table.cpp).
const std::vector<Field>& fields();
// The tables of a configuration file.
inline const std::vector<std::string> kSections = {"run",    "domain", "particles", "physics",
                                                   "boundary", "solver", "treatment", "diagnostics"};
// The key with this schema path ("run.dim", "boundary[].kind"), or null.
const Field* find_spec(const std::string& path);
// How many entries a key of this scope has in `c` (a section key: one).
std::size_t entries(const Config& c, Scope scope);
// The name of key `f` of entry i in messages: "run.dim", "boundary[0].kind".
std::string display_name(const Field& f, std::size_t i);

// The rules that combine keys (config_validate.cpp; each key's own rule is in
// the table). Throws ConfigError.
void validate(const Config& c);

}  // namespace otfp::app::config_detail
