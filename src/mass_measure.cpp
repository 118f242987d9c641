#include "otfp/mass_measure.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <optional>
#include <vector>

namespace otfp {

namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kSqrtPi = 1.7724538509055160273;  // sqrt(pi)

// Gauss rule from the symmetric tridiagonal Jacobi matrix of a family of
// orthogonal polynomials (Golub-Welsch): nodes are its eigenvalues, weights
// mu0 times the squared first components of its eigenvectors.
struct Rule {
  std::vector<double> x, w;
};

Rule golub_welsch(int n, const std::vector<double>& offdiag, double mu0) {
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i + 1 < n; ++i) J(i, i + 1) = J(i + 1, i) = offdiag[static_cast<std::size_t>(i)];
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(J);
  Rule r;
  for (int i = 0; i < n; ++i) {
    r.x.push_back(es.eigenvalues()[i]);
    const double v0 = es.eigenvectors()(0, i);
    r.w.push_back(mu0 * v0 * v0);
  }
  return r;
}

// Gauss-Legendre on [-1, 1]: off-diagonal k / sqrt(4 k^2 - 1), mu0 = 2.
const Rule& legendre16() {
  static const Rule rule = [] {
    const int n = 16;
    std::vector<double> b;
    for (int k = 1; k < n; ++k) b.push_back(k / std::sqrt(4.0 * k * k - 1.0));
    return golub_welsch(n, b, 2.0);
  }();
  return rule;
}

// Gauss-Hermite for the weight exp(-z^2) / sqrt(pi) (a probability measure):
// off-diagonal sqrt(k/2), mu0 = 1.
Rule hermite(int n) {
  std::vector<double> b;
  for (int k = 1; k < n; ++k) b.push_back(std::sqrt(0.5 * k));
  return golub_welsch(n, b, 1.0);
}

const Rule& hermite_cached(int n) {
  static const std::vector<Rule> rules = [] {
    std::vector<Rule> v(65);
    for (int k = 1; k <= 64; ++k) v[static_cast<std::size_t>(k)] = hermite(k);
    return v;
  }();
  return rules[static_cast<std::size_t>(n)];
}

double clamp01(double p) { return std::min(1.0, std::max(0.0, p)); }

// Half-width of the disc quadrature window in units of s: exp(-49) ~ 5e-22.
constexpr double kDiscWindow = 7.0;

double fraction_closed_form(const DomainShape& sh, const Vec3& x, double s) {
  switch (sh.kind) {
    case DomainShape::Kind::Box:
      return gaussian_in_box(sh.dim, x, s, sh.lo, sh.hi);
    case DomainShape::Kind::Ball: {
      if (sh.dim == 1) return gaussian_in_interval(x[0], s, sh.center[0] - sh.radius, sh.center[0] + sh.radius);
      double r2 = 0.0;
      for (int k = 0; k < sh.dim; ++k) r2 += (x[k] - sh.center[k]) * (x[k] - sh.center[k]);
      return gaussian_in_ball(sh.dim, std::sqrt(r2), s, sh.radius);
    }
    case DomainShape::Kind::Cylinder:
      return gaussian_in_cylinder(x, s, sh.end_a, sh.end_b, sh.radius);
  }
  return 0.0;
}

// Unit outward normal at x: from the closest point where |sd| is not tiny,
// otherwise the central-difference gradient of sd.
Vec3 outward_normal(const Domain& dom, const Vec3& x, const BoundaryQuery& q, double s) {
  const int d = dom.dim();
  if (std::abs(q.signed_distance) > 1e-9 * s) {
    Vec3 n = (x - q.closest_point) / q.signed_distance;
    for (int k = d; k < 3; ++k) n[k] = 0.0;
    const double len = n.norm();
    if (len > 0.5) return n / len;
  }
  Vec3 g = Vec3::Zero();
  const double h = 1e-4 * s;
  for (int k = 0; k < d; ++k) {
    Vec3 e = Vec3::Zero();
    e[k] = h;
    g[k] = (dom.signed_distance(x + e) - dom.signed_distance(x - e)) / (2.0 * h);
  }
  const double len = g.norm();
  return len > 0.0 ? Vec3(g / len) : Vec3(Vec3::UnitX());
}

// Standard normal-like CDF of the weight exp(-xi^2)/sqrt(pi): int_-inf^xi.
double weight_cdf(double xi) { return 0.5 * std::erfc(-xi); }

// Crossing of sd = 0 between xi = a (value ga) and b (value gb) of opposite
// inside/outside status, by the Illinois variant of regula falsi (one step on
// a plane).
double crossing_between(const Domain& dom, const Vec3& p, const Vec3& n, double s, double a, double ga, double b,
                        double gb) {
  int side = 0;
  for (int it = 0; it < 100 && b - a > 1e-13; ++it) {
    const double c = (a * gb - b * ga) / (gb - ga);
    const double mid = std::isfinite(c) && c > a && c < b ? c : 0.5 * (a + b);
    const double gc = dom.signed_distance(p + (s * mid) * n);
    if (std::abs(gc) <= 1e-14 * s) return mid;
    if ((gc <= 0.0) == (ga <= 0.0)) {
      a = mid;
      ga = gc;
      if (side == -1) gb *= 0.5;
      side = -1;
    } else {
      b = mid;
      gb = gc;
      if (side == 1) ga *= 0.5;
      side = 1;
    }
  }
  return 0.5 * (a + b);
}

// The weight of the part of the line x + s xi n, xi in [-xi_max, xi_max],
// inside Omega (the ends stand for -/+ infinity). The line is walked with
// steps of max(|sd|/s, kMinStep): sd is 1-Lipschitz, so a step of |sd| never
// jumps over the boundary; every change of status is located by
// crossing_between(). Slivers thinner than kMinStep s can be missed.
double line_fraction(const Domain& dom, const Vec3& p, const Vec3& n, double s, double xi_max) {
  constexpr double kMinStep = 0.1;
  // The whole line on one side: one query.
  const double g0 = dom.signed_distance(p);
  if (std::abs(g0) >= xi_max * s) return g0 <= 0.0 ? 1.0 : 0.0;
  double a = -xi_max;
  double ga = dom.signed_distance(p + (s * a) * n);
  bool inside = ga <= 0.0;
  double start = -std::numeric_limits<double>::infinity();  // of the current inside segment
  double sum = 0.0;
  while (a < xi_max) {
    const double b = std::min(xi_max, a + std::max(std::abs(ga) / s, kMinStep));
    const double gb = dom.signed_distance(p + (s * b) * n);
    if ((gb <= 0.0) != inside) {
      const double c = crossing_between(dom, p, n, s, a, ga, b, gb);
      if (inside) sum += weight_cdf(c) - weight_cdf(start);
      else start = c;
      inside = !inside;
    }
    a = b;
    ga = gb;
  }
  if (inside) sum += 1.0 - weight_cdf(start);
  return sum;
}

}  // namespace

void BlobMassOptions::validate() const {
  require(std::isfinite(cutoff_tolerance) && cutoff_tolerance > 0.0 && cutoff_tolerance < 1.0,
          "BlobMassOptions::cutoff_tolerance", cutoff_tolerance, "must be in (0, 1)");
  require(hermite_nodes >= 1 && hermite_nodes <= 64, "BlobMassOptions::hermite_nodes", hermite_nodes,
          "must be in [1, 64]");
}

// ---------------------------------------------------------------------------
// Closed forms

double gaussian_in_interval(double x, double s, double lo, double hi) {
  if (!(hi > lo)) return 0.0;
  const double a = (lo - x) / s, b = (hi - x) / s;
  // erf differences lose everything in the tails; erfc keeps full relative accuracy there.
  if (a >= 0.0) return clamp01(0.5 * (std::erfc(a) - std::erfc(b)));
  if (b <= 0.0) return clamp01(0.5 * (std::erfc(-b) - std::erfc(-a)));
  return clamp01(1.0 - 0.5 * (std::erfc(-a) + std::erfc(b)));
}

double gaussian_in_box(int dim, const Vec3& x, double s, const Vec3& lo, const Vec3& hi) {
  double p = 1.0;
  for (int k = 0; k < dim; ++k) p *= gaussian_in_interval(x[k], s, lo[k], hi[k]);
  return p;
}

double gaussian_in_ball(int dim, double r0, double s, double radius) {
  if (dim < 1 || dim > 3) require(false, "dim", dim, "must be 1, 2 or 3");
  r0 = std::abs(r0);
  if (dim == 1) return gaussian_in_interval(r0, s, -radius, radius);
  if (dim == 2) return gaussian_in_disc(r0, s, radius);
  // Radial density of |X| for X ~ N(mu, s^2/2 I_3), |mu| = r0:
  //   f(r) = r / (r0 s sqrt(pi)) [exp(-(r - r0)^2/s^2) - exp(-(r + r0)^2/s^2)].
  // Integrating r times a Gaussian over [0, R] (with u = r -/+ r0) gives
  //   P = (erf(A) + erf(B))/2 - s/(2 sqrt(pi) r0) (exp(-A^2) - exp(-B^2)).
  const double A = (radius - r0) / s, B = (radius + r0) / s;
  // (erf(A) + erf(B))/2 in erfc form (B >= |A|).
  const double term1 = A >= 0.0 ? 1.0 - 0.5 * (std::erfc(A) + std::erfc(B)) : 0.5 * (std::erfc(-A) - std::erfc(B));
  // exp(-A^2) - exp(-B^2) = exp(-A^2) (1 - exp(-4 R r0 / s^2)): no cancellation, no overflow.
  const double c = 4.0 * radius / (s * s);
  const double ratio = r0 > 0.0 ? -std::expm1(-c * r0) / r0 : c;  // (1 - exp(-c r0)) / r0
  const double term2 = s / (2.0 * kSqrtPi) * std::exp(-A * A) * ratio;
  return clamp01(term1 - term2);
}

double bessel_i0_scaled(double z) {
  z = std::abs(z);
  if (z <= 20.0) {
    // I0(z) = sum_k (z^2/4)^k / (k!)^2: positive terms, no cancellation.
    const double q = 0.25 * z * z;
    double term = 1.0, sum = 1.0;
    for (int k = 1; k < 200; ++k) {
      term *= q / (static_cast<double>(k) * k);
      sum += term;
      if (term < 1e-17 * sum) break;
    }
    return sum * std::exp(-z);
  }
  // exp(-z) I0(z) ~ (2 pi z)^-1/2 sum_k ((2k-1)!!)^2 / (k! (8z)^k); at z > 20 the
  // terms fall below 1e-17 long before they start to grow.
  double term = 1.0, sum = 1.0;
  for (int k = 1; k < 60; ++k) {
    const double f = 2.0 * k - 1.0;
    term *= f * f / (8.0 * k * z);
    sum += term;
    if (term < 1e-17 * sum) break;
  }
  return sum / std::sqrt(2.0 * kPi * z);
}

double gaussian_in_disc(double r0, double s, double radius) {
  r0 = std::abs(r0);
  const double lo = std::max(0.0, r0 - kDiscWindow * s);
  const double hi = std::min(radius, r0 + kDiscWindow * s);
  if (!(hi > lo)) return r0 > radius ? 0.0 : 1.0;
  if (r0 + kDiscWindow * s <= radius) return 1.0;  // the whole window is inside
  const Rule& gl = legendre16();
  const double inv_s2 = 1.0 / (s * s);
  const int panels = std::max(1, static_cast<int>(std::ceil((hi - lo) / (2.0 * s))));
  const double h = (hi - lo) / panels;
  double sum = 0.0;
  for (int j = 0; j < panels; ++j) {
    const double mid = lo + (j + 0.5) * h;
    double panel = 0.0;
    for (std::size_t i = 0; i < gl.x.size(); ++i) {
      const double r = mid + 0.5 * h * gl.x[i];
      const double u = r - r0;
      panel += gl.w[i] * 2.0 * r * inv_s2 * std::exp(-u * u * inv_s2) * bessel_i0_scaled(2.0 * r * r0 * inv_s2);
    }
    sum += 0.5 * h * panel;
  }
  return clamp01(sum);
}

double gaussian_in_cylinder(const Vec3& x, double s, const Vec3& a, const Vec3& b, double radius) {
  const Vec3 axis = b - a;
  const double len = axis.norm();
  if (!(len > 0.0)) return 0.0;
  const Vec3 u = axis / len;
  const Vec3 rel = x - a;
  const double t = rel.dot(u);
  const double rho = (rel - t * u).norm();
  const double axial = gaussian_in_interval(t, s, 0.0, len);
  return axial > 0.0 ? axial * gaussian_in_disc(rho, s, radius) : 0.0;
}

// ---------------------------------------------------------------------------
// Generic quadrature

double blob_fraction_quadrature(const Domain& domain, const Vec3& x, double width_s, const BlobMassOptions& options) {
  const double s = width_s;
  const double xi_max = std::sqrt(std::log(1.0 / options.cutoff_tolerance));
  const double rc = xi_max * s;
  const BoundaryQuery q = domain.query(x);
  const double sd = q.signed_distance;
  if (sd <= -rc) return 1.0;  // also free space and periodic boxes (sd = -inf)
  if (sd >= rc) return 0.0;
  const int d = domain.dim();
  const Vec3 n = outward_normal(domain, x, q, s);
  if (d == 1) return clamp01(line_fraction(domain, x, n, s, xi_max));
  // Tangents: d = 2 the in-plane normal to n; d = 3 two orthonormal vectors.
  Vec3 t1, t2 = Vec3::Zero();
  if (d == 2) {
    t1 = Vec3(-n[1], n[0], 0.0);
  } else {
    int e = 0;
    for (int k = 1; k < 3; ++k)
      if (std::abs(n[k]) < std::abs(n[e])) e = k;
    const Vec3 ek = Vec3::Unit(e);
    t1 = (ek - ek.dot(n) * n).normalized();
    t2 = n.cross(t1);
  }
  const Rule& gh = hermite_cached(options.hermite_nodes);
  const std::size_t m = gh.x.size();
  double sum = 0.0;
  for (std::size_t i = 0; i < m; ++i) {
    const Vec3 pi = x + (s * gh.x[i]) * t1;
    if (d == 2) {
      sum += gh.w[i] * line_fraction(domain, pi, n, s, xi_max);
      continue;
    }
    for (std::size_t j = 0; j < m; ++j) {
      const Vec3 p = pi + (s * gh.x[j]) * t2;
      sum += gh.w[i] * gh.w[j] * line_fraction(domain, p, n, s, xi_max);
    }
  }
  return clamp01(sum);
}

// ---------------------------------------------------------------------------
// Dispatch

BlobMassMethod blob_mass_method(const Domain& domain, const BlobMassOptions& options) {
  if (domain.is_periodic()) return BlobMassMethod::Total;
  if (!options.force_quadrature && domain.shape()) return BlobMassMethod::ClosedForm;
  return BlobMassMethod::Quadrature;
}

double blob_fraction_in_domain(const Domain& domain, const Vec3& x, double width_s, const BlobMassOptions& options) {
  options.validate();
  require(std::isfinite(width_s) && width_s > 0.0, "width_s", width_s, "must be finite and > 0");
  if (domain.is_periodic()) return 1.0;
  if (!options.force_quadrature)
    if (const std::optional<DomainShape> sh = domain.shape()) return fraction_closed_form(*sh, x, width_s);
  return blob_fraction_quadrature(domain, x, width_s, options);
}

std::vector<double> blob_fractions_in_domain(const Domain& domain, const ParticleSet& particles,
                                             const BlobMassOptions& options) {
  options.validate();
  const std::size_t n = particles.size();
  std::vector<double> out(n, 1.0);
  if (domain.is_periodic()) return out;
  const std::optional<DomainShape> sh = options.force_quadrature ? std::nullopt : domain.shape();
  const auto& x = particles.positions();
  const auto& s = particles.widths();
  for (std::size_t p = 0; p < n; ++p)
    if (!(std::isfinite(s[p]) && s[p] > 0.0))
      require(false, "width_s of particle " + std::to_string(p), s[p], "must be finite and > 0");
  const auto count = static_cast<std::ptrdiff_t>(n);
#pragma omp parallel for schedule(dynamic, 64) if (n > 2048)
  for (std::ptrdiff_t i = 0; i < count; ++i) {
    const auto p = static_cast<std::size_t>(i);
    out[p] = sh ? fraction_closed_form(*sh, x[p], s[p]) : blob_fraction_quadrature(domain, x[p], s[p], options);
  }
  return out;
}

double blob_mass_in_domain(const Domain& domain, const ParticleSet& particles, const BlobMassOptions& options) {
  const std::vector<double> f = blob_fractions_in_domain(domain, particles, options);
  const auto& m = particles.masses();
  double sum = 0.0;
  for (std::size_t p = 0; p < f.size(); ++p) sum += m[p] * f[p];
  return sum;
}

}  // namespace otfp
