// The density error estimate of the implicit step (ErrorMeasure::Density,
// docs/stepper.md): it must scale like dt^(p+1) and track the true local
// error of the smoothed blob density. The true local error is computed
// independently: the same step from the same state, against 64 substeps of
// dt/64 (whose own error is about 1/64 of the step's for Euler), both
// measured by blob_density with the estimate's smoothing at the step's
// particles.
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
constexpr int kSide = 24;  // particles per axis of the unit periodic box
const double kDr = 1.0 / kSide, kWidth = kDr / std::sqrt(2.0), kDtExplicit = kDr * kDr;

DomainPtr unit_box() { return make_periodic_box(kDim, Vec3::Zero(), Vec3(1.0, 1.0, 0.0)); }

// 1 + a cos(2 pi x) on a staggered lattice (particles placed by the inverse
// CDF), or a uniform random fill (a relaxing arrangement). Staggered: the
// square lattice is a saddle of the entropy at beta dr^2 = 2 (docs/stepper.md,
// "The step's Hessian"), where a step of 4 dt_explicit is not convex and lands
// in whichever minimum the solver's path leads to: there the estimate was
// 1.9x the true error with the stopping rule's bound on the largest particle
// at 10 and 0.32x at 100 (2026-12-03), the same solve tolerance. On the
// staggered lattice, a minimum, both give the same step: 1.39x, 1.41x and
// 1.74x the true error at 1, 2 and 4 dt_explicit.
ParticleSet fill(bool random) {
  DomainPtr box = unit_box();
  FillOptions f;
  f.shape = random ? FillShape::Uniform : FillShape::Cosine;
  f.count = kSide * kSide;
  f.width_s = kWidth;
  f.mass = 1.0 / f.count;
  f.lattice = !random;
  f.staggered = !random;
  f.lattice_counts = {kSide, kSide, 1};
  f.lo = Vec3::Zero();
  f.hi = Vec3(1.0, 1.0, 0.0);
  f.amplitude = 0.5;
  f.wavenumber = 2.0 * M_PI;
  Rng rng(7);
  return fill_particles(*box, f, rng);
}

ImplicitOptions options(TimeScheme scheme) {
  ImplicitOptions o;
  o.time_scheme = scheme;
  o.error_measure = ErrorMeasure::Density;
  o.rho_ref = 1.0;
  // Solves far tighter than the time errors measured here.
  o.displacement_tolerance = 1e-8;
  o.relative_tolerance = 1e-8;
  o.minimizer.max_iterations = 20000;
  o.minimizer.max_evaluations = 50000;
  o.sort_particles = false;
  return o;
}

struct Measured {
  double estimate = 0.0, truth = 0.0, displacement_estimate = 0.0;
};

// Steps `history` steps of dt (to build the history the estimate needs),
// then one more; returns that step's estimates and its true local error.
Measured measure(bool random, TimeScheme scheme, double dt, int history) {
  const DomainPtr box = unit_box();
  const Periodicity per = Periodicity::from_domain(*box);
  ParticleSet ps = fill(random);
  ImplicitStepper st(kDim, options(scheme), Barrier{}, per);
  for (int k = 0; k < history; ++k) {
    const StepSummary s = st.step(ps, dt);
    EXPECT_TRUE(s.accepted) << s.message;
  }
  ParticleSet start = ps;
  const StepSummary s = st.step(ps, dt);
  EXPECT_TRUE(s.accepted) << s.message;
  Measured r;
  r.estimate = s.density_error_estimate;
  r.displacement_estimate = s.displacement_error_estimate;
  EXPECT_EQ(s.error_estimate, s.density_error_estimate);
  // The exact flow from `start`, by 64 Euler substeps (the history does not
  // enter an Euler step).
  ImplicitStepper fine(kDim, options(TimeScheme::Euler), Barrier{}, per);
  constexpr int kSub = 64;
  for (int k = 0; k < kSub; ++k) {
    const StepSummary f = fine.step(start, dt / kSub);
    EXPECT_TRUE(f.accepted) << f.message;
  }
  r.truth = test::smoothed_density_difference(ps, start, options(scheme).error_smoothing, per);
  if (std::getenv("OTFP_TEST_VERBOSE"))
    std::printf("%s %s dt = %g dt_e: estimate %.4g, true %.4g (ratio %.3f), displacement estimate %.4g\n",
                random ? "random" : "cosine", scheme == TimeScheme::Euler ? "euler" : "bdf2", dt / kDtExplicit,
                r.estimate, r.truth, r.estimate / r.truth, r.displacement_estimate);
  return r;
}

// Within 2x of the true local error at 1, 2 and 4 dt_explicit, and growing
// with dt faster than dt^1 and no faster than dt^(p+1) (plus slack). Not
// dt^(p+1) itself: the true error's own exponent here is 1.3, because part of
// it is the rearrangement of the particles, which does not vanish with dt
// (docs/stepper.md, "The density estimate", has the figures, also those of
// a random fill and of BDF2, which this does not assert).
void expect_order_and_tracking(bool random, TimeScheme scheme, int order) {
  std::vector<Measured> m;
  for (double f : {1.0, 2.0, 4.0}) m.push_back(measure(random, scheme, f * kDtExplicit, order));
  for (std::size_t i = 0; i < m.size(); ++i) {
    EXPECT_GT(m[i].estimate, 0.5 * m[i].truth) << "dt factor " << (1 << i);
    EXPECT_LT(m[i].estimate, 2.0 * m[i].truth) << "dt factor " << (1 << i);
  }
  for (std::size_t i = 1; i < m.size(); ++i) {
    const double exponent = std::log2(m[i].estimate / m[i - 1].estimate);
    EXPECT_GT(exponent, 1.0) << "dt factor " << (1 << i);
    EXPECT_LT(exponent, order + 1.5) << "dt factor " << (1 << i);
  }
}

}  // namespace

TEST(DensityErrorEstimate, TracksTheLocalErrorOfTheCosineModeEuler) {
  expect_order_and_tracking(false, TimeScheme::Euler, 1);
}

// What the estimate is for: a motion that leaves the density as it was is no
// error. A uniform lattice (a fixed point of the step, by symmetry) whose
// history says it moved by one lattice spacing last step: the Euler
// prediction x + dr e_x is the same lattice, so the density estimate is zero
// (to the solve's motion), while the displacement estimate reports
// |x_new - prediction| / 2 = dr / 2 in every particle, dr / (2 s) = 1/sqrt(2)
// in widths.
TEST(DensityErrorEstimate, ALatticeShiftedByALatticeVectorIsNoError) {
  const DomainPtr box = unit_box();
  const Periodicity per = Periodicity::from_domain(*box);
  ParticleSet ps(kDim);
  for (int i = 0; i < kSide; ++i)
    for (int j = 0; j < kSide; ++j) ps.add(Vec3((i + 0.5) * kDr, (j + 0.5) * kDr, 0.0), kWidth, 1.0 / (kSide * kSide));
  for (ErrorMeasure measure : {ErrorMeasure::Density, ErrorMeasure::Displacement}) {
    ImplicitOptions o = options(TimeScheme::Euler);
    o.error_measure = measure;
    ImplicitStepper st(kDim, o, Barrier{}, per);
    const double dt = 4.0 * kDtExplicit;
    ImplicitStepper::HistoryState h;
    h.dt1 = dt;
    for (std::size_t p = 0; p < ps.size(); ++p) {
      ImplicitStepper::HistoryEntry e;
      e.id = ps.ids()[p];
      e.d1 = Vec3(kDr, 0.0, 0.0);
      e.count = 1;
      h.entries.push_back(e);
    }
    st.restore_history(h);
    ParticleSet q = ps;
    const StepSummary s = st.step(q, dt);
    ASSERT_TRUE(s.accepted) << s.message;
    double moved = 0.0;
    for (std::size_t p = 0; p < q.size(); ++p)
      moved = std::max(moved, (q.positions()[p] - ps.positions()[static_cast<std::size_t>(ps.index_of(q.ids()[p]))]).norm());
    EXPECT_LT(moved, 1e-9) << "the uniform lattice is a fixed point";
    if (measure == ErrorMeasure::Density)
      EXPECT_LT(s.density_error_estimate, 1e-9);
    else
      EXPECT_TRUE(std::isnan(s.density_error_estimate)) << "computed only when asked for";
    EXPECT_NEAR(s.displacement_error_estimate, 1.0 / std::sqrt(2.0), 1e-6);
    EXPECT_EQ(s.error_estimate,
              measure == ErrorMeasure::Density ? s.density_error_estimate : s.displacement_error_estimate);
  }
}
