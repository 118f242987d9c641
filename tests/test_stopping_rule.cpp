// The implicit solve's stopping rule (ImplicitOptions::stopping_norm,
// docs/stepper.md): at large steps the solve error must stay a small fraction
// of the step's time error. Measured on the cosine mode 1 + a cos(2 pi x) in
// the periodic unit square, in the norm the density error estimate uses (the
// blob density smoothed over error_smoothing widths, RMS relative to its
// mean): the solve error is the distance of the step's result to the same
// step solved to 1e-10, the time error that of the latter to 64 substeps of
// dt/64 (the exact flow from the same start to about 1/64 of the step's error).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "otfp/density.hpp"
#include "otfp/geometry.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/initial_fill.hpp"
#include "smoothed_density.hpp"

using namespace otfp;

namespace {

constexpr int kDim = 2;
constexpr int kSide = 24;
const double kDr = 1.0 / kSide, kWidth = kDr / std::sqrt(2.0), kDtExplicit = kDr * kDr;

DomainPtr unit_box() { return make_periodic_box(kDim, Vec3::Zero(), Vec3(1.0, 1.0, 0.0)); }

ParticleSet cosine_mode() {
  DomainPtr box = unit_box();
  FillOptions f;
  f.shape = FillShape::Cosine;
  f.count = kSide * kSide;
  f.width_s = kWidth;
  f.mass = 1.0 / f.count;
  f.lattice = true;
  f.lattice_counts = {kSide, kSide, 1};
  f.hi = Vec3(1.0, 1.0, 0.0);
  f.amplitude = 0.5;
  f.wavenumber = 2.0 * M_PI;
  Rng rng(7);
  return fill_particles(*box, f, rng);
}

struct Solve {
  ParticleSet result{kDim};
  int evaluations = 0;
};

// One Euler step of dt from the cosine mode.
Solve step(double dt, StoppingNorm norm, double tight) {
  const Periodicity per = Periodicity::from_domain(*unit_box());
  ImplicitOptions o;
  o.stopping_norm = norm;
  o.sort_particles = false;
  o.minimizer.max_iterations = 50000;
  o.minimizer.max_evaluations = 100000;
  if (tight > 0.0) {
    o.displacement_tolerance = tight;
    o.relative_tolerance = tight;
  }
  ImplicitStepper st(kDim, o, Barrier{}, per);
  Solve s;
  s.result = cosine_mode();
  const StepSummary sum = st.step(s.result, dt);
  EXPECT_TRUE(sum.accepted) << sum.message;
  s.evaluations = sum.evaluations;
  return s;
}

}  // namespace

TEST(StoppingRule, SolveErrorIsASmallFractionOfTheTimeErrorAtLargeSteps) {
  const Periodicity per = Periodicity::from_domain(*unit_box());
  const double smoothing = ImplicitOptions{}.error_smoothing;
  for (double factor : {10.0, 100.0}) {
    const double dt = factor * kDtExplicit;
    const Solve exact = step(dt, StoppingNorm::Max, 1e-10);
    Solve fine;
    fine.result = cosine_mode();
    {
      ImplicitOptions o;
      o.sort_particles = false;
      ImplicitStepper st(kDim, o, Barrier{}, per);
      for (int k = 0; k < 64; ++k) ASSERT_TRUE(st.step(fine.result, dt / 64).accepted);
    }
    const double time_error = test::smoothed_density_difference(exact.result, fine.result, smoothing, per);
    const Solve energy = step(dt, StoppingNorm::Energy, 0.0), max = step(dt, StoppingNorm::Max, 0.0);
    const double energy_error = test::smoothed_density_difference(energy.result, exact.result, smoothing, per);
    const double max_error = test::smoothed_density_difference(max.result, exact.result, smoothing, per);
    if (std::getenv("OTFP_TEST_VERBOSE"))
      std::printf("%gx: time error %.4g; energy norm: solve error %.4g, %d evaluations; max norm: %.4g, %d\n", factor,
                  time_error, energy_error, energy.evaluations, max_error, max.evaluations);
    // Both rules hold the solve error far below the time error (the 4-6%
    // this mode is off at 10x is time error, not solve error); neither
    // costs fewer evaluations here (docs/stepper.md).
    EXPECT_LE(energy_error, 0.1 * time_error) << factor << "x";
    EXPECT_LE(max_error, 0.1 * time_error) << factor << "x";
  }
}

namespace {

// A staggered lattice (a minimum of the entropy, docs/stepper.md) of side x
// side particles at spacing kDr in a periodic square of side side * kDr, with
// a local compression about its centre: particles within a few spacings
// moved towards it by up to 0.15 spacings. The disturbance is the same in
// every size; only the undisturbed rest grows.
struct Bump {
  DomainPtr box;
  Periodicity per;
  ParticleSet ps{kDim};
};

Bump local_bump(int side) {
  Bump b;
  const double length = side * kDr;
  b.box = make_periodic_box(kDim, Vec3::Zero(), Vec3(length, length, 0.0));
  b.per = Periodicity::from_domain(*b.box);
  FillOptions f;
  f.count = static_cast<std::int64_t>(side) * side;
  f.width_s = kWidth;
  f.mass = 1.0 / (24.0 * 24.0);
  f.lattice = true;
  f.staggered = true;
  f.lattice_counts = {side, side, 1};
  f.hi = Vec3(length, length, 0.0);
  Rng rng(7);
  ParticleSet ps = fill_particles(*b.box, f, rng);
  const Vec3 centre(0.5 * length, 0.5 * length, 0.0);
  const double reach = 3.0 * kDr;
  std::vector<Vec3> x = ps.positions();
  for (Vec3& p : x) {
    const Vec3 d = p - centre;
    const double r = d.norm();
    p -= 0.15 * kDr / reach * d * std::exp(-0.5 * r * r / (reach * reach));
  }
  for (std::size_t i = 0; i < x.size(); ++i) b.ps.add(x[i], kWidth, ps.masses()[i]);
  return b;
}

ParticleSet bump_step(const Bump& b, double dt, double factor, double tight, int substeps, int* evaluations,
                      double relative = -1.0) {
  ImplicitOptions o;
  if (relative >= 0.0) o.relative_tolerance = relative;
  o.sort_particles = false;
  o.minimizer.max_iterations = 50000;
  o.minimizer.max_evaluations = 100000;
  if (factor > 0.0) o.max_norm_factor = factor;
  if (tight > 0.0) {
    o.stopping_norm = StoppingNorm::Max;
    o.displacement_tolerance = tight;
    o.relative_tolerance = tight;
  }
  ImplicitStepper st(kDim, o, Barrier{}, b.per);
  ParticleSet ps = b.ps;
  int evals = 0;
  for (int k = 0; k < substeps; ++k) {
    const StepSummary s = st.step(ps, dt / substeps);
    EXPECT_TRUE(s.accepted) << s.message;
    evals += s.evaluations;
  }
  if (evaluations) *evaluations = evals;
  return ps;
}

}  // namespace

// The energy rule's absolute tolerance bounds the mass-weighted RMS of the
// residual over the whole system, in which a local disturbance is diluted
// by the undisturbed rest. The relative rule (1e-2 of the step's first
// gradient step, in the same norm) is not: both are diluted alike. So the
// local solve error (the largest difference of the smoothed density to the
// step solved to 1e-9) must stay a small fraction of the local time error
// in a system 9x larger. Measured (2026-12-03, 1x): 1.2% of it (24 x 24)
// and 0.6% (72 x 72), with max_norm_factor 10, 100 or none alike (at 10x
// 0.6% and 1.7%); without the relative rule 6% and 38%.
TEST(StoppingRule, LocalSolveErrorStaysSmallInALargeSystem) {
  const double smoothing = ImplicitOptions{}.error_smoothing;
  const double dt = kDtExplicit;
  for (int side : {24, 72}) {
    const Bump b = local_bump(side);
    const ParticleSet exact = bump_step(b, dt, 0.0, 1e-9, 1, nullptr);
    const ParticleSet fine = bump_step(b, dt, 0.0, 0.0, 16, nullptr);
    const double time_error = test::largest_smoothed_density_difference(exact, fine, smoothing, b.per);
    int evals = 0;
    const ParticleSet got = bump_step(b, dt, 0.0, 0.0, 1, &evals);
    const double solve_error = test::largest_smoothed_density_difference(got, exact, smoothing, b.per);
    if (std::getenv("OTFP_TEST_VERBOSE")) {
      int evals_abs = 0;
      const ParticleSet abs_only = bump_step(b, dt, 0.0, 0.0, 1, &evals_abs, 0.0);
      const double e = test::largest_smoothed_density_difference(abs_only, exact, smoothing, b.per);
      std::printf("side %d: time error %.3g; solve error %.3g (%.3f of it), %d evaluations; without the relative "
                  "rule %.3g (%.3f), %d\n",
                  side, time_error, solve_error, solve_error / time_error, evals, e, e / time_error, evals_abs);
    }
    EXPECT_LE(solve_error, 0.1 * time_error) << "side " << side;
  }
}
