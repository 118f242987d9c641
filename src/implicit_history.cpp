// The stepper's memory of each particle's last two diffusive displacements
// (by id), and what extrapolates from it: the predictor's start of a step and
// the local error estimate (Milne's device). BDF2's reference, the third use,
// is part of the step (src/implicit_stepper.cpp).
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <unordered_map>
#include <vector>

#include "otfp/density.hpp"
#include "otfp/implicit_stepper.hpp"

namespace otfp {

void ImplicitStepper::reset_history() {
  history_.clear();
  dt1_ = dt2_ = 0.0;
  previous_history_.clear();
  can_undo_history_ = false;
}

void ImplicitStepper::undo_last_history_update() {
  if (!can_undo_history_)
    throw std::logic_error("ImplicitStepper::undo_last_history_update: the history's last change was not an accepted step");
  history_.swap(previous_history_);
  dt1_ = previous_dt1_;
  dt2_ = previous_dt2_;
  previous_history_.clear();
  can_undo_history_ = false;
}

ImplicitStepper::HistoryState ImplicitStepper::history_state() const {
  HistoryState st;
  st.dt1 = dt1_;
  st.dt2 = dt2_;
  st.entries.reserve(history_.size());
  for (const auto& [id, h] : history_) st.entries.push_back({id, h.d1, h.d2, h.ds1, h.ds2, h.count});
  std::sort(st.entries.begin(), st.entries.end(),
            [](const HistoryEntry& a, const HistoryEntry& b) { return a.id < b.id; });
  return st;
}

void ImplicitStepper::restore_history(const HistoryState& st) {
  require(std::isfinite(st.dt1) && st.dt1 >= 0.0, "history dt1", st.dt1, "must be finite and >= 0");
  require(std::isfinite(st.dt2) && st.dt2 >= 0.0, "history dt2", st.dt2, "must be finite and >= 0");
  std::unordered_map<ParticleId, History> map;
  map.reserve(st.entries.size());
  for (const HistoryEntry& e : st.entries) {
    require(e.count >= 0 && e.count <= 2, "history count of particle " + std::to_string(e.id), e.count,
            "must be 0, 1 or 2");
    require(e.d1.allFinite() && e.d2.allFinite() && std::isfinite(e.ds1) && std::isfinite(e.ds2),
            "history of particle " + std::to_string(e.id), 0.0, "must be finite");
    require(map.emplace(e.id, History{e.d1, e.d2, e.ds1, e.ds2, e.count}).second,
            "history of particle " + std::to_string(e.id), static_cast<double>(e.id), "appears twice");
  }
  history_ = std::move(map);
  dt1_ = st.dt1;
  dt2_ = st.dt2;
  previous_history_.clear();
  can_undo_history_ = false;
}

// The predictor's start for one particle: the extrapolation `to`, or the
// largest of 1/2, 1/4, 1/8 of the way from `from` that is no further outside
// the barrier domain and the mirrored walls than `from` is; else `from`.
Vec3 ImplicitStepper::admissible_start(const Vec3& from, const Vec3& to) const {
  const Barrier& barrier = functional_.barrier().barrier();
  const auto& walls = functional_.images().walls();
  const bool use_barrier = barrier.active();
  if (!use_barrier && walls.empty()) return to;
  auto admissible = [&](const Vec3& y) {
    if (use_barrier && barrier.distance(y) > std::max(0.0, barrier.distance(from))) return false;
    for (const auto& w : walls)
      if (w->distance(y) > std::max(0.0, w->distance(from))) return false;
    return true;
  };
  double f = 1.0;
  for (int k = 0; k < 4; ++k, f *= 0.5) {
    const Vec3 y = from + f * (to - from);
    if (admissible(y)) return y;
  }
  return from;
}

// Linear extrapolation moves a particle by w d1. A mode that decays within
// a step (lambda dt >= 1, the large steps) moves less each step, and linear
// extrapolation overshoots it; Damped scales by the particle's last ratio
// d1.d2 / |d2|^2 (clamped to [0, 1]; linear while only d1 is known).
double ImplicitStepper::predictor_factor(Predictor predictor, const History& h, double omega) {
  if (predictor == Predictor::None || h.count < 1) return 0.0;
  if (predictor == Predictor::Extrapolate || h.count < 2) return omega;
  const double d22 = h.d2.squaredNorm() + h.ds2 * h.ds2;
  if (!(d22 > 0.0)) return 0.0;
  return omega * std::min(std::max((h.d1.dot(h.d2) + h.ds1 * h.ds2) / d22, 0.0), 1.0);
}

std::vector<Vec3> ImplicitStepper::predict(const ParticleSet& particles, double dt) const {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  std::vector<Vec3> out = particles.positions();
  if (!(dt1_ > 0.0)) return out;
  const double omega = dt / dt1_;
  const Predictor kind = options_.predictor == Predictor::None ? Predictor::Extrapolate : options_.predictor;
  for (std::size_t p = 0; p < out.size(); ++p) {
    const auto it = history_.find(particles.ids()[p]);
    if (it == history_.end()) continue;
    const double g = predictor_factor(kind, it->second, omega);
    if (g > 0.0) out[p] = admissible_start(out[p], out[p] + g * it->second.d1);
  }
  return out;
}

// The local error estimate of a solved step (into summary): the error
// committed in the step, i.e. the distance from x^{k+1} to the exact solution
// through x^k, from the difference to the explicit extrapolation of the
// scheme's order (Milne's device). The history x^{k-1}, x^{k-2} is
// numerical, and its own errors enter at the same order (docs/stepper.md
// derives the factors):
//   Euler (p1 linear through x^{k-1}, x^k):       e = (x^{k+1} - p1) / 2, for any w;
//   BDF2  (p2 quadratic through x^{k-2}..x^k):    e = (x^{k+1} - p2) / 3.
// BDF2's factor is exactly 1/3 at any constant step ratio w (geometric
// growth, as the controller takes in a settled state) and within 15% of the
// exact one when the ratio changes every step between 0.57 and 1.4 (its
// exact value depends on the older steps too). The factor this code used
// before, (1+w) h^2 / (w (h+h1)(h+h1+h2)), was off by about the factor w
// (1.35x at w = 1.4, 0.73x at w = 0.75; 1.7x at the controller's w = 2). Checked against the exact one-step
// error of x' = -lambda x (test_time_schemes.cpp).
void ImplicitStepper::estimate_local_error(const std::vector<Vec3>& x, const std::vector<double>& s,
                                           const std::vector<Vec3>& x_new, const std::vector<double>& s_new,
                                           const std::vector<double>& m, const std::vector<History>& hist,
                                           double dt, double dt1, double dt2, StepSummary& summary) const {
  const std::size_t n = x.size();
  const bool widths = options_.width_mode == WidthMode::PerParticle;
  const double omega = dt1 > 0.0 ? dt / dt1 : 0.0;  // dt_k / dt_{k-1}
  const bool bdf2 = options_.time_scheme == TimeScheme::Bdf2;
  const int need = bdf2 ? 2 : 1;
  const double h = dt, h1 = dt1, h2 = dt2;
  double factor = 0.0;
  if (!bdf2 && h1 > 0.0)
    factor = 0.5;
  else if (bdf2 && h1 > 0.0 && h2 > 0.0)
    factor = 1.0 / 3.0;
  // Per particle first; then the estimate that controls dt is taken of the
  // error field smoothed over a neighbourhood (Gaussian of standard deviation
  // error_smoothing x s_q, within the neighbour list): the part of a
  // particle's motion that alternates between neighbours is the relaxation
  // of the particle arrangement (damped by both schemes, invisible in the
  // density at the blob scale), not an error of the solution's time evolution
  // (docs/stepper.md).
  std::vector<Vec3> ex(factor > 0.0 ? n : 0, Vec3::Zero());
  std::vector<double> es(ex.size(), 0.0);
  std::vector<char> has(ex.size(), 0);
  for (std::size_t p = 0; p < ex.size(); ++p) {
    const History& H = hist[p];
    if (H.count < need) continue;
    Vec3 pred_x;
    double pred_s;
    if (!bdf2) {
      pred_x = x[p] + omega * H.d1;
      pred_s = s[p] + omega * H.ds1;
    } else {
      // Newton form: p(t) = x^k + v1 (t - t_k) + a (t - t_k)(t - t_{k-1}).
      const Vec3 v1 = H.d1 / h1, v2 = H.d2 / h2;
      const Vec3 acc = (v1 - v2) / (h1 + h2);
      pred_x = x[p] + h * v1 + h * (h + h1) * acc;
      const double w1 = H.ds1 / h1, w2 = H.ds2 / h2;
      pred_s = s[p] + h * w1 + h * (h + h1) * (w1 - w2) / (h1 + h2);
    }
    ex[p] = factor * (x_new[p] - pred_x);
    es[p] = widths ? factor * (s_new[p] - pred_s) : 0.0;
    has[p] = 1;
  }
  // Two blob-density sweeps: only when the estimate is the one asked for.
  const double density_error = factor > 0.0 && options_.error_measure == ErrorMeasure::Density
                                   ? density_error_estimate(x_new, s_new, m, ex, es, has, factor)
                                   : NAN;
  double sum_raw = 0.0, sum_smooth = 0.0, sum_m = 0.0;
  const NeighborList& list = functional_.list();
  const bool list_ok = list.built() && list.size() >= n;
  const Periodicity& per = functional_.periodicity();
  const double smoothing = options_.error_smoothing, smoothing2 = smoothing * smoothing;
  // With the width skin the list holds more pairs; the smoothing keeps to the
  // pairs the list would hold without it (the wider blob's cut-off plus the skin).
  const bool cut_pairs = widths && options_.width_skin > 0.0;
  const double tol = options_.neighbor.kernel_tolerance, skin_plain = list.skin() / (1.0 + options_.width_skin);
  for (std::size_t p = 0; p < ex.size(); ++p) {
    if (!has[p]) continue;
    const double sp2 = s_new[p] * s_new[p];
    sum_raw += m[p] * (ex[p].squaredNorm() + es[p] * es[p]) / sp2;
    double wsum = m[p];
    Vec3 ax = wsum * ex[p];
    double as = wsum * es[p];
    if (list_ok && smoothing > 0.0) {
      for (std::uint32_t k = list.offsets()[p]; k < list.offsets()[p + 1]; ++k) {
        const std::size_t q = list.indices()[k];
        if (q >= n || !has[q]) continue;  // image blobs and particles without an estimate
        const double sq2 = s_new[q] * s_new[q];
        const double r2 = per.displacement(x_new[p], x_new[q]).squaredNorm();
        if (cut_pairs) {
          const double rad = cutoff_radius(std::max(s_new[p], s_new[q]), tol) + skin_plain;
          if (r2 > rad * rad) continue;
        }
        const double w = m[q] * std::exp(-0.5 * r2 / (smoothing2 * sq2));
        wsum += w;
        ax += w * ex[q];
        as += w * es[q];
      }
    }
    ax /= wsum;
    as /= wsum;
    sum_smooth += m[p] * (ax.squaredNorm() + as * as) / sp2;
    sum_m += m[p];
  }
  if (sum_m > 0.0) {
    const double smooth = std::sqrt(sum_smooth / sum_m), raw = std::sqrt(sum_raw / sum_m);
    const double err = options_.error_measure == ErrorMeasure::Density ? density_error : smooth;
    // NaN-aware maxima over substeps.
    if (!(summary.error_estimate >= err)) summary.error_estimate = err;
    if (!(summary.displacement_error_estimate >= smooth)) summary.displacement_error_estimate = smooth;
    if (!(summary.density_error_estimate >= density_error)) summary.density_error_estimate = density_error;
    if (!(summary.particle_error_estimate >= raw)) summary.particle_error_estimate = raw;
    summary.error_order = bdf2 ? 2 : 1;
  }
}

// The local error of the blob density (ErrorMeasure::Density): the density
// of the step's result minus that of the explicit extrapolation (the same
// Milne factor as the displacement estimate), both smoothed by a Gaussian of
// error_smoothing widths (a blob of width s convolved with it is a blob of
// width s sqrt(1 + c^2)), at the new particle positions; mass-weighted RMS
// relative to the mass-weighted mean density. A permutation of particles, or
// their relaxation at the particle scale, leaves the smoothed density (and
// so the estimate) unchanged: the density ripple of a lattice of spacing
// dr = sqrt(2) s is damped by exp(-pi^2 (1 + c^2)) by the smoothing, below
// 1e-20 at c = 2. Particles without the history the estimate needs enter both
// densities at their new place. NaN when no particle has an estimate.
double ImplicitStepper::density_error_estimate(const std::vector<Vec3>& x_new, const std::vector<double>& s_new,
                                               const std::vector<double>& m, const std::vector<Vec3>& ex,
                                               const std::vector<double>& es, const std::vector<char>& has,
                                               double factor) const {
  const std::size_t n = x_new.size();
  bool any = false;
  for (char h : has) any = any || h;
  if (!any || !(factor > 0.0)) return NAN;
  const double widen = std::sqrt(1.0 + options_.error_smoothing * options_.error_smoothing);
  std::vector<Vec3> x_pred(n);
  std::vector<double> w_new(n), w_pred(n);
  for (std::size_t p = 0; p < n; ++p) {
    // ex = factor (x_new - pred): the prediction is x_new - ex / factor.
    x_pred[p] = has[p] ? Vec3(x_new[p] - ex[p] / factor) : x_new[p];
    w_new[p] = widen * s_new[p];
    const double sp = has[p] && !es.empty() ? s_new[p] - es[p] / factor : s_new[p];
    w_pred[p] = widen * (sp > 0.0 ? sp : s_new[p]);
  }
  const Periodicity& per = functional_.periodicity();
  // The estimate needs a relative precision of about 1e-6 of the density;
  // the kernel's own tolerance where that is tighter.
  const double tol = std::max(options_.neighbor.kernel_tolerance, kErrorKernelTolerance);
  // Probes: every (2^d / 2)-th particle (the particles are in spatial order
  // after sort_particles), about one per 1.6 spacings in 3-D, where the
  // smoothed density varies over 2.2 widths = 1.6 spacings: the same RMS at
  // a quarter of the sweeps' cost.
  const std::size_t stride = dim_ == 3 ? 4 : dim_ == 2 ? 2 : 1;
  std::vector<Vec3> probes;
  std::vector<double> probe_m;
  probes.reserve(n / stride + 1);
  probe_m.reserve(n / stride + 1);
  for (std::size_t p = 0; p < n; p += stride) {
    probes.push_back(x_new[p]);
    probe_m.push_back(m[p]);
  }
  std::vector<double> rho_new, rho_pred;
  blob_density(dim_, x_new, w_new, m, probes, per, tol, rho_new, nullptr);
  blob_density(dim_, x_pred, w_pred, m, probes, per, tol, rho_pred, nullptr);
  double sum = 0.0, mean = 0.0, mass = 0.0;
  for (std::size_t j = 0; j < probes.size(); ++j) {
    const double e = factor * (rho_new[j] - rho_pred[j]);
    sum += probe_m[j] * e * e;
    mean += probe_m[j] * rho_new[j];
    mass += probe_m[j];
  }
  if (!(mass > 0.0) || !(mean > 0.0)) return NAN;
  mean /= mass;
  return std::sqrt(sum / mass) / mean;
}

}  // namespace otfp
