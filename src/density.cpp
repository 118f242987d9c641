#include "otfp/density.hpp"

#include <cmath>

#include "cell_grid.hpp"

namespace otfp {

namespace {
// Adds blob q's contribution at y.
inline void accumulate(const Vec3& d, double beta, double mc, double& rho, Vec3& grad) {
  const double w = mc * std::exp(-beta * d.squaredNorm());
  rho += w;
  grad += -2.0 * beta * w * d;
}
}  // namespace

void blob_density(const ParticleSet& particles, const std::vector<Vec3>& points, const Periodicity& periodicity,
                  double kernel_tolerance, std::vector<double>& rho, std::vector<Vec3>* grad) {
  blob_density(particles.dim(), particles.positions(), particles.widths(), particles.masses(), points, periodicity,
               kernel_tolerance, rho, grad);
}

void blob_density(int dim, const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m,
                  const std::vector<Vec3>& points, const Periodicity& periodicity, double kernel_tolerance,
                  std::vector<double>& rho, std::vector<Vec3>* grad) {
  require(kernel_tolerance > 0.0 && kernel_tolerance < 1.0, "kernel_tolerance", kernel_tolerance, "must be in (0, 1)");
  require(dim >= 1 && dim <= 3, "dim", dim, "must be 1, 2 or 3");
  require(s.size() == x.size() && m.size() == x.size(), "widths/masses size", static_cast<double>(s.size()),
          "must equal the number of positions");
  const double half_d = 0.5 * dim;
  if (x.empty()) {
    rho.assign(points.size(), 0.0);
    if (grad) grad->assign(points.size(), Vec3::Zero());
    return;
  }
  double s_max = 0.0;
  for (double v : s) s_max = std::max(s_max, v);
  const double radius = cutoff_radius(s_max, kernel_tolerance);
  Periodicity per = periodicity;
  per.dim = dim;
  CellGrid grid;
  grid.build(x, radius, per);
  rho.assign(points.size(), 0.0);
  if (grad) grad->assign(points.size(), Vec3::Zero());
  // Per blob once: beta_q and m_q (beta_q / pi)^(d/2).
  std::vector<double> beta(x.size()), coef(x.size());
  for (std::size_t q = 0; q < x.size(); ++q) {
    beta[q] = 1.0 / (s[q] * s[q]);
    coef[q] = m[q] * std::pow(beta[q] / M_PI, half_d);
  }
  const double reach = std::log(1.0 / kernel_tolerance);
#pragma omp parallel for schedule(static)
  for (std::size_t i = 0; i < points.size(); ++i) {
    double r = 0.0;
    Vec3 g = Vec3::Zero();
    grid.for_each_candidate(points[i], [&](std::uint32_t q) {
      const Vec3 d = per.displacement(points[i], x[q]);
      if (beta[q] * d.squaredNorm() > reach) return;  // beyond q's own cut-off
      accumulate(d, beta[q], coef[q], r, g);
    });
    rho[i] = r;
    if (grad) (*grad)[i] = g;
  }
}

void blob_density_all_pairs(const ParticleSet& particles, const std::vector<Vec3>& points,
                            const Periodicity& periodicity, std::vector<double>& rho, std::vector<Vec3>* grad) {
  const auto& x = particles.positions();
  const double half_d = 0.5 * particles.dim();
  rho.assign(points.size(), 0.0);
  if (grad) grad->assign(points.size(), Vec3::Zero());
  for (std::size_t i = 0; i < points.size(); ++i) {
    double r = 0.0;
    Vec3 g = Vec3::Zero();
    for (std::size_t q = 0; q < x.size(); ++q) {
      const double beta = particles.beta(q);
      accumulate(periodicity.displacement(points[i], x[q]), beta,
                 particles.masses()[q] * std::pow(beta / M_PI, half_d), r, g);
    }
    rho[i] = r;
    if (grad) (*grad)[i] = g;
  }
}

}  // namespace otfp
