// One implicit step (28) over the ranks (otfp/distributed_stepper.hpp).
//
// The serial stepper's solve (src/step_solve.cpp), with the distributed
// hooks: the objective's functional is the DistributedFunctional's F, whose
// reductions (the stopping measure's RMS and max, a non-finite point, the
// thresholds' smallest width and mass) are MPI_Allreduce's; the minimiser is
// TAO on PETSC_COMM_WORLD; the local error estimate sums over the ranks, with
// the error field of the ghosts sent by their owners (the smoothing over the
// neighbour list) and the blobs within the smoothed kernel's reach of a
// rank's probes sent to it (the density estimate). Every verdict (converged,
// non-finite, the energy inequality, the error test) is computed from global
// values, so all ranks accept or refuse the step together.
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
#include "../step_solve.hpp"
#include "otfp/tao.hpp"
#include "particle_exchange.hpp"
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
}

}  // namespace

struct DistributedImplicitStepper::Impl {
  int dim;
  ImplicitOptions options;
  Barrier barrier;  // the predictor's admissible start (the functional holds its own)
  DistributedFunctional functional;
  MPI_Comm comm = MPI_COMM_NULL;
  ExternalPotential none;
  Periodicity periodicity;
  StepHistory history;

  Impl(int d, const ImplicitOptions& o, Barrier b, Periodicity p)
      : dim(d), options(o), barrier(b), functional(d, detail::functional_options(o), std::move(b), p), periodicity(p) {}

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

  detail::StepSolveHooks hooks(const std::vector<ParticleId>& ids) {
    detail::StepSolveHooks h;
    h.functional = step_functional();
    h.external = &none;
    h.prepare = [this](double dt, const std::vector<Vec3>& x_ref, const std::vector<double>& s_ref,
                       const std::vector<double>& m, const std::vector<double>& weights, const std::vector<Vec3>&,
                       const std::vector<double>&) {
      functional.set_dt(dt);
      functional.set_reference(x_ref, s_ref, m, weights);  // the ghosts and list are rebuilt at the next evaluation
    };
    h.admissible_start = [this](const Vec3& from, const Vec3& to) {
      return detail::admissible_start(barrier, functional.images().walls(), from, to);
    };
    h.minimize = [this](Objective& objective, std::vector<double>& z, const MinimizerOptions& mo) {
      mo.validate();
      return detail::minimize_with(objective, z, mo, detail::run_tao_world, step_functional().all);
    };
    h.estimate = [this, &ids](const std::vector<Vec3>& x, const std::vector<double>& s,
                              const std::vector<Vec3>& x_new, const std::vector<double>& s_new,
                              const std::vector<double>& m, const std::vector<DisplacementHistory>& hist, double dt,
                              double dt1, double dt2, StepSummary& summary) {
      estimate(ids, x, s, x_new, s_new, m, hist, dt, dt1, dt2, summary);
    };
    h.on_collective_error = [this](const char* what) { abort_unless_alone(comm, what); };
    return h;
  }

  void estimate(const std::vector<ParticleId>& ids, const std::vector<Vec3>& x, const std::vector<double>& s,
                const std::vector<Vec3>& x_new, const std::vector<double>& s_new, const std::vector<double>& m,
                const std::vector<DisplacementHistory>& hist, double dt, double dt1, double dt2,
                StepSummary& summary);
  double density_error(const std::vector<ParticleId>& ids, const std::vector<Vec3>& x_new,
                       const std::vector<double>& s_new, const std::vector<double>& m, const detail::MilneErrors& e);
};

// The serial estimate (ImplicitStepper::estimate_local_error) over the
// ranks: the smoothing of a particle's error over its list neighbours takes
// the ghosts' errors from their owners (the list's pair set is the serial
// one, built at the same positions), and the sums are global.
void DistributedImplicitStepper::Impl::estimate(const std::vector<ParticleId>& ids, const std::vector<Vec3>& x,
                                                const std::vector<double>& s, const std::vector<Vec3>& x_new,
                                                const std::vector<double>& s_new, const std::vector<double>& m,
                                                const std::vector<DisplacementHistory>& hist, double dt, double dt1,
                                                double dt2, StepSummary& summary) {
  const detail::MilneErrors e = detail::milne_errors(options, x, s, x_new, s_new, hist, dt, dt1, dt2);
  if (!(e.factor > 0.0)) return;  // the step sizes decide: every rank alike
  const std::size_t n = x.size();
  const double density = options.error_measure == ErrorMeasure::Density ? density_error(ids, x_new, s_new, m, e) : NAN;
  // The ghosts' rows (new position, width, mass and errors) from their owners.
  const std::vector<double> own = detail::error_rows(x_new, s_new, m, e);
  double sums[3] = {0.0, 0.0, 0.0};  // raw, smoothed, mass
  detail::smoothed_error_sums(options, functional.list(), periodicity, n, own,
                              functional.ghost_values(own, detail::kErrorRow), sums);
  MPI_Allreduce(MPI_IN_PLACE, sums, 3, MPI_DOUBLE, MPI_SUM, comm);
  detail::record_error_estimates(options, sums[0], sums[1], sums[2], density, summary);
}

// The density estimate over the ranks: every blob (new and extrapolated)
// within the smoothed kernel's reach of a rank's bounding box is sent to it,
// and each rank sums its own probes (chosen by id, detail::is_density_probe).
double DistributedImplicitStepper::Impl::density_error(const std::vector<ParticleId>& ids,
                                                       const std::vector<Vec3>& x_new,
                                                       const std::vector<double>& s_new, const std::vector<double>& m,
                                                       const detail::MilneErrors& e) {
  const std::size_t n = x_new.size();
  int any = std::find(e.has.begin(), e.has.end(), char{1}) != e.has.end() ? 1 : 0;
  MPI_Allreduce(MPI_IN_PLACE, &any, 1, MPI_INT, MPI_MAX, comm);
  if (any == 0) return NAN;
  detail::SmoothedBlobs b = detail::smoothed_blobs(options, x_new, s_new, e);
  const double tol = detail::density_error_tolerance(options);
  double w_max = 0.0;
  for (std::size_t p = 0; p < n; ++p) w_max = std::max({w_max, b.w_new[p], b.w_pred[p]});
  MPI_Allreduce(MPI_IN_PLACE, &w_max, 1, MPI_DOUBLE, MPI_MAX, comm);
  const double reach = cutoff_radius(w_max, tol);
  int size = 1, rank = 0;
  MPI_Comm_size(comm, &size);
  MPI_Comm_rank(comm, &rank);
  const std::vector<double> boxes = detail::all_boxes(x_new, comm);
  constexpr int k = 9;  // x_new, w_new, m, x_pred, w_pred
  std::vector<detail::Rows> to(static_cast<std::size_t>(size));
  for (int r = 0; r < size; ++r) {
    const double* bx = &boxes[6 * static_cast<std::size_t>(r)];
    if (r == rank || bx[0] > bx[3]) continue;
    const Vec3 lo(bx[0], bx[1], bx[2]), hi(bx[3], bx[4], bx[5]);
    detail::Rows& out = to[static_cast<std::size_t>(r)];
    for (std::size_t p = 0; p < n; ++p) {
      if (detail::distance_to_box(x_new[p], lo, hi, periodicity, dim) > reach &&
          detail::distance_to_box(b.x_pred[p], lo, hi, periodicity, dim) > reach)
        continue;
      out.ids.push_back(ids[p]);
      out.values.insert(out.values.end(), {x_new[p][0], x_new[p][1], x_new[p][2], b.w_new[p], m[p], b.x_pred[p][0],
                                           b.x_pred[p][1], b.x_pred[p][2], b.w_pred[p]});
    }
  }
  const detail::Rows in = detail::exchange_rows(to, k, comm);
  std::vector<Vec3> xs = x_new;
  std::vector<double> ms = m;
  for (std::size_t i = 0; i < in.ids.size(); ++i) {
    const double* v = &in.values[i * k];
    xs.emplace_back(v[0], v[1], v[2]);
    b.w_new.push_back(v[3]);
    ms.push_back(v[4]);
    b.x_pred.emplace_back(v[5], v[6], v[7]);
    b.w_pred.push_back(v[8]);
  }
  std::vector<std::size_t> probes;
  for (std::size_t p = 0; p < n; ++p)
    if (detail::is_density_probe(ids[p], dim)) probes.push_back(p);
  // A small set with no id on the stride anywhere: every particle (as serially).
  int probes_anywhere = probes.empty() ? 0 : 1;
  MPI_Allreduce(MPI_IN_PLACE, &probes_anywhere, 1, MPI_INT, MPI_MAX, comm);
  if (probes_anywhere == 0)
    for (std::size_t p = 0; p < n; ++p) probes.push_back(p);
  detail::DensityErrorSums sums =
      detail::density_error_sums(dim, xs, b.w_new, b.x_pred, b.w_pred, ms, probes, periodicity, tol, e.factor);
  double v[3] = {sums.error2, sums.density, sums.mass};
  MPI_Allreduce(MPI_IN_PLACE, v, 3, MPI_DOUBLE, MPI_SUM, comm);
  sums.error2 = v[0];
  sums.density = v[1];
  sums.mass = v[2];
  return detail::density_error_from(sums);
}

DistributedImplicitStepper::DistributedImplicitStepper(int dim, ImplicitOptions options, Barrier barrier,
                                                       Periodicity periodicity) {
  register_tao_backend();
  require_supported(options);
  impl_ = std::make_unique<Impl>(dim, options, std::move(barrier), periodicity);
  impl_->comm = PETSC_COMM_WORLD;
}

DistributedImplicitStepper::~DistributedImplicitStepper() = default;

// The serial stepper's step: a failed solve is retried as 2, 4, ...
// substeps (max_halvings), and the accepted positions are wrapped into a
// periodic box.
StepSummary DistributedImplicitStepper::step(ParticleSet& owned, double dt, double max_error) {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(!(max_error <= 0.0), "max_error", max_error, "must be > 0 (infinity: no error control)");
  require(owned.dim() == impl_->dim, "particles dim", owned.dim(),
          "must equal the stepper's dim " + std::to_string(impl_->dim));
  const auto t0 = Clock::now();
  Impl& d = *impl_;
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  StepSummary summary;
  summary.dt = dt;
  const int builds_before = d.functional.exchange().rebuilds;
  const double list_seconds_before = d.functional.exchange().list_seconds;
  const std::uint64_t pairs_before = d.functional.pair_evaluations();
  const std::vector<ParticleId>& ids = owned.ids();
  std::vector<DisplacementHistory> hist = d.history.lookup(ids);
  detail::StepSolveHooks hooks = d.hooks(ids);
  std::vector<Vec3> x = owned.positions();
  std::vector<double> s = owned.widths();
  double dt1 = d.history.dt1(), dt2 = d.history.dt2();
  if (detail::step_with_halvings(d.options, hooks, x, s, owned.masses(), hist, dt1, dt2, dt, max_error, summary)) {
    for (Vec3& y : x) y = d.periodicity.wrap(y);
    owned.positions() = std::move(x);
    owned.widths() = std::move(s);
    d.history.commit(ids, hist, dt1, dt2);
  }
  if (!summary.accepted && summary.message.empty()) summary.message = "step rejected";
  summary.list_builds = d.functional.exchange().rebuilds - builds_before;
  d.functional.add_step_work(list_seconds_before, pairs_before, summary);
  summary.wall_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return summary;
}

StepHistory& DistributedImplicitStepper::history() { return impl_->history; }
const ExchangeStats& DistributedImplicitStepper::exchange() const { return impl_->functional.exchange(); }
DistributedFunctional& DistributedImplicitStepper::functional() { return impl_->functional; }
const ImplicitOptions& DistributedImplicitStepper::options() const { return impl_->options; }

}  // namespace otfp
