#pragma once
// Helpers shared by the tests of the command-line tool (otfp_app).
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace otfp::test {

// An empty scratch directory under the system temp directory, unique per process.
inline std::filesystem::path fresh_dir(const std::string& tag) {
  const std::filesystem::path p =
      std::filesystem::temp_directory_path() / ("otfp_test_" + tag + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(p);
  return p;
}

inline std::string read_text(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// RFC 4180 CSV (quoted fields may hold commas and doubled quotes) as rows of
// column -> field, keyed by the header.
inline std::vector<std::map<std::string, std::string>> read_csv(const std::filesystem::path& p) {
  const std::string text = read_text(p);
  std::vector<std::vector<std::string>> rows(1);
  std::string cur;
  bool quoted = false;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char ch = text[i];
    if (quoted) {
      if (ch == '"' && i + 1 < text.size() && text[i + 1] == '"') {
        cur += '"';
        ++i;
      } else if (ch == '"') {
        quoted = false;
      } else {
        cur += ch;
      }
    } else if (ch == '"') {
      quoted = true;
    } else if (ch == ',') {
      rows.back().push_back(cur);
      cur.clear();
    } else if (ch == '\n') {
      rows.back().push_back(cur);
      cur.clear();
      rows.emplace_back();
    } else {
      cur += ch;
    }
  }
  if (rows.back().empty()) rows.pop_back();
  std::vector<std::map<std::string, std::string>> out;
  for (std::size_t r = 1; r < rows.size(); ++r) {
    std::map<std::string, std::string> m;
    for (std::size_t c = 0; c < rows[0].size() && c < rows[r].size(); ++c) m[rows[0][c]] = rows[r][c];
    out.push_back(m);
  }
  return out;
}

}  // namespace otfp::test
