// One implicit Euler step (28) over the ranks (otfp/distributed_stepper.hpp).
//
// The serial stepper's problem, shared: the objective is StepObjective (the
// scaled unknowns z = sqrt(m/dt) x and z_s = b log(s/s^k), the stopping
// measure) on a StepFunctional whose F is the DistributedFunctional's and
// whose reductions are MPI's; the thresholds are step_tolerances() of the
// global smallest width and mass, total mass and F; minimize_with() runs the
// library's start checks and relative rule around TAO on PETSC_COMM_WORLD.
// Every verdict (converged, non-finite, energy inequality) is computed from
// global values, so all ranks accept or refuse the step together.
#include "otfp/distributed_stepper.hpp"

#include <mpi.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <memory>
#include <limits>
#include <mutex>
#include <string>

#include "../minimizer_backends.hpp"
#include "../step_objective.hpp"
#include "otfp/tao.hpp"
#include "petsc_session.hpp"

namespace otfp {

namespace {

using Clock = std::chrono::steady_clock;

// An error on one rank inside the collective part of a step: with other
// ranks in the world they wait in a collective, so the world is aborted.
void abort_unless_alone(MPI_Comm comm, const char* what) {
  int size = 1, rank = 0;
  MPI_Comm_size(comm, &size);
  if (size == 1) return;
  MPI_Comm_rank(comm, &rank);
  std::fprintf(stderr, "otfp: error: rank %d: distributed step: %s (aborting all ranks)\n", rank, what);
  std::fflush(stderr);
  MPI_Abort(comm, 1);
}

void require_supported(const ImplicitOptions& o) {
  o.validate();
  require(o.minimizer.backend == Backend::Tao, "minimizer.backend", to_string(o.minimizer.backend),
          "a distributed step is solved by TAO: must be tao");
  require(o.time_scheme == TimeScheme::Euler, "time_scheme", to_string(o.time_scheme),
          "a distributed step is implicit Euler only (BDF2 not yet)");
  require(o.predictor == Predictor::None, "predictor", to_string(o.predictor),
          "a distributed step starts from x^k (no predictor yet)");
}

}  // namespace

struct DistributedImplicitStepper::Impl {
  int dim;
  ImplicitOptions options;
  DistributedFunctional functional;
  MPI_Comm comm = MPI_COMM_NULL;

  Periodicity periodicity;

  Impl(int d, const ImplicitOptions& o, Barrier b, Periodicity p)
      : dim(d), options(o), functional(d, detail::functional_options(o), std::move(b), p), periodicity(p) {}

  bool solve(std::vector<Vec3>& x, std::vector<double>& s, const std::vector<double>& m, double dt,
             StepSummary& summary);

  detail::StepFunctional step_functional() {
    detail::StepFunctional sf;
    sf.dim = dim;
    sf.c_w = width_metric_coefficient(options.width_metric, dim);
    sf.evaluate = [this](const std::vector<Vec3>& x, const std::vector<double>& s, Gradient* g) {
      return functional.evaluate(x, s, g);
    };
    sf.all = [this](bool local) {
      int v = local ? 1 : 0, all = 0;
      MPI_Allreduce(&v, &all, 1, MPI_INT, MPI_MIN, comm);
      return all == 1;
    };
    sf.sum = [this](double* v, int n) { MPI_Allreduce(MPI_IN_PLACE, v, n, MPI_DOUBLE, MPI_SUM, comm); };
    sf.max = [this](double v) {
      double out = v;
      MPI_Allreduce(&v, &out, 1, MPI_DOUBLE, MPI_MAX, comm);
      return out;
    };
    return sf;
  }
};

DistributedImplicitStepper::DistributedImplicitStepper(int dim, ImplicitOptions options, Barrier barrier,
                                                       Periodicity periodicity) {
  register_tao_backend();
  require_supported(options);
  impl_ = std::make_unique<Impl>(dim, options, std::move(barrier), periodicity);
  impl_->comm = PETSC_COMM_WORLD;
}

DistributedImplicitStepper::~DistributedImplicitStepper() = default;

// One solve of (28) over [t, t + dt] from (x, s): on success (every rank's
// verdict alike) x and s hold the minimiser.
bool DistributedImplicitStepper::Impl::solve(std::vector<Vec3>& x, std::vector<double>& s,
                                             const std::vector<double>& m, double dt, StepSummary& summary) {
  const ImplicitOptions& o = options;
  const bool widths = o.width_mode == WidthMode::PerParticle;
  functional.set_dt(dt);
  functional.set_reference(x, s, m);
  const double s_max = o.max_width_factor > 0.0 ? o.max_width_factor * o.nominal_width : 0.0;
  const ExternalPotential none;
  // The objective checks this rank's particles (a width above the bound, say)
  // and may refuse them: all ranks learn of it before any collective, and
  // all throw (this rank its own message).
  std::unique_ptr<detail::StepObjective> made;
  std::exception_ptr refused;
  try {
    made = std::make_unique<detail::StepObjective>(step_functional(), none, x, s, m, dt, widths,
                                                   std::vector<double>{}, s_max);
  } catch (...) {
    refused = std::current_exception();
  }
  int any_refused = refused ? 1 : 0;
  MPI_Allreduce(MPI_IN_PLACE, &any_refused, 1, MPI_INT, MPI_MAX, comm);
  if (refused) std::rethrow_exception(refused);
  require(any_refused == 0, "particles", 0.0, "refused by another rank (its error names the field)");
  // From here on every rank runs the same collectives: an exception on one
  // rank only (its share of F, a PETSc failure) would leave the others
  // waiting in one, so it aborts the world, with the reason on stderr.
  try {
    detail::StepObjective& objective = *made;
    if (o.stopping_norm == StoppingNorm::Energy) objective.set_max_norm_factor(o.max_norm_factor);
    std::vector<double> z(objective.num_variables());
    objective.pack(x, s, z.data());

    // The thresholds of the serial stepper, from global figures.
    double mins[2] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
    double mass = 0.0;
    for (std::size_t p = 0; p < m.size(); ++p) {
      mins[0] = std::min(mins[0], s[p]);
      mins[1] = std::min(mins[1], m[p]);
      mass += m[p];
    }
    MPI_Allreduce(MPI_IN_PLACE, mins, 2, MPI_DOUBLE, MPI_MIN, comm);
    MPI_Allreduce(MPI_IN_PLACE, &mass, 1, MPI_DOUBLE, MPI_SUM, comm);
    const double s_min = std::isfinite(mins[0]) ? mins[0] : 1.0;
    const double m_min = std::isfinite(mins[1]) ? mins[1] : 1.0;

    double f0 = 0.0;
    const bool start_ok = objective.evaluate(z.data(), &f0, nullptr);
    const FunctionalParts before = objective.parts();
    const detail::StepTolerances tol = detail::step_tolerances(o, dt, s_min, m_min, mass, before);
    MinimizerOptions mo = o.minimizer;
    mo.gradient_tolerance = tol.gradient_tolerance;
    mo.relative_gradient_tolerance = o.relative_tolerance;  // the papers' path: the rule at x^k
    mo.gradient_tolerance_floor = tol.floor_measure;
    mo.start_tolerance = tol.stall_measure;
    mo.validate();

    MinimizerSummary ms;
    if (start_ok) ms = detail::minimize_with(objective, z, mo, detail::run_tao_world, step_functional().all);
    detail::record_solve(ms, start_ok, before, f0, summary);
    summary.f_start = f0;
    // Into copies: the objective refers to (x, s) as the step's start.
    std::vector<Vec3> x_new = x;
    std::vector<double> s_new = s;
    if (!detail::accept_solve(objective, z, start_ok, ms, tol, f0, before, o.energy_tolerance, x_new, s_new, summary))
      return false;
    x = std::move(x_new);
    s = std::move(s_new);
    return true;
  } catch (const std::exception& e) {
    abort_unless_alone(comm, e.what());
    throw;
  } catch (...) {
    abort_unless_alone(comm, "an unknown exception");
    throw;
  }
}

// The serial stepper's step: a failed solve is retried as 2, 4, ...
// substeps (max_halvings), and the accepted positions are wrapped into a
// periodic box.
StepSummary DistributedImplicitStepper::step(ParticleSet& owned, double dt) {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(owned.dim() == impl_->dim, "particles dim", owned.dim(),
          "must equal the stepper's dim " + std::to_string(impl_->dim));
  const auto t0 = Clock::now();
  Impl& d = *impl_;
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  StepSummary summary;
  summary.dt = dt;
  const int builds_before = d.functional.exchange().rebuilds;
  for (int halvings = 0; halvings <= d.options.max_halvings; ++halvings) {
    std::vector<Vec3> x = owned.positions();
    std::vector<double> s = owned.widths();
    const int substeps = 1 << halvings;
    const double h = dt / substeps;
    bool ok = true;
    FunctionalParts first_before;
    double first_f = 0.0;
    for (int k = 0; k < substeps && ok; ++k) {
      ok = d.solve(x, s, owned.masses(), h, summary);
      if (k == 0) {
        first_before = summary.parts_before;
        first_f = summary.f_before;
      }
    }
    summary.halvings = halvings;
    if (!ok) {
      ++summary.rejected_solves;
      continue;
    }
    summary.substeps = substeps;
    summary.parts_before = first_before;
    summary.f_before = summary.f_start = first_f;
    summary.accepted = true;
    for (Vec3& y : x) y = d.periodicity.wrap(y);
    owned.positions() = std::move(x);
    owned.widths() = std::move(s);
    break;
  }
  if (!summary.accepted && summary.message.empty()) summary.message = "step rejected";
  summary.list_builds = d.functional.exchange().rebuilds - builds_before;
  summary.wall_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return summary;
}

const ExchangeStats& DistributedImplicitStepper::exchange() const { return impl_->functional.exchange(); }
DistributedFunctional& DistributedImplicitStepper::functional() { return impl_->functional; }
const ImplicitOptions& DistributedImplicitStepper::options() const { return impl_->options; }

}  // namespace otfp
