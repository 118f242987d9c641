// The serial stepper's use of its StepHistory (otfp/step_history.hpp): the
// predictor's start of a step and the local error estimate (Milne's device,
// the per-particle part in src/step_solve.cpp). BDF2's reference, the third
// use, is part of the solve (src/step_solve.cpp).
#include <algorithm>
#include <cmath>
#include <vector>

#include "otfp/implicit_stepper.hpp"
#include "step_solve.hpp"

namespace otfp {

void ImplicitStepper::reset_history() { history_.reset(); }
void ImplicitStepper::undo_last_history_update() { history_.undo_last_update(); }
ImplicitStepper::HistoryState ImplicitStepper::history_state() const { return history_.state(); }
void ImplicitStepper::restore_history(const HistoryState& st) { history_.restore(st); }

std::vector<Vec3> ImplicitStepper::predict(const ParticleSet& particles, double dt) const {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  std::vector<Vec3> out = particles.positions();
  if (!(history_.dt1() > 0.0)) return out;
  const double omega = dt / history_.dt1();
  const Predictor kind = options_.predictor == Predictor::None ? Predictor::Extrapolate : options_.predictor;
  const Barrier& barrier = functional_.barrier().barrier();
  const auto& walls = functional_.images().walls();
  for (std::size_t p = 0; p < out.size(); ++p) {
    const DisplacementHistory* h = history_.find(particles.ids()[p]);
    if (h == nullptr) continue;
    const double g = detail::predictor_factor(kind, *h, omega);
    if (g > 0.0) out[p] = detail::admissible_start(barrier, walls, out[p], out[p] + g * h->d1);
  }
  return out;
}

// The estimate that controls dt: the error field smoothed over a
// neighbourhood (Gaussian of standard deviation error_smoothing x s_q, within
// the neighbour list; detail::smoothed_error_sums), or, with
// ErrorMeasure::Density, the error of the smoothed blob density at the
// probes (detail::density_error_sums).
void ImplicitStepper::estimate_local_error(const std::vector<ParticleId>& ids, const std::vector<Vec3>& x,
                                           const std::vector<double>& s, const std::vector<Vec3>& x_new,
                                           const std::vector<double>& s_new, const std::vector<double>& m,
                                           const std::vector<DisplacementHistory>& hist, double dt, double dt1,
                                           double dt2, StepSummary& summary) const {
  const std::size_t n = x.size();
  const detail::MilneErrors e = detail::milne_errors(options_, x, s, x_new, s_new, hist, dt, dt1, dt2);
  if (!(e.factor > 0.0)) return;
  // Two blob-density sweeps: only when the estimate is the one asked for.
  double density_error = NAN;
  if (options_.error_measure == ErrorMeasure::Density) {
    const detail::SmoothedBlobs b = detail::smoothed_blobs(options_, x_new, s_new, e);
    std::vector<std::size_t> probes;
    for (std::size_t p = 0; p < n; ++p)
      if (detail::is_density_probe(ids[p], dim_)) probes.push_back(p);
    if (probes.empty())  // a small set with no id on the stride: every particle
      for (std::size_t p = 0; p < n; ++p) probes.push_back(p);
    if (std::find(e.has.begin(), e.has.end(), char{1}) != e.has.end())
      density_error = detail::density_error_from(
          detail::density_error_sums(dim_, x_new, b.w_new, b.x_pred, b.w_pred, m, probes, functional_.periodicity(),
                                     detail::density_error_tolerance(options_), e.factor));
  }
  double sums[3] = {0.0, 0.0, 0.0};
  detail::smoothed_error_sums(options_, functional_.list(), functional_.periodicity(), n,
                              detail::error_rows(x_new, s_new, m, e), {}, sums);
  detail::record_error_estimates(options_, sums[0], sums[1], sums[2], density_error, summary);
}

}  // namespace otfp
