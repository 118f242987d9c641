#pragma once
// Configuration of one otfp run: the TOML schema (docs/configuration.md), its
// typed form, and parsing with --set overrides. Every rejected value raises
// ConfigError with the message "<key> = <value>: <rule>" (exit code 2).
//
// One table in config_table.cpp lists every key (path, type, member,
// choices, range rule); parsing, validation, to_toml, config_to_json and
// schema() iterate it. A key's default is the in-class default of its member below, and where
// the key sets a library option, that default is the library's own
// (ImplicitOptions{}, ExplicitOptions{}, MinimizerOptions{}).
#include <cstdint>
#include <filesystem>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "otfp/explicit_stepper.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/initial_fill.hpp"
#include "otfp/run_setup.hpp"
#include "otfp/types.hpp"

namespace otfp::app {

// User text in a one-line message: control characters as \xHH.
std::string one_line(const std::string& s);

class ConfigError : public std::runtime_error {
 public:
  ConfigError(const std::string& key, const std::string& value, const std::string& rule);
  // Already formatted (e.g. a TOML syntax error with its location).
  ConfigError(const std::string& key, const std::string& message);
  const std::string& key() const { return key_; }

 private:
  std::string key_;
};

// The choices of the configuration are enums once parsed (the table in
// config_table.cpp holds their names): the library's own where the choice is a
// library option (otfp/enums.hpp), and these for what only a configuration
// file describes.
enum class DtMode { Fixed, Adaptive };
enum class DomainType { Ball, Box, Cylinder, PeriodicBox, SquarePipeObstacle, Free };
enum class Axis { X, Y, Z };
enum class Fill { Empty, Uniform, Gaussian, Cosine, File };  // the shapes of FillShape, no particles, or a file
enum class Arrangement { Random, Lattice, StaggeredLattice };
std::string to_string(DtMode m);
std::string to_string(DomainType t);
std::string to_string(Axis a);
std::string to_string(Fill f);
std::string to_string(Arrangement a);

struct RunSection {
  int dim = 3;
  double t_end = RunSetupOptions{}.t_end;
  std::optional<double> dt;  // absent: dt_factor * dr^2 / kappa
  double dt_factor = RunSetupOptions{}.dt_factor;
  std::int64_t seed = static_cast<std::int64_t>(SimulationOptions{}.seed);
  std::int64_t max_steps = 0;  // 0: no limit
  DtMode dt_mode = DtMode::Fixed;  // fixed | adaptive (implicit stepper, docs/stepper.md)
  double time_tolerance = TimeStepControlOptions{}.tolerance;   // adaptive: largest local error estimate per step, in blob widths
  std::optional<double> dt_min;   // adaptive: absent = 1e-3 x the initial dt
  std::optional<double> dt_max;   // adaptive: absent = t_end
  std::int64_t vtk_interval = 50;  // 0: initial and final snapshot only
  std::int64_t checkpoint_interval = 100;  // a checkpoint every this many steps and at the end; 0: at the end only
  std::int64_t max_particles = 0;  // a run that would hold more fails; 0: half the memory / kBytesPerParticle
  int threads = 1;  // 0: OpenMP default
};

struct SubPatchSpec {
  std::string name;
  std::string on;               // base patch name
  std::optional<Vec3> center;   // absent: centre of the base patch
  double radius = std::numeric_limits<double>::quiet_NaN();  // required: NaN until given
};

struct DomainSection {
  DomainType type = DomainType::Ball;  // ball | box | cylinder | periodic_box | square_pipe_obstacle | free
  Vec3 center = Vec3::Zero();
  double radius = 1.0;
  Vec3 lo = Vec3::Zero();
  Vec3 hi = Vec3::Ones();
  Vec3 end_a = Vec3::Zero();
  Vec3 end_b = Vec3::UnitX();
  std::optional<Vec3> obstacle_center;
  std::optional<double> obstacle_radius;
  Axis obstacle_axis = Axis::Z;  // x | y | z
  std::vector<SubPatchSpec> subpatches;
};

struct ParticlesSection {
  std::int64_t n_inf = RunSetupOptions{}.n_inf;
  std::optional<double> mass;
  SpacingRule spacing_rule = TreatmentOptions{}.spacing_rule;  // cube | sphere_radius (default: cube; sphere_radius in 3-D under treatment.preset = "papers")
  double beta_factor = RunSetupOptions{}.beta_factor;
  double width_exponent = WidthScaling{}.exponent;           // q: s = s_rule(dr) (dr / dr_ref)^(q - 1), in (0, 2]
  std::int64_t width_reference_n = static_cast<std::int64_t>(WidthScaling{}.reference_n);  // n at which dr_ref is taken (>= 1)
  double layer_b = 0.0;   // 0: sqrt(length_L dr)
  double length_L = 0.0;  // 0: from the domain
  DirichletTarget dirichlet_target = ProjectionOptions{}.dirichlet_target;  // cell_integral | paper_eq34
  Fill fill = Fill::Empty;  // empty | uniform | gaussian | cosine | file
  // fill = "file": the particle file, resolved against the directory of the
  // configuration file (parse_config_string: the current directory).
  std::optional<std::string> fill_file;
  std::optional<std::int64_t> fill_count;
  std::optional<double> fill_mass;
  std::optional<Vec3> fill_center;
  double fill_sigma = FillOptions{}.sigma;
  Arrangement fill_arrangement = Arrangement::Random;  // random | lattice | staggered_lattice (box-shaped domains)
  double fill_amplitude = FillOptions{}.amplitude;  // a of the cosine fill 1 + a cos(k x)
  std::int64_t fill_mode = 1;   // k = 2 pi fill_mode / (hi_x - lo_x)
};

struct PhysicsSection {
  double kappa = RunSetupOptions{}.kappa;
  double rho_ref = RunSetupOptions{}.rho_ref;
  Vec3 velocity = Vec3::Zero();
  double source_rate = 0.0;
};

struct BoundarySpec {
  std::string patch;
  std::optional<PatchKind> kind;  // dirichlet | neumann | no_flux: required, absent until given
  std::optional<double> value;
  double t_start = 0.0;
  std::optional<double> t_end;
};

// The keys that set a library option take their default from the library's
// option struct (one default per option; tests/test_config.cpp pins the values).
struct SolverSection {
  StepperKind stepper = RunSetupOptions{}.stepper;  // implicit | explicit
  Backend backend = ImplicitOptions{}.minimizer.backend;      // ceres | nlopt
  Algorithm algorithm = ImplicitOptions{}.minimizer.algorithm;  // lbfgs | ... (by backend)
  ExplicitScheme explicit_scheme = ExplicitOptions{}.scheme;         // euler27 | rk4 | euler_exact
  WidthMode width_mode = ImplicitOptions{}.width_mode;          // fixed | per_particle
  WidthMetric width_metric = ImplicitOptions{}.width_metric;  // as_printed | exact
  TimeScheme time_scheme = ImplicitOptions{}.time_scheme;        // euler | bdf2
  Predictor predictor = ImplicitOptions{}.predictor;            // none | extrapolate | damped
  double error_smoothing = ImplicitOptions{}.error_smoothing;  // error estimate: smoothing length in widths
  ErrorMeasure error_measure = ImplicitOptions{}.error_measure;    // density | displacement
  StoppingNorm stopping_norm = ImplicitOptions{}.stopping_norm;    // energy | max
  double max_norm_factor = ImplicitOptions{}.max_norm_factor;  // energy norm: largest residual / RMS tolerance
  double displacement_tolerance = ImplicitOptions{}.displacement_tolerance;
  double relative_tolerance = ImplicitOptions{}.relative_tolerance;
  std::int64_t max_iterations = ImplicitOptions{}.minimizer.max_iterations;
  std::int64_t max_evaluations = ImplicitOptions{}.minimizer.max_evaluations;
  std::int64_t lbfgs_memory = ImplicitOptions{}.minimizer.lbfgs_memory;
  std::int64_t max_halvings = ImplicitOptions{}.max_halvings;
  double energy_tolerance = ImplicitOptions{}.energy_tolerance;
  double barrier_factor = RunSetupOptions{}.barrier_factor;
  std::optional<double> barrier_stiffness;
  double kernel_tolerance = ImplicitOptions{}.neighbor.kernel_tolerance;
  double skin_factor = ImplicitOptions{}.neighbor.skin_factor;
  double max_width_factor = ImplicitOptions{}.max_width_factor;  // per_particle: s_p <= this x s0 (0: off)
};

// How the boundaries are treated (docs/boundaries.md): the papers' way or the
// treatments that converge (issue 10).
// The defaults are the "converging" preset (docs/validation.md, study 5);
// treatment.preset = "papers" restores Sec. 4.2 (see apply_treatment_preset).
struct TreatmentSection {
  TreatmentPreset preset = TreatmentPreset::Converging; // converging | papers: the defaults of the keys below
  NoFluxTreatment no_flux = TreatmentOptions{}.no_flux; // barrier | images (image blobs at every non-Dirichlet wall)
  DirichletMode dirichlet = TreatmentOptions{}.dirichlet; // layer (Sec. 4.2) | reservoir (persistent band outside the face)
  double reservoir_width = TreatmentOptions{}.reservoir_width; // band thickness in units of the kernel cut-off r_c of the blobs
  std::int64_t reservoir_sublayers = TreatmentOptions{}.reservoir_sublayers; // 0: round(2 w / dr), half a spacing per sublayer
  ReservoirProfile reservoir_profile = TreatmentOptions{}.reservoir_profile; // uniform (g) | odd (2 g - interior mirror density)
  ReservoirControl reservoir_control = TreatmentOptions{}.reservoir_control; // quiet (tolerance band, density-ranked placement) | exact (issue 10)
  double reservoir_tolerance = TreatmentOptions{}.reservoir_tolerance; // quiet: correct a sublayer when |N - X| > max(1, this sqrt(X))
  std::int64_t reservoir_candidates = TreatmentOptions{}.reservoir_candidates; // quiet: fixed candidate points per target particle
  double reservoir_integral = TreatmentOptions{}.reservoir_integral; // quiet: integral action's tau in w^2 / kappa (0: off)
  double reservoir_group = TreatmentOptions{}.reservoir_group_target; // quiet: sublayers held together up to this target (particles)
  NeumannOutflow neumann_outflow = TreatmentOptions{}.neumann_outflow;  // written "nearest" for NearestParticles (an older name)
  // layer (B_l only) | nearest (beyond B_l when it runs empty)
  bool absorb_stranded = TreatmentOptions{}.absorb_stranded;  // written keep | absorb: particles beyond a Dirichlet face (layer treatment)
};

struct DiagnosticsSection {
  std::optional<Vec3> center;
  std::optional<double> M_inf;
  std::optional<double> J_inf;
  std::string reference = "none";  // none | crank_sphere | crank_slab | free_space | cosine_mode
  std::optional<double> reference_radius;
  std::optional<double> reference_length;
};

struct Config {
  RunSection run;
  DomainSection domain;
  ParticlesSection particles;
  PhysicsSection physics;
  std::vector<BoundarySpec> boundary;
  SolverSection solver;
  TreatmentSection treatment;
  DiagnosticsSection diagnostics;
  std::string source = "<string>";      // file the configuration came from
  std::vector<std::string> overrides;   // the --set arguments, in order
};

// Parses, applies the overrides ("a.b=value", in order) and validates every
// value that does not need the geometry (ConfiguredRun checks the rest).
Config parse_config_file(const std::filesystem::path& file, const std::vector<std::string>& overrides = {});
Config parse_config_string(std::string_view toml_text, const std::vector<std::string>& overrides = {},
                           const std::string& source = "<string>");

// Every key of the schema as "section.key", arrays of tables as
// "boundary[].patch" and "domain.subpatch[].name" (for docs and tests).
std::vector<std::string> schema_keys();

// One key of the table, as docs and tests see it.
struct KeyInfo {
  std::string path;                  // "run.dim", "boundary[].kind"
  std::string type;                  // "integer", "number", "string" or "point"
  nlohmann::json default_value;      // the member's in-class default; null: none (optional or required key)
  bool optional = false;             // absent unless given (a std::optional member)
  bool required = false;             // a key of an array of tables that every entry must give
  std::vector<std::string> choices;  // allowed strings (empty: any)
  std::string rule;                  // the key's own range rule, e.g. "> 0", "in (0, 2]" (empty: none)
};
const std::vector<KeyInfo>& schema();

// The typed configuration as a TOML document (all keys, defaults filled in;
// absent optional keys and keys that do not apply are omitted). Parsing it
// again gives the same Config.
std::string to_toml(const Config& config);

// The keys a resumed run may change (otfp run --resume DIR --set ...): where
// it ends and how it writes; every other key is the checkpoint's.
const std::vector<std::string>& resume_keys();

// Levenshtein distance between two words (the "did you mean" hints of keys,
// subcommands and options).
std::size_t edit_distance(const std::string& a, const std::string& b);

// The configuration as a checkpoint records it: every key but resume_keys(),
// "section.key" (arrays of tables "boundary[0].value") -> the value as JSON
// text, taken from the configuration as config.toml holds it (to_toml parsed
// again, so that keys to_toml leaves out compare equal). A resume compares
// its own with the checkpoint's and refuses any difference.
std::map<std::string, std::string> config_fingerprint(const Config& config);

// The resolved configuration as JSON (what `otfp check` and summary.json
// show): every key with defaults filled in, absent optional keys as null,
// "boundary" and "domain.subpatch" as arrays of objects.
nlohmann::json config_to_json(const Config& config);

}  // namespace otfp::app
