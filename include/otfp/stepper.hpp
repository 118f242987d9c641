#pragma once
// Time steppers for the diffusive fractional step: the implicit variational
// step (minimise (28) with Ceres or NLopt) and the explicit baselines of
// Algorithm 1 (sign corrected, METHOD-NOTES 2.1).
#include <functional>
#include <string>
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
  double gradient_norm = 0.0;               // final scaled stopping measure (a displacement)
  int list_builds = 0;                      // neighbour-list builds during the step
  double wall_seconds = 0.0;
  double solver_seconds = 0.0;              // time inside the optimiser itself
  double gradient_tolerance = 0.0;          // stopping threshold used (implicit: after the relative rule)
  double list_seconds = 0.0;                // time in neighbour-list builds
  std::uint64_t pair_evaluations = 0;
  long inserted = 0, removed = 0;           // particles, filled by source/projection steps
};

struct ImplicitOptions {
  MinimizerOptions minimizer;                        // backend, algorithm, caps (gradient_tolerance is set per step)
  double displacement_tolerance = 1e-2;              // stop when max |dt/m dF/dx| <= this x smallest width s
  double relative_tolerance = 1e-1;                  // ... or <= this x the step's first gradient step, if smaller
  WidthMode width_mode = WidthMode::Fixed;           // optimise widths or not
  WidthMetric width_metric = WidthMetric::AsPrinted; // c_w = 1 or d/2
  double kappa = 1.0;                                // diffusivity
  double rho_ref = 1.0;                              // reference density in the entropy
  NeighborOptions neighbor{1e-8, -1.0, 1.0};         // cut-off tolerance; skin = 1 x smallest s
  int max_halvings = 4;                              // retries with dt/2 substeps after a failed solve
  double energy_tolerance = 1e-9;                    // allowed F_after - F_before, relative to |F_before| + |E|
  bool sort_particles = true;                        // reorder particles spatially at each accepted step (ids kept)
  void validate() const;
};

class ImplicitStepper {
 public:
  ImplicitStepper(int dim, ImplicitOptions options, Barrier barrier = {}, Periodicity periodicity = {});
  // One implicit step of length dt from the state in `particles`. On failure
  // (after max_halvings retries) the particles are left exactly as they were.
  // On success they may also be reordered (sort_particles); ids are kept.
  StepSummary step(ParticleSet& particles, double dt);
  void set_external_potential(ExternalPotential u) { external_ = std::move(u); }
  const ImplicitOptions& options() const { return options_; }
  Functional& functional() { return functional_; }
  Barrier& barrier() { return functional_.barrier().barrier(); }

 private:
  bool solve(std::vector<Vec3>& x, std::vector<double>& s, const std::vector<double>& m, double dt,
             StepSummary& summary);
  int dim_;
  ImplicitOptions options_;
  Functional functional_;
  ExternalPotential external_;
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
  Barrier& barrier() { return functional_.barrier().barrier(); }
  Functional& functional() { return functional_; }

 private:
  void velocity(const std::vector<Vec3>& x, const std::vector<double>& s, std::vector<Vec3>& v);
  int dim_;
  ExplicitOptions options_;
  Functional functional_;
};

}  // namespace otfp
