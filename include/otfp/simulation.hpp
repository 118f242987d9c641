#pragma once
// Algorithm 1 of [2025] as one library object. Each step is
//   line 2      advection by a uniform velocity,
//   line 3      the volumetric source,
//   line 4      the diffusive step (implicit (28) or an explicit scheme),
//   lines 5-23  the boundary projection onto the Dirichlet and Neumann data,
// followed by putting back particles that crossed a mirrored wall, and a
// check of the ledger n(t) = n(0) + inserted - removed (and the same for the
// mass). The Simulation owns its particles, random numbers, steppers and
// projection; save_checkpoint()/load_checkpoint() continue a run bit for bit.
//
//   otfp::Simulation sim(domain, {{0, otfp::PatchKind::Dirichlet, 1.0}}, options);
//   sim.start(otfp::ParticleSet(3));
//   sim.run_until(1.0, dt, [](const otfp::Simulation& s, const otfp::SimulationStep& step) { ... });
#include <cstdint>
#include <filesystem>
#include <functional>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "otfp/boundary.hpp"
#include "otfp/diagnostics.hpp"
#include "otfp/geometry.hpp"
#include "otfp/ledger.hpp"
#include "otfp/mass_measure.hpp"
#include "otfp/particles.hpp"
#include "otfp/stepper.hpp"
#include "otfp/time_step_control.hpp"
#include "otfp/enums.hpp"

namespace otfp {

// Constant data on one patch, switched on over [t_start, t_end): Dirichlet g
// or Neumann outward flux f (a step receives the exact integral over the
// part of the window it covers).
struct ConstantBoundaryData {
  int patch = -1;
  PatchKind kind = PatchKind::Dirichlet;
  double value = 0.0;
  double t_start = 0.0;
  double t_end = std::numeric_limits<double>::infinity();
};

// Memory of one particle in a run (particles, neighbour list, solver arrays):
// the maximum resident set grew by 2.46 KB per particle from n = 2e4 to 8e4
// for a uniform 3-D fill (otfp run of free_space_heat.toml with fill =
// "uniform"); a dense Gaussian cloud holds more neighbours and costs more.
constexpr double kBytesPerParticle = 2500.0;
// Half the machine's physical memory over kBytesPerParticle (at least 1000):
// what SimulationOptions::max_particles = 0 means.
std::int64_t default_max_particles();

struct SimulationOptions {
  double particle_mass = 0.0;      // m_p of the particles the projection and source insert (> 0)
  double width_s = 0.0;            // s = beta^-1/2 of inserted particles (> 0)
  bool bounded = true;             // false: free space (the domain only measures; no barrier, walls or data)
  double barrier_stiffness = 0.0;  // C of (40) (> 0 for a bounded, non-periodic domain)
  NoFluxTreatment no_flux = NoFluxTreatment::Images;  // walls without data
  // layer_b, the target rule, the outflow rule; dirichlet_mode = Reservoir with
  // reservoir_thickness w > 0 puts a band outside the Dirichlet patches (its
  // reservoir_domain is built here).
  ProjectionOptions projection;
  bool fill_reservoir_at_start = true;  // reservoir: fill the band before the first step (counted as step 0)
  StepperKind stepper = StepperKind::Implicit;
  ImplicitOptions implicit;                    // kappa, rho_ref, solver, time scheme (implicit)
  ExplicitOptions explicit_options;            // scheme, kappa, rho_ref (explicit)
  Vec3 velocity = Vec3::Zero();                // uniform advection velocity (line 2)
  double source_rate = 0.0;                    // uniform volumetric source rate s (line 3)
  bool source_draws_by_id = true;              // the source's random numbers per particle id (independent of storage order and rank count); false: one stream in storage order (serial only: a distributed Simulation refuses it)
  TimeStepControlOptions time_control;         // advance_adaptive(): tolerance, dt_min, dt_max
  int max_error_rejections = 1000;             // advance_adaptive(): tries per step before failing
  std::uint64_t seed = 1;                      // random numbers (projection, source) unless start() is given an Rng
  std::int64_t max_particles = 0;              // a step that would exceed it fails (StepFailure); 0: default_max_particles()
  void validate() const;                       // throws InvalidArgument naming the field
};

// Raised by the constructor when the pieces do not fit together; stage()
// says which part failed so that a caller can name its own input.
class SimulationSetupError : public InvalidArgument {
 public:
  enum class Stage { Reservoir, ReservoirMirror, Projection, Walls, Periodic, Stepper };
  SimulationSetupError(Stage stage, const std::string& message) : InvalidArgument(message), stage_(stage) {}
  Stage stage() const { return stage_; }

 private:
  Stage stage_;
};

// A step that could not be taken (the diffusive solve failed, the error test
// rejected too many tries, the projection or source would exceed
// max_particles, or the ledger broke). The state is the one the step started
// from.
class StepFailure : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Totals over the steps taken (wall times are not reproducible).
struct SimulationTotals {
  std::int64_t iterations = 0, evaluations = 0, rejected_solves = 0, halvings = 0;
  std::int64_t error_rejected_steps = 0, steps_forced_at_dt_min = 0;
  double dt_min_used = std::numeric_limits<double>::infinity(), dt_max_used = 0.0;
  double step_seconds = 0.0, solver_seconds = 0.0, list_seconds = 0.0;
};

// One step of Algorithm 1.
struct SimulationStep {
  std::int64_t step = 0;          // k: 1 for the first step
  double t_start = 0.0, t_end = 0.0;
  StepSummary diffusion;          // the accepted diffusive step (empty set: accepted, nothing moved)
  std::int64_t inserted = 0, removed = 0;  // this step: source and projection
  std::int64_t reflected = 0;     // put back across mirrored walls
  std::int64_t error_rejections = 0;  // advance_adaptive(): tries rejected before this one
  bool forced_at_dt_min = false;  // advance_adaptive(): accepted at dt_min above the tolerance
  double dt_next = 0.0;           // advance_adaptive(): the controller's next proposal
  double wall_seconds = 0.0;
  double dt() const { return t_end - t_start; }
  // One line: step, time, dt, F, evaluations, insertions and removals.
  std::string brief_report() const;
  // Several lines: the above and the solver's termination, F's parts, the
  // error estimate and the adaptive tries.
  std::string full_report() const;
};

// The grid of a run's fixed steps (Simulation::run): step k ends at
// t_origin + (k - k_origin) dt, the last one (k = k_end) on t_end exactly. A
// checkpoint keeps it, so that a resumed run takes the same steps.
struct TimeGrid {
  double t_origin = 0.0;       // where the grid starts
  std::int64_t k_origin = 0;   // the step number there
  double dt = 0.0;             // its step (0: no grid yet)
  std::int64_t k_end = 0;      // the step that ends on t_end
  double t_end = 0.0;          // the end of the run it was made for
  double time_of(std::int64_t k) const {
    return k == k_end ? t_end : t_origin + static_cast<double>(k - k_origin) * dt;
  }
};

// What Simulation::run() steps to and when it stops.
struct RunControl {
  double t_end = 0.0;          // end of the run (finite)
  double dt = 0.0;             // fixed steps: the step of a new grid; adaptive: the first try (> 0)
  bool adaptive = false;       // advance_adaptive() to t_end instead of the grid
  std::int64_t max_steps = 0;  // stop after step number max_steps (step_count(), the whole run's); 0: no limit
  std::int64_t checkpoint_interval = 0;  // on_checkpoint() after each step k with k % this == 0 (0: at the end only)
  std::function<bool(const SimulationStep&)> stop;  // asked after every step: true ends the run with it
  void validate() const;       // throws InvalidArgument naming the field
};

// What a caller of run() sees: every step, and the moments to checkpoint.
class RunObserver {
 public:
  virtual ~RunObserver() = default;
  // After every step; `last`: the run ends with this step (t_end, max_steps or a stop).
  virtual void on_step(const class Simulation& sim, const SimulationStep& step, bool last) = 0;
  // At the checkpoint cadence, and once after the last step (a stopped run too).
  virtual void on_checkpoint(const class Simulation&) {}
};

enum class RunEnd {
  Completed,  // t_end reached
  MaxSteps,   // stopped at max_steps before t_end
  Stopped     // the stop predicate ended it before either
};
std::string to_string(RunEnd e);  // "completed" | "max_steps" | "stopped"

class RunDistribution;

class Simulation {
 public:
  // boundary: the data per patch (patches not listed are no-flux walls).
  // Builds the projection, the barrier domain (Omega, Omega inflated by b
  // over the Dirichlet patches, or Omega with the reservoir band), the
  // mirrored walls and the stepper; every check that needs the geometry is
  // done here. Throws SimulationSetupError or InvalidArgument.
  Simulation(DomainPtr domain, std::vector<ConstantBoundaryData> boundary, SimulationOptions options);
  // A run over several processes (otfp/run_distribution.hpp; MpiDistribution
  // in otfp::mpi): every process builds the Simulation with the same
  // arguments and its own distribution object, and holds a share of the
  // particles (start() takes any split; particles() is this process's share;
  // measure() and blob_mass() are global). The steps (fixed or adaptive,
  // Euler or BDF2, with the predictor), projections, source and ledger are
  // those of the serial run on the union (the projection draws its random
  // deletions by id, the source per particle id); the explicit stepper's
  // steps too (fixed steps only, as serially). Refused (InvalidArgument
  // naming the field): an implicit run with a backend other than TAO.
  // Collective: the constructor, start(), every step and the checkpoints.
  Simulation(DomainPtr domain, std::vector<ConstantBoundaryData> boundary, SimulationOptions options,
             std::shared_ptr<RunDistribution> distribution);
  ~Simulation();
  bool distributed() const { return distribution_ != nullptr; }
  // The particle count over all processes (particles().size() when serial; collective).
  std::int64_t global_size() const;
  Simulation(const Simulation&) = delete;
  Simulation& operator=(const Simulation&) = delete;

  // Sets the state at time t0 (the particles may be empty), resets ledger,
  // totals and stepper history, and (reservoir, fill_reservoir_at_start)
  // fills the band to its target: a zero-length projection whose counts are
  // initial_step()'s, step 0. The Rng continues a stream the caller began
  // (e.g. to place the particles); without it, Rng(options.seed).
  void start(ParticleSet particles, double t0 = 0.0);
  void start(ParticleSet particles, Rng rng, double t0 = 0.0);
  const SimulationStep& initial_step() const { return initial_; }
  bool started() const { return started_; }

  // One step from time() to t_end (> time()). Throws StepFailure (state kept)
  // or std::logic_error before start().
  SimulationStep advance_to(double t_end);
  SimulationStep advance(double dt) { return advance_to(time_ + dt); }
  // One adaptive step (implicit stepper): tries the controller's proposal,
  // undoes and retries tries whose error estimate exceeds the tolerance, and
  // ends on t_limit exactly when the proposal comes within 10% of it.
  SimulationStep advance_adaptive(double t_limit);
  // Steps to t_end: adaptive when `adaptive`, else with n = ceil((t_end -
  // time()) / dt) equal steps; the observer sees every step.
  using Observer = std::function<void(const Simulation&, const SimulationStep&)>;
  void run_until(double t_end, double dt, const Observer& observer = {}, bool adaptive = false);

  // The time loop (the command line's too). Fixed steps follow time_grid():
  // a new grid from time() with about control.dt per step; a run that
  // continues a grid (after an earlier run() or load_checkpoint()) keeps it
  // when its step is control.dt, moving only its end to control.t_end, and
  // otherwise keeps its step: equal steps of about that step from time() to
  // t_end. Adaptive: advance_adaptive(t_end), the first try control.dt
  // (within the controller's bounds) unless one is pending. Returns at once,
  // calling nothing, when finished(control). Throws StepFailure (the state
  // of the failed step's start; the steps before it stand).
  RunEnd run(const RunControl& control, RunObserver* observer = nullptr);
  TimeGrid grid_for(const RunControl& control) const;  // the grid run(control) steps on (fixed steps)
  bool finished(const RunControl& control) const;      // run(control) would take no step
  const TimeGrid& time_grid() const { return grid_; }

  double time() const { return time_; }
  std::int64_t step_count() const { return step_; }
  double next_dt() const { return dt_next_; }  // advance_adaptive()'s next try (0: none yet)
  void set_next_dt(double dt);                 // the first adaptive try, or a new one
  const ParticleSet& particles() const { return particles_; }
  const Domain& domain() const { return *domain_; }
  DomainPtr domain_ptr() const { return domain_; }
  const SimulationOptions& options() const { return options_; }
  // options().max_particles, or default_max_particles() for 0.
  std::int64_t max_particles() const {
    return options_.max_particles > 0 ? options_.max_particles : default_max_particles();
  }
  const std::vector<ConstantBoundaryData>& boundary() const { return boundary_; }
  const SimulationLedger& ledger() const { return ledger_; }
  const SimulationTotals& totals() const { return totals_; }
  // The run so far: time, steps, particles, ledger and solver totals (several lines).
  std::string full_report() const;
  // Per condition, in the order of `boundary` minus the no-flux entries;
  // condition_of(patch) gives the index or -1.
  const BoundaryProjection& projection() const { return *projection_; }
  int condition_of(int patch) const;
  // The particles' regions and the sums (43)-(44) about `center` (over all
  // processes when distributed: collective; `region` is this process's).
  const BufferSpec& buffer() const { return buffer_; }
  StateMeasures measure(const Vec3& center, std::vector<std::int32_t>* region = nullptr) const;
  // The band of the reservoir treatment (null for the papers' layer).
  DomainPtr reservoir_domain() const { return reservoir_domain_; }
  // What the barrier holds the particles in, and the walls with image blobs.
  std::string barrier_domain_description() const { return barrier_description_; }
  int mirrored_walls() const;
  // M_rho: the blob density the functional sees integrated over Omega, the
  // image blobs at the mirrored walls included (blob_mass_in_domain() of the
  // particles plus that of their images): a particle next to a no-flux wall
  // counts whole, as its image folds its tail back, and a Dirichlet face is
  // crossed smoothly. Layers of particles that settle parallel to a face move
  // the count of centres (43) by a fraction of a layer; this measure does not
  // see where the layers fall (docs/boundaries.md, "Quiet reservoir").
  // (Over all processes when distributed: collective.)
  double blob_mass(const BlobMassOptions& options = {}) const;
  // The blob density (29) at this process's particles, of all particles
  // (images not included; collective when distributed).
  std::vector<double> particle_density(double kernel_tolerance) const;
  // Over several processes: the union of the shares in id order (a copy of
  // particles() when serial), whether this is the process that writes
  // files (true when serial), and whether v holds on any process (all
  // collective).
  ParticleSet gathered_particles() const;
  bool root_process() const;
  bool any_process(bool v) const;
  int process_rank() const;   // 0 when serial
  int process_count() const;  // 1 when serial
  ImplicitStepper* implicit_stepper() { return implicit_.get(); }
  ExplicitStepper* explicit_stepper() { return explicit_.get(); }

  // A checkpoint holds the particles (ids, widths, masses, birth times), the
  // random numbers, the ledger and totals, the projection's carries and
  // deficits, the implicit stepper's history and the time and step; `extra`
  // is kept for the caller (e.g. its own diagnostics). The file is written
  // atomically (a temporary file renamed over `path`). It also records the
  // setup: the domain (dimension, patches, volume, bounding box, patch
  // areas), the boundary data and the options that give the state its
  // meaning (particle mass, width, barrier, boundary treatment, stepper,
  // kappa, rho_ref, scheme, velocity, source); load_checkpoint() refuses a
  // file of another setup naming the first field that differs (the resource
  // limit, the adaptive controller, solver tolerances and the seed may
  // differ). It throws InvalidArgument (state unchanged) for a damaged,
  // truncated or foreign file, and for a path that is not a regular file.
  void save_checkpoint(const std::filesystem::path& path, const std::string& extra = {}) const;
  void load_checkpoint(const std::filesystem::path& path, std::string* extra = nullptr);
  // The caller's `extra` of a checkpoint file (checked as load_checkpoint
  // checks it, but not loaded): a caller can check its own data first.
  static std::string checkpoint_extra(const std::filesystem::path& path);

 private:
  // The state a step may change, taken before each step into arrays kept
  // from step to step (no allocation once they are large enough); a failed
  // step swaps it back. The implicit stepper's history is not copied: the
  // stepper keeps the one an accepted step replaced.
  struct Saved;
  void save_state();
  void restore_state();
  SimulationStep guarded(const std::function<SimulationStep()>& body);
  SimulationStep advance_to_impl(double t_end);
  SimulationStep advance_adaptive_impl(double t_limit);
  bool changes_before_solve() const;  // advection or a source: take_step changes the state before the solve
  SimulationStep take_step(double t0, double t1, double max_error);
  void undo_try();
  void finish_step(SimulationStep& step);
  void check_ledger(std::int64_t step, double t) const;
  void require_started(const char* what) const;

  PatchLedger project(double t, double dt);  // the projection, serial or over the distribution
  double share_blob_mass(const BlobMassOptions& options) const;  // blob_mass() of this process's particles
  void write_checkpoint(const std::filesystem::path& path, const std::string& extra,
                        const ParticleSet& particles, const HistoryState& history) const;
  void load_checkpoint_file(const std::filesystem::path& path, std::string* extra);
  DomainPtr domain_;
  std::vector<ConstantBoundaryData> boundary_;
  std::shared_ptr<RunDistribution> distribution_;
  ParticleSet particles_;
  SimulationOptions options_;
  Rng rng_;
  bool started_ = false;
  double time_ = 0.0;
  std::int64_t step_ = 0;
  double dt_next_ = 0.0;
  TimeGrid grid_;
  std::vector<int> condition_of_patch_;
  std::shared_ptr<std::pair<double, double>> step_window_;
  std::unique_ptr<BoundaryProjection> projection_;
  DomainPtr reservoir_domain_;
  std::vector<std::shared_ptr<const MirrorWall>> walls_;
  std::string barrier_description_ = "none";
  std::unique_ptr<ImplicitStepper> implicit_;
  std::unique_ptr<ExplicitStepper> explicit_;
  BufferSpec buffer_;
  SimulationLedger ledger_;
  SimulationTotals totals_;
  SimulationStep initial_;
  std::unique_ptr<Saved> saved_;
  bool history_updated_ = false;  // this step's diffusive step was accepted by the implicit stepper
};

}  // namespace otfp
