#pragma once
// The papers' parameter rules, eqs. (36)-(40) of the 2025 paper.
#include <cstddef>

namespace otfp {

// How the mean spacing dr follows from |Omega| and n.
enum class SpacingRule {
  Cube,         // (37): dr = (|Omega|/n)^(1/d)
  SphereRadius  // Tables 1-3: radius of a ball of volume |Omega|/n, dr = (3|Omega|/(4 pi n))^(1/3) (d = 3)
};

struct PaperParameters {
  double dr = 0.0;           // (37) mean particle spacing (|Omega|/n)^(1/d)
  double beta = 0.0;         // (36) beta = beta_factor / dr^2
  double width_s = 0.0;      // s = beta^-1/2
  double layer_b = 0.0;      // (38) boundary-layer thickness b = sqrt(L dr)
  double dt_explicit = 0.0;  // (39) explicit limit dr^2 / kappa
  double barrier_C = 0.0;    // (40) C = 1 / dt_explicit
};

// volume |Omega|, particle count n, dimension d, specimen length L, diffusivity
// kappa, and c in beta = c / dr^2 (the sphere and box examples use c = 2, the pipe c = 1).
PaperParameters paper_parameters(double volume, std::size_t n, int dim, double length_L, double kappa,
                                 double beta_factor = 2.0, SpacingRule rule = SpacingRule::Cube);
// The same rules from a given spacing dr.
PaperParameters paper_parameters_from_spacing(double dr, double length_L, double kappa, double beta_factor = 2.0);

}  // namespace otfp
