#pragma once
// Time steppers for the diffusive fractional step: the implicit variational
// step (minimise (28) with Ceres or NLopt) and the explicit baselines of
// Algorithm 1 (sign corrected, docs/method_notes.md#explicit-sign).
#include <functional>
#include <limits>
#include <string>
#include <unordered_map>
#include <vector>

#include "otfp/functional.hpp"
#include "otfp/minimizer.hpp"

namespace otfp {

enum class WidthMode {
  Fixed,       // widths stay as given (the papers' choice)
  PerParticle  // one optimised width per particle, minimising (28) in s as well
};
std::string to_string(WidthMode m);
WidthMode width_mode_from_string(const std::string& s);  // "fixed" | "per_particle"

// Time discretisation of the implicit step (docs/stepper.md).
enum class TimeScheme {
  Euler,  // implicit Euler: minimise (28) from x^k (the papers' scheme, first order)
  Bdf2    // variational BDF2: the same functional about x_hat = x^k + c (x^k - x^{k-1}), second order
};
std::string to_string(TimeScheme s);
TimeScheme time_scheme_from_string(const std::string& s);  // "euler" | "bdf2"

// Starting point of each solve.
enum class Predictor {
  None,        // x^k (the warm start of the papers)
  Extrapolate,  // x^k + (dt_k / dt_{k-1}) (x^k - x^{k-1}), kept inside the walls
  Damped        // the same times each particle's observed ratio of successive displacements, in [0, 1]
};
std::string to_string(Predictor p);
Predictor predictor_from_string(const std::string& s);  // "none" | "extrapolate" | "damped"

// Optional external potential per unit mass (the Psi of (15)); returns its
// value at x and, if grad is not null, its gradient. Added to the barrier.
using ExternalPotential = std::function<double(const Vec3& x, Vec3* grad)>;

// What every step reports.
struct StepSummary {
  bool accepted = false;                    // false: the state was left untouched
  TerminationReason reason = TerminationReason::Converged;  // of the last solve
  std::string message;                      // why a step was rejected or retried
  double dt = 0.0;                          // the step requested
  int substeps = 1;                         // 2^halvings substeps of dt / 2^halvings were taken
  int halvings = 0;                         // how often a failed solve was retried with dt/2
  int rejected_solves = 0;                  // failed solves (each is retried or reported)
  double f_before = 0.0, f_after = 0.0;     // F at the warm start and at the result (last substep)
  FunctionalParts parts_before, parts_after;
  int iterations = 0;                       // summed over substeps
  int evaluations = 0;                      // value+gradient evaluations, summed
  double residual_displacement = 0.0;       // final stopping measure: largest dt/m |dF/dx| left (a length)
  int list_builds = 0;                      // neighbour-list builds during the step
  double wall_seconds = 0.0;
  double solver_seconds = 0.0;              // time inside the optimiser itself
  double gradient_tolerance = 0.0;          // stopping threshold used (implicit: after the relative rule)
  double list_seconds = 0.0;                // time in neighbour-list builds
  std::uint64_t pair_evaluations = 0;
  long inserted = 0, removed = 0;           // particles, filled by source/projection steps
  // Local time-error estimate (implicit stepper): mass-weighted RMS over the
  // particles with enough history of |e_p| / s_p, e_p the Milne estimate of
  // the step's local error (order 1: Euler, 2: BDF2) averaged over the
  // particle's neighbourhood (ImplicitOptions::error_smoothing); NaN when no particle has the history it
  // needs (first steps, docs/stepper.md). Largest over substeps.
  double error_estimate = std::numeric_limits<double>::quiet_NaN();
  double particle_error_estimate = std::numeric_limits<double>::quiet_NaN();  // the same without the average
  int error_order = 0;                      // order of the scheme the estimate belongs to
  bool error_rejected = false;              // rejected because error_estimate > the caller's limit
  long bdf2_particles = 0;                  // particles stepped with the BDF2 form (last substep)
  long predicted_particles = 0;             // particles started from the extrapolation (last substep)
  double f_start = 0.0;                     // F at the solver's start point (== f_before without a predictor)
};

struct ImplicitOptions {
  MinimizerOptions minimizer;                        // backend, algorithm, caps (gradient_tolerance is set per step)
  double displacement_tolerance = 1e-3;              // stop when max |dt/m dF/dx| <= this x smallest width s
  double relative_tolerance = 1e-2;                  // ... or <= this x the step's first gradient step, if smaller
  WidthMode width_mode = WidthMode::Fixed;           // optimise widths or not
  WidthMetric width_metric = WidthMetric::AsPrinted; // c_w = 1 or d/2
  double kappa = 1.0;                                // diffusivity
  double rho_ref = 1.0;                              // reference density in the entropy
  NeighborOptions neighbor{1e-8, -1.0, 1.0};         // cut-off tolerance; skin = 1 x smallest s
  int max_halvings = 4;                              // retries with dt/2 substeps after a failed solve
  double energy_tolerance = 1e-9;                    // allowed F_after - F_before, relative to |F_before| + |E|
  bool sort_particles = true;                        // reorder particles spatially at each accepted step (ids kept)
  TimeScheme time_scheme = TimeScheme::Euler;        // implicit Euler or variational BDF2
  Predictor predictor = Predictor::None;             // start of each solve
  double error_smoothing = 2.0;                      // error estimate: smoothing length in widths s (0: per particle)
  void validate() const;
};

class ImplicitStepper {
 public:
  ImplicitStepper(int dim, ImplicitOptions options, Barrier barrier = {}, Periodicity periodicity = {});
  // One implicit step of length dt from the state in `particles`. On failure
  // (after max_halvings retries) the particles are left exactly as they were.
  // On success they may also be reordered (sort_particles); ids are kept.
  // max_error: a step whose error_estimate exceeds it is not taken
  // (accepted == false, error_rejected == true; the history is kept), so an
  // adaptive caller (TimeStepController) can retry with a smaller dt.
  StepSummary step(ParticleSet& particles, double dt,
                   double max_error = std::numeric_limits<double>::infinity());
  // The stepper remembers each particle's last two diffusive displacements
  // (by id) for the predictor, BDF2 and the error estimate. Call this when the
  // particles were changed in a way that is not a time step (a new set, a restart).
  void reset_history();
  std::size_t history_size() const { return history_.size(); }
  // The history as data (for checkpoints), entries sorted by id; importing
  // it into a stepper built with the same options continues bit for bit.
  struct HistoryEntry {
    ParticleId id = 0;
    Vec3 d1 = Vec3::Zero(), d2 = Vec3::Zero();
    double ds1 = 0.0, ds2 = 0.0;
    int count = 0;
  };
  struct HistoryState {
    std::vector<HistoryEntry> entries;
    double dt1 = 0.0, dt2 = 0.0;
  };
  HistoryState history_state() const;
  void restore_history(const HistoryState& state);  // throws InvalidArgument for a bad entry
  // Where the predictor (options().predictor, or Extrapolate if None) would
  // start a step of length dt, in the order of `particles`: e.g.
  // x + (dt / dt_{k-1}) (x^k - x^{k-1}), pulled back towards x where that would
  // leave the barrier domain or cross a mirrored wall; x itself for particles
  // with no history.
  std::vector<Vec3> predict(const ParticleSet& particles, double dt) const;
  double previous_dt() const { return dt1_; }
  void set_external_potential(ExternalPotential u) { external_ = std::move(u); }
  const ImplicitOptions& options() const { return options_; }
  Functional& functional() { return functional_; }
  Barrier& barrier() { return functional_.barrier().barrier(); }

 private:
  // Per-particle history, aligned with the particles during a step.
  struct History {
    Vec3 d1 = Vec3::Zero(), d2 = Vec3::Zero();  // x^k - x^{k-1}, x^{k-1} - x^{k-2} (diffusive part)
    double ds1 = 0.0, ds2 = 0.0;                // the same for widths
    int count = 0;                              // how many of d1, d2 are known
  };
  bool solve(std::vector<Vec3>& x, std::vector<double>& s, const std::vector<double>& m, std::vector<History>& hist,
             double& dt1, double& dt2, double dt, StepSummary& summary);
  Vec3 admissible_start(const Vec3& from, const Vec3& to) const;
  // Factor g of the predicted displacement g d1 for a step w = dt / dt_{k-1} times the last.
  static double predictor_factor(Predictor predictor, const History& h, double omega);
  int dim_;
  ImplicitOptions options_;
  Functional functional_;
  ExternalPotential external_;
  std::unordered_map<ParticleId, History> history_;
  double dt1_ = 0.0, dt2_ = 0.0;  // the last two step sizes (0: none)
};

enum class ExplicitScheme {
  EulerForce27,       // Algorithm 1 line 4: x <- x - dt (kappa grad rho/rho + grad Psi)
  Rk4Force27,         // classical RK4 with the same velocity ([2023] Sec. 5.1)
  EulerExactGradient  // x <- x - dt/m dF/dx with the exact gradient of (28)
};
std::string to_string(ExplicitScheme s);
ExplicitScheme explicit_scheme_from_string(const std::string& s);  // "euler27" | "rk4" | "euler_exact"

struct ExplicitOptions {
  ExplicitScheme scheme = ExplicitScheme::EulerForce27;  // which explicit update
  double kappa = 1.0;                                    // diffusivity
  double rho_ref = 1.0;                                  // reference density (only shifts F)
  NeighborOptions neighbor{1e-8, -1.0, 1.0};             // cut-off tolerance and skin
  bool sort_particles = true;                            // reorder particles spatially each step (ids kept)
  void validate() const;
};

class ExplicitStepper {
 public:
  ExplicitStepper(int dim, ExplicitOptions options, Barrier barrier = {}, Periodicity periodicity = {});
  // Widths stay fixed. A step that produces non-finite positions is rejected
  // (the particles may have been reordered, ids kept, but not moved).
  StepSummary step(ParticleSet& particles, double dt);
  // The external potential per unit mass: its force -grad U joins the
  // velocity of every scheme, its energy sum m U the barrier part of F.
  void set_external_potential(ExternalPotential u) { external_ = std::move(u); }
  Barrier& barrier() { return functional_.barrier().barrier(); }
  Functional& functional() { return functional_; }

 private:
  void velocity(const std::vector<Vec3>& x, const std::vector<double>& s, std::vector<Vec3>& v);
  void add_external(const std::vector<Vec3>& x, const std::vector<double>& m, FunctionalParts& parts) const;
  ExternalPotential external_;
  int dim_;
  ExplicitOptions options_;
  Functional functional_;
};

}  // namespace otfp
