#include "otfp/functional.hpp"

#include <omp.h>

#include <algorithm>
#include <cmath>

#include "pair_kernels.hpp"

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
                               const std::vector<Vec3>& x_ref, const std::vector<double>& s_ref, Gradient* grad,
                               const std::vector<double>& weights) const {
  const std::size_t n = x.size();
  const bool widths = grad && grad->s.size() == n;
  const bool weighted = !weights.empty();
  double sum = 0.0;
  for (std::size_t p = 0; p < n; ++p) {
    const Vec3 dx = x[p] - x_ref[p];
    const double ds = s[p] - s_ref[p];
    const double w = (weighted ? weights[p] * m[p] : m[p]) / dt_;
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

// Assembles dE/dx_r and dE/ds_r from the sweep results:
//   dE/dx_r = kappa (m_r/rho_r) grad rho(x_r)                      (term 1)
//           + 2 kappa beta_r sum_p (m_p/rho_p) w_pr (x_p - x_r)      (term 2)
//   dE/dbeta_r = kappa sum_p (m_p/rho_p) w_pr (d/(2 beta_r) - |x_p - x_r|^2), ds/dbeta = -s^3/2.
inline void assemble(double kappa, double half_d, double a_r, double beta_r, const Vec3& grad_rho, const Vec3& gathered,
                     double wsum, double wr2, Vec3& gx, double* gs) {
  gx = kappa * (a_r * grad_rho + 2.0 * beta_r * gathered);
  if (gs) *gs = kappa * (half_d / beta_r * wsum - wr2) * (-2.0 * beta_r * std::sqrt(beta_r));
}

}  // namespace

void EntropyTerm::prepare(const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m) {
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
}

double EntropyTerm::value_from_density(const std::vector<double>& m, std::size_t rows) const {
  // Summed in index order: independent of the thread count.
  double value = 0.0;
  for (std::size_t p = 0; p < rows; ++p) value += m[p] * std::log(rho_[p] / rho_ref_);
  return kappa_ * value;
}

double EntropyTerm::evaluate(const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m,
                             const NeighborList& list, Gradient* grad, std::size_t rows) {
  require(list.built() && list.size() == x.size(), "neighbour list", static_cast<double>(list.size()),
          "must be built for the current particles");
  const std::size_t n = x.size();
  const std::size_t nr = std::min(rows, n);  // blobs with an entropy term; the rest are images
  prepare(x, s, m);
  // Equal widths (the common case) let a neighbour's record carry mc instead
  // of beta: one load per neighbour in the density sweep.
  const bool uniform = n > 0 && std::all_of(beta_.begin(), beta_.end(), [&](double v) { return v == beta_[0]; });
  double* xyzb = detail::packed_records(xyzb_, n);
  for (std::size_t p = 0; p < n; ++p) {
    xyzb[4 * p] = x[p][0];
    xyzb[4 * p + 1] = x[p][1];
    xyzb[4 * p + 2] = x[p][2];
    xyzb[4 * p + 3] = uniform ? mc_[p] : beta_[p];
  }
  const detail::BlobArrays b{xyzb, mc_.data(), uniform ? beta_[0] : 0.0, n};
  detail::MinimumImage mi;
  const Periodicity& per = list.periodicity();
  for (int k = 0; k < 3; ++k) {
    if (per.period[k] > 0.0) {
      mi.period[k] = per.period[k];
      mi.inv_period[k] = 1.0 / per.period[k];
      mi.any = true;
    }
  }
  const std::uint32_t* off = list.offsets().data();
  const std::uint32_t* idx = list.indices().data();
  t0_.resize(n);
  t1_.resize(n);
  t2_.resize(n);
  t3_.resize(n);
  t4_.resize(n);
  // Rows are split into fixed chunks; each row writes only its own outputs.
  constexpr std::size_t kChunk = 256;
  const std::size_t nchunks_rho = (nr + kChunk - 1) / kChunk;
#pragma omp parallel for schedule(dynamic, 4)
  for (std::size_t c = 0; c < nchunks_rho; ++c)
    detail::density_rows(c * kChunk, std::min(nr, (c + 1) * kChunk), off, idx, b, mi, rho_.data(), t0_.data(),
                         t1_.data(), t2_.data());
  for (std::size_t p = 0; p < nr; ++p) grad_rho_[p] = Vec3(t0_[p], t1_[p], t2_[p]);
  for (std::size_t p = nr; p < n; ++p) {  // images: no density of their own is needed
    rho_[p] = 0.0;
    grad_rho_[p].setZero();
  }
  pair_evals_ += off[nr] - off[0];
  const double value = value_from_density(m, nr);
  if (!grad) return value;

  a_.resize(n);
  double* xyza = detail::packed_records(xyza_, n);
  for (std::size_t p = 0; p < n; ++p) {
    a_[p] = p < nr ? m[p] / rho_[p] : 0.0;
    xyza[4 * p] = x[p][0];
    xyza[4 * p + 1] = x[p][1];
    xyza[4 * p + 2] = x[p][2];
    xyza[4 * p + 3] = a_[p];
  }
  std::vector<double>& wsum = t3_;
  std::vector<double>& wr2 = t4_;
  const std::size_t nchunks = (n + kChunk - 1) / kChunk;
#pragma omp parallel for schedule(dynamic, 4)
  for (std::size_t c = 0; c < nchunks; ++c)
    detail::gather_rows(c * kChunk, std::min(n, (c + 1) * kChunk), off, idx, b, xyza, mi, t0_.data(),
                        t1_.data(), t2_.data(), wsum.data(), wr2.data());
  pair_evals_ += list.num_entries();
  const bool widths = grad->s.size() == n;
  const double half_d = 0.5 * dim_;
  for (std::size_t r = 0; r < n; ++r)
    assemble(kappa_, half_d, a_[r], beta_[r], grad_rho_[r], Vec3(t0_[r], t1_[r], t2_[r]), wsum[r], wr2[r],
             grad->x[r], widths ? &grad->s[r] : nullptr);
  return value;
}

double EntropyTerm::evaluate_all_pairs(const std::vector<Vec3>& x, const std::vector<double>& s,
                                       const std::vector<double>& m, const Periodicity& per, Gradient* grad,
                                       std::size_t rows) {
  // Plain O(n^2) loops with std::exp: the reference the accelerated path is tested against.
  const std::size_t n = x.size();
  const std::size_t nr = std::min(rows, n);
  prepare(x, s, m);
  for (std::size_t p = 0; p < n; ++p) {
    rho_[p] = 0.0;
    grad_rho_[p].setZero();
    if (p >= nr) continue;
    double rho = 0.0;
    Vec3 g = Vec3::Zero();
    for (std::size_t q = 0; q < n; ++q) {
      const Vec3 d = per.displacement(x[p], x[q]);
      const double w = mc_[q] * std::exp(-beta_[q] * d.squaredNorm());
      rho += w;
      g += -2.0 * beta_[q] * w * d;
    }
    rho_[p] = rho;
    grad_rho_[p] = g;
  }
  pair_evals_ += nr * n;
  const double value = value_from_density(m, nr);
  if (!grad) return value;
  const bool widths = grad->s.size() == n;
  const double half_d = 0.5 * dim_;
  for (std::size_t r = 0; r < n; ++r) {
    Vec3 gathered = Vec3::Zero();
    double wsum = 0.0, wr2 = 0.0;
    for (std::size_t p = 0; p < nr; ++p) {
      const Vec3 d = per.displacement(x[p], x[r]);
      const double w = m[p] / rho_[p] * mc_[r] * std::exp(-beta_[r] * d.squaredNorm());
      gathered += w * d;
      wsum += w;
      wr2 += w * d.squaredNorm();
    }
    assemble(kappa_, half_d, r < nr ? m[r] / rho_[r] : 0.0, beta_[r], grad_rho_[r], gathered, wsum, wr2, grad->x[r],
             widths ? &grad->s[r] : nullptr);
  }
  pair_evals_ += nr * n;
  return value;
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
  require(std::isfinite(width_skin) && width_skin >= 0.0, "width_skin", width_skin, "must be finite and >= 0");
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
                               const std::vector<double>& m, std::vector<double> transport_weights) {
  require(x_ref.size() == s_ref.size() && x_ref.size() == m.size(), "reference sizes",
          static_cast<double>(x_ref.size()), "x, s and m must have the same length");
  require(transport_weights.empty() || transport_weights.size() == m.size(), "transport_weights size",
          static_cast<double>(transport_weights.size()), "must be 0 or the number of particles");
  for (double a : transport_weights)
    require(std::isfinite(a) && a > 0.0, "transport weight", a, "must be finite and > 0");
  x_ref_ = x_ref;
  s_ref_ = s_ref;
  m_ = m;
  weights_ = std::move(transport_weights);
}

namespace {
void add_into(Gradient& acc, const Gradient& g) {
  for (std::size_t p = 0; p < acc.x.size(); ++p) acc.x[p] += g.x[p];
  if (acc.s.size() == g.s.size())
    for (std::size_t p = 0; p < acc.s.size(); ++p) acc.s[p] += g.s[p];
}
}  // namespace

void Functional::set_images(WallImages images) {
  require(!images.active() || !per_.any(), "images", "walls", "cannot be combined with a periodic box");
  images_ = std::move(images);
  images_built_for_ = static_cast<std::size_t>(-1);  // the next evaluation rebuilds
}

void Functional::extend(const std::vector<Vec3>& x, const std::vector<double>& s) {
  const std::size_t n = x.size();
  images_.positions(x, grad_image_);  // grad_image_ as scratch for the image positions
  const auto& src = images_.sources();
  const std::size_t ni = src.size();
  x_ext_.resize(n + ni);
  s_ext_.resize(n + ni);
  m_ext_.resize(n + ni);
  std::copy(x.begin(), x.end(), x_ext_.begin());
  std::copy(s.begin(), s.end(), s_ext_.begin());
  std::copy(m_.begin(), m_.end(), m_ext_.begin());
  for (std::size_t i = 0; i < ni; ++i) {
    x_ext_[n + i] = grad_image_[i];
    s_ext_[n + i] = s[src[i]];
    m_ext_[n + i] = m_[src[i]];
  }
}

void Functional::select_images(const std::vector<Vec3>& x, const std::vector<double>& s) {
  // Each particle is mirrored across the walls within its list radius, with
  // the skin the list is about to use (NeighborList::build's rule).
  // (With the width skin, the list's widths.)
  const NeighborOptions& no = options_.neighbor;
  const std::vector<double>& sl = list_widths(s);
  const double s_min = sl.empty() ? 1.0 : *std::min_element(sl.begin(), sl.end());
  const double skin = no.skin >= 0.0 ? no.skin : no.skin_factor * s_min;
  // r_c(s) = s sqrt(log(1/tol)) (cutoff_radius), the factor taken once.
  const double rc_per_s = cutoff_radius(1.0, no.kernel_tolerance);
  reach_.resize(x.size());
  for (std::size_t p = 0; p < x.size(); ++p) reach_[p] = sl[p] * rc_per_s + skin;
  images_.select(x, reach_);
  extend(x, s);
}

const std::vector<double>& Functional::list_widths(const std::vector<double>& s) {
  if (!inflates_widths()) return s;
  s_list_.resize(s.size());
  const double f = 1.0 + options_.width_skin;
  for (std::size_t p = 0; p < s.size(); ++p) s_list_[p] = f * s[p];
  return s_list_;
}

void Functional::rebuild_list(const std::vector<Vec3>& x, const std::vector<double>& s) {
  // The list is built for the (possibly inflated) widths; needs_rebuild()
  // compares the actual widths with those, so growth within the margin is free.
  if (!images_.active()) {
    list_.build(x, list_widths(s), per_);
    return;
  }
  require(x.size() == m_.size() && s.size() == m_.size(), "configuration size", static_cast<double>(x.size()),
          "must match the reference set by set_reference()");
  select_images(x, s);
  list_.build(x_ext_, list_widths(s_ext_), per_);
  images_built_for_ = x.size();
}

void Functional::ensure_list(const std::vector<Vec3>& x, const std::vector<double>& s) {
  if (!images_.active()) {
    if (list_.needs_rebuild(x, s)) list_.build(x, list_widths(s), per_);
    return;
  }
  if (images_built_for_ == x.size() && list_.built()) {
    extend(x, s);
    if (!list_.needs_rebuild(x_ext_, s_ext_)) return;
  }
  rebuild_list(x, s);
}

FunctionalParts Functional::evaluate(const std::vector<Vec3>& x, const std::vector<double>& s, Gradient* grad) {
  return evaluate_impl(x, s, grad, false);
}

FunctionalParts Functional::evaluate_all_pairs(const std::vector<Vec3>& x, const std::vector<double>& s,
                                               Gradient* grad) {
  return evaluate_impl(x, s, grad, true);
}

FunctionalParts Functional::evaluate_impl(const std::vector<Vec3>& x, const std::vector<double>& s, Gradient* grad,
                                          bool all_pairs) {
  require(x.size() == m_.size() && s.size() == m_.size(), "configuration size", static_cast<double>(x.size()),
          "must match the reference set by set_reference()");
  const std::size_t n = x.size();
  const bool images = images_.active();
  if (!all_pairs) {
    ensure_list(x, s);
  } else if (images) {
    // The same image set as a list build would choose, summed over all pairs.
    select_images(x, s);
    images_built_for_ = static_cast<std::size_t>(-1);  // the list no longer matches the selection
  }
  FunctionalParts parts;
  const bool widths = grad && options_.optimise_widths;
  const std::size_t n_ext = images ? x_ext_.size() : n;
  if (grad) {
    grad->resize(n, widths);
    scratch_.resize(n_ext, widths);
  }
  parts.transport = transport_.evaluate(x, s, m_, x_ref_, s_ref_, grad, weights_);
  Gradient* g = grad ? &scratch_ : nullptr;
  if (!images)
    parts.entropy = all_pairs ? entropy_.evaluate_all_pairs(x, s, m_, per_, g) : entropy_.evaluate(x, s, m_, list_, g);
  else
    parts.entropy = all_pairs ? entropy_.evaluate_all_pairs(x_ext_, s_ext_, m_ext_, per_, g, n)
                              : entropy_.evaluate(x_ext_, s_ext_, m_ext_, list_, g, n);
  if (grad) {
    for (std::size_t p = 0; p < n; ++p) grad->x[p] += scratch_.x[p];
    if (widths)
      for (std::size_t p = 0; p < n; ++p) grad->s[p] += scratch_.s[p];
    if (images) {
      // Images move with their sources (chain rule through the reflection) and share their widths.
      const auto& src = images_.sources();
      grad_image_.assign(scratch_.x.begin() + static_cast<std::ptrdiff_t>(n), scratch_.x.end());
      images_.pull_back(x, grad_image_, grad->x);
      if (widths)
        for (std::size_t i = 0; i < src.size(); ++i) grad->s[src[i]] += scratch_.s[n + i];
    }
    scratch_.resize(n, false);
    scratch_.s.clear();  // the barrier has no width gradient
  }
  parts.barrier = barrier_.evaluate(x, m_, grad ? &scratch_ : nullptr);
  if (grad) add_into(*grad, scratch_);
  return parts;
}

void Functional::explicit_velocity(const std::vector<Vec3>& x, const std::vector<double>& s, std::vector<Vec3>& v) {
  ensure_list(x, s);
  if (images_.active())
    entropy_.evaluate(x_ext_, s_ext_, m_ext_, list_, nullptr, x.size());
  else
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
