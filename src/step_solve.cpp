// One solve of (28), shared by the serial and the distributed step
// (step_solve.hpp).
#include "step_solve.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <limits>
#include <memory>
#include <string>

#include "otfp/density.hpp"

namespace otfp::detail {

double predictor_factor(Predictor predictor, const DisplacementHistory& h, double omega) {
  // Linear extrapolation moves a particle by w d1. A mode that decays within
  // a step (lambda dt >= 1, the large steps) moves less each step, and linear
  // extrapolation overshoots it; Damped scales by the particle's last ratio
  // d1.d2 / |d2|^2 (clamped to [0, 1]; linear while only d1 is known).
  if (predictor == Predictor::None || h.count < 1) return 0.0;
  if (predictor == Predictor::Extrapolate || h.count < 2) return omega;
  const double d22 = h.d2.squaredNorm() + h.ds2 * h.ds2;
  if (!(d22 > 0.0)) return 0.0;
  return omega * std::min(std::max((h.d1.dot(h.d2) + h.ds1 * h.ds2) / d22, 0.0), 1.0);
}

Vec3 admissible_start(const Barrier& barrier, const std::vector<MirrorWallPtr>& walls, const Vec3& from,
                      const Vec3& to) {
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

// The local error estimate of a solved step (Milne's device): the distance
// from x^{k+1} to the exact solution through x^k, from the difference to the
// explicit extrapolation of the scheme's order. The history x^{k-1}, x^{k-2}
// is numerical, and its own errors enter at the same order (docs/stepper.md
// derives the factors):
//   Euler (p1 linear through x^{k-1}, x^k):       e = (x^{k+1} - p1) / 2, for any w;
//   BDF2  (p2 quadratic through x^{k-2}..x^k):    e = (x^{k+1} - p2) / 3.
// BDF2's factor is exactly 1/3 at any constant step ratio w (geometric
// growth, as the controller takes in a settled state) and within 15% of the
// exact one when the ratio changes every step between 0.57 and 1.4 (its
// exact value depends on the older steps too). Checked against the exact
// one-step error of x' = -lambda x (test_time_schemes.cpp).
MilneErrors milne_errors(const ImplicitOptions& options, const std::vector<Vec3>& x, const std::vector<double>& s,
                         const std::vector<Vec3>& x_new, const std::vector<double>& s_new,
                         const std::vector<DisplacementHistory>& hist, double dt, double dt1, double dt2) {
  MilneErrors out;
  const std::size_t n = x.size();
  const bool widths = options.width_mode == WidthMode::PerParticle;
  const double omega = dt1 > 0.0 ? dt / dt1 : 0.0;  // dt_k / dt_{k-1}
  const bool bdf2 = options.time_scheme == TimeScheme::Bdf2;
  const int need = bdf2 ? 2 : 1;
  const double h = dt, h1 = dt1, h2 = dt2;
  if (!bdf2 && h1 > 0.0)
    out.factor = 0.5;
  else if (bdf2 && h1 > 0.0 && h2 > 0.0)
    out.factor = 1.0 / 3.0;
  if (!(out.factor > 0.0)) return out;
  out.ex.assign(n, Vec3::Zero());
  out.es.assign(n, 0.0);
  out.has.assign(n, 0);
  for (std::size_t p = 0; p < n; ++p) {
    const DisplacementHistory& H = hist[p];
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
    out.ex[p] = out.factor * (x_new[p] - pred_x);
    out.es[p] = widths ? out.factor * (s_new[p] - pred_s) : 0.0;
    out.has[p] = 1;
  }
  return out;
}

bool is_density_probe(ParticleId id, int dim) {
  const ParticleId stride = dim == 3 ? 4 : dim == 2 ? 2 : 1;
  return id % stride == 0;
}

void record_error_estimates(const ImplicitOptions& options, double sum_raw, double sum_smooth, double sum_m,
                            double density_error, StepSummary& summary) {
  if (!(sum_m > 0.0)) return;
  const double smooth = std::sqrt(sum_smooth / sum_m), raw = std::sqrt(sum_raw / sum_m);
  const double err = options.error_measure == ErrorMeasure::Density ? density_error : smooth;
  // NaN-aware maxima over substeps.
  if (!(summary.error_estimate >= err)) summary.error_estimate = err;
  if (!(summary.displacement_error_estimate >= smooth)) summary.displacement_error_estimate = smooth;
  if (!(summary.density_error_estimate >= density_error)) summary.density_error_estimate = density_error;
  if (!(summary.particle_error_estimate >= raw)) summary.particle_error_estimate = raw;
  summary.error_order = options.time_scheme == TimeScheme::Bdf2 ? 2 : 1;
}

bool solve_step(const ImplicitOptions& options, StepSolveHooks& hooks, std::vector<Vec3>& x, std::vector<double>& s,
                const std::vector<double>& m, std::vector<DisplacementHistory>& hist, double& dt1, double& dt2,
                double dt, StepSummary& summary) {
  const StepFunctional& sf = hooks.functional;
  auto all = [&](bool v) { return sf.all ? sf.all(v) : v; };
  auto sum = [&](double* v, int k) {
    if (sf.sum) sf.sum(v, k);
  };
  auto max = [&](double v) { return sf.max ? sf.max(v) : v; };

  const std::size_t n = x.size();
  const bool widths = options.width_mode == WidthMode::PerParticle;
  const double omega = dt1 > 0.0 ? dt / dt1 : 0.0;  // dt_k / dt_{k-1}

  // Variational BDF2 (docs/stepper.md): the variable-step BDF2 update
  //   a0 x^{k+1} - (1+w) x^k + w^2/(1+w) x^{k-1} = -dt/m dE/dx(x^{k+1}),
  //   a0 = (1+2w)/(1+w), w = dt_k/dt_{k-1},
  // is the stationarity condition of  a0 m/(2 dt) |x - x_hat|^2 + E(x)  with
  //   x_hat = x^k + w^2/(1+2w) (x^k - x^{k-1}),
  // i.e. (28) with the reference x_hat and transport weight a0 (w = 1: 3/(4 dt),
  // x_hat = (4 x^k - x^{k-1})/3). Particles with no x^{k-1} take the Euler form.
  std::vector<Vec3> x_ref = x;
  std::vector<double> s_ref = s, weights;
  double bdf2_particles = 0.0;
  if (options.time_scheme == TimeScheme::Bdf2 && dt1 > 0.0) {
    const double c = omega * omega / (1.0 + 2.0 * omega);
    const double a0 = (1.0 + 2.0 * omega) / (1.0 + omega);
    weights.assign(n, 1.0);
    for (std::size_t p = 0; p < n; ++p) {
      if (hist[p].count < 1) continue;
      x_ref[p] = x[p] + c * hist[p].d1;
      if (widths) s_ref[p] = s[p] + c * hist[p].ds1;
      weights[p] = a0;
      bdf2_particles += 1.0;
    }
    // Each process decides for its own particles; the count is global.
    if (bdf2_particles == 0.0) weights.clear();
    sum(&bdf2_particles, 1);
  }
  summary.bdf2_particles = static_cast<long>(bdf2_particles);

  hooks.prepare(dt, x_ref, s_ref, m, weights, x, s);

  const double s_max = options.max_width_factor > 0.0 ? options.max_width_factor * options.nominal_width : 0.0;
  // The objective checks this process's particles (a width above the bound,
  // say) and may refuse them: every process learns of it before any
  // collective, and all throw (this one its own message).
  std::unique_ptr<StepObjective> made;
  std::exception_ptr refused;
  try {
    made = std::make_unique<StepObjective>(sf, *hooks.external, x, s, m, dt, widths, weights, s_max);
  } catch (...) {
    refused = std::current_exception();
  }
  const bool none_refused = all(!refused);
  if (refused) std::rethrow_exception(refused);
  require(none_refused, "particles", 0.0, "refused by another process (its error names the field)");
  // From here on every process runs the same collectives: an exception on one
  // only (its share of F, a backend failure) goes to on_collective_error.
  try {
    StepObjective& objective = *made;
    if (options.stopping_norm == StoppingNorm::Energy) objective.set_max_norm_factor(options.max_norm_factor);
    std::vector<double> z(objective.num_variables());
    objective.pack(x, s, z.data());
    // sqrt(m/dt) overflows for a dt of a few 1e-308: no step can be taken in
    // unknowns that are not finite (the run fails with this message).
    bool finite = true;
    for (double v : z) finite = finite && std::isfinite(v);
    if (!all(finite)) {
      char buf[64];
      std::snprintf(buf, sizeof(buf), "%.6g", dt);
      summary.message = std::string("dt = ") + buf + " is too small: the scaled unknowns sqrt(m/dt) x overflow";
      summary.reason = TerminationReason::NonFinite;
      return false;
    }

    // The thresholds from the smallest width and mass and the total mass
    // over every process's particles.
    double s_min = std::numeric_limits<double>::infinity(), m_min = s_min, mass = 0.0;
    for (double v : s) s_min = std::min(s_min, v);
    for (double v : m) {
      m_min = std::min(m_min, v);
      mass += v;
    }
    s_min = -max(-s_min);
    m_min = -max(-m_min);
    sum(&mass, 1);
    if (!std::isfinite(s_min)) s_min = 1.0;
    if (!std::isfinite(m_min)) m_min = 1.0;
    MinimizerOptions mo = options.minimizer;

    // The anchor x^k: F there is the right-hand side of the energy inequality
    // the step must satisfy (Euler: E(x^k); BDF2: the modified energy, below).
    // The papers' path (Euler, no predictor) starts there and lets the
    // minimiser apply the relative rule; otherwise the rule is measured at the
    // anchor, so that a good start does not make the tolerance stricter.
    const bool papers_path = options.time_scheme == TimeScheme::Euler && options.predictor == Predictor::None;
    std::vector<double> g_anchor(papers_path ? 0 : z.size());
    double f0 = 0.0;
    const bool start_ok = objective.evaluate(z.data(), &f0, papers_path ? nullptr : g_anchor.data());
    const FunctionalParts before = objective.parts();
    if (!papers_path) ++summary.evaluations;
    double f_start = f0;

    const StepTolerances tol = step_tolerances(options, dt, s_min, m_min, mass, before);
    mo.gradient_tolerance = tol.gradient_tolerance;
    const double floor_measure = tol.floor_measure, stall_measure = tol.stall_measure;
    // Relative rule: the first gradient step is the explicit displacement of
    // the step; at small dt the absolute rule alone stops before the solution
    // has moved by much more than the tolerance (under-diffusion,
    // docs/validation.md study 3).
    if (papers_path) {
      mo.relative_gradient_tolerance = options.relative_tolerance;
    } else {
      const double measure0 = start_ok ? objective.stopping_measure(z.data(), g_anchor.data()) : 0.0;
      if (options.relative_tolerance > 0.0 && measure0 > 0.0)
        mo.gradient_tolerance =
            std::max(std::min(mo.gradient_tolerance, options.relative_tolerance * measure0), floor_measure);
      mo.relative_gradient_tolerance = 0.0;
    }
    mo.gradient_tolerance_floor = floor_measure;
    mo.start_tolerance = stall_measure;

    // Predictor: start from the extrapolated trajectory where that lowers F.
    double predicted = 0.0;
    if (start_ok && options.predictor != Predictor::None && dt1 > 0.0) {
      std::vector<Vec3> xp = x;
      std::vector<double> sp = s;
      for (std::size_t p = 0; p < n; ++p) {
        // Particles inserted since the last step (no history) start where they are.
        const double g = predictor_factor(options.predictor, hist[p], omega);
        if (!(g > 0.0)) continue;
        xp[p] = hooks.admissible_start(x[p], x[p] + g * hist[p].d1);
        if (widths) sp[p] = std::max(s[p] + g * hist[p].ds1, 0.5 * s[p]);
        if (widths && s_max > 0.0) sp[p] = std::min(sp[p], s_max);  // inside the bound
        predicted += 1.0;
      }
      sum(&predicted, 1);
      if (predicted > 0.0) {
        std::vector<double> zp(z.size());
        objective.pack(xp, sp, zp.data());
        double fp = 0.0;
        ++summary.evaluations;
        if (objective.evaluate(zp.data(), &fp, nullptr) && fp < f0) {
          z = std::move(zp);
          f_start = fp;
        } else {
          predicted = 0.0;
        }
      }
    }
    summary.predicted_particles = static_cast<long>(predicted);
    summary.f_start = f_start;

    MinimizerSummary ms;
    if (start_ok) ms = hooks.minimize(objective, z, mo);
    record_solve(ms, start_ok, before, f0, summary);

    // Into copies: the objective refers to (x, s) as the step's start.
    std::vector<Vec3> x_new = x;
    std::vector<double> s_new = s;
    if (!accept_solve(objective, z, start_ok, ms, tol, f0, before, options.energy_tolerance, x_new, s_new, summary))
      return false;

    // The local error estimate (Milne's device).
    hooks.estimate(x, s, x_new, s_new, m, hist, dt, dt1, dt2, summary);

    // Shift the history: the new diffusive displacement (unwrapped).
    for (std::size_t p = 0; p < n; ++p) {
      DisplacementHistory& H = hist[p];
      H.d2 = H.d1;
      H.ds2 = H.ds1;
      H.d1 = x_new[p] - x[p];
      H.ds1 = s_new[p] - s[p];
      H.count = std::min(H.count + 1, 2);
    }
    dt2 = dt1;
    dt1 = dt;
    x = std::move(x_new);
    s = std::move(s_new);
    return true;
  } catch (const std::exception& e) {
    if (hooks.on_collective_error) hooks.on_collective_error(e.what());
    throw;
  } catch (...) {
    if (hooks.on_collective_error) hooks.on_collective_error("an unknown exception");
    throw;
  }
}

}  // namespace otfp::detail

namespace otfp::detail {

SmoothedBlobs smoothed_blobs(const ImplicitOptions& options, const std::vector<Vec3>& x_new,
                             const std::vector<double>& s_new, const MilneErrors& e) {
  const std::size_t n = x_new.size();
  const double widen = std::sqrt(1.0 + options.error_smoothing * options.error_smoothing);
  SmoothedBlobs b;
  b.x_pred.resize(n);
  b.w_new.resize(n);
  b.w_pred.resize(n);
  for (std::size_t p = 0; p < n; ++p) {
    const bool has = !e.has.empty() && e.has[p];
    // ex = factor (x_new - pred): the prediction is x_new - ex / factor.
    b.x_pred[p] = has ? Vec3(x_new[p] - e.ex[p] / e.factor) : x_new[p];
    b.w_new[p] = widen * s_new[p];
    const double sp = has ? s_new[p] - e.es[p] / e.factor : s_new[p];
    b.w_pred[p] = widen * (sp > 0.0 ? sp : s_new[p]);
  }
  return b;
}

DensityErrorSums density_error_sums(int dim, const std::vector<Vec3>& x_new, const std::vector<double>& w_new,
                                    const std::vector<Vec3>& x_pred, const std::vector<double>& w_pred,
                                    const std::vector<double>& m, const std::vector<std::size_t>& probes,
                                    const Periodicity& per, double kernel_tolerance, double factor) {
  DensityErrorSums out;
  if (probes.empty()) return out;
  std::vector<Vec3> at(probes.size());
  for (std::size_t j = 0; j < probes.size(); ++j) at[j] = x_new[probes[j]];
  std::vector<double> rho_new, rho_pred;
  blob_density(dim, x_new, w_new, m, at, per, kernel_tolerance, rho_new, nullptr);
  blob_density(dim, x_pred, w_pred, m, at, per, kernel_tolerance, rho_pred, nullptr);
  for (std::size_t j = 0; j < probes.size(); ++j) {
    const double mj = m[probes[j]];
    const double e = factor * (rho_new[j] - rho_pred[j]);
    out.error2 += mj * e * e;
    out.density += mj * rho_new[j];
    out.mass += mj;
  }
  return out;
}

double density_error_from(const DensityErrorSums& sums) {
  if (!(sums.mass > 0.0) || !(sums.density > 0.0)) return NAN;
  return std::sqrt(sums.error2 / sums.mass) / (sums.density / sums.mass);
}

double density_error_tolerance(const ImplicitOptions& options) {
  constexpr double kErrorKernelTolerance = 1e-6;
  return std::max(options.neighbor.kernel_tolerance, kErrorKernelTolerance);
}

}  // namespace otfp::detail

namespace otfp::detail {

std::vector<double> error_rows(const std::vector<Vec3>& x_new, const std::vector<double>& s_new,
                               const std::vector<double>& m, const MilneErrors& e) {
  const std::size_t n = x_new.size();
  std::vector<double> rows(n * kErrorRow);
  for (std::size_t p = 0; p < n; ++p) {
    double* r = &rows[p * kErrorRow];
    r[0] = x_new[p][0], r[1] = x_new[p][1], r[2] = x_new[p][2], r[3] = s_new[p], r[4] = m[p];
    r[5] = e.ex[p][0], r[6] = e.ex[p][1], r[7] = e.ex[p][2], r[8] = e.es[p], r[9] = e.has[p];
  }
  return rows;
}

// The part of a particle's motion that alternates between neighbours is the
// relaxation of the particle arrangement (damped by both schemes, invisible
// in the density at the blob scale), not an error of the solution's time
// evolution (docs/stepper.md): the estimate that controls dt is taken of the
// error field smoothed over a neighbourhood.
void smoothed_error_sums(const ImplicitOptions& options, const NeighborList& list, const Periodicity& per,
                         std::size_t n, const std::vector<double>& own, const std::vector<double>& ghost,
                         double sums[3]) {
  const std::size_t local = n + ghost.size() / kErrorRow;
  auto row = [&](std::size_t q) { return q < n ? &own[q * kErrorRow] : &ghost[(q - n) * kErrorRow]; };
  const bool list_ok = list.built() && list.size() >= n;
  const double smoothing = options.error_smoothing, smoothing2 = smoothing * smoothing;
  // With the width skin the list holds more pairs; the smoothing keeps to the
  // pairs the list would hold without it (the wider blob's cut-off plus the skin).
  const bool cut_pairs = options.width_mode == WidthMode::PerParticle && options.width_skin > 0.0;
  const double tol = options.neighbor.kernel_tolerance, skin_plain = list.skin() / (1.0 + options.width_skin);
  for (std::size_t p = 0; p < n; ++p) {
    const double* rp = row(p);
    if (rp[9] == 0.0) continue;
    const Vec3 xp(rp[0], rp[1], rp[2]), ep(rp[5], rp[6], rp[7]);
    const double sp = rp[3], mp = rp[4], esp = rp[8];
    const double sp2 = sp * sp;
    sums[0] += mp * (ep.squaredNorm() + esp * esp) / sp2;
    double wsum = mp;
    Vec3 ax = wsum * ep;
    double as = wsum * esp;
    if (list_ok && smoothing > 0.0) {
      for (std::uint32_t k = list.offsets()[p]; k < list.offsets()[p + 1]; ++k) {
        const std::size_t q = list.indices()[k];
        if (q >= local) continue;  // image blobs
        const double* r = row(q);
        if (r[9] == 0.0) continue;  // no estimate
        const double sq = r[3];
        const double r2 = per.displacement(xp, Vec3(r[0], r[1], r[2])).squaredNorm();
        if (cut_pairs) {
          const double rad = cutoff_radius(std::max(sp, sq), tol) + skin_plain;
          if (r2 > rad * rad) continue;
        }
        const double w = r[4] * std::exp(-0.5 * r2 / (smoothing2 * (sq * sq)));
        wsum += w;
        ax += w * Vec3(r[5], r[6], r[7]);
        as += w * r[8];
      }
    }
    ax /= wsum;
    as /= wsum;
    sums[1] += mp * (ax.squaredNorm() + as * as) / sp2;
    sums[2] += mp;
  }
}

}  // namespace otfp::detail

namespace otfp::detail {

bool step_with_halvings(const ImplicitOptions& options, StepSolveHooks& hooks, std::vector<Vec3>& x0,
                        std::vector<double>& s0, const std::vector<double>& m, std::vector<DisplacementHistory>& hist0,
                        double& dt1_0, double& dt2_0, double dt, double max_error, StepSummary& summary) {
  for (int halvings = 0; halvings <= options.max_halvings; ++halvings) {
    std::vector<Vec3> x = x0;
    std::vector<double> s = s0;
    std::vector<DisplacementHistory> hist = hist0;
    double dt1 = dt1_0, dt2 = dt2_0;
    const int substeps = 1 << halvings;
    const double h = dt / substeps;
    bool ok = true;
    FunctionalParts first_before;
    double first_f = 0.0, first_start = 0.0;
    summary.error_estimate = summary.particle_error_estimate = std::numeric_limits<double>::quiet_NaN();
    summary.displacement_error_estimate = summary.density_error_estimate = std::numeric_limits<double>::quiet_NaN();
    summary.error_order = 0;
    for (int k = 0; k < substeps && ok; ++k) {
      ok = solve_step(options, hooks, x, s, m, hist, dt1, dt2, h, summary);
      if (k == 0) {
        first_before = summary.parts_before;
        first_f = summary.f_before;
        first_start = summary.f_start;
      }
    }
    summary.halvings = halvings;
    if (!ok) {
      ++summary.rejected_solves;
      continue;
    }
    summary.substeps = substeps;
    summary.parts_before = first_before;
    summary.f_before = first_f;
    summary.f_start = first_start;
    if (summary.error_estimate > max_error) {
      // Too inaccurate for the caller (a global estimate: every process
      // alike): nothing is committed, not even the history.
      summary.error_rejected = true;
      summary.message = "local error estimate " + std::to_string(summary.error_estimate) + " > limit " +
                        std::to_string(max_error);
      return false;
    }
    summary.accepted = true;
    x0 = std::move(x);
    s0 = std::move(s);
    hist0 = std::move(hist);
    dt1_0 = dt1;
    dt2_0 = dt2;
    return true;
  }
  return false;
}

}  // namespace otfp::detail
