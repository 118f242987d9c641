#include "otfp/functional.hpp"

#include <omp.h>

#include <cmath>

#include "fast_exp.hpp"

namespace otfp {

double width_metric_coefficient(WidthMetric metric, int dim) {
  return metric == WidthMetric::AsPrinted ? 1.0 : 0.5 * dim;
}

void Gradient::resize(std::size_t n, bool with_widths) {
  x.resize(n);
  s.resize(with_widths ? n : 0);
}

void Gradient::set_zero() {
  for (auto& g : x) g.setZero();
  std::fill(s.begin(), s.end(), 0.0);
}

// ---------------------------------------------------------------- Transport

TransportTerm::TransportTerm(double dt, double c_w) : dt_(dt), c_w_(c_w) {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(std::isfinite(c_w) && c_w > 0.0, "c_w", c_w, "must be finite and > 0");
}

double TransportTerm::evaluate(const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m,
                               const std::vector<Vec3>& x_ref, const std::vector<double>& s_ref, Gradient* grad) const {
  const std::size_t n = x.size();
  const bool widths = grad && grad->s.size() == n;
  double sum = 0.0;
  for (std::size_t p = 0; p < n; ++p) {
    const Vec3 dx = x[p] - x_ref[p];
    const double ds = s[p] - s_ref[p];
    const double w = m[p] / dt_;
    sum += 0.5 * w * (dx.squaredNorm() + c_w_ * ds * ds);
    if (grad) {
      grad->x[p] = w * dx;
      if (widths) grad->s[p] = w * c_w_ * ds;
    }
  }
  return sum;
}

// ------------------------------------------------------------------ Entropy

EntropyTerm::EntropyTerm(int dim, double kappa, double rho_ref) : dim_(dim), kappa_(kappa), rho_ref_(rho_ref) {
  require(dim >= 1 && dim <= 3, "dim", dim, "must be 1, 2 or 3");
  require(std::isfinite(kappa) && kappa > 0.0, "kappa", kappa, "must be finite and > 0");
  require(std::isfinite(rho_ref) && rho_ref > 0.0, "rho_ref", rho_ref, "must be finite and > 0");
}

namespace {

// Rows of a neighbour list.
struct ListRows {
  const std::uint32_t* off;
  const std::uint32_t* idx;
  std::uint32_t begin(std::size_t p) const { return off[p]; }
  std::uint32_t end(std::size_t p) const { return off[p + 1]; }
  std::uint32_t at(std::uint32_t k) const { return idx[k]; }
  bool skip(std::size_t, std::uint32_t) const { return false; }
};

// Every other particle: the O(n^2) reference.
struct AllRows {
  std::uint32_t n;
  std::uint32_t begin(std::size_t) const { return 0; }
  std::uint32_t end(std::size_t) const { return n; }
  std::uint32_t at(std::uint32_t k) const { return k; }
  bool skip(std::size_t p, std::uint32_t q) const { return p == q; }
};

}  // namespace

template <class Rows>
double EntropyTerm::evaluate_impl(const std::vector<Vec3>& x, const std::vector<double>& s,
                                  const std::vector<double>& m, const Periodicity& per, const Rows& rows,
                                  Gradient* grad) {
  const std::size_t n = x.size();
  rho_.resize(n);
  grad_rho_.resize(n);
  beta_.resize(n);
  mc_.resize(n);
  const double half_d = 0.5 * dim_;
  for (std::size_t q = 0; q < n; ++q) {
    beta_[q] = 1.0 / (s[q] * s[q]);
    mc_[q] = m[q] * std::pow(beta_[q] / M_PI, half_d);
  }
  const bool periodic = per.any();
  const bool want_grad = grad != nullptr;
  const bool widths = want_grad && grad->s.size() == n;
  std::uint64_t evals = 0;

  // Sweep 1: rho_p = sum_q w_q(x_p) (q = p included) and grad rho(x_p).
#pragma omp parallel for schedule(static) reduction(+ : evals)
  for (std::size_t p = 0; p < n; ++p) {
    const Vec3 xp = x[p];
    double rho = mc_[p];
    double gx = 0.0, gy = 0.0, gz = 0.0;
    const std::uint32_t b = rows.begin(p), e = rows.end(p);
    for (std::uint32_t k = b; k < e; ++k) {
      const std::uint32_t q = rows.at(k);
      if (rows.skip(p, q)) continue;
      const Vec3 d = periodic ? per.displacement(xp, x[q]) : Vec3(xp - x[q]);
      const double r2 = d.squaredNorm();
      const double w = mc_[q] * detail::exp_nonpositive(-beta_[q] * r2);
      rho += w;
      const double c = -2.0 * beta_[q] * w;
      gx += c * d[0];
      gy += c * d[1];
      gz += c * d[2];
    }
    evals += e - b;
    rho_[p] = rho;
    grad_rho_[p] = Vec3(gx, gy, gz);
  }

  // Value: per-particle terms summed in index order (thread-count independent).
  double value = 0.0;
  for (std::size_t p = 0; p < n; ++p) value += m[p] * std::log(rho_[p] / rho_ref_);
  value *= kappa_;

  if (want_grad) {
    // Sweep 2, for each r: a_r = sum_p (m_p/rho_p) w_r(x_p) (x_p - x_r) and, for the
    // widths, sum_p (m_p/rho_p) w_r(x_p) (d/(2 beta_r) - |x_p - x_r|^2) (p = r included).
    a_.resize(n);
    for (std::size_t p = 0; p < n; ++p) a_[p] = m[p] / rho_[p];
#pragma omp parallel for schedule(static) reduction(+ : evals)
    for (std::size_t r = 0; r < n; ++r) {
      const Vec3 xr = x[r];
      const double br = beta_[r];
      double ax = 0.0, ay = 0.0, az = 0.0;
      double wsum = a_[r] * mc_[r];  // self term's weight (its displacement is zero)
      double w_r2 = 0.0;
      const std::uint32_t b = rows.begin(r), e = rows.end(r);
      for (std::uint32_t k = b; k < e; ++k) {
        const std::uint32_t p = rows.at(k);
        if (rows.skip(r, p)) continue;
        const Vec3 d = periodic ? per.displacement(x[p], xr) : Vec3(x[p] - xr);
        const double r2 = d.squaredNorm();
        const double w = a_[p] * mc_[r] * detail::exp_nonpositive(-br * r2);
        ax += w * d[0];
        ay += w * d[1];
        az += w * d[2];
        wsum += w;
        w_r2 += w * r2;
      }
      evals += e - b;
      // dE/dx_r = -2 kappa (m_r/rho_r) sum_q beta_q w_rq (x_r - x_q)   (term 1)
      //           + 2 kappa beta_r sum_p (m_p/rho_p) w_pr (x_p - x_r)    (term 2)
      grad->x[r] = kappa_ * (a_[r] * grad_rho_[r] + 2.0 * br * Vec3(ax, ay, az));
      if (widths) {
        // dE/dbeta_r = kappa sum_p (m_p/rho_p) w_pr (d/(2 beta_r) - |x_p - x_r|^2); ds/dbeta = -s^3/2.
        const double dE_dbeta = kappa_ * (half_d / br * wsum - w_r2);
        grad->s[r] = dE_dbeta * (-2.0 * br * std::sqrt(br));
      }
    }
  }
  pair_evals_ += evals;
  return value;
}

double EntropyTerm::evaluate(const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m,
                             const NeighborList& list, Gradient* grad) {
  require(list.built() && list.size() == x.size(), "neighbour list", static_cast<double>(list.size()),
          "must be built for the current particles");
  return evaluate_impl(x, s, m, list.periodicity(), ListRows{list.offsets().data(), list.indices().data()}, grad);
}

double EntropyTerm::evaluate_all_pairs(const std::vector<Vec3>& x, const std::vector<double>& s,
                                       const std::vector<double>& m, const Periodicity& periodicity, Gradient* grad) {
  return evaluate_impl(x, s, m, periodicity, AllRows{static_cast<std::uint32_t>(x.size())}, grad);
}

// ------------------------------------------------------------------ Barrier

BarrierTerm::BarrierTerm(Barrier barrier) : barrier_(std::move(barrier)) {}

double BarrierTerm::evaluate(const std::vector<Vec3>& x, const std::vector<double>& m, Gradient* grad) const {
  const std::size_t n = x.size();
  if (!barrier_.active()) {
    if (grad)
      for (auto& g : grad->x) g.setZero();
    return 0.0;
  }
  std::vector<double> val(n);
#pragma omp parallel for schedule(static)
  for (std::size_t p = 0; p < n; ++p) {
    Vec3 g;
    val[p] = m[p] * barrier_.value(x[p], grad ? &g : nullptr);
    if (grad) grad->x[p] = m[p] * g;
  }
  double sum = 0.0;
  for (double v : val) sum += v;
  return sum;
}

// --------------------------------------------------------------- Functional

void FunctionalOptions::validate() const {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(std::isfinite(kappa) && kappa > 0.0, "kappa", kappa, "must be finite and > 0");
  require(std::isfinite(rho_ref) && rho_ref > 0.0, "rho_ref", rho_ref, "must be finite and > 0");
  neighbor.validate();
}

Functional::Functional(int dim, FunctionalOptions options, Barrier barrier, Periodicity periodicity)
    : dim_(dim),
      options_((options.validate(), options)),
      transport_(options.dt, width_metric_coefficient(options.width_metric, dim)),
      entropy_(dim, options.kappa, options.rho_ref),
      barrier_(std::move(barrier)),
      per_(periodicity),
      list_(options.neighbor) {
  per_.dim = dim;
}

void Functional::set_dt(double dt) {
  options_.dt = dt;
  transport_ = TransportTerm(dt, width_metric_coefficient(options_.width_metric, dim_));
}

void Functional::set_reference(const std::vector<Vec3>& x_ref, const std::vector<double>& s_ref,
                               const std::vector<double>& m) {
  require(x_ref.size() == s_ref.size() && x_ref.size() == m.size(), "reference sizes",
          static_cast<double>(x_ref.size()), "x, s and m must have the same length");
  x_ref_ = x_ref;
  s_ref_ = s_ref;
  m_ = m;
}

namespace {
void add_into(Gradient& acc, const Gradient& g) {
  for (std::size_t p = 0; p < acc.x.size(); ++p) acc.x[p] += g.x[p];
  if (acc.s.size() == g.s.size())
    for (std::size_t p = 0; p < acc.s.size(); ++p) acc.s[p] += g.s[p];
}
}  // namespace

FunctionalParts Functional::evaluate(const std::vector<Vec3>& x, const std::vector<double>& s, Gradient* grad) {
  require(x.size() == m_.size() && s.size() == m_.size(), "configuration size", static_cast<double>(x.size()),
          "must match the reference set by set_reference()");
  if (list_.needs_rebuild(x, s)) list_.build(x, s, per_);
  FunctionalParts parts;
  const bool widths = grad && options_.optimise_widths;
  if (grad) {
    grad->resize(x.size(), widths);
    scratch_.resize(x.size(), widths);
  }
  parts.transport = transport_.evaluate(x, s, m_, x_ref_, s_ref_, grad);
  parts.entropy = entropy_.evaluate(x, s, m_, list_, grad ? &scratch_ : nullptr);
  if (grad) add_into(*grad, scratch_);
  if (grad) scratch_.s.clear();  // the barrier has no width gradient
  parts.barrier = barrier_.evaluate(x, m_, grad ? &scratch_ : nullptr);
  if (grad) add_into(*grad, scratch_);
  return parts;
}

FunctionalParts Functional::evaluate_all_pairs(const std::vector<Vec3>& x, const std::vector<double>& s,
                                               Gradient* grad) {
  FunctionalParts parts;
  const bool widths = grad && options_.optimise_widths;
  Gradient g2;
  if (grad) {
    grad->resize(x.size(), widths);
    g2.resize(x.size(), widths);
  }
  parts.transport = transport_.evaluate(x, s, m_, x_ref_, s_ref_, grad);
  parts.entropy = entropy_.evaluate_all_pairs(x, s, m_, per_, grad ? &g2 : nullptr);
  if (grad) add_into(*grad, g2);
  if (grad) g2.s.clear();
  parts.barrier = barrier_.evaluate(x, m_, grad ? &g2 : nullptr);
  if (grad) add_into(*grad, g2);
  return parts;
}

void Functional::explicit_velocity(const std::vector<Vec3>& x, const std::vector<double>& s, std::vector<Vec3>& v) {
  if (list_.needs_rebuild(x, s)) list_.build(x, s, per_);
  entropy_.evaluate(x, s, m_, list_, nullptr);
  const auto& rho = entropy_.density();
  const auto& grho = entropy_.density_gradient();
  v.resize(x.size());
  const double kappa = options_.kappa;
#pragma omp parallel for schedule(static)
  for (std::size_t r = 0; r < x.size(); ++r) {
    Vec3 gpsi;
    barrier_.barrier().value(x[r], &gpsi);
    v[r] = -(kappa * grho[r] / rho[r] + gpsi);
  }
}

}  // namespace otfp
