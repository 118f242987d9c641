#pragma once
// The explicit baselines of the diffusive fractional step: Algorithm 1
// (sign corrected, docs/method_notes.md#explicit-sign), its RK4 variant and
// an Euler step with the exact gradient of (28). ExplicitScheme and
// ExplicitOptions live here; the report is StepSummary (step_summary.hpp).
#include <string>
#include <utility>
#include <vector>

#include "otfp/external_potential.hpp"
#include "otfp/functional.hpp"
#include "otfp/step_summary.hpp"
#include "otfp/enums.hpp"

namespace otfp {

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
  // Widths stay fixed. Throws InvalidArgument for dt <= 0 and for particles
  // of another dimension. As in ImplicitStepper, a step from non-positive or
  // non-finite masses or widths, with a non-finite F before or after, or that
  // produces non-finite positions is rejected (accepted == false, reason
  // NonFinite) and leaves the particles exactly as they were; an accepted
  // step may also reorder them (sort_particles; ids kept).
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
