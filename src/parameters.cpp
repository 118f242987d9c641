#include "otfp/parameters.hpp"

#include <cmath>

#include "otfp/types.hpp"

namespace otfp {

void WidthScaling::validate() const {
  require(std::isfinite(exponent) && exponent > 0.0 && exponent <= 2.0, "width exponent q", exponent,
          "must be in (0, 2]");
  require(reference_n >= 1, "width reference n", static_cast<double>(reference_n), "must be >= 1");
}

double spacing(double volume, std::size_t n, int dim, SpacingRule rule) {
  require(std::isfinite(volume) && volume > 0.0, "volume", volume, "must be finite and > 0");
  require(n > 0, "n", static_cast<double>(n), "must be > 0");
  require(dim >= 1 && dim <= 3, "dim", dim, "must be 1, 2 or 3");
  const double per_particle = volume / static_cast<double>(n);
  return rule == SpacingRule::Cube ? std::pow(per_particle, 1.0 / dim) : std::cbrt(3.0 * per_particle / (4.0 * M_PI));
}

double scaled_width(double dr, double beta_factor, double exponent, double dr_ref) {
  require(std::isfinite(dr) && dr > 0.0, "dr", dr, "must be finite and > 0");
  require(std::isfinite(beta_factor) && beta_factor > 0.0, "beta_factor", beta_factor, "must be finite and > 0");
  const double s_rule = 1.0 / std::sqrt(beta_factor / (dr * dr));  // as paper_parameters_from_spacing()
  if (exponent == 1.0) return s_rule;
  require(std::isfinite(dr_ref) && dr_ref > 0.0, "dr_ref", dr_ref, "must be finite and > 0");
  return s_rule * std::pow(dr / dr_ref, exponent - 1.0);
}

PaperParameters paper_parameters(double volume, std::size_t n, int dim, double length_L, double kappa,
                                 double beta_factor, SpacingRule rule, const WidthScaling& width) {
  width.validate();
  const double dr = spacing(volume, n, dim, rule);
  PaperParameters p = paper_parameters_from_spacing(dr, length_L, kappa, beta_factor);
  p.width_exponent = width.exponent;
  p.dr_ref = spacing(volume, width.reference_n, dim, rule);
  if (width.exponent != 1.0) {
    p.width_s = scaled_width(dr, beta_factor, width.exponent, p.dr_ref);
    p.beta = 1.0 / (p.width_s * p.width_s);
  }
  return p;
}

PaperParameters paper_parameters_from_spacing(double dr, double length_L, double kappa, double beta_factor) {
  require(std::isfinite(dr) && dr > 0.0, "dr", dr, "must be finite and > 0");
  require(std::isfinite(length_L) && length_L > 0.0, "length_L", length_L, "must be finite and > 0");
  require(std::isfinite(kappa) && kappa > 0.0, "kappa", kappa, "must be finite and > 0");
  require(std::isfinite(beta_factor) && beta_factor > 0.0, "beta_factor", beta_factor, "must be finite and > 0");
  PaperParameters p;
  p.dr = dr;
  p.beta = beta_factor / (p.dr * p.dr);
  p.width_s = 1.0 / std::sqrt(p.beta);
  p.layer_b = std::sqrt(length_L * p.dr);
  p.dt_explicit = p.dr * p.dr / kappa;
  p.barrier_C = 1.0 / p.dt_explicit;
  return p;
}

}  // namespace otfp
