// Configuration schema, --set overrides and the rejection of bad input
// (exit code 2, a message naming the key, nothing written).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "otfp_app/cli.hpp"
#include "otfp_app/config.hpp"
#include "otfp_app/simulation.hpp"

using namespace otfp;
using namespace otfp::app;
namespace fs = std::filesystem;

namespace {

const fs::path kSource = OTFP_SOURCE_DIR;

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// A small valid configuration the bad cases start from.
const std::string kBase = R"(
[run]
t_end = 0.1
[domain]
type = "ball"
radius = 1.0
[particles]
n_inf = 100
[[boundary]]
patch = "surface"
kind = "dirichlet"
value = 0.25
)";

// Parses and builds; returns the ConfigError message ("" if accepted).
std::string rejection(const std::string& text, const std::vector<std::string>& sets = {}) {
  try {
    Simulation sim(parse_config_string(text, sets));
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

fs::path fresh_dir(const std::string& tag) {
  const fs::path p = fs::temp_directory_path() / ("otfp_test_config_" + tag + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  return p;
}

}  // namespace

TEST(Config, EmptyDocumentGivesDocumentedDefaults) {
  const Config c = parse_config_string("");
  EXPECT_EQ(c.run.dim, 3);
  EXPECT_DOUBLE_EQ(c.run.t_end, 1.0);
  EXPECT_FALSE(c.run.dt.has_value());
  EXPECT_DOUBLE_EQ(c.run.dt_factor, 1.0);
  EXPECT_EQ(c.run.threads, 1);
  EXPECT_EQ(c.domain.type, "ball");
  EXPECT_EQ(c.particles.n_inf, 400);
  EXPECT_EQ(c.particles.spacing_rule, "cube");
  EXPECT_DOUBLE_EQ(c.particles.beta_factor, 2.0);
  EXPECT_EQ(c.solver.stepper, "implicit");
  EXPECT_EQ(c.solver.backend, "ceres");
  EXPECT_EQ(c.solver.width_metric, "as_printed");
  EXPECT_DOUBLE_EQ(c.solver.barrier_factor, 1.0);
  EXPECT_EQ(c.diagnostics.reference, "none");
  EXPECT_TRUE(c.boundary.empty());
}

TEST(Config, ToTomlRoundTrips) {
  const Config a = parse_config_file(kSource / "examples" / "pipe_neumann.toml");
  const Config b = parse_config_string(to_toml(a));
  EXPECT_EQ(to_toml(a), to_toml(b));
  ASSERT_EQ(b.boundary.size(), 2u);
  EXPECT_EQ(b.boundary[1].patch, "outlet");
  EXPECT_DOUBLE_EQ(*b.boundary[1].value, 20000.0);
  ASSERT_EQ(b.domain.subpatches.size(), 1u);
  EXPECT_EQ(b.domain.subpatches[0].on, "cap_b");
}

// docs/configuration.md must document every key of the schema.
TEST(Config, EveryKeyIsDocumented) {
  const std::string doc = read_text(kSource / "docs" / "configuration.md");
  ASSERT_FALSE(doc.empty());
  for (const std::string& key : schema_keys()) {
    const std::string name = key.substr(key.rfind('.') + 1);
    const std::string section = key.substr(0, key.find_first_of(".["));
    EXPECT_NE(doc.find("`" + name + "`"), std::string::npos) << key << " is not documented";
    EXPECT_NE(doc.find(section), std::string::npos) << key;
  }
}

TEST(Config, TreatmentKeysReachTheRun) {
  Simulation papers(parse_config_string(kBase, {"treatment.preset=papers"}));
  EXPECT_EQ(papers.derived().mirrored_walls, 0);
  EXPECT_EQ(papers.derived().reservoir_width, 0.0);
  EXPECT_EQ(papers.config().particles.spacing_rule, "sphere_radius");
  // The default preset ("converging"): the odd reservoir, whose back face is mirrored, and the true spacing.
  Simulation converging(parse_config_string(kBase));
  EXPECT_EQ(converging.config().treatment.preset, "converging");
  EXPECT_EQ(converging.config().treatment.dirichlet, "reservoir");
  EXPECT_EQ(converging.config().treatment.reservoir_profile, "odd");
  EXPECT_EQ(converging.config().particles.spacing_rule, "cube");
  EXPECT_EQ(converging.derived().mirrored_walls, 1);
  EXPECT_GT(converging.derived().reservoir_width, 0.0);
  // A key set beside the preset wins over it, wherever it stands.
  const Config mixed = parse_config_string(kBase + "[treatment]\nno_flux = \"barrier\"\npreset = \"converging\"\n",
                                           {"treatment.neumann_outflow=layer"});
  EXPECT_EQ(mixed.treatment.no_flux, "barrier");
  EXPECT_EQ(mixed.treatment.neumann_outflow, "layer");
  EXPECT_EQ(mixed.treatment.dirichlet, "reservoir");
  const Config explicit_rule = parse_config_string(kBase, {"treatment.preset=papers", "particles.spacing_rule=cube"});
  EXPECT_EQ(explicit_rule.particles.spacing_rule, "cube");
  EXPECT_EQ(parse_config_string(kBase, {"treatment.preset=papers", "run.dim=2"}).particles.spacing_rule, "cube");
  Simulation reservoir(parse_config_string(kBase, {"particles.n_inf=1600", "treatment.dirichlet=reservoir",
                                                   "treatment.reservoir_width=1.5", "treatment.reservoir_profile=odd"}));
  const Derived& d = reservoir.derived();
  // w = 1.5 r_c with r_c = s sqrt(ln(1e8)); sublayers round(2 w / dr); the band's back face is mirrored.
  EXPECT_NEAR(d.reservoir_width, 1.5 * d.width_s * std::sqrt(std::log(1e8)), 1e-12);
  EXPECT_EQ(d.reservoir_sublayers, static_cast<int>(std::lround(2.0 * d.reservoir_width / d.dr)));
  EXPECT_EQ(d.mirrored_walls, 1);
  EXPECT_EQ(reservoir.describe()["config"]["treatment"]["reservoir_profile"], "odd");
  // The resolved TOML parses back to the same treatment.
  const Config again = parse_config_string(to_toml(reservoir.config()));
  EXPECT_EQ(again.treatment.dirichlet, "reservoir");
  EXPECT_DOUBLE_EQ(again.treatment.reservoir_width, 1.5);
  EXPECT_EQ(again.treatment.reservoir_profile, "odd");
  // A box with one Dirichlet face: images at the five others (papers' layer),
  // and the reservoir's back face as well under the default preset.
  Simulation box(parse_config_file(std::filesystem::path(OTFP_SOURCE_DIR) / "examples" / "box_mixed.toml",
                                   {"treatment.preset=papers", "treatment.no_flux=images"}));
  EXPECT_EQ(box.derived().mirrored_walls, 5);
  Simulation box_default(parse_config_file(std::filesystem::path(OTFP_SOURCE_DIR) / "examples" / "box_mixed.toml"));
  EXPECT_EQ(box_default.derived().mirrored_walls, 6);
  // The square pipe: six faces and the obstacle (a round wall with the domain outside).
  Simulation pipe(parse_config_file(std::filesystem::path(OTFP_SOURCE_DIR) / "examples" / "square_pipe_occlusion.toml"));
  EXPECT_EQ(pipe.derived().mirrored_walls, 7);
}

TEST(Config, SetUsesTheTypeOfTheKey) {
  const Config c = parse_config_string(kBase, {"particles.n_inf=3200", "solver.stepper=explicit",
                                               "physics.kappa=2", "run.t_end=0.5", "physics.velocity=[1, 0, 0]",
                                               "solver.backend=\"nlopt\"", "diagnostics.center=[0.5]"});
  EXPECT_EQ(c.particles.n_inf, 3200);
  EXPECT_EQ(c.solver.stepper, "explicit");
  EXPECT_DOUBLE_EQ(c.physics.kappa, 2.0);  // an integer literal into a float key
  EXPECT_DOUBLE_EQ(c.run.t_end, 0.5);
  EXPECT_DOUBLE_EQ(c.physics.velocity.x(), 1.0);
  EXPECT_EQ(c.solver.backend, "nlopt");
  EXPECT_DOUBLE_EQ(c.diagnostics.center->x(), 0.5);
  EXPECT_DOUBLE_EQ(c.diagnostics.center->y(), 0.0);
}

TEST(Config, SetAddressesBoundaryEntriesByIndexOrPatchName) {
  Config c = parse_config_string(kBase, {"boundary.0.value=0.5"});
  EXPECT_DOUBLE_EQ(*c.boundary[0].value, 0.5);
  c = parse_config_string(kBase, {"boundary.surface.value=0.75"});
  EXPECT_DOUBLE_EQ(*c.boundary[0].value, 0.75);
  c = parse_config_string(kBase, {"boundary[0].value=0.1"});
  EXPECT_DOUBLE_EQ(*c.boundary[0].value, 0.1);
  // A new patch name appends an entry.
  const std::string box = "[domain]\ntype = \"box\"\n[particles]\nn_inf = 100\n";
  c = parse_config_string(box, {"boundary.x-.kind=dirichlet", "boundary.x-.value=2"});
  ASSERT_EQ(c.boundary.size(), 1u);
  EXPECT_EQ(c.boundary[0].patch, "x-");
  EXPECT_EQ(c.boundary[0].kind, "dirichlet");
  // Index == size appends too.
  c = parse_config_string(box, {"boundary.0.patch=y+", "boundary.0.kind=no_flux"});
  EXPECT_EQ(c.boundary[0].patch, "y+");
}

// Every bad configuration is rejected with a message that names the key.
TEST(Config, BadConfigurationsNameTheirKey) {
  struct Case {
    std::string what, text;
    std::vector<std::string> sets;
    std::string key;
  };
  const std::vector<Case> cases = {
      {"unknown key", kBase + "[solver]\nbacknd = \"ceres\"\n", {}, "solver.backnd"},
      {"unknown section", kBase + "[solvers]\nbackend = \"ceres\"\n", {}, "solvers"},
      {"negative kappa", kBase, {"physics.kappa=-1"}, "physics.kappa"},
      {"zero kappa", kBase, {"physics.kappa=0"}, "physics.kappa"},
      {"dt = 0", kBase, {"run.dt=0"}, "run.dt"},
      {"negative dt", kBase, {"run.dt=-0.1"}, "run.dt"},
      {"NaN", kBase, {"physics.rho_ref=nan"}, "physics.rho_ref"},
      {"infinite t_end", kBase, {"run.t_end=inf"}, "run.t_end"},
      {"empty ball", kBase, {"domain.radius=0"}, "domain.radius"},
      {"empty box", "[domain]\ntype = \"box\"\nlo = [0, 0, 0]\nhi = [1, 0, 1]\n", {}, "domain.hi"},
      {"b larger than the domain", kBase, {"treatment.preset=papers", "particles.layer_b=1.5"}, "particles.layer_b"},
      {"unknown preset", kBase, {"treatment.preset=paper"}, "treatment.preset"},
      {"missing patch kind", kBase + "[[boundary]]\npatch = \"orifice\"\nvalue = 1.0\n", {}, "boundary[1].kind"},
      {"missing patch name", kBase + "[[boundary]]\nkind = \"neumann\"\nvalue = 1.0\n", {}, "boundary[1].patch"},
      {"unknown patch name", kBase, {"boundary.0.patch=north"}, "boundary[0].patch"},
      {"duplicate patch", kBase, {"boundary.1.patch=surface", "boundary.1.kind=no_flux"}, "boundary[1].patch"},
      {"wrong type", kBase, {"physics.kappa=\"one\""}, "physics.kappa"},
      {"wrong type in the file", kBase + "[solver]\nmax_iterations = \"many\"\n", {}, "solver.max_iterations"},
      {"integer key given a float", kBase, {"particles.n_inf=10.5"}, "particles.n_inf"},
      {"unknown backend", kBase, {"solver.backend=petsc"}, "solver.backend"},
      {"algorithm of the other backend", kBase, {"solver.algorithm=mma"}, "solver.algorithm"},
      {"unknown domain type", kBase, {"domain.type=torus"}, "domain.type"},
      {"negative Dirichlet density", kBase, {"boundary.0.value=-0.1"}, "boundary[0].value"},
      {"Dirichlet window", kBase, {"boundary.0.t_end=1"}, "boundary[0].t_end"},
      {"value on no_flux", kBase, {"boundary.0.kind=no_flux"}, "boundary[0].value"},
      {"sub-patch on unknown patch",
       kBase + "[[domain.subpatch]]\nname = \"o\"\non = \"top\"\nradius = 0.1\n", {}, "domain.subpatch[0].on"},
      {"sub-patch centre off the boundary",
       kBase + "[[domain.subpatch]]\nname = \"o\"\non = \"surface\"\ncenter = [0, 0, 0.5]\nradius = 0.1\n", {},
       "domain.subpatch[0].center"},
      {"dim out of range", kBase, {"run.dim=4"}, "run.dim"},
      {"point with 4 components", kBase, {"diagnostics.center=[1, 2, 3, 4]"}, "diagnostics.center"},
      {"fill count and mass", kBase, {"particles.fill=uniform", "particles.fill_count=10", "particles.fill_mass=1"},
       "particles.fill_count"},
      {"malformed --set", kBase, {"physics.kappa"}, "--set"},
      {"crank_slab on a ball", kBase, {"diagnostics.reference=crank_slab"}, "diagnostics.reference_length"},
      {"periodic box under two list radii", "[domain]\ntype = \"periodic_box\"\n", {}, "domain.hi"},
      {"width exponent zero", kBase, {"particles.width_exponent=0"}, "particles.width_exponent"},
      {"width exponent above 2", kBase, {"particles.width_exponent=2.5"}, "particles.width_exponent"},
      {"width exponent NaN", kBase, {"particles.width_exponent=nan"}, "particles.width_exponent"},
      {"width reference n zero", kBase, {"particles.width_reference_n=0"}, "particles.width_reference_n"},
      {"width reference n not an integer", kBase, {"particles.width_reference_n=1.5"}, "particles.width_reference_n"},
      {"unknown no-flux treatment", kBase, {"treatment.no_flux=mirror"}, "treatment.no_flux"},
      {"unknown Dirichlet treatment", kBase, {"treatment.dirichlet=bath"}, "treatment.dirichlet"},
      {"reservoir width zero", kBase, {"treatment.reservoir_width=0"}, "treatment.reservoir_width"},
      {"reservoir width above 10", kBase, {"treatment.reservoir_width=11"}, "treatment.reservoir_width"},
      {"odd reservoir deeper than the ball", kBase,
       {"treatment.dirichlet=reservoir", "treatment.reservoir_profile=odd", "treatment.reservoir_width=1.5"},
       "treatment.reservoir_width"},
      {"negative sublayers", kBase, {"treatment.reservoir_sublayers=-1"}, "treatment.reservoir_sublayers"},
      {"unknown reservoir profile", kBase, {"treatment.reservoir_profile=even"}, "treatment.reservoir_profile"},
      {"unknown outflow rule", kBase, {"treatment.neumann_outflow=all"}, "treatment.neumann_outflow"},
      {"reservoir on a sub-patch",
       kBase + "[[domain.subpatch]]\nname = \"o\"\non = \"surface\"\ncenter = [0, 0, 1]\nradius = 0.3\n",
       {"boundary.0.patch=o", "treatment.dirichlet=reservoir"}, "treatment.dirichlet"},
  };
  ASSERT_GE(cases.size(), 10u);
  const fs::path file = fs::temp_directory_path() / ("otfp_test_config_bad_" + std::to_string(::getpid()) + ".toml");
  const fs::path dir = fresh_dir("bad");
  for (const Case& c : cases) {
    const std::string msg = rejection(c.text, c.sets);
    EXPECT_FALSE(msg.empty()) << c.what << ": accepted";
    EXPECT_NE(msg.find(c.key), std::string::npos) << c.what << ": message '" << msg << "' does not name " << c.key;
    // The same through the command line: exit code 2, one line, no output directory.
    {
      std::ofstream f(file);
      f << c.text;
    }
    std::vector<std::string> args = {"otfp", "run", file.string(), "--out", dir.string(), "--quiet"};
    for (const std::string& s : c.sets) {
      args.push_back("--set");
      args.push_back(s);
    }
    std::vector<const char*> argv;
    for (const std::string& a : args) argv.push_back(a.c_str());
    std::ostringstream out, err;
    EXPECT_EQ(cli_main(static_cast<int>(argv.size()), argv.data(), out, err), 2) << c.what;
    EXPECT_EQ(err.str(), "otfp: error: " + msg + "\n") << c.what;
    EXPECT_FALSE(fs::exists(dir)) << c.what;
  }
  fs::remove(file);
}

TEST(Config, SyntaxErrorsGiveFileLineAndColumn) {
  try {
    parse_config_string("[run\nt_end = 1\n", {}, "bad.toml");
    FAIL() << "accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.toml:1:"), std::string::npos) << e.what();
  }
}

TEST(Config, EveryExampleIsValid) {
  int count = 0;
  for (const auto& entry : fs::directory_iterator(kSource / "examples")) {
    if (entry.path().extension() != ".toml") continue;
    ++count;
    SCOPED_TRACE(entry.path().string());
    EXPECT_NO_THROW({ Simulation sim(parse_config_file(entry.path())); });
  }
  EXPECT_GE(count, 6);
}

// The papers' parameter rules come out of the example configurations with
// treatment.preset = "papers".
TEST(Config, ExamplesReproduceThePapersTables) {
  {
    Simulation s(parse_config_file(kSource / "examples" / "sphere_dirichlet.toml",
                                   {"particles.n_inf=1600", "treatment.preset=papers"}));
    EXPECT_NEAR(s.derived().dr, 0.085498797, 1e-8);      // Table 1
    EXPECT_NEAR(s.derived().beta, 273.59615, 1e-4);
    EXPECT_NEAR(s.derived().particle_mass, 6.25e-4, 1e-15);
    EXPECT_NEAR(s.derived().layer_b, std::sqrt(0.085498797), 1e-8);
  }
  {
    Simulation s(parse_config_file(kSource / "examples" / "box_mixed.toml", {"treatment.preset=papers"}));
    EXPECT_NEAR(s.derived().dr, 0.10607847, 1e-7);       // Table 2, n_inf = 400
    EXPECT_NEAR(s.derived().beta, 177.73604, 1e-4);
    EXPECT_NEAR(s.derived().particle_mass, 2.5, 1e-12);
    ASSERT_TRUE(s.derived().J_inf.has_value());
    EXPECT_NEAR(*s.derived().J_inf, 500.0, 1e-9);          // (48)
  }
  {
    Simulation s(parse_config_file(kSource / "examples" / "pipe_neumann.toml", {"run.t_end=6", "treatment.preset=papers"}));
    EXPECT_NEAR(s.derived().dr, 0.0721, 1e-4);           // Table 3, n_initial = 1000
    EXPECT_NEAR(s.derived().layer_b, 0.190, 1e-3);
    EXPECT_NEAR(s.derived().dt, 0.0052, 1e-5);
    EXPECT_NEAR(s.derived().beta, 192.30, 1e-2);
    EXPECT_EQ(s.derived().fill_count, 1000);
    EXPECT_NEAR(s.derived().particle_mass, 1.0, 1e-12);
  }
}

TEST(Config, DefaultMinfAndJinfFollowTheDomain) {
  // Dirichlet ball: M_inf = g |Omega|, J_inf = 3/5 M_inf R^2 about the centre.
  Simulation s(parse_config_string(kBase));
  const double vol = 4.0 / 3.0 * M_PI;
  EXPECT_NEAR(s.derived().M_inf, 0.25 * vol, 1e-12);
  ASSERT_TRUE(s.derived().J_inf.has_value());
  EXPECT_NEAR(*s.derived().J_inf, 0.6 * 0.25 * vol, 1e-12);
  EXPECT_NEAR(s.derived().particle_mass, 0.25 * vol / 100.0, 1e-15);
  // Injection only (no Dirichlet, empty start): M_inf is the injected mass f A (t_end - t_start).
  const std::string inj = R"(
[run]
t_end = 10.0
[domain]
type = "box"
[[boundary]]
patch = "x-"
kind = "neumann"
value = -3.0
t_end = 4.0
)";
  Simulation s2(parse_config_string(inj));
  EXPECT_NEAR(s2.derived().neumann_net_inflow, 12.0, 1e-12);
  EXPECT_NEAR(s2.derived().M_inf, 12.0, 1e-12);
  EXPECT_NEAR(*s2.derived().J_inf, 12.0 * 3.0 / 12.0, 1e-12);  // unit cube about its centre
}

// Through the command line: exit code 2, "otfp: error: <key> = ...", and no output directory.
TEST(Config, CommandLineRejectsBeforeCreatingTheOutputDirectory) {
  const fs::path dir = fresh_dir("cli");
  const std::string config = (kSource / "examples" / "sphere_dirichlet.toml").string();
  const std::vector<std::vector<std::string>> bad = {
      {"--set", "physics.kappa=-1"}, {"--set", "solver.backend=petsc"}, {"--set", "nonsense.key=1"},
      {"--set", "boundary.0.patch=north"}, {"--set", "run.dt=0"}};
  for (const auto& extra : bad) {
    std::vector<std::string> args = {"otfp", "run", config, "--out", dir.string(), "--quiet"};
    args.insert(args.end(), extra.begin(), extra.end());
    std::vector<const char*> argv;
    for (const std::string& a : args) argv.push_back(a.c_str());
    std::ostringstream out, err;
    const int code = cli_main(static_cast<int>(argv.size()), argv.data(), out, err);
    EXPECT_EQ(code, 2) << extra[1];
    const std::string key = extra[1].substr(0, extra[1].find('='));
    EXPECT_EQ(err.str().rfind("otfp: error: ", 0), 0u) << err.str();
    EXPECT_NE(err.str().find(key.substr(0, key.find('.'))), std::string::npos) << err.str();
    EXPECT_FALSE(fs::exists(dir)) << extra[1];
  }
  // Usage errors are exit code 2 as well.
  const char* no_out[] = {"otfp", "run", config.c_str()};
  std::ostringstream out, err;
  EXPECT_EQ(cli_main(3, no_out, out, err), 2);
  EXPECT_FALSE(fs::exists(dir));
}

TEST(Config, CheckPrintsTheResolvedConfiguration) {
  const std::string config = (kSource / "examples" / "box_mixed.toml").string();
  const char* argv[] = {"otfp", "check", config.c_str(), "--set", "particles.n_inf=800", "--set", "treatment.preset=papers"};
  std::ostringstream out, err;
  EXPECT_EQ(cli_main(7, argv, out, err), 0) << err.str();
  const nlohmann::json j = nlohmann::json::parse(out.str());
  EXPECT_EQ(j["config"]["particles"]["n_inf"], 800);
  // Table 2, n_inf = 800 (the table differs from (3 m_p / (4 pi rho))^(1/3) in its 8th digit).
  EXPECT_NEAR(j["derived"]["dr"].get<double>(), 0.084194539, 1e-7);
}

// particles.width_exponent q and particles.width_reference_n: s = s_rule(dr) (dr / dr_ref)^(q - 1).
TEST(Config, WidthExponent) {
  const Config def = parse_config_string("");
  EXPECT_DOUBLE_EQ(def.particles.width_exponent, 1.0);
  EXPECT_EQ(def.particles.width_reference_n, 400);
  // Round trip.
  const Config a = parse_config_string(kBase, {"particles.width_exponent=0.5", "particles.width_reference_n=800"});
  const Config b = parse_config_string(to_toml(a));
  EXPECT_EQ(to_toml(a), to_toml(b));
  EXPECT_DOUBLE_EQ(b.particles.width_exponent, 0.5);
  EXPECT_EQ(b.particles.width_reference_n, 800);
  // q = 1 is the papers' width bit for bit, whatever width_reference_n.
  const Simulation base(parse_config_string(kBase));
  const Simulation one(parse_config_string(kBase, {"particles.width_exponent=1", "particles.width_reference_n=7"}));
  const double dr = base.derived().dr;
  EXPECT_EQ(one.derived().width_s, base.derived().width_s);
  EXPECT_EQ(one.derived().beta, base.derived().beta);
  EXPECT_EQ(base.derived().beta, 2.0 / (dr * dr));
  EXPECT_EQ(base.derived().width_s, 1.0 / std::sqrt(2.0 / (dr * dr)));
  // kBase: unit ball, cube rule, n_inf = 100; with n_ref = 800, dr / dr_ref = 2 and
  // q = 1/2 gives s = (dr / sqrt(2)) 2^(-1/2) = dr / 2.
  const Simulation half(a);
  EXPECT_EQ(half.derived().dr, dr);
  EXPECT_NEAR(half.derived().width_reference_dr, dr / 2.0, 1e-15);
  EXPECT_NEAR(half.derived().width_s, dr / 2.0, 1e-15);
  EXPECT_NEAR(half.derived().beta, 4.0 / (dr * dr), 1e-9 * half.derived().beta);
  EXPECT_NEAR(half.derived().beta_true_spacing2, 4.0, 1e-12);  // cube rule: dr is the true spacing
  EXPECT_NEAR(half.derived().dt_explicit, dr * dr, 1e-15);     // the step still follows dr
  const nlohmann::json j = half.describe();
  EXPECT_EQ(j["config"]["particles"]["width_exponent"], 0.5);
  EXPECT_EQ(j["config"]["particles"]["width_reference_n"], 800);
  EXPECT_NEAR(j["derived"]["width_s"].get<double>(), dr / 2.0, 1e-15);
  // The one-line message names the key, the value and the rule.
  EXPECT_EQ(rejection(kBase, {"particles.width_exponent=2.5"}).rfind("particles.width_exponent = 2.5: must be in (0, 2]", 0),
            0u);
  EXPECT_EQ(rejection(kBase, {"particles.width_reference_n=0"}), "particles.width_reference_n = 0: must be >= 1");
  // (papers preset: the odd reservoir of a 100-particle ball cannot mirror a band this wide)
  EXPECT_EQ(rejection(kBase, {"particles.width_exponent=2", "treatment.preset=papers"}), "");
}

// The sphere-radius rule is 1.61 times below the true spacing: beta dr_true^2 = 2 x 2.60
// with treatment.preset = "papers"; the default preset takes the true spacing, so
// beta dr_true^2 is beta_factor (docs/configuration.md, "Spacing and width").
TEST(Config, ExamplesBetaTimesTrueSpacingSquared) {
  struct Expect {
    std::string name;
    double converging, papers;
  };
  const std::vector<Expect> expect = {{"sphere_dirichlet.toml", 2.0, 5.1970},      {"box_mixed.toml", 2.0, 5.1970},
                                      {"pipe_neumann.toml", 1.0, 2.5985},          {"free_space_heat.toml", 2.0, 2.0},
                                      {"periodic_cosine.toml", 2.0, 2.0},          {"sphere_injection.toml", 2.0, 5.1970},
                                      {"square_pipe_occlusion.toml", 1.0, 2.5985}};
  for (const Expect& e : expect)
    for (const bool papers : {false, true}) {
      std::vector<std::string> sets;
      if (papers) sets.push_back("treatment.preset=papers");
      const Simulation s(parse_config_file(kSource / "examples" / e.name, sets));
      EXPECT_NEAR(s.derived().beta_true_spacing2, papers ? e.papers : e.converging, 1e-4) << e.name << " " << papers;
      EXPECT_NEAR(s.derived().true_spacing,
                  std::pow(s.derived().volume / static_cast<double>(s.config().particles.n_inf), 1.0 / s.config().run.dim),
                  1e-15)
          << e.name;
    }
}

// Issue 11's keys: each bad value or combination is one line naming the key.
TEST(Config, TimeSchemeAndAdaptiveKeysAreChecked) {
  EXPECT_EQ(rejection(kBase, {"run.dt_mode=adaptive", "solver.time_scheme=bdf2", "solver.predictor=damped"}), "");
  EXPECT_EQ(rejection(kBase, {"run.dt_mode=adaptive", "solver.stepper=explicit"}).rfind("run.dt_mode = \"adaptive\": needs solver.stepper = \"implicit\"", 0), 0u);
  EXPECT_EQ(rejection(kBase, {"solver.time_scheme=bdf2", "solver.stepper=explicit"}).rfind("solver.time_scheme = \"bdf2\": needs", 0), 0u);
  EXPECT_EQ(rejection(kBase, {"solver.predictor=extrapolate", "solver.stepper=explicit"}).rfind("solver.predictor = \"extrapolate\": needs", 0), 0u);
  EXPECT_EQ(rejection(kBase, {"run.time_tolerance=0"}), "run.time_tolerance = 0: must be > 0");
  EXPECT_EQ(rejection(kBase, {"run.dt_min=0.5", "run.dt_max=0.1"}).rfind("run.dt_max = 0.1: must be >= run.dt_min", 0), 0u);
  EXPECT_EQ(rejection(kBase, {"solver.error_smoothing=4"}).rfind("solver.error_smoothing = 4: must be in [0, 3]", 0), 0u);
  EXPECT_NE(rejection(kBase, {"solver.time_scheme=bdf3"}).find("solver.time_scheme"), std::string::npos);
}
