// Configuration schema, --set overrides and the rejection of bad input
// (exit code 2, a message naming the key, nothing written).
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <toml++/toml.h>

#include "otfp/boundary.hpp"
#include "otfp/explicit_stepper.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/minimizer.hpp"
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
    ConfiguredRun sim(parse_config_string(text, sets));
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
  EXPECT_EQ(c.domain.type, DomainType::Ball);
  EXPECT_EQ(c.particles.n_inf, 400);
  EXPECT_EQ(c.particles.spacing_rule, SpacingRule::Cube);
  EXPECT_DOUBLE_EQ(c.particles.beta_factor, 2.0);
  EXPECT_EQ(c.solver.stepper, StepperKind::Implicit);
  EXPECT_EQ(c.solver.backend, Backend::Ceres);
  EXPECT_EQ(c.solver.width_metric, WidthMetric::AsPrinted);
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
  ConfiguredRun papers(parse_config_string(kBase, {"treatment.preset=papers"}));
  EXPECT_EQ(papers.derived().mirrored_walls, 0);
  EXPECT_EQ(papers.derived().reservoir_width, 0.0);
  EXPECT_EQ(papers.config().particles.spacing_rule, SpacingRule::SphereRadius);
  // The default preset ("converging"): the odd reservoir, whose back face is mirrored, and the true spacing.
  ConfiguredRun converging(parse_config_string(kBase));
  EXPECT_EQ(converging.config().treatment.preset, TreatmentPreset::Converging);
  EXPECT_EQ(converging.config().treatment.dirichlet, DirichletMode::Reservoir);
  EXPECT_EQ(converging.config().treatment.reservoir_profile, ReservoirProfile::Odd);
  EXPECT_EQ(converging.config().particles.spacing_rule, SpacingRule::Cube);
  EXPECT_EQ(converging.derived().mirrored_walls, 1);
  EXPECT_GT(converging.derived().reservoir_width, 0.0);
  // A key set beside the preset wins over it, wherever it stands.
  const Config mixed = parse_config_string(kBase + "[treatment]\nno_flux = \"barrier\"\npreset = \"converging\"\n",
                                           {"treatment.neumann_outflow=layer"});
  EXPECT_EQ(mixed.treatment.no_flux, NoFluxTreatment::Barrier);
  EXPECT_EQ(mixed.treatment.neumann_outflow, NeumannOutflow::Layer);
  EXPECT_EQ(mixed.treatment.dirichlet, DirichletMode::Reservoir);
  const Config explicit_rule = parse_config_string(kBase, {"treatment.preset=papers", "particles.spacing_rule=cube"});
  EXPECT_EQ(explicit_rule.particles.spacing_rule, SpacingRule::Cube);
  EXPECT_EQ(parse_config_string(kBase, {"treatment.preset=papers", "run.dim=2"}).particles.spacing_rule, SpacingRule::Cube);
  ConfiguredRun reservoir(parse_config_string(kBase, {"particles.n_inf=1600", "treatment.dirichlet=reservoir",
                                                   "treatment.reservoir_width=1.5", "treatment.reservoir_profile=odd"}));
  const Derived& d = reservoir.derived();
  // w = 1.5 r_c with r_c = s sqrt(ln(1e8)); sublayers round(2 w / dr); the band's back face is mirrored.
  EXPECT_NEAR(d.reservoir_width, 1.5 * d.width_s * std::sqrt(std::log(1e8)), 1e-12);
  EXPECT_EQ(d.reservoir_sublayers, static_cast<int>(std::lround(2.0 * d.reservoir_width / d.dr)));
  EXPECT_EQ(d.mirrored_walls, 1);
  EXPECT_EQ(reservoir.describe()["config"]["treatment"]["reservoir_profile"], "odd");
  // The resolved TOML parses back to the same treatment.
  const Config again = parse_config_string(to_toml(reservoir.config()));
  EXPECT_EQ(again.treatment.dirichlet, DirichletMode::Reservoir);
  EXPECT_DOUBLE_EQ(again.treatment.reservoir_width, 1.5);
  EXPECT_EQ(again.treatment.reservoir_profile, ReservoirProfile::Odd);
  // A box with one Dirichlet face: images at the five others (papers' layer),
  // and the reservoir's back face as well under the default preset.
  ConfiguredRun box(parse_config_file(std::filesystem::path(OTFP_SOURCE_DIR) / "examples" / "box_mixed.toml",
                                   {"treatment.preset=papers", "treatment.no_flux=images"}));
  EXPECT_EQ(box.derived().mirrored_walls, 5);
  ConfiguredRun box_default(parse_config_file(std::filesystem::path(OTFP_SOURCE_DIR) / "examples" / "box_mixed.toml"));
  EXPECT_EQ(box_default.derived().mirrored_walls, 6);
  // The square pipe: six faces and the obstacle (a round wall with the domain outside).
  ConfiguredRun pipe(parse_config_file(std::filesystem::path(OTFP_SOURCE_DIR) / "examples" / "square_pipe_occlusion.toml"));
  EXPECT_EQ(pipe.derived().mirrored_walls, 7);
}

TEST(Config, SetUsesTheTypeOfTheKey) {
  const Config c = parse_config_string(kBase, {"particles.n_inf=3200", "solver.stepper=explicit",
                                               "physics.kappa=2", "run.t_end=0.5", "physics.velocity=[1, 0, 0]",
                                               "solver.backend=\"nlopt\"", "diagnostics.center=[0.5]"});
  EXPECT_EQ(c.particles.n_inf, 3200);
  EXPECT_EQ(c.solver.stepper, StepperKind::Explicit);
  EXPECT_DOUBLE_EQ(c.physics.kappa, 2.0);  // an integer literal into a float key
  EXPECT_DOUBLE_EQ(c.run.t_end, 0.5);
  EXPECT_DOUBLE_EQ(c.physics.velocity.x(), 1.0);
  EXPECT_EQ(c.solver.backend, Backend::Nlopt);
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
  EXPECT_EQ(c.boundary[0].kind, PatchKind::Dirichlet);
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
      {"algorithm NLopt does not offer", kBase, {"solver.backend=nlopt", "solver.algorithm=bfgs"}, "solver.algorithm"},
      // In this process TAO is not registered (the backend is refused); the
      // tool registers it (its algorithm is refused): both name solver.backend.
      {"algorithm TAO does not offer", kBase, {"solver.backend=tao", "solver.algorithm=bfgs"}, "solver.backend"},
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

// Found by test_config_fuzz.cpp: an integer beyond 2^53 given to a number key
// ("length_L = 9223372036854775807", --set solver.skin_factor=9223372036854775807)
// escaped as std::bad_optional_access (toml++'s value<double>() refuses an
// integer that is not exactly a double). It is read as the nearest double, as
// the float literal with the same digits would be.
TEST(Config, IntegerBeyondTwoToThe53IntoANumberKey) {
  const Config c = parse_config_string(
      "[particles]\nn_inf = 100\nlength_L = 9223372036854775807\n[physics]\nvelocity = [9007199254740993, 0]\n",
      {"solver.skin_factor=9223372036854775807", "diagnostics.center=[-9223372036854775808]"});
  EXPECT_EQ(c.particles.length_L, 9223372036854775807.0);
  EXPECT_EQ(c.physics.velocity.x(), 9007199254740992.0);
  EXPECT_EQ(c.solver.skin_factor, 9223372036854775807.0);
  EXPECT_EQ(c.diagnostics.center->x(), -9223372036854775808.0);
  // The geometry checks take it from there (a ConfigError, not another exception).
  EXPECT_NE(rejection("[particles]\nn_inf = 100\nlength_L = 9223372036854775807\n[[boundary]]\npatch = \"surface\"\n"
                      "kind = \"neumann\"\nvalue = 1.0\n"),
            "");
}

// Found by test_config_fuzz.cpp: box_mixed.toml with "length_L = 9223372036854775807"
// (b = sqrt(L dr) ~ 1e9): the Dirichlet face uses the reservoir, so b is not
// bounded by the domain, but the projection still samples the face's layer cell
// of half-thickness b and its rejection sampler gave up with a
// std::runtime_error that escaped ConfiguredRun. It is a ConfigError now.
TEST(Config, HugeLayerWithAReservoirFaceIsAConfigError) {
  // A tiny g, so that the data check (g |A| b / m_p particles) lets it through
  // to the library's setup, whose sampler cannot hit the layer cell.
  const std::string why = rejection(read_text(kSource / "examples" / "box_mixed.toml"),
                                    {"particles.length_L=9223372036854775807", "boundary.0.value=1e-9"});
  EXPECT_NE(why.find("boundary: "), std::string::npos) << why;
  EXPECT_EQ(why.find('\n'), std::string::npos) << why;
  // With the example's g the data check refuses it first, naming the value.
  const std::string data = rejection(read_text(kSource / "examples" / "box_mixed.toml"),
                                     {"particles.length_L=9223372036854775807"});
  EXPECT_EQ(data.rfind("boundary[0].value = ", 0), 0u) << data;
}

// A name with a newline given in the file (patch = "a\nb", a sub-patch named
// so) was echoed raw: the ConfigError spanned two lines. Every message is one line.
TEST(Config, NamesWithControlCharactersKeepTheMessageOnOneLine) {
  const std::string why = rejection("[particles]\nn_inf = 100\n[[boundary]]\npatch = \"a\\nb\"\n"
                                    "kind = \"dirichlet\"\nvalue = 1.0\n");
  EXPECT_EQ(why, "boundary[0].patch = \"a\\x0ab\": unknown patch (patches: surface)");
  const std::string sub = rejection(
      "[particles]\nn_inf = 100\n[[domain.subpatch]]\nname = \"x\\ty\"\non = \"surface\"\n"
      "center = [0.0, 0.0, 1.0]\nradius = 0.25\n[[boundary]]\npatch = \"nope\"\nkind = \"no_flux\"\n");
  EXPECT_NE(sub.find("x\\x09y"), std::string::npos) << sub;
  EXPECT_EQ(sub.find_first_of("\n\t"), std::string::npos) << sub;
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
    EXPECT_NO_THROW({ ConfiguredRun sim(parse_config_file(entry.path())); });
  }
  EXPECT_GE(count, 6);
}

// The papers' parameter rules come out of the example configurations with
// treatment.preset = "papers".
TEST(Config, ExamplesReproduceThePapersTables) {
  {
    ConfiguredRun s(parse_config_file(kSource / "examples" / "sphere_dirichlet.toml",
                                   {"particles.n_inf=1600", "treatment.preset=papers"}));
    EXPECT_NEAR(s.derived().dr, 0.085498797, 1e-8);      // Table 1
    EXPECT_NEAR(s.derived().beta, 273.59615, 1e-4);
    EXPECT_NEAR(s.derived().particle_mass, 6.25e-4, 1e-15);
    EXPECT_NEAR(s.derived().layer_b, std::sqrt(0.085498797), 1e-8);
  }
  {
    ConfiguredRun s(parse_config_file(kSource / "examples" / "box_mixed.toml", {"treatment.preset=papers"}));
    EXPECT_NEAR(s.derived().dr, 0.10607847, 1e-7);       // Table 2, n_inf = 400
    EXPECT_NEAR(s.derived().beta, 177.73604, 1e-4);
    EXPECT_NEAR(s.derived().particle_mass, 2.5, 1e-12);
    ASSERT_TRUE(s.derived().J_inf.has_value());
    EXPECT_NEAR(*s.derived().J_inf, 500.0, 1e-9);          // (48)
  }
  {
    ConfiguredRun s(parse_config_file(kSource / "examples" / "pipe_neumann.toml", {"run.t_end=6", "treatment.preset=papers"}));
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
  ConfiguredRun s(parse_config_string(kBase));
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
  ConfiguredRun s2(parse_config_string(inj));
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
  const ConfiguredRun base(parse_config_string(kBase));
  const ConfiguredRun one(parse_config_string(kBase, {"particles.width_exponent=1", "particles.width_reference_n=7"}));
  const double dr = base.derived().dr;
  EXPECT_EQ(one.derived().width_s, base.derived().width_s);
  EXPECT_EQ(one.derived().beta, base.derived().beta);
  EXPECT_EQ(base.derived().beta, 2.0 / (dr * dr));
  EXPECT_EQ(base.derived().width_s, 1.0 / std::sqrt(2.0 / (dr * dr)));
  // kBase: unit ball, cube rule, n_inf = 100; with n_ref = 800, dr / dr_ref = 2 and
  // q = 1/2 gives s = (dr / sqrt(2)) 2^(-1/2) = dr / 2.
  const ConfiguredRun half(a);
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
      const ConfiguredRun s(parse_config_file(kSource / "examples" / e.name, sets));
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

// Issue 15: the bound on optimised widths, s_p < max_width_factor x s0.
TEST(Config, MaxWidthFactorIsChecked) {
  const std::string pp = "solver.width_mode=per_particle";
  EXPECT_EQ(rejection(kBase, {pp, "solver.max_width_factor=2"}), "");
  EXPECT_EQ(rejection(kBase, {pp, "solver.max_width_factor=0"}), "");
  EXPECT_EQ(rejection(kBase, {"solver.max_width_factor=0"}), "");
  for (const std::string v : {"0.5", "1", "-1", "2e6"})
    EXPECT_EQ(rejection(kBase, {pp, "solver.max_width_factor=" + v}).rfind("solver.max_width_factor = ", 0), 0u) << v;
  EXPECT_EQ(rejection(kBase, {pp, "solver.max_width_factor=1"}),
            "solver.max_width_factor = 1: must be 0 (off) or in (1, 1e6]");
  EXPECT_EQ(rejection(kBase, {pp, "solver.max_width_factor=-1"}),
            "solver.max_width_factor = -1: must be 0 (off) or in (1, 1e6]");
  EXPECT_EQ(rejection(kBase, {"solver.max_width_factor=2"}).rfind(
                "solver.max_width_factor = 2: needs solver.width_mode = \"per_particle\"", 0),
            0u);
  EXPECT_NE(rejection(kBase, {pp, "solver.max_width_factor=\"big\""}).find("solver.max_width_factor"),
            std::string::npos);
  // The library receives the factor and the run's s0.
  const Config c = parse_config_string(kBase, {pp, "solver.max_width_factor=3"});
  EXPECT_EQ(c.solver.max_width_factor, 3.0);
}

// ------------------------------------------------------------------ issue 12: one table

namespace {

const KeyInfo& info(const std::string& path) {
  for (const KeyInfo& k : schema())
    if (k.path == path) return k;
  throw std::runtime_error("no key " + path);
}

// Numbers compare by value (a TOML literal 0 equals the default 0.0).
bool same_value(const nlohmann::json& a, const nlohmann::json& b) {
  if (a.is_number() && b.is_number()) return a.get<double>() == b.get<double>();
  if (a.is_array() && b.is_array()) {
    if (a.size() != b.size()) return false;
    for (std::size_t i = 0; i < a.size(); ++i)
      if (!same_value(a[i], b[i])) return false;
    return true;
  }
  return a == b;
}

// A TOML inline value ("1e-3", "\"ceres\"", "[0, 0, 0]") as JSON.
nlohmann::json toml_literal(const std::string& text) {
  const toml::table t = toml::parse("v = " + text);
  const toml::node& n = *t.get("v");
  if (auto i = n.as_integer()) return i->get();
  if (auto f = n.as_floating_point()) return f->get();
  if (auto s = n.as_string()) return s->get();
  nlohmann::json out = nlohmann::json::array();
  for (const toml::node& e : *n.as_array()) out.push_back(e.value<double>().value());
  return out;
}

std::vector<std::string> table_cells(const std::string& line) {
  std::vector<std::string> cells;
  std::string cur;
  for (std::size_t i = 1; i < line.size(); ++i) {  // line[0] == '|'
    if (line[i] == '|' && line[i - 1] != '\\') {
      const auto b = cur.find_first_not_of(' '), e = cur.find_last_not_of(' ');
      cells.push_back(b == std::string::npos ? "" : cur.substr(b, e - b + 1));
      cur.clear();
    } else {
      cur += line[i];
    }
  }
  return cells;
}

struct DocRow {
  std::string default_text, constraint;
};

// The key tables of docs/configuration.md (header "| key | ... | default | constraint |")
// under the headings "## `[run]`", "### `[[domain.subpatch]]`", "## `[[boundary]]`", ...
std::map<std::string, DocRow> documented_keys(const std::string& doc) {
  std::map<std::string, DocRow> rows;
  std::istringstream in(doc);
  std::string line, prefix;
  int key_col = -1, default_col = -1, constraint_col = -1;
  while (std::getline(in, line)) {
    if (line.rfind("#", 0) == 0) {
      prefix.clear();
      key_col = -1;
      const auto a = line.find("`["), b = line.find("]`");
      if (a != std::string::npos && b != std::string::npos) {
        const bool array = line.compare(a + 1, 2, "[[") == 0;
        const std::string name = array ? line.substr(a + 3, b - a - 4) : line.substr(a + 2, b - a - 2);
        prefix = name + (array ? "[]." : ".");
      }
      continue;
    }
    if (line.rfind("|", 0) != 0) {
      key_col = -1;
      continue;
    }
    const std::vector<std::string> cells = table_cells(line);
    if (cells.empty() || cells[0].rfind("---", 0) == 0) continue;
    if (key_col < 0) {  // a header
      if (cells[0] != "key") {
        key_col = -2;  // not a key table: skip its rows
        continue;
      }
      key_col = 0;
      for (std::size_t i = 0; i < cells.size(); ++i) {
        if (cells[i] == "default") default_col = static_cast<int>(i);
        if (cells[i] == "constraint") constraint_col = static_cast<int>(i);
      }
      continue;
    }
    if (key_col == -2) continue;
    const std::string key = cells[0].substr(1, cells[0].size() - 2);  // `name`
    EXPECT_FALSE(prefix.empty()) << "key table outside a section: " << line;
    rows[prefix + key] = {cells.at(default_col), cells.at(constraint_col)};
  }
  return rows;
}

}  // namespace

// docs/configuration.md lists exactly the keys of the table, with the table's
// defaults, choices and range rules.
TEST(Config, DocumentationAgreesWithTheTable) {
  const std::map<std::string, DocRow> doc = documented_keys(read_text(kSource / "docs" / "configuration.md"));
  ASSERT_GT(doc.size(), 50u);
  std::set<std::string> table;
  for (const KeyInfo& k : schema()) table.insert(k.path);
  for (const auto& [path, row] : doc) EXPECT_TRUE(table.count(path)) << path << " is documented but not in the table";
  // The keys whose default the preset sets (documented as "from `preset`").
  const nlohmann::json converging = config_to_json(parse_config_string(""));
  const nlohmann::json papers = config_to_json(parse_config_string("", {"treatment.preset=papers"}));
  for (const KeyInfo& k : schema()) {
    SCOPED_TRACE(k.path);
    const auto it = doc.find(k.path);
    if (it == doc.end()) {
      ADD_FAILURE() << k.path << " is missing from the key tables of docs/configuration.md";
      continue;
    }
    const DocRow& row = it->second;
    const std::string& d = row.default_text;
    if (k.required) {
      EXPECT_EQ(d.rfind("required", 0), 0u) << d;
    } else if (k.optional) {
      EXPECT_NE(d.rfind("`", 0), 0u) << "an optional key has no default value: " << d;
    } else if (d.rfind("`", 0) == 0) {
      const std::string literal = d.substr(1, d.find('`', 1) - 1);
      EXPECT_TRUE(same_value(toml_literal(literal), k.default_value))
          << "doc default " << literal << ", table default " << k.default_value.dump();
    } else {
      const std::string section = k.path.substr(0, k.path.find('.')), name = k.path.substr(k.path.find('.') + 1);
      EXPECT_EQ(d, "from `preset`");
      EXPECT_NE(converging[section][name], papers[section][name]) << "the preset does not set this key";
    }
    for (const std::string& choice : k.choices)
      EXPECT_NE(row.constraint.find("`" + choice + "`"), std::string::npos) << choice << " not in " << row.constraint;
    if (!k.rule.empty()) {
      EXPECT_NE(row.constraint.find(k.rule), std::string::npos) << k.rule << " not in " << row.constraint;
    }
  }
}

// The table's defaults are what an empty document gives, and they obey the table's own choices.
TEST(Config, TableDefaultsAreTheParsedDefaults) {
  const nlohmann::json empty = config_to_json(parse_config_string(""));
  std::vector<std::string> paths;
  for (const KeyInfo& k : schema()) {
    SCOPED_TRACE(k.path);
    paths.push_back(k.path);
    EXPECT_TRUE(k.type == "integer" || k.type == "number" || k.type == "string" || k.type == "point") << k.type;
    if (!k.choices.empty()) {
      EXPECT_EQ(k.type, "string");
      if (!k.default_value.is_null()) {
        EXPECT_NE(std::find(k.choices.begin(), k.choices.end(), k.default_value.get<std::string>()), k.choices.end());
      }
    }
    if (k.path.find("[]") != std::string::npos) continue;
    const std::string section = k.path.substr(0, k.path.find('.')), name = k.path.substr(k.path.find('.') + 1);
    ASSERT_TRUE(empty[section].contains(name));
    EXPECT_EQ(empty[section][name], k.default_value);
    EXPECT_EQ(k.optional, k.default_value.is_null());
  }
  EXPECT_EQ(paths, schema_keys());
}

// Where a key sets a library option, its default is the library's, and the
// values are today's (results stay bitwise unchanged).
TEST(Config, CliDefaultsAreTheLibraryDefaults) {
  const Config c = parse_config_string("");
  const SolverSection& s = c.solver;
  const ImplicitOptions io;
  const ExplicitOptions eo;
  EXPECT_EQ(s.backend, io.minimizer.backend);
  EXPECT_EQ(s.algorithm, io.minimizer.algorithm);
  EXPECT_EQ(s.max_iterations, io.minimizer.max_iterations);
  EXPECT_EQ(s.max_evaluations, io.minimizer.max_evaluations);
  EXPECT_EQ(s.lbfgs_memory, io.minimizer.lbfgs_memory);
  EXPECT_EQ(s.width_mode, io.width_mode);
  EXPECT_EQ(s.width_metric, io.width_metric);
  EXPECT_EQ(s.time_scheme, io.time_scheme);
  EXPECT_EQ(s.predictor, io.predictor);
  EXPECT_EQ(s.error_smoothing, io.error_smoothing);
  EXPECT_EQ(s.displacement_tolerance, io.displacement_tolerance);
  EXPECT_EQ(s.relative_tolerance, io.relative_tolerance);
  EXPECT_EQ(s.max_halvings, io.max_halvings);
  EXPECT_EQ(s.energy_tolerance, io.energy_tolerance);
  EXPECT_EQ(s.kernel_tolerance, io.neighbor.kernel_tolerance);
  EXPECT_EQ(s.skin_factor, io.neighbor.skin_factor);
  EXPECT_EQ(s.max_width_factor, io.max_width_factor);
  EXPECT_EQ(s.max_width_factor, 0.0);
  EXPECT_EQ(s.kernel_tolerance, eo.neighbor.kernel_tolerance);
  EXPECT_EQ(s.skin_factor, eo.neighbor.skin_factor);
  EXPECT_EQ(s.explicit_scheme, eo.scheme);
  EXPECT_EQ(c.physics.kappa, io.kappa);
  EXPECT_EQ(c.physics.rho_ref, io.rho_ref);
  EXPECT_EQ(c.physics.kappa, eo.kappa);
  EXPECT_EQ(c.treatment.reservoir_sublayers, ProjectionOptions{}.reservoir_sublayers);
  // The set-up and the treatment: the library's RunSetupOptions and the converging preset.
  const RunSetupOptions ro;
  const TreatmentOptions to = treatment_preset(TreatmentPreset::Converging, 3);
  EXPECT_EQ(c.treatment.preset, TreatmentPreset::Converging);
  EXPECT_EQ(c.treatment.no_flux, to.no_flux);
  EXPECT_EQ(c.treatment.dirichlet, to.dirichlet);
  EXPECT_EQ(c.treatment.reservoir_profile, to.reservoir_profile);
  EXPECT_EQ(c.treatment.reservoir_control, to.reservoir_control);
  EXPECT_EQ(c.treatment.reservoir_width, to.reservoir_width);
  EXPECT_EQ(c.treatment.reservoir_tolerance, to.reservoir_tolerance);
  EXPECT_EQ(c.treatment.reservoir_candidates, to.reservoir_candidates);
  EXPECT_EQ(c.treatment.neumann_outflow, NeumannOutflow::NearestParticles);
  EXPECT_EQ(to.neumann_outflow, NeumannOutflow::NearestParticles);
  EXPECT_EQ(c.particles.spacing_rule, to.spacing_rule);
  EXPECT_EQ(c.particles.n_inf, ro.n_inf);
  EXPECT_EQ(c.particles.beta_factor, ro.beta_factor);
  EXPECT_EQ(c.run.t_end, ro.t_end);
  EXPECT_EQ(c.run.dt_factor, ro.dt_factor);
  EXPECT_EQ(c.solver.barrier_factor, ro.barrier_factor);
  EXPECT_EQ(c.solver.kernel_tolerance, ro.kernel_tolerance);
  // Today's values, bit for bit.
  EXPECT_EQ(s.displacement_tolerance, 1e-3);
  EXPECT_EQ(s.relative_tolerance, 1e-2);
  EXPECT_EQ(s.error_smoothing, 2.0);
  EXPECT_EQ(s.max_iterations, 1000);
  EXPECT_EQ(s.max_evaluations, 5000);
  EXPECT_EQ(s.lbfgs_memory, 10);
  EXPECT_EQ(s.max_halvings, 4);
  EXPECT_EQ(s.energy_tolerance, 1e-9);
  EXPECT_EQ(s.kernel_tolerance, 1e-8);
  EXPECT_EQ(s.skin_factor, 1.0);
  EXPECT_EQ(s.backend, Backend::Ceres);
  EXPECT_EQ(s.algorithm, Algorithm::Lbfgs);
  EXPECT_EQ(s.explicit_scheme, ExplicitScheme::EulerForce27);
  EXPECT_EQ(s.width_mode, WidthMode::Fixed);
  EXPECT_EQ(s.time_scheme, TimeScheme::Euler);
  EXPECT_EQ(s.predictor, Predictor::None);
}

// Every choice of a key that maps to a library enum converts with the
// library's function and back to the same name.
TEST(Config, ChoicesConvertWithTheLibrary) {
  const auto each = [](const std::string& path, const auto& convert) {
    const KeyInfo& k = info(path);
    ASSERT_FALSE(k.choices.empty()) << path;
    for (const std::string& c : k.choices) EXPECT_EQ(to_string(convert(c)), c) << path;
  };
  each("solver.backend", backend_from_string);
  each("solver.algorithm", algorithm_from_string);
  each("solver.explicit_scheme", explicit_scheme_from_string);
  each("solver.width_mode", width_mode_from_string);
  each("solver.time_scheme", time_scheme_from_string);
  each("solver.predictor", predictor_from_string);
  each("boundary[].kind", patch_kind_from_string);
  each("treatment.dirichlet", dirichlet_mode_from_string);
  each("treatment.reservoir_profile", reservoir_profile_from_string);
  each("particles.spacing_rule", spacing_rule_from_string);
  each("particles.dirichlet_target", dirichlet_target_from_string);
  each("solver.width_metric", width_metric_from_string);
  EXPECT_EQ(info("solver.algorithm").choices.size(), 6u);
  EXPECT_THROW(backend_from_string("petsc"), std::exception);
}

// Each key's own rule: one line "<key> = <value>: <rule>", the same as before the table.
TEST(Config, RangeRulesOfTheTable) {
  const std::string sub = kBase + "[[domain.subpatch]]\nname = \"o\"\non = \"surface\"\ncenter = [0, 0, 1]\n";
  struct Case {
    std::string text;
    std::vector<std::string> sets;
    std::string message;
  };
  const std::vector<Case> cases = {
      {kBase, {"run.dim=0"}, "run.dim = 0: must be 1, 2 or 3"},
      {kBase, {"run.dim=9999999999"}, "run.dim = 9999999999: out of range"},
      {kBase, {"run.seed=-1"}, "run.seed = -1: must be >= 0"},
      {kBase, {"run.threads=5000"}, "run.threads = 5000: must be in [0, 4096] (0: OpenMP default)"},
      {kBase, {"run.dt_min=-1"}, "run.dt_min = -1: must be > 0"},
      {kBase, {"run.checkpoint_interval=-1"}, "run.checkpoint_interval = -1: must be >= 0"},
      {kBase, {"domain.radius=-0.5"}, "domain.radius = -0.5: must be > 0"},
      {sub, {}, "domain.subpatch[0].radius = (missing): required, > 0"},
      {sub + "radius = -0.1\n", {}, "domain.subpatch[0].radius = -0.1: must be > 0"},
      {kBase + "[[domain.subpatch]]\non = \"surface\"\nradius = 0.1\n", {}, "domain.subpatch[0].name = (missing): required, a non-empty patch name"},
      {kBase, {"particles.fill=uniform", "particles.fill_count=-1"}, "particles.fill_count = -1: must be >= 0"},
      {kBase, {"particles.fill_amplitude=1"}, "particles.fill_amplitude = 1: must be in [0, 1) (density 1 + a cos(k x) > 0)"},
      {kBase, {"particles.fill_mode=0"}, "particles.fill_mode = 0: must be >= 1"},
      {kBase, {"boundary.0.t_start=-1"}, "boundary[0].t_start = -1: must be >= 0"},
      {kBase, {"solver.lbfgs_memory=0"}, "solver.lbfgs_memory = 0: must be >= 1"},
      {kBase, {"solver.lbfgs_memory=1001"}, "solver.lbfgs_memory = 1001: must be <= 1000"},
      {kBase, {"solver.max_iterations=0"}, "solver.max_iterations = 0: must be >= 1"},
      {kBase, {"solver.max_evaluations=3000000000"}, "solver.max_evaluations = 3000000000: out of range"},
      {kBase, {"solver.max_halvings=21"}, "solver.max_halvings = 21: must be in [0, 20]"},
      {kBase, {"solver.kernel_tolerance=1"}, "solver.kernel_tolerance = 1: must be in (0, 1)"},
      {kBase, {"solver.relative_tolerance=-0.5"}, "solver.relative_tolerance = -0.5: must be in [0, 1] (0: absolute rule only)"},
      {kBase, {"treatment.reservoir_width=0"}, "treatment.reservoir_width = 0: must be > 0"},
      {kBase, {"treatment.reservoir_width=10.5"}, "treatment.reservoir_width = 10.5: must be <= 10 (kernel cut-offs)"},
      {kBase, {"treatment.reservoir_sublayers=1001"},
       "treatment.reservoir_sublayers = 1001: must be in [0, 1000] (0: about one spacing per sublayer)"},
      {kBase, {"diagnostics.M_inf=0"}, "diagnostics.M_inf = 0: must be > 0"},
  };
  for (const Case& c : cases) EXPECT_EQ(rejection(c.text, c.sets), c.message);
  // A rule that holds only where its key is used: domain.radius is not a box's.
  EXPECT_NO_THROW(parse_config_string("[domain]\ntype = \"box\"\nradius = -1\n"));
  EXPECT_EQ(rejection(kBase, {"run.checkpoint_interval=0"}), "");
}

// A setup that fails names the key at fault, not a bystander: a kernel
// tolerance of 1e-300 makes the cut-off (and so the reservoir band, in
// cut-offs) deeper than the ball; 1000 sublayers are too thin to sample;
// both used to blame treatment.reservoir_width. dt_min = 0 lets a tiny
// tolerance shrink the step to 0 (exit 1 "dt = 0" after writing files).
TEST(Config, SetupErrorsNameTheKeyAtFault) {
  const std::string sphere = (std::filesystem::path(OTFP_SOURCE_DIR) / "examples" / "sphere_dirichlet.toml").string();
  auto message = [&](const std::vector<std::string>& sets) {
    try {
      const ConfiguredRun run(parse_config_file(sphere, sets));
      return std::string();
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
  };
  EXPECT_EQ(message({"solver.kernel_tolerance=1e-300"}).rfind("solver.kernel_tolerance = 1e-300: ", 0), 0u)
      << message({"solver.kernel_tolerance=1e-300"});
  EXPECT_EQ(message({"solver.kernel_tolerance=1e-300", "treatment.reservoir_sublayers=1000"})
                .rfind("solver.kernel_tolerance = 1e-300: ", 0),
            0u)
      << message({"solver.kernel_tolerance=1e-300", "treatment.reservoir_sublayers=1000"});
  // n_inf = 100: a band a little deeper than the radius; its default 6
  // sublayers mirror, 1000 do not.
  EXPECT_EQ(message({"particles.n_inf=100"}), "");
  EXPECT_EQ(message({"particles.n_inf=100", "treatment.reservoir_sublayers=1000"})
                .rfind("treatment.reservoir_sublayers = 1000: ", 0),
            0u)
      << message({"particles.n_inf=100", "treatment.reservoir_sublayers=1000"});
  // A band too wide whatever the other keys: the width is at fault.
  EXPECT_EQ(message({"treatment.reservoir_width=10"}).rfind("treatment.reservoir_width = 10: ", 0), 0u)
      << message({"treatment.reservoir_width=10"});
  EXPECT_EQ(message({"run.dt_mode=adaptive", "run.dt_min=0", "run.time_tolerance=1e-30"}),
            "run.dt_min = 0: must be > 0");
  EXPECT_EQ(message({"run.dt_mode=adaptive", "run.dt_min=1e-300"}).rfind("run.dt_min = 1e-300: must be >= 1e-9 x run.t_end", 0), 0u)
      << message({"run.dt_mode=adaptive", "run.dt_min=1e-300"});
  EXPECT_EQ(message({"run.dt_mode=adaptive", "run.dt_min=1e-6"}), "");
}

// A fill_file that is not a regular file is named for what it is, not "no such file".
TEST(Config, FillFileThatIsNotAFileSaysWhatItIs) {
  const std::string dir = std::filesystem::temp_directory_path().string();
  auto message = [](const std::string& file) {
    try {
      parse_config_string("[particles]\nfill = \"file\"\nfill_file = \"" + file + "\"\n");
      return std::string();
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
  };
  EXPECT_EQ(message("/dev/null"),
            "particles.fill_file = \"/dev/null\": is a device, not a particle file (.csv or .vtp)");
  EXPECT_EQ(message(dir), "particles.fill_file = \"" + dir + "\": is a directory, not a particle file (.csv or .vtp)");
  EXPECT_EQ(message("/nonexistent/p.csv").rfind("particles.fill_file = \"/nonexistent/p.csv\": no such file", 0), 0u)
      << message("/nonexistent/p.csv");
}

// Values refused before any work: particles.layer_b where no patch uses the
// layer (the converging preset's reservoir sphere), a Gaussian fill wider
// than 1e6 domain sizes (exit 1 after writing files: its squares overflow).
TEST(Config, KeysWithoutEffectOrBeyondRangeAreRefusedBeforeWork) {
  const std::filesystem::path examples = std::filesystem::path(OTFP_SOURCE_DIR) / "examples";
  auto message = [&](const char* example, const std::vector<std::string>& sets) {
    try {
      const ConfiguredRun run(parse_config_file(examples / example, sets));
      return std::string();
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
  };
  EXPECT_EQ(message("sphere_dirichlet.toml", {"particles.layer_b=10"}).rfind("particles.layer_b = 10: has no effect", 0), 0u)
      << message("sphere_dirichlet.toml", {"particles.layer_b=10"});
  EXPECT_EQ(message("sphere_dirichlet.toml", {"particles.layer_b=0.1"}).rfind("particles.layer_b = 0.1: has no effect", 0),
            0u);
  EXPECT_EQ(message("sphere_dirichlet.toml", {"particles.layer_b=0.1", "treatment.preset=papers"}), "");
  EXPECT_EQ(message("pipe_neumann.toml", {"particles.layer_b=0.05"}), "") << "a Neumann patch uses the layer";
  EXPECT_EQ(message("free_space_heat.toml", {"particles.fill_sigma=1e300"}).rfind("particles.fill_sigma = 1e+300: must be at most 1e6 domain sizes", 0), 0u)
      << message("free_space_heat.toml", {"particles.fill_sigma=1e300"});
  EXPECT_EQ(message("free_space_heat.toml", {"particles.fill_sigma=10"}), "");
}

TEST(Config, CheckpointInterval) {
  EXPECT_EQ(parse_config_string("").run.checkpoint_interval, 100);
  const Config c = parse_config_string(kBase, {"run.checkpoint_interval=0"});
  EXPECT_EQ(c.run.checkpoint_interval, 0);
  EXPECT_EQ(parse_config_string(to_toml(c)).run.checkpoint_interval, 0);
  EXPECT_EQ(config_to_json(parse_config_string("[run]\ncheckpoint_interval = 7\n"))["run"]["checkpoint_interval"], 7);
  EXPECT_EQ(rejection(kBase, {"run.checkpoint_interval=2.5"}).rfind("run.checkpoint_interval = 2.5: must be an integer", 0), 0u);
}

// particles.fill = "file": particles.fill_file (relative to the configuration
// file's directory) is required, and the keys of the other fills do not apply.
TEST(Config, FillFromFile) {
  const fs::path dir = fresh_dir("fill_file");
  fs::create_directories(dir / "sub");
  { std::ofstream(dir / "sub" / "particles.csv") << "x,y,z,m,s\n0,0,0,1,0.1\n"; }
  const auto with_fill = [](const std::string& keys) {
    std::string t = kBase;
    const std::string n = "n_inf = 100\n";
    return t.replace(t.find(n), n.size(), n + keys);
  };
  const std::string text = with_fill("fill = \"file\"\nfill_file = \"sub/particles.csv\"\n");
  {
    std::ofstream(dir / "run.toml") << text;
  }
  const Config c = parse_config_file(dir / "run.toml");
  ASSERT_TRUE(c.particles.fill_file.has_value());
  EXPECT_TRUE(fs::equivalent(*c.particles.fill_file, dir / "sub" / "particles.csv"));
  EXPECT_TRUE(fs::path(*c.particles.fill_file).is_absolute());
  // The resolved path survives the round trip through TOML and JSON.
  const Config again = parse_config_string(to_toml(c));
  EXPECT_EQ(again.particles.fill_file, c.particles.fill_file);
  EXPECT_EQ(to_toml(again), to_toml(c));
  EXPECT_EQ(to_toml(c).find("fill_sigma"), std::string::npos);  // keys that do not apply are not written
  EXPECT_EQ(config_to_json(c)["particles"]["fill_file"], *c.particles.fill_file);
  EXPECT_TRUE(config_to_json(parse_config_string(""))["particles"]["fill_file"].is_null());
  // parse_config_string: relative to the current directory.
  const fs::path cwd = fs::current_path();
  fs::current_path(dir / "sub");
  const Config here = parse_config_string(kBase, {"particles.fill=file", "particles.fill_file=particles.csv"});
  fs::current_path(cwd);
  EXPECT_TRUE(fs::equivalent(*here.particles.fill_file, dir / "sub" / "particles.csv"));

  const std::string abs = (dir / "sub" / "particles.csv").string();
  EXPECT_EQ(rejection(kBase, {"particles.fill=file"}),
            "particles.fill_file = (missing): required with particles.fill = \"file\"");
  EXPECT_EQ(rejection(kBase, {"particles.fill=uniform", "particles.fill_file=" + abs}),
            "particles.fill_file = \"" + abs + "\": needs particles.fill = \"file\" (particles.fill = \"uniform\")");
  const std::string missing = (dir / "nothing.csv").string();
  EXPECT_EQ(rejection(kBase, {"particles.fill=file", "particles.fill_file=" + missing}).rfind(
                "particles.fill_file = \"" + missing + "\": no such file", 0),
            0u);
  const std::vector<std::pair<std::string, std::string>> other = {
      {"fill_count", "10"},         {"fill_mass", "1.5"},   {"fill_center", "[0.5, 0, 0]"}, {"fill_sigma", "0.2"},
      {"fill_arrangement", "lattice"}, {"fill_amplitude", "0.25"}, {"fill_mode", "2"}};
  for (const auto& [key, value] : other) {
    const std::string msg = rejection(kBase, {"particles.fill=file", "particles.fill_file=" + abs, "particles." + key + "=" + value});
    EXPECT_EQ(msg.rfind("particles." + key + " = ", 0), 0u) << msg;
    EXPECT_NE(msg.find(": does not apply to particles.fill = \"file\""), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
  }
  // Given in the file as well, not only with --set; and a default value given explicitly counts.
  EXPECT_EQ(rejection(with_fill("fill = \"file\"\nfill_file = \"" + abs + "\"\nfill_sigma = 0.1\n"))
                .rfind("particles.fill_sigma = 0.1: does not apply", 0),
            0u);
  fs::remove_all(dir);
}

// summary.json's "config" (describe()) holds every key of the table,
// including each entry of the arrays of tables.
TEST(Config, ResolvedJsonHoldsEveryKeyOfTheTable) {
  for (const std::string name : {"pipe_neumann.toml", "box_mixed.toml", "sphere_injection.toml"}) {
    SCOPED_TRACE(name);
    const ConfiguredRun sim(parse_config_file(kSource / "examples" / name));
    const nlohmann::json cfg = sim.describe()["config"];
    for (const std::string& key : schema_keys()) {
      // "a.b" or "a[].b" / "a.b[].c": every element of the array holds the key.
      const auto brackets = key.find("[]");
      if (brackets == std::string::npos) {
        const auto dot = key.find('.');
        ASSERT_TRUE(cfg.contains(key.substr(0, dot))) << key;
        EXPECT_TRUE(cfg[key.substr(0, dot)].contains(key.substr(dot + 1))) << key;
        continue;
      }
      const std::string array_path = key.substr(0, brackets), field = key.substr(brackets + 3);
      const auto dot = array_path.find('.');
      const nlohmann::json& arr =
          dot == std::string::npos ? cfg[array_path] : cfg[array_path.substr(0, dot)][array_path.substr(dot + 1)];
      ASSERT_TRUE(arr.is_array()) << key;
      for (const auto& element : arr) EXPECT_TRUE(element.contains(field)) << key;
    }
  }
}

// Parsing the TOML of any example gives the same configuration (every key of the table reads what it writes).
TEST(Config, EveryExampleRoundTripsThroughTheTable) {
  for (const auto& entry : fs::directory_iterator(kSource / "examples")) {
    if (entry.path().extension() != ".toml") continue;
    SCOPED_TRACE(entry.path().string());
    const Config a = parse_config_file(entry.path(), {"run.checkpoint_interval=3"});
    const Config b = parse_config_string(to_toml(a));
    EXPECT_EQ(config_to_json(a).dump(), config_to_json(b).dump());
    EXPECT_EQ(to_toml(a), to_toml(b));
  }
}
