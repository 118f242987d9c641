#pragma once
// The papers' parameter rules, eqs. (36)-(40) of the 2025 paper.
#include <cstddef>

#include "otfp/enums.hpp"

namespace otfp {

// How the blob width follows the spacing. The papers keep beta dr^2 fixed
// (q = 1). With q != 1 the width is
//   s = s_rule(dr) (dr / dr_ref)^(q - 1),   s_rule(dr) = (beta_factor / dr^2)^(-1/2) = dr / sqrt(beta_factor),
// where dr_ref is the spacing the same rule gives at n = reference_n: the
// width equals the papers' at n = reference_n and shrinks like dr^q with n
// (q < 1: more slowly than the spacing, as blob-method theory asks).
struct WidthScaling {
  double exponent = 1.0;          // q, in (0, 2]
  std::size_t reference_n = 400;  // >= 1

  void validate() const;  // throws InvalidArgument naming the field
};

// Mean spacing of n particles in |Omega| by the rule: (|Omega|/n)^(1/d), or
// the radius of a ball of volume |Omega|/n (d = 3).
double spacing(double volume, std::size_t n, int dim, SpacingRule rule = SpacingRule::Cube);

// The width s of the rule above; exponent = 1 returns s_rule(dr) exactly as
// paper_parameters_from_spacing() computes it (dr_ref is then not used).
double scaled_width(double dr, double beta_factor, double exponent, double dr_ref);

struct PaperParameters {
  double dr = 0.0;           // (37) mean particle spacing (|Omega|/n)^(1/d)
  double beta = 0.0;         // (36) beta = beta_factor / dr^2 (q = 1), otherwise 1 / width_s^2
  double width_s = 0.0;      // s = beta^-1/2 (scaled_width() when q != 1)
  double width_exponent = 1.0;  // q of WidthScaling
  double dr_ref = 0.0;       // spacing at WidthScaling::reference_n (0 from paper_parameters_from_spacing)
  double layer_b = 0.0;      // (38) boundary-layer thickness b = sqrt(L dr)
  double dt_explicit = 0.0;  // (39) explicit limit dr^2 / kappa
  double barrier_C = 0.0;    // (40) C = 1 / dt_explicit
};

// volume |Omega|, particle count n, dimension d, specimen length L, diffusivity
// kappa, and c in beta = c / dr^2 (the sphere and box examples use c = 2, the pipe c = 1).
// `width` sets the width exponent (default: the papers' fixed beta dr^2).
PaperParameters paper_parameters(double volume, std::size_t n, int dim, double length_L, double kappa,
                                 double beta_factor = 2.0, SpacingRule rule = SpacingRule::Cube,
                                 const WidthScaling& width = {});
// The same rules from a given spacing dr.
PaperParameters paper_parameters_from_spacing(double dr, double length_L, double kappa, double beta_factor = 2.0);

}  // namespace otfp
