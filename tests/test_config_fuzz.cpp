// Deterministic mutation fuzzing of the configuration reader (issue 13).
//
// Seeds: every examples/*.toml. A fixed-seed generator mutates them (bytes,
// values, lines, sections, keys) and adds --set overrides built from the
// schema's key list. For every case, parsing and building the ConfiguredRun
// either succeeds or throws ConfigError with a one-line message: any other
// exception escaping (std::out_of_range, a toml++ or nlohmann exception,
// std::bad_alloc, ...) is a defect and fails with the case printed. A few of
// the accepted cases with small derived numbers are also run (two steps, in
// memory): the run completes or fails cleanly and no step record holds a
// non-finite number. The case list is the same on every run and machine
// (std::mt19937_64 used through its raw output only).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <typeinfo>
#include <utility>
#include <vector>

#include "otfp_app/config.hpp"
#include "otfp_app/simulation.hpp"

using namespace otfp::app;
using otfp::StepRecord;
namespace fs = std::filesystem;

namespace {

constexpr std::uint64_t kFuzzSeed = 0x0f1c0f13'5eed'0013ULL;
constexpr int kCases = 1500;      // parse cases in total
constexpr int kRunCases = 25;     // accepted cases that are also run
constexpr std::int64_t kRunParticleCap = 2000;  // n_inf and fill_count of a run case

struct Seed {
  std::string name, text;
};

std::vector<Seed> load_seeds() {
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(fs::path(OTFP_SOURCE_DIR) / "examples"))
    if (e.is_regular_file() && e.path().extension() == ".toml") files.push_back(e.path());
  std::sort(files.begin(), files.end());  // directory order is not fixed
  std::vector<Seed> out;
  for (const fs::path& f : files) {
    std::ifstream in(f, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    out.push_back({f.filename().string(), s.str()});
  }
  return out;
}

// Values a mutated key or --set may take: the brief's edge numbers, the wrong
// types, and strings with escapes, control and non-ASCII characters.
const std::vector<std::string>& value_dictionary() {
  static const std::vector<std::string> v = {
      "0", "-0", "-1", "1e308", "-1e308", "1e-308", "nan", "inf", "-inf", "1e400", "9223372036854775807",
      "18446744073709551616", "3.0", "\"x\"", "true", "[]", "[1,2,3,4]", "[1e308, -1e308, 0]", "[nan]", "-nan",
      "+inf", "0.5", "2", "1000000000", "-9223372036854775808", "4.9e-324", "\"\"", "\"a\\nb\"", "\"\\t\\u0000\"",
      "\"\\u00e9t\\u00e9\"", "\"x-\"", "\"surface\"", "\"cap_b\"", "\"file\"", "\"lattice\"", "\"cosine\"",
      "\"papers\"", "\"explicit\"", "\"adaptive\"", "\"per_particle\"", "\"no_flux\"", "\"dirichlet\"",
      "\"neumann\"", "\"periodic_box\"", "\"free\"", "\"box\"", "\"cylinder\"", "\"ball\"", "{a = 1}",
      "1979-05-27", "0x10", "1_000", "'lit'", "[[1]]", "\"../\""};
  return v;
}

const std::vector<std::string>& special_bytes() {
  static const std::vector<std::string> v = {
      std::string(1, '\0'), "\x01", "\x1f", "\x7f", "\n", "\r", "\t", "\"", "'", "[", "]", "=", "#", "\\",
      "{", "}", ",", ".", "\x80", "\xc3\xa9", "\xff", "\xfe", "\xef\xbb\xbf", "\xe2\x80\xa8", "\\u", "\"\"\"",
      "[[", "]]", "\\n", "e", "-", "+", "_", "9"};
  return v;
}

class Mutator {
 public:
  explicit Mutator(std::uint64_t seed) : gen_(seed) {}

  std::size_t below(std::size_t n) { return n == 0 ? 0 : static_cast<std::size_t>(gen_() % n); }
  bool chance(int percent) { return below(100) < static_cast<std::size_t>(percent); }
  template <class T>
  const T& pick(const std::vector<T>& v) {
    return v[below(v.size())];
  }

  // One mutation of `text`; `what` says which.
  void mutate(std::string& text, std::string& what) {
    switch (below(10)) {
      case 0: flip_byte(text, what); break;
      case 1: delete_bytes(text, what); break;
      case 2: duplicate_bytes(text, what); break;
      case 3: insert_bytes(text, what); break;
      case 4:
      case 5: replace_value(text, what); break;
      case 6: drop_line(text, what); break;
      case 7: drop_section(text, what); break;
      case 8: duplicate_key(text, what); break;
      default: swap_values(text, what); break;
    }
  }

  // A --set override from the schema's key list, with a dictionary value.
  std::string override_from_schema(const std::vector<std::string>& keys) {
    std::string key = pick(keys);
    const auto entry = [this]() -> std::string {
      static const std::vector<std::string> sel = {"0", "1", "2", "surface", "x-", "outlet", "99999999999999999999"};
      return pick(sel);
    };
    if (key.rfind("boundary[]", 0) == 0) {
      key = (chance(50) ? "boundary." + entry() : "boundary[" + entry() + "]") + key.substr(10);
    } else if (key.rfind("domain.subpatch[]", 0) == 0) {
      key = (chance(50) ? "domain.subpatch." + entry() : "domain.subpatch[" + entry() + "]") + key.substr(17);
    }
    std::string value = pick(value_dictionary());
    if (chance(15) && value.size() > 2 && value.front() == '"') value = value.substr(1, value.size() - 2);  // bare word
    return key + "=" + value;
  }

 private:
  struct Line {
    std::size_t begin, end;  // [begin, end), without the newline
  };
  std::vector<Line> lines(const std::string& t) const {
    std::vector<Line> out;
    std::size_t b = 0;
    while (b <= t.size()) {
      std::size_t e = t.find('\n', b);
      if (e == std::string::npos) e = t.size();
      out.push_back({b, e});
      b = e + 1;
    }
    return out;
  }
  // Lines of the form `key = value` (value from after '=' to a comment or the end).
  struct KeyLine {
    std::size_t line_begin, line_end, value_begin, value_end;
  };
  std::vector<KeyLine> key_lines(const std::string& t) const {
    std::vector<KeyLine> out;
    for (const Line& l : lines(t)) {
      const std::string s = t.substr(l.begin, l.end - l.begin);
      const std::size_t first = s.find_first_not_of(" \t");
      if (first == std::string::npos || s[first] == '#' || s[first] == '[') continue;
      const std::size_t eq = s.find('=');
      if (eq == std::string::npos) continue;
      std::size_t vb = s.find_first_not_of(" \t", eq + 1);
      if (vb == std::string::npos) continue;
      std::size_t ve = s.size();
      if (s[vb] != '"') {
        const std::size_t hash = s.find('#', vb);
        if (hash != std::string::npos) ve = hash;
      } else {
        const std::size_t close = s.find('"', vb + 1);
        if (close != std::string::npos) ve = close + 1;
      }
      while (ve > vb && (s[ve - 1] == ' ' || s[ve - 1] == '\t')) --ve;
      out.push_back({l.begin, l.end, l.begin + vb, l.begin + ve});
    }
    return out;
  }

  void flip_byte(std::string& t, std::string& what) {
    if (t.empty()) return;
    const std::size_t i = below(t.size());
    const auto mask = static_cast<unsigned char>(chance(50) ? 1u << below(8) : 1 + below(255));
    t[i] = static_cast<char>(static_cast<unsigned char>(t[i]) ^ mask);
    what += "flip@" + std::to_string(i) + " ";
  }
  void delete_bytes(std::string& t, std::string& what) {
    if (t.empty()) return;
    const std::size_t i = below(t.size());
    const std::size_t n = 1 + below(chance(80) ? 4 : 64);
    t.erase(i, n);
    what += "delete@" + std::to_string(i) + "+" + std::to_string(n) + " ";
  }
  void duplicate_bytes(std::string& t, std::string& what) {
    if (t.empty()) return;
    const std::size_t i = below(t.size());
    const std::size_t n = std::min(t.size() - i, 1 + below(chance(70) ? 8 : 128));
    const std::size_t at = below(t.size() + 1);
    t.insert(at, t.substr(i, n));
    what += "dup@" + std::to_string(i) + "+" + std::to_string(n) + "->" + std::to_string(at) + " ";
  }
  void insert_bytes(std::string& t, std::string& what) {
    const std::size_t at = below(t.size() + 1);
    std::string ins;
    for (std::size_t k = 0, n = 1 + below(4); k < n; ++k)
      ins += chance(60) ? pick(special_bytes()) : std::string(1, static_cast<char>(below(256)));
    t.insert(at, ins);
    what += "insert@" + std::to_string(at) + " ";
  }
  void replace_value(std::string& t, std::string& what) {
    const auto kl = key_lines(t);
    if (kl.empty()) return;
    const KeyLine& k = pick(kl);
    const std::string v = pick(value_dictionary());
    what += "value '" + t.substr(k.line_begin, k.value_begin - k.line_begin) + v + "' ";
    t.replace(k.value_begin, k.value_end - k.value_begin, v);
  }
  void drop_line(std::string& t, std::string& what) {
    const auto ls = lines(t);
    const Line& l = pick(ls);
    what += "drop line '" + t.substr(l.begin, l.end - l.begin) + "' ";
    t.erase(l.begin, std::min(t.size(), l.end + 1) - l.begin);
  }
  void drop_section(std::string& t, std::string& what) {
    std::vector<std::size_t> headers;
    for (const Line& l : lines(t))
      if (l.end > l.begin && t[l.begin] == '[') headers.push_back(l.begin);
    if (headers.empty()) return;
    const std::size_t h = below(headers.size());
    const std::size_t b = headers[h];
    const std::size_t e = h + 1 < headers.size() ? headers[h + 1] : t.size();
    what += "drop section '" + t.substr(b, t.find('\n', b) - b) + "' ";
    t.erase(b, e - b);
  }
  void duplicate_key(std::string& t, std::string& what) {
    const auto kl = key_lines(t);
    if (kl.empty()) return;
    const KeyLine& k = pick(kl);
    std::string line = t.substr(k.line_begin, k.line_end - k.line_begin);
    if (chance(50)) line = t.substr(k.line_begin, k.value_begin - k.line_begin) + pick(value_dictionary());
    what += "dup key '" + line + "' ";
    t.insert(std::min(t.size(), k.line_end + 1), line + "\n");
  }
  void swap_values(std::string& t, std::string& what) {
    const auto kl = key_lines(t);
    if (kl.size() < 2) return;
    std::size_t a = below(kl.size()), b = below(kl.size());
    if (a == b) return;
    if (a > b) std::swap(a, b);
    const std::string va = t.substr(kl[a].value_begin, kl[a].value_end - kl[a].value_begin);
    const std::string vb = t.substr(kl[b].value_begin, kl[b].value_end - kl[b].value_begin);
    what += "swap '" + va + "' '" + vb + "' ";
    // The later one first: the earlier offsets stay valid.
    t.replace(kl[b].value_begin, kl[b].value_end - kl[b].value_begin, va);
    t.replace(kl[a].value_begin, kl[a].value_end - kl[a].value_begin, vb);
  }

  std::mt19937_64 gen_;
};

struct Case {
  int index = 0;
  std::string seed, what, text;
  std::vector<std::string> sets;
};

// The fixed list of cases: one to three mutations of a seed's text and/or up to
// three --set overrides (at least one of either).
std::vector<Case> make_cases() {
  const std::vector<Seed> seeds = load_seeds();
  const std::vector<std::string> keys = schema_keys();
  Mutator m(kFuzzSeed);
  std::vector<Case> out;
  for (int i = 0; i < kCases; ++i) {
    const Seed& s = seeds[static_cast<std::size_t>(i) % seeds.size()];
    Case c;
    c.index = i;
    c.seed = s.name;
    c.text = s.text;
    const std::size_t shape = m.below(10);  // 0-5 text, 6-7 --set, 8-9 both
    if (shape < 6 || shape >= 8)
      for (std::size_t k = 0, n = 1 + m.below(3); k < n; ++k) m.mutate(c.text, c.what);
    if (shape >= 6)
      for (std::size_t k = 0, n = 1 + m.below(3); k < n; ++k) c.sets.push_back(m.override_from_schema(keys));
    out.push_back(std::move(c));
  }
  return out;
}

// Bytes as C escapes, so that a failure shows the case exactly.
std::string printable(const std::string& s) {
  std::string out;
  for (const char ch : s) {
    const auto u = static_cast<unsigned char>(ch);
    if (ch == '\n')
      out += "\\n\n";  // keeps the lines
    else if (ch == '\\')
      out += "\\\\";
    else if (u < 0x20 || u >= 0x7f) {
      static const char* hex = "0123456789abcdef";
      out += "\\x";
      out += hex[u >> 4];
      out += hex[u & 15];
    } else {
      out += ch;
    }
  }
  return out;
}

std::string describe(const Case& c) {
  std::string out = "case " + std::to_string(c.index) + " (seed " + c.seed + "; " + c.what + ")\n";
  for (const std::string& s : c.sets) out += "--set " + printable(s) + "\n";
  return out + "---- text ----\n" + printable(c.text) + "\n---- end ----";
}

std::string type_of(const std::exception& e) { return typeid(e).name(); }

// Outcome of parsing and building one case.
enum class Outcome { Accepted, Rejected, Defect };

// Parses and builds; a defect (another exception type, a multi-line or empty
// ConfigError) is a test failure with the case printed.
Outcome check_case(const Case& c, const std::vector<std::string>& sets, std::unique_ptr<ConfiguredRun>* keep = nullptr) {
  try {
    auto run = std::make_unique<ConfiguredRun>(parse_config_string(c.text, sets));
    if (keep) *keep = std::move(run);
    return Outcome::Accepted;
  } catch (const ConfigError& e) {
    const std::string what = e.what();
    if (what.empty() || what.find('\n') != std::string::npos) {
      ADD_FAILURE() << "ConfigError message is empty or not one line: \"" << printable(what) << "\"\n" << describe(c);
      return Outcome::Defect;
    }
    return Outcome::Rejected;
  } catch (const std::exception& e) {
    ADD_FAILURE() << "exception " << type_of(e) << " (not ConfigError): " << printable(e.what()) << "\n" << describe(c);
  } catch (...) {
    ADD_FAILURE() << "unknown exception (not ConfigError)\n" << describe(c);
  }
  return Outcome::Defect;
}

bool all_finite(const StepRecord& r, std::string& bad) {
  const std::pair<const char*, double> values[] = {
      {"t", r.t},
      {"dt", r.dt},
      {"mass_total", r.mass_total},
      {"mass_inside", r.mass_inside},
      {"mass_with_layer", r.mass_with_layer},
      {"polar_inertia", r.polar_inertia},
      {"polar_inertia_with_layer", r.polar_inertia_with_layer},
      {"polar_inertia_total", r.polar_inertia_total},
      {"energy", r.energy},
      {"transport", r.transport},
      {"entropy", r.entropy},
      {"barrier", r.barrier},
      {"residual_displacement", r.residual_displacement},
      {"error_estimate", r.error_estimate.value_or(0.0)},
      {"mean_age", r.mean_age},
      {"max_age", r.max_age},
      {"l1_mass", r.l1_mass},
      {"l1_polar_inertia", r.l1_polar_inertia},
      {"mass_ratio", r.mass_ratio},
      {"mass_blob", r.mass_blob},
      {"mass_blob_ratio", r.mass_blob_ratio},
      {"error_mass_blob", r.error_mass_blob.value_or(0.0)},
      {"polar_inertia_ratio", r.polar_inertia_ratio.value_or(0.0)},
      {"reference", r.reference.value_or(0.0)},
      {"wall_seconds", r.wall_seconds},
      {"step_seconds", r.step_seconds},
      {"solver_seconds", r.solver_seconds},
      {"list_seconds", r.list_seconds},
  };
  for (const auto& [name, v] : values)
    if (!std::isfinite(v)) {
      bad = std::string(name) + " = " + std::to_string(v);
      return false;
    }
  for (std::size_t i = 0; i < r.reference_values.size(); ++i)
    if (!std::isfinite(r.reference_values[i])) {
      bad = "reference_values[" + std::to_string(i) + "] = " + std::to_string(r.reference_values[i]);
      return false;
    }
  return true;
}

}  // namespace

// Every case is accepted or rejected with ConfigError; never another exception.
TEST(ConfigFuzz, MutatedExamplesAreAcceptedOrRejectedWithConfigError) {
  const std::vector<Case> cases = make_cases();
  ASSERT_EQ(cases.size(), static_cast<std::size_t>(kCases));
  int accepted = 0, rejected = 0, defects = 0;
  for (const Case& c : cases) {
    switch (check_case(c, c.sets)) {
      case Outcome::Accepted: ++accepted; break;
      case Outcome::Rejected: ++rejected; break;
      case Outcome::Defect: ++defects; break;
    }
  }
  std::cout << "[ fuzz     ] " << cases.size() << " cases: " << accepted << " accepted, " << rejected
            << " rejected with ConfigError, " << defects << " defects\n";
  EXPECT_EQ(defects, 0);
  // The mutations must leave a fair share of cases that get past the parser.
  EXPECT_GT(accepted, kCases / 20);
  EXPECT_GT(rejected, kCases / 4);
}

// A few accepted cases with small derived numbers run two steps in memory: the
// run completes or fails (exit code 0 or 1) and writes no non-finite number.
TEST(ConfigFuzz, AcceptedMutantsRunCleanly) {
  const std::vector<Case> cases = make_cases();
  int ran = 0, completed = 0;
  for (const Case& c : cases) {
    if (ran >= kRunCases) break;
    std::vector<std::string> sets = c.sets;
    sets.push_back("run.max_steps=2");
    std::unique_ptr<ConfiguredRun> run;
    if (check_case(c, sets, &run) != Outcome::Accepted) continue;
    const Derived& d = run->derived();
    if (run->config().particles.n_inf > kRunParticleCap || d.fill_count > kRunParticleCap) continue;
    // Image blobs at a curved wall cost seconds per step even at n_inf = 400
    // (minutes under ASan): such runs are left to the examples' own tests.
    const DomainType type = run->config().domain.type;
    if (d.mirrored_walls > 0 &&
        (type == DomainType::Ball || type == DomainType::Cylinder || type == DomainType::SquarePipeObstacle))
      continue;
#if defined(OTFP_SANITIZE_ADDRESS)
    // Under the sanitizers (about 7x slower) a case whose Dirichlet data fill
    // the reservoir band with far more particles than n_inf (g |Omega| >>
    // M_inf) is left to the Release pass, which runs it: one such case (235k
    // blobs, each overlapping 18k others, refused by the neighbour list) took
    // 3 of the sanitizer pass's 5 minutes of tests.
    double g_max = 0.0;
    for (const PatchInfo& p : run->patches())
      if (p.kind == otfp::PatchKind::Dirichlet) g_max = std::max(g_max, std::abs(p.value));
    if (g_max * d.volume > 50.0 * d.M_inf) continue;
#endif
    ++ran;
    if (std::getenv("OTFP_FUZZ_TRACE")) std::cerr << "case " << ran << "\n" << describe(c) << std::endl;
    RunOptions options;  // empty out_dir: in memory, nothing written
    options.keep_series = true;
    RunResult r;
    try {
      r = run->run(options);
    } catch (const std::exception& e) {
      ADD_FAILURE() << "run() threw " << type_of(e) << ": " << printable(e.what()) << "\n" << describe(c);
      continue;
    } catch (...) {
      ADD_FAILURE() << "run() threw an unknown exception\n" << describe(c);
      continue;
    }
    EXPECT_TRUE(r.status == "completed" || r.status == "failed") << r.status << "\n" << describe(c);
    EXPECT_TRUE(r.exit_code == 0 || r.exit_code == 1) << r.exit_code << "\n" << describe(c);
    EXPECT_EQ(r.exit_code == 0, r.status == "completed") << describe(c);
    if (r.status == "completed") {
      ++completed;
      EXPECT_FALSE(r.series.empty()) << describe(c);
    }
    for (const StepRecord& rec : r.series) {
      std::string bad;
      if (!all_finite(rec, bad)) {
        ADD_FAILURE() << "non-finite " << bad << " at step " << rec.step << " (status " << r.status << ")\n"
                      << describe(c);
        break;
      }
    }
  }
  std::cout << "[ fuzz     ] ran " << ran << " accepted cases: " << completed << " completed\n";
  EXPECT_EQ(ran, kRunCases);
}
