#pragma once
// A run as the CLI makes it: the configuration turned into the papers'
// numbers (36)-(40) and an otfp::Simulation (the library's Algorithm 1),
// then the steps with their rows, snapshots, checkpoints and summary.
//
// ConfiguredRun's constructor does every check that needs the geometry and
// builds all library objects; it throws ConfigError (exit code 2) and never
// touches the file system. run() creates the output directory and steps.
#include <array>
#include <csignal>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "otfp/boundary.hpp"
#include "otfp/run_record.hpp"
#include "otfp/geometry.hpp"
#include "otfp/particles.hpp"
#include "otfp/simulation.hpp"
#include "otfp_app/config.hpp"

namespace otfp::app {

// Library version the tool reports.
std::string version();

// One boundary patch of the built domain and what is imposed on it.
struct PatchInfo {
  int id = 0;
  std::string name;
  double area = 0.0;
  PatchKind kind = PatchKind::NoFlux;
  double value = 0.0;            // g or f
  double t_start = 0.0;
  std::optional<double> t_end;
  int condition = -1;            // index into BoundaryProjection::conditions(), -1 for no_flux
};

// Numbers derived from the configuration by the papers' rules (36)-(40).
struct Derived {
  double volume = 0.0;       // |Omega| (free: the reference box)
  double dr = 0.0;           // mean spacing (37) or the sphere-radius rule
  double beta = 0.0;         // beta_factor / dr^2
  double width_s = 0.0;      // beta^-1/2
  double width_reference_dr = 0.0;  // spacing of the same rule at particles.width_reference_n
  double true_spacing = 0.0;        // (|Omega|/n_inf)^(1/d), whatever the spacing rule
  double beta_true_spacing2 = 0.0;  // beta * true_spacing^2 (2 for beta_factor 2 with "cube", q = 1)
  double length_L = 0.0;     // L of b = sqrt(L dr)
  double layer_b = 0.0;      // boundary-layer half-thickness b
  double dt_explicit = 0.0;  // dr^2 / kappa (39)
  double dt = 0.0;           // the step used: t_end / n_steps
  std::int64_t n_steps = 0;  // steps to t_end
  std::int64_t steps_to_run = 0;  // n_steps, or run.max_steps if smaller
  double barrier_C = 0.0;    // (40): barrier_factor / dt_explicit unless given
  std::string barrier_domain = "none";  // what Omega' the barrier keeps the particles in
  int mirrored_walls = 0;               // wall surfaces with image blobs (treatment.no_flux, reservoir back faces)
  double reservoir_width = 0.0;         // band width w of the Dirichlet reservoir (0: papers' layer)
  int reservoir_sublayers = 0;          // sublayers of the band, each held at its own count
  double particle_mass = 0.0;
  double M_inf = 0.0;
  std::string M_inf_rule;
  std::optional<double> J_inf;
  std::string J_inf_rule;
  Vec3 center = Vec3::Zero();  // polar inertia centre
  std::int64_t fill_count = 0;
  std::int64_t max_particles = 0;  // run.max_particles, or half the memory / kBytesPerParticle
  double neumann_net_inflow = 0.0;  // integral over [0, t_end] of the inflow of all Neumann patches
  std::optional<double> reference_radius, reference_length;
  std::optional<double> reference_J_inf;  // analytic steady polar inertia (J reference of crank_*)
  int slab_axis = -1;                     // crank_slab on a box: axis normal to the held face
  bool slab_held_at_hi = false;           // the held face is x = hi (else x = lo)
  std::array<std::int64_t, 3> lattice_counts{1, 1, 1};  // fill_arrangement = lattice: points per axis
  double mode_wavenumber = 0.0;           // k of the cosine fill
};

// Exit code of a run stopped by SIGINT/SIGTERM (checkpoint written; continue
// with `otfp run --resume DIR`). 0 completed, 1 failed, 2 bad input.
constexpr int kExitInterrupted = 3;
// A resume refused before any file was touched (a damaged or foreign
// checkpoint, series.csv or timing.csv unreadable, run.t_end before the
// checkpoint's time): bad input, exit code 2.
constexpr int kExitRefused = 2;

struct RunOptions {
  std::filesystem::path out_dir;  // empty: write nothing (in-memory run for tests)
  bool progress = false;          // progress line on stderr
  bool keep_series = true;        // keep every StepRecord in RunResult::series
  bool resume = false;            // continue from out_dir/checkpoint.bin (series.csv cut back to its step)
  const volatile std::sig_atomic_t* stop_flag = nullptr;  // set (by a signal handler): stop after the current step
  std::int64_t stop_after_step = 0;  // > 0: stop as if signalled after this step (tests)
};

struct RunResult {
  int exit_code = 0;              // 0 completed, 1 failed, kExitInterrupted, kExitRefused
  std::string status;             // "completed" | "failed" | "interrupted" | "refused" (nothing written)
  bool nothing_to_do = false;     // resume: the checkpoint is already at run.t_end (no file touched)
  std::string error;              // why it failed
  std::vector<StepRecord> series;
  StepRecord last;
  bool rows = false;              // at least one row (step 0) was written
  nlohmann::json summary;         // what summary.json holds
};

// The number of ranks mpirun (Open MPI, or PMI: MPICH, Slurm) started this
// process among; 1 when not started by it. With more than one, a
// ConfiguredRun is distributed over them (docs/distributed.md).
int launched_ranks();
// This process's rank among them (0 when not started by mpirun).
int launched_rank();

class ConfiguredRun {
 public:
  explicit ConfiguredRun(Config config);
  ~ConfiguredRun();
  ConfiguredRun(const ConfiguredRun&) = delete;
  ConfiguredRun& operator=(const ConfiguredRun&) = delete;

  RunResult run(const RunOptions& options);

  // A new Simulation built as run() builds its own and started with the same
  // initial particles and random stream: stepping it with advance_to(k dt)
  // (dt = derived().dt) reproduces run()'s steps bit for bit. For callers that
  // step themselves (the Python module); nothing is written.
  std::unique_ptr<otfp::Simulation> make_simulation() const;
  // The initial particles of the configuration (particles.fill), drawn from rng.
  ParticleSet initial_particles(Rng& rng) const;

  // Started by mpirun on several ranks: whether this is the rank that
  // writes the files and prints (true when serial), and whether v holds on
  // some rank (collective).
  bool root_process() const;
  bool any_process(bool v) const;

  const Config& config() const { return config_; }
  const Derived& derived() const { return derived_; }
  const Domain& domain() const { return *domain_; }
  DomainPtr domain_ptr() const { return domain_; }
  const std::vector<PatchInfo>& patches() const { return patches_; }
  // The resolved configuration and derived numbers (summary.json "config"/"derived").
  nlohmann::json describe() const;

 private:
  void check_magnitudes(const std::vector<ConstantBoundaryData>& data) const;
  struct State;
  Config config_;
  DomainPtr domain_;
  bool free_space_ = false;
  Derived derived_;
  std::vector<PatchInfo> patches_;
  std::unique_ptr<State> state_;
};

}  // namespace otfp::app
