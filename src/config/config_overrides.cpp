// --set overrides: "key=value" with a TOML inline value, applied to the parsed
// file before it is read (entries of the arrays of tables by index or name).
#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <string>
#include <vector>

#include "config_toml.hpp"

namespace otfp::app::config_detail {

namespace {

bool all_digits(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

std::vector<std::string> split_path(std::string path) {
  // a[1].b -> a.1.b
  for (char& c : path)
    if (c == '[') c = '.';
  path.erase(std::remove(path.begin(), path.end(), ']'), path.end());
  std::vector<std::string> out;
  std::string cur;
  for (char c : path) {
    if (c == '.') {
      out.push_back(cur);
      cur.clear();
    } else {
      cur += c;
    }
  }
  out.push_back(cur);
  return out;
}

// The element of an array of tables addressed by an index (== size appends)
// or by the value of `name_key` (a missing name appends a new entry with it).
toml::table& select_entry(toml::array& arr, const std::string& sel, const std::string& name_key,
                          const std::string& array_key, const std::string& assignment, std::size_t& index) {
  if (all_digits(sel)) {
    std::size_t i = 0;
    const auto [end, ec] = std::from_chars(sel.data(), sel.data() + sel.size(), i);
    if (ec != std::errc() || end != sel.data() + sel.size() || i > arr.size())
      throw ConfigError(array_key + "[" + sel + "]", assignment,
                        fmt::format("index out of range (there are {} entries; {} appends one)", arr.size(),
                                    arr.size()));
    if (i == arr.size()) arr.push_back(toml::table{});
    index = i;
    return *arr.get(i)->as_table();
  }
  for (std::size_t i = 0; i < arr.size(); ++i) {
    toml::table& t = *arr.get(i)->as_table();
    if (auto s = t[name_key].value<std::string>(); s && *s == sel) {
      index = i;
      return t;
    }
  }
  arr.push_back(toml::table{{name_key, sel}});
  index = arr.size() - 1;
  return *arr.back().as_table();
}

toml::array& array_of_tables(toml::table& parent, const std::string& key, const std::string& display) {
  if (!parent.contains(key)) parent.insert(key, toml::array{});
  toml::array* a = parent[key].as_array();
  if (!a || !(a->empty() || a->is_array_of_tables()))
    throw ConfigError(display, format_node(*parent.get(key)), "must be an array of tables");
  return *a;
}

// A --set key: section.key, boundary.<index or patch>.key,
// domain.subpatch.<index or name>.key, with boundary[...] and subpatch[...]
// as the bracket forms; segments of letters, digits, '_', '+' and '-'.
bool well_formed_key(const std::string& path) {
  const auto word = [](char ch) {
    return (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') || ch == '_' ||
           ch == '+' || ch == '-';
  };
  std::size_t i = 0;
  for (;;) {
    const std::size_t start = i;
    while (i < path.size() && word(path[i])) ++i;
    if (i == start) return false;
    if (i < path.size() && path[i] == '[') {
      const std::string seg = path.substr(start, i - start);
      if (seg != "boundary" && seg != "subpatch") return false;
      const std::size_t sel = ++i;
      while (i < path.size() && word(path[i])) ++i;
      if (i == sel || i == path.size() || path[i] != ']') return false;
      ++i;
    }
    if (i == path.size()) return true;
    if (path[i] != '.') return false;
    ++i;
  }
}

}  // namespace

void apply_override(toml::table& root, const std::string& assignment) {
  const auto eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0)
    throw ConfigError("--set", quoted(assignment), "must have the form key=value");
  const std::string path = assignment.substr(0, eq);
  const std::string text = assignment.substr(eq + 1);
  if (!well_formed_key(path))
    throw ConfigError(escaped(path), quoted(text),
                      "malformed key (the forms are section.key, boundary.<index or patch>.key or "
                      "boundary[<index>].key, domain.subpatch.<index or name>.key)");
  if (has_control_character(text))
    throw ConfigError(path, quoted(text), "must not contain control characters (newline, tab, ...)");
  const std::vector<std::string> seg = split_path(path);
  for (const std::string& s : seg)
    if (s.empty()) throw ConfigError(path, quoted(text), "malformed key path");

  toml::table* target = nullptr;
  std::string spec_path, display;
  const std::string& section = seg[0];
  if (section == "boundary") {
    if (seg.size() != 3)
      throw ConfigError(path, quoted(text), "must be boundary.<index or patch name>.<key>");
    std::size_t idx = 0;
    target = &select_entry(array_of_tables(root, "boundary", "boundary"), seg[1], "patch", "boundary", text, idx);
    spec_path = "boundary[]." + seg[2];
    display = fmt::format("boundary[{}].{}", idx, seg[2]);
  } else if (std::find(kSections.begin(), kSections.end(), section) != kSections.end()) {
    if (!root.contains(section)) root.insert(section, toml::table{});
    toml::table* sec = root[section].as_table();
    if (!sec) throw ConfigError(section, format_node(*root.get(section)), "must be a table");
    if (section == "domain" && seg.size() >= 2 && seg[1] == "subpatch") {
      if (seg.size() != 4)
        throw ConfigError(path, quoted(text), "must be domain.subpatch.<index or name>.<key>");
      std::size_t idx = 0;
      target = &select_entry(array_of_tables(*sec, "subpatch", "domain.subpatch"), seg[2], "name",
                             "domain.subpatch", text, idx);
      spec_path = "domain.subpatch[]." + seg[3];
      display = fmt::format("domain.subpatch[{}].{}", idx, seg[3]);
    } else {
      if (seg.size() != 2) throw ConfigError(path, quoted(text), "unknown key");
      target = sec;
      spec_path = path;
      display = path;
    }
  } else {
    throw ConfigError(path, quoted(text), "unknown section (allowed: " + join(kSections) + ")");
  }
  const Field* spec = find_spec(spec_path);
  if (!spec) {
    const std::string prefix = spec_path.substr(0, spec_path.rfind('.') + 1);
    throw ConfigError(display, quoted(text), unknown_key_rule(prefix, spec_path.substr(prefix.size())));
  }
  const std::string key = spec_path.substr(spec_path.rfind('.') + 1);

  // The value is a TOML inline value; a bare word is accepted for string keys.
  toml::table parsed;
  bool ok = true;
  try {
    parsed = toml::parse("v = " + text);
  } catch (const toml::parse_error&) {
    ok = false;
  }
  if (!ok || !parsed.contains("v")) {
    if (spec->kind != Kind::String)
      throw ConfigError(display, quoted(text), "not a TOML value; " + kind_rule(*spec));
    parsed = toml::table{{"v", text}};
  }
  const toml::node& n = *parsed.get("v");
  // Numbers are echoed as written (3.0, 1e3), not as read back.
  check_kind(n, *spec, display, spec->kind == Kind::Int || spec->kind == Kind::Float ? text : "");
  switch (spec->kind) {
    case Kind::Int: target->insert_or_assign(key, n.as_integer()->get()); break;
    case Kind::Float: target->insert_or_assign(key, number_of(n)); break;
    case Kind::String: target->insert_or_assign(key, n.as_string()->get()); break;
    case Kind::Point: {
      toml::array a;
      for (const toml::node& e : *n.as_array()) a.push_back(number_of(e));
      target->insert_or_assign(key, std::move(a));
      break;
    }
  }
}

}  // namespace otfp::app::config_detail
