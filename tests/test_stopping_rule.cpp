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
