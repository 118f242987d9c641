#pragma once
// Internal to the implicit stepper (src/implicit_stepper.cpp): the objective
// one implicit step minimises, (28) in scaled unknowns, and the norm of its
// stopping rule (stopping_measure); and the Functional options of either
// stepper (the explicit ones use those too). Definitions in
// src/step_objective.cpp and src/explicit_stepper.cpp.
#include <cstddef>
#include <functional>
#include <vector>

#include "otfp/functional.hpp"
#include "otfp/explicit_stepper.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/minimizer.hpp"
#include "otfp/step_summary.hpp"

namespace otfp::detail {

// The objective in scaled unknowns: z_x = sqrt(a m/dt) x makes the transport
// Hessian the identity (a: the transport weight, 1 for Euler, (1+2w)/(1+w)
// for BDF2); widths are z_s = b_p log(s/s^k) with b_p = s^k sqrt(c_w a m/dt),
// which keeps s > 0 without bounds (NLopt's bounds slow L-BFGS down, Ceres has
// none) and has unit curvature at s = s^k. s_anchor = s^k, the widths at the
// start of the step (for BDF2 the functional's reference is s_hat instead).
//
// With an upper bound S on the widths (max_width_factor) the widths go
// through a fold in log s: log(s/S) = phi(v), phi(v) = v for v <= -d and
// -(v - d)^2/(4d) above (C1, d = kWidthFold), with z_s = b'_p (v - v^k). phi
// is the log map below S e^-d, reaches its maximum 0 (s = S) at the finite
// v = d and falls again beyond, so a width held by the bound is a stationary
// point at finite z (a logistic map reaches S only as z -> infinity, and the
// minimiser, chasing it, stalls: Ceres' relative step norm underflows).
// b'_p = b_p phi'(v^k) (at least b_p/2) keeps unit curvature at s^k below the
// fold. F itself is unchanged (a change of unknowns, not a penalty or a
// clamp), so a step still only lowers F and the energy inequality holds.
//
// The functional is reached through a StepFunctional: the serial Functional,
// or one rank's share of a DistributedFunctional (src/mpi/), whose F is
// already summed over the ranks. Its reductions make the objective's own
// sums (the external potential, the stopping measure) and its verdicts (a
// non-finite point) those of all the ranks; serially they are the identity.
struct StepFunctional {
  int dim = 3;
  double c_w = 1.0;
  std::function<FunctionalParts(const std::vector<Vec3>&, const std::vector<double>&, Gradient*)> evaluate;
  std::function<bool(bool)> all;                  // true iff every rank's value is true (null: identity)
  std::function<void(double*, int)> sum;          // in place, over the ranks (null: identity)
  std::function<double(double)> max;             // over the ranks (null: identity)
};

StepFunctional serial_step_functional(Functional& f);

// The functional's options of a step with these options (dt set per step).
FunctionalOptions functional_options(const ImplicitOptions& o);
// The explicit stepper's (serial and distributed).
FunctionalOptions functional_options(const ExplicitOptions& o);

// The thresholds of one step's stopping rule, from the smallest width and
// mass, the total mass and F's parts at the anchor, each taken over every
// particle of the step (every rank's in a distributed step).
struct StepTolerances {
  double gradient_tolerance = 0.0;  // displacement_tolerance x s_min
  double floor_measure = 0.0;       // the round-off floor of the stopping measure
  double stall_measure = 0.0;       // below it (and the tolerance) a start is as converged as F can tell
};
StepTolerances step_tolerances(const ImplicitOptions& o, double dt, double s_min, double m_min, double mass,
                               const FunctionalParts& before);

class StepObjective final : public Objective {
 public:
  StepObjective(Functional& f, const ExternalPotential& ext, const std::vector<Vec3>& x_anchor,
                const std::vector<double>& s_anchor, const std::vector<double>& m, double dt, bool widths,
                const std::vector<double>& weights, double s_max);
  StepObjective(StepFunctional f, const ExternalPotential& ext, const std::vector<Vec3>& x_anchor,
                const std::vector<double>& s_anchor, const std::vector<double>& m, double dt, bool widths,
                const std::vector<double>& weights, double s_max);

  std::size_t num_variables() const override { return n_ * (dim_ + (widths_ ? 1 : 0)); }

  void pack(const std::vector<Vec3>& x, const std::vector<double>& s, double* z) const;
  void unpack(const double* z, std::vector<Vec3>& x, std::vector<double>& s) const;

  bool evaluate(const double* z, double* value, double* gradient) override;

  // The gradient step d_p = dt/m dF/dx (and dt/(c_w m) dF/ds): how far one
  // gradient step would move particle p. With the bound the width part is
  // |dt/(c_w m) dF/ds| phi'(v) b'/b: the same below the fold, zero where the
  // bound holds a width (dF/ds < 0 there).
  //   Max:    max_p |d_p| (componentwise);
  //   Energy: max(RMS, max / max_norm_factor), RMS = sqrt(sum_p m_p (|d_p|^2 +
  //           c_w d_s,p^2) / M), the norm of the transport term in which the
  //           step's error is measured: with the Hessian in the scaled
  //           unknowns >= I, RMS bounds the M-weighted RMS distance to the
  //           solution of the step (docs/stepper.md).
  double stopping_measure(const double* z, const double* gradient) const override;
  // Energy norm: the factor by which the max-norm may exceed the tolerance (0: Max norm).
  void set_max_norm_factor(double f) { max_norm_factor_ = f; }

  const FunctionalParts& parts() const { return parts_; }

  // Width of particle p for the unknown zs, and the unknown for width s.
  double width_of(std::size_t p, double zs) const;
  double width_unknown(std::size_t p, double s) const;

 private:
  StepFunctional f_;
  const ExternalPotential& ext_;
  const std::vector<double>& s_ref_;
  const std::vector<double>& m_;
  int dim_;
  bool widths_;
  std::size_t n_;
  double s_max_;  // upper bound on the widths (0: none)
  double c_w_ = 1.0;
  double max_norm_factor_ = 0.0;
  std::vector<double> scale_x_, scale_s_, disp_x_, disp_s_, scale_b_, u_ref_;
  std::vector<Vec3> x_;
  std::vector<double> s_;
  Gradient g_;
  FunctionalParts parts_;
};

// One solve's figures into the step's summary, the same for the serial and
// the distributed step: the counts and solver time add up over substeps;
// reason, residual, tolerance, parts and F before are the solve's.
void record_solve(const MinimizerSummary& ms, bool start_ok, const FunctionalParts& before, double f0,
                  StepSummary& summary);

// The verdict on one step's solve, the same for the serial and the
// distributed step: accepted when the solver converged, or when it stalled
// (a failed line search) at F's round-off floor; then (x_new, s_new) is the
// result, and the energy inequality F(x^{k+1}) <= F(x^k) (+ energy_tolerance)
// must hold. Fills the summary's F after, parts and message; (x_new, s_new)
// enter as the start of the step.
bool accept_solve(StepObjective& objective, const std::vector<double>& z, bool start_ok, const MinimizerSummary& ms,
                  const StepTolerances& tol, double f0, const FunctionalParts& before, double energy_tolerance,
                  std::vector<Vec3>& x_new, std::vector<double>& s_new, StepSummary& summary);

// StepObjective with its own copies of the state it refers to (step_problem()).
class OwnedStepObjective final : public Objective {
 public:
  OwnedStepObjective(Functional& f, const ExternalPotential& ext, std::vector<Vec3> x, std::vector<double> s,
                     std::vector<double> m, double dt, bool widths, double s_max)
      : x_(std::move(x)), s_(std::move(s)), m_(std::move(m)), obj_(f, ext, x_, s_, m_, dt, widths, {}, s_max) {}
  std::size_t num_variables() const override { return obj_.num_variables(); }
  bool evaluate(const double* z, double* value, double* gradient) override { return obj_.evaluate(z, value, gradient); }
  double stopping_measure(const double* z, const double* gradient) const override {
    return obj_.stopping_measure(z, gradient);
  }
  std::vector<double> start() const {
    std::vector<double> z(obj_.num_variables());
    obj_.pack(x_, s_, z.data());
    return z;
  }

 private:
  std::vector<Vec3> x_;
  std::vector<double> s_, m_;
  StepObjective obj_;
};

}  // namespace otfp::detail
