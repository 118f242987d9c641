// One explicit step over the ranks (otfp/distributed_explicit_stepper.hpp):
// ExplicitStepper::step with every velocity from the DistributedFunctional
// and every verdict (bad input, non-finite F or positions) taken over all
// ranks, so that they accept or reject the step together. Non-finite
// positions are caught before they reach a collective (the serial stepper
// lets the neighbour search throw on them; here one rank's exception would
// leave the others waiting).
#include "otfp/distributed_explicit_stepper.hpp"

#include <mpi.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <mutex>
#include <string>

#include <fmt/format.h>

#include "../step_objective.hpp"
#include "petsc_session.hpp"

namespace otfp {

namespace {

using Clock = std::chrono::steady_clock;

bool all_ranks(bool local, MPI_Comm comm) {
  int v = local ? 1 : 0, all = 0;
  MPI_Allreduce(&v, &all, 1, MPI_INT, MPI_MIN, comm);
  return all == 1;
}

bool all_finite(const std::vector<Vec3>& x, MPI_Comm comm) {
  bool finite = true;
  for (const Vec3& y : x) finite = finite && y.allFinite();
  return all_ranks(finite, comm);
}

}  // namespace

struct DistributedExplicitStepper::Impl {
  int dim;
  ExplicitOptions options;
  DistributedFunctional functional;
  Periodicity periodicity;
  MPI_Comm comm = MPI_COMM_NULL;

  Impl(int d, const ExplicitOptions& o, Barrier b, Periodicity p)
      : dim(d), options(o), functional(d, detail::functional_options(o), std::move(b), p), periodicity(p) {}

  // The scheme's velocity at x (collective), as ExplicitStepper::velocity.
  void velocity(const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m,
                std::vector<Vec3>& v) {
    if (options.scheme == ExplicitScheme::EulerExactGradient) {
      // Only ever at x^k, the reference step() set (set_reference() again
      // would force a new ghost set): the transport gradient vanishes there,
      // v = -(1/m) d(E + B)/dx.
      Gradient g;
      functional.evaluate(x, s, &g);
      v.resize(x.size());
      for (std::size_t p = 0; p < x.size(); ++p) v[p] = -g.x[p] / m[p];
    } else {
      functional.explicit_velocity(x, s, v);
    }
  }
};

DistributedExplicitStepper::DistributedExplicitStepper(int dim, ExplicitOptions options, Barrier barrier,
                                                       Periodicity periodicity) {
  options.validate();
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  detail::ensure_petsc();
  impl_ = std::make_unique<Impl>(dim, options, std::move(barrier), periodicity);
  impl_->comm = detail::world_comm();
}

DistributedExplicitStepper::~DistributedExplicitStepper() = default;

DistributedFunctional& DistributedExplicitStepper::functional() { return impl_->functional; }
const ExplicitOptions& DistributedExplicitStepper::options() const { return impl_->options; }

StepSummary DistributedExplicitStepper::step(ParticleSet& owned, double dt) {
  Impl& d = *impl_;
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(owned.dim() == d.dim, "particles dim", owned.dim(), "must equal the stepper's dim " + std::to_string(d.dim));
  const auto t0 = Clock::now();
  StepSummary summary;
  summary.dt = dt;
  summary.iterations = 1;
  auto finish = [&](bool accepted, const std::string& why) {
    summary.accepted = accepted;
    summary.reason = accepted ? TerminationReason::Converged : TerminationReason::NonFinite;
    summary.message = why;
    summary.wall_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    return summary;
  };
  // What the serial stepper refuses, refused on every rank alike.
  const std::size_t n = owned.size();
  std::string bad;
  for (std::size_t p = 0; p < n && bad.empty(); ++p) {
    const double mp = owned.masses()[p], sp = owned.widths()[p];
    if (!(std::isfinite(mp) && mp > 0.0))
      bad = fmt::format("particle {}: mass = {}: must be finite and > 0", owned.ids()[p], mp);
    else if (!(std::isfinite(sp) && sp > 0.0))
      bad = fmt::format("particle {}: width s = {}: must be finite and > 0", owned.ids()[p], sp);
  }
  {
    const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
    if (!all_ranks(bad.empty(), d.comm)) return finish(false, bad.empty() ? "refused by another rank" : bad);
  }

  const std::vector<Vec3> x0 = owned.positions();
  const std::vector<double> s = owned.widths(), m = owned.masses();
  const int builds_before = d.functional.exchange().rebuilds;
  const double list_seconds_before = d.functional.exchange().list_seconds;
  const std::uint64_t pairs_before = d.functional.pair_evaluations();
  std::vector<Vec3> x = x0, v;
  bool finite = true;
  std::string failure = "explicit update produced non-finite positions";
  try {
    const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
    d.functional.set_dt(dt);
    d.functional.set_reference(x0, s, m);
    summary.parts_before = d.functional.evaluate(x0, s, nullptr);
    summary.f_before = summary.parts_before.total();
    finite = std::isfinite(summary.f_before);  // global: the parts are sums over the ranks
    if (!finite) {
      failure = "non-finite F at the start of the step";
    } else if (d.options.scheme == ExplicitScheme::Rk4Force27) {
      std::vector<Vec3> k1, k2, k3, k4, tmp(n);
      summary.evaluations = 1;
      d.velocity(x0, s, m, k1);
      for (std::size_t p = 0; p < n; ++p) tmp[p] = x0[p] + 0.5 * dt * k1[p];
      finite = all_finite(tmp, d.comm);
      if (finite) {
        ++summary.evaluations;
        d.velocity(tmp, s, m, k2);
        for (std::size_t p = 0; p < n; ++p) tmp[p] = x0[p] + 0.5 * dt * k2[p];
        finite = all_finite(tmp, d.comm);
      }
      if (finite) {
        ++summary.evaluations;
        d.velocity(tmp, s, m, k3);
        for (std::size_t p = 0; p < n; ++p) tmp[p] = x0[p] + dt * k3[p];
        finite = all_finite(tmp, d.comm);
      }
      if (finite) {
        ++summary.evaluations;
        d.velocity(tmp, s, m, k4);
        for (std::size_t p = 0; p < n; ++p) x[p] = x0[p] + dt / 6.0 * (k1[p] + 2.0 * k2[p] + 2.0 * k3[p] + k4[p]);
      }
    } else {
      d.velocity(x0, s, m, v);
      for (std::size_t p = 0; p < n; ++p) x[p] = x0[p] + dt * v[p];
      summary.evaluations = 1;
    }
    if (finite) finite = all_finite(x, d.comm);
    if (finite) {
      // The reference is still x^k (the serial stepper sets it again).
      summary.parts_after = d.functional.evaluate(x, s, nullptr);
      summary.f_after = summary.parts_after.total();
      if (!std::isfinite(summary.f_after)) {
        finite = false;
        failure = "non-finite F after the explicit update";
      }
    }
  } catch (const std::exception& e) {
    // One rank's error inside the collectives (a resource limit of the
    // neighbour search): the others wait in a collective, so the world ends.
    int size = 1, rank = 0;
    MPI_Comm_size(d.comm, &size);
    if (size == 1) throw;
    MPI_Comm_rank(d.comm, &rank);
    std::fprintf(stderr, "otfp: error: rank %d: distributed explicit step: %s (aborting all ranks)\n", rank, e.what());
    std::fflush(stderr);
    MPI_Abort(d.comm, 1);
  }
  summary.list_builds = d.functional.exchange().rebuilds - builds_before;
  d.functional.add_step_work(list_seconds_before, pairs_before, summary);
  if (!finite) return finish(false, failure);
  for (Vec3& y : x) y = d.periodicity.wrap(y);
  owned.positions() = std::move(x);
  return finish(true, "");
}

}  // namespace otfp
