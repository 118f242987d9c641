#pragma once
// Boundary-layer projection of Sec. 4.2 (Algorithm 1, lines 5-23) and the mass ledger.
//
// Each boundary patch A_l gets a kind. Dirichlet patches hold the density g in
// B_l^int by inserting/deleting particles there; Neumann patches exchange the
// mass of the prescribed outward flux f with B_l, carrying the fractional
// remainder to the next step (METHOD-NOTES 2.6); no-flux patches only have the
// barrier. Every inserted and removed particle is counted per patch.
#include <functional>
#include <string>
#include <vector>

#include "otfp/geometry.hpp"
#include "otfp/particles.hpp"

namespace otfp {

enum class PatchKind { NoFlux, Dirichlet, Neumann };
std::string to_string(PatchKind k);
PatchKind patch_kind_from_string(const std::string& s);  // "no_flux" | "dirichlet" | "neumann"

// Scalar boundary data g(x, t) (density) or f(x, t) (outward mass flux per unit area and time).
using BoundaryData = std::function<double(const Vec3& x, double t)>;

// How the Dirichlet target mass of B_l^int is computed (METHOD-NOTES 2.7).
enum class DirichletTarget {
  CellIntegral,  // integral of g over the cell B_l^int itself (default)
  PaperEq34      // (34): b times the integral of g over A_l (over-fills curved layers)
};

struct PatchCondition {
  int patch = 0;                       // patch id in the domain
  PatchKind kind = PatchKind::NoFlux;  // what is imposed there
  BoundaryData data;                   // g for Dirichlet, f for Neumann (outward flux; < 0 is inflow)
  bool data_is_constant = true;        // constant data lets integrals be exact (cell volume x value)
};

// Cumulative counts of one patch.
//
// Neumann bookkeeping: carry is signed (> 0: mass still to insert, < 0: mass
// still to remove) and always satisfies
//   mass_inserted - mass_removed + carry == flux_integral.
// After apply() carry is in (-m_p, m_p) (particles of mass m_p) unless B_l ran
// out of particles; then deficit = -carry (>= m_p) flags the owed outflow.
// deficit is a view of carry, not extra mass: later steps remove it once
// particles reach B_l.
struct PatchLedger {
  long inserted = 0, removed = 0;
  double mass_inserted = 0.0, mass_removed = 0.0;
  double flux_integral = 0.0;  // Neumann: integral over time of the inward mass flux (f < 0 gives > 0)
  double carry = 0.0;          // Neumann: mass owed but not yet moved (fractional remainder), in mass units
  double deficit = 0.0;        // Neumann outflow that found too few particles in B_l (mass), still owed
};

struct ProjectionOptions {
  double layer_b = 0.1;                                   // half-thickness b of the boundary layer
  DirichletTarget dirichlet_target = DirichletTarget::CellIntegral;  // target mass rule
  int quadrature_samples = 200000;                        // Monte Carlo points for non-constant g/f integrals
  void validate() const;
};

class BoundaryProjection {
 public:
  // particle_mass and width_s are used for inserted particles.
  BoundaryProjection(DomainPtr domain, std::vector<PatchCondition> conditions, ProjectionOptions options,
                     double particle_mass, double width_s);

  // Projects the predictor onto the boundary conditions at t_new = t + dt:
  // Dirichlet cells are filled or emptied to their target mass, Neumann cells
  // receive or lose the flux mass of [t, t + dt]. Inserted particles get birth time t_new.
  // Returns the counts of this call (summed over patches); its carry and
  // deficit are the Neumann state after the call, summed over patches.
  PatchLedger apply(ParticleSet& particles, double t, double dt, Rng& rng);

  const std::vector<PatchLedger>& ledger() const { return ledger_; }  // indexed by position in conditions()
  const std::vector<PatchCondition>& conditions() const { return conditions_; }
  // Patches that the barrier must inflate by b (the Dirichlet buffers B^ext).
  std::vector<int> dirichlet_patches() const;
  // Target mass of B_l^int for a Dirichlet condition at time t.
  double dirichlet_target_mass(std::size_t condition_index, double t) const;
  const ProjectionOptions& options() const { return options_; }

 private:
  DomainPtr domain_;
  std::vector<PatchCondition> conditions_;
  ProjectionOptions options_;
  double particle_mass_, width_s_;
  std::vector<PatchLedger> ledger_;
  std::vector<double> interior_cell_volume_;  // |B_l^int| per condition
  // Fixed-seed quadrature points per condition (empty for no-flux): one point
  // for data constant in space (still evaluated at each t), otherwise
  // quadrature_samples points, uniform in B_l^int for the cell integral or
  // projected onto A_l from uniform points of B_l for surface integrals.
  std::vector<std::vector<Vec3>> quadrature_points_;
};

}  // namespace otfp
