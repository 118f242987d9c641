#pragma once
// Boundary-layer projection of Sec. 4.2 (Algorithm 1, lines 5-23) and the mass ledger.
//
// Each boundary patch A_l gets a kind. Dirichlet patches hold the density g in
// B_l^int by inserting/deleting particles there; Neumann patches exchange the
// mass of the prescribed outward flux f with B_l, carrying the fractional
// remainder to the next step (docs/method_notes.md#neumann-carry); no-flux patches only have the
// barrier. Every inserted and removed particle is counted per patch.
//
// Options beyond the papers (issue 10; the defaults are the papers' treatment):
// - NeumannOutflow::NearestParticles: an outlet whose B_l runs short removes
//   the rest of the owed outflow from the particles nearest A_l.
// - DirichletMode::Reservoir: a persistent band of thickness w outside each
//   Dirichlet patch, split into K sublayers by depth, each held at its own
//   count; particles beyond the reservoir domain are absorbed.
// - absorb_exterior (Layer mode): particles outside Omega on a Dirichlet patch
//   are absorbed instead of resting against the barrier.
#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "otfp/geometry.hpp"
#include "otfp/images.hpp"
#include "otfp/particles.hpp"
#include "otfp/enums.hpp"

namespace otfp {

// Scalar boundary data g(x, t) (density) or f(x, t) (outward mass flux per unit area and time).
using BoundaryData = std::function<double(const Vec3& x, double t)>;

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
// particles reach B_l (with NeumannOutflow::NearestParticles: once any
// particle exists).
//
// absorbed / mass_absorbed count the particles removed because they had left
// the region a Dirichlet patch controls (beyond the reservoir domain in
// Reservoir mode, outside Omega with absorb_exterior in Layer mode). They are
// a subset of removed / mass_removed, so the total mass always changes by
// mass_inserted - mass_removed.
struct PatchLedger {
  long inserted = 0, removed = 0;
  double mass_inserted = 0.0, mass_removed = 0.0;
  long absorbed = 0;           // removed particles that were beyond the controlled region (subset of removed)
  double mass_absorbed = 0.0;  // their mass (subset of mass_removed)
  double flux_integral = 0.0;  // Neumann: integral over time of the inward mass flux (f < 0 gives > 0)
  double carry = 0.0;          // Neumann: mass owed but not yet moved (fractional remainder), in mass units
  double deficit = 0.0;        // Neumann outflow that found too few particles in B_l (mass), still owed
};

struct ProjectionOptions {
  double layer_b = 0.1;                                   // half-thickness b of the boundary layer
  DirichletTarget dirichlet_target = DirichletTarget::CellIntegral;  // target mass rule
  int quadrature_samples = 200000;                        // Monte Carlo points for non-constant g/f integrals
  NeumannOutflow neumann_outflow = NeumannOutflow::Layer;  // where an outlet takes its outflow from
  int nearest_surface_points = 4096;                      // fixed-seed points on A_l for particle-to-patch distances
  DirichletMode dirichlet_mode = DirichletMode::Layer;    // papers' layer or persistent reservoir
  DomainPtr reservoir_domain;                             // Reservoir: Omega_ext = Omega extended by w over Dirichlet
  double reservoir_thickness = 0.0;                       // Reservoir: band thickness w (> 0)
  int reservoir_sublayers = 0;                            // Reservoir: sublayers K per patch (0: ~one spacing each)
  int reservoir_volume_samples = 1000000;                 // Reservoir: Monte Carlo points per patch, sublayer volumes
  ReservoirProfile reservoir_profile = ReservoirProfile::Uniform;  // Reservoir: g, or odd parity about g
  ReservoirControl reservoir_control = ReservoirControl::Quiet;    // Reservoir: tolerance band + placement, or exact counts
  double reservoir_tolerance = 1.0;    // Reservoir, Quiet: correct sublayer j when its deficit exceeds this (particles)
  int reservoir_candidates = 4;        // Reservoir, Quiet: fixed candidate points per target particle of a sublayer
  double reservoir_integral_time = 0.0;  // Reservoir, Quiet: tau of the deficit's time integral within the tolerance (0: off; setup_run: 10 w^2 / kappa)
  double reservoir_group_target = 64.0;  // Reservoir, Quiet: sublayers held together until their targets reach this (particles)
  bool absorb_exterior = false;                           // Layer: remove particles outside Omega on Dirichlet patches
  bool draw_by_id = true;  // random deletions drawn from the candidates in id order (independent of storage order and rank count); false: storage order (serial only: a distributed Simulation refuses it)
  // Throws InvalidArgument naming the field, the value and the rule. The
  // reservoir fields are checked only with dirichlet_mode = Reservoir;
  // reservoir_domain only when asked (a Simulation builds its own).
  void validate(bool require_reservoir_domain = true) const;
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
  //
  // Neumann, NearestParticles: the owed outflow is removed from random
  // particles of B_l as in the papers; what B_l cannot supply is removed from
  // the particles nearest A_l among those present at the start of the call
  // (and not removed by another patch in this call), nearest first. The
  // distance of x to A_l is |sd(x)| when the closest boundary point of x lies
  // on A_l (exact), otherwise the distance to the nearest of
  // nearest_surface_points fixed-seed points on A_l (an upper bound of the
  // true distance, off by about the point spacing squared over the distance).
  //
  // Dirichlet, Reservoir: the band of patch l is
  //   { x : sd_Omega(x) > 0, sd_ext(x) <= 0, patch_Omega(x) = l },
  // sublayer j of it the points at depth sd_Omega in (j w / K, (j + 1) w / K].
  //  1. Particles whose Omega patch is a Dirichlet patch and that lie outside
  //     the reservoir domain (sd_ext > 0) are removed and counted as absorbed
  //     (particles outside Omega at no-flux or Neumann patches are left alone).
  //  2. Quiet control (the default): the deficit of sublayer j is measured
  //     on blob masses, D_j = (T_j - M_j) / m_p, M_j the blob mass in the
  //     sublayer (tails beyond the back wall folded back) and T_j its target
  //     g |sublayer j| (uniform) or 2 g |sublayer j| - M'_j |sublayer j| /
  //     |mirror j| (odd, M'_j the blob mass in the sublayer's mirror image
  //     inside Omega; clamped to [0, 2 g |sublayer j|]). Consecutive
  //     sublayers are held as one group until their targets add up to
  //     reservoir_group_target particles. A group is left alone while its
  //     summed deficit |D| <= reservoir_tolerance; otherwise round(D)
  //     particles, shared among its sublayers by their own deficits (largest
  //     remainders), leave where the blob density (images across
  //     set_mirror_walls() included) exceeds its pointwise target most, or are
  //     put, one at a time, at the candidate point where it falls short most
  //     (reservoir_candidates fixed points per target particle). The sublayer
  //     next to the back wall (K >= 2) is held only within 5% of its target.
  //     Integral action (reservoir_integral_time tau > 0): while no group
  //     is beyond its tolerance, the summed deficit D of the held groups
  //     (all but the back sublayer) is integrated, I <- I + sign(D)
  //     max(|D| - q, 0) min(1, dt / tau), q = |held sublayers| / (|Omega| +
  //     |band|) the change of D by one particle once spread, and one
  //     particle is inserted (removed) in the held group furthest off
  //     whenever I >= 1 (<= -1): D then averages to within q of zero instead
  //     of resting anywhere in the tolerance band (a 1-D band of ~4
  //     particles rested a quarter short), and a settled state stays a
  //     fixed point.
  //     No random numbers are drawn, and a settled state is left unchanged.
  //  2'. Exact control: each sublayer is set to exactly T_j particles: surplus ones are deleted
  //     uniformly at random, missing ones inserted uniformly in the sublayer.
  //     T_j = floor(X_j + r_j), X_j = (integral of g over sublayer j) / m_p,
  //     and the carry r_j <- X_j + r_j - T_j in [0, 1) (error diffusion), so
  //     the count averaged over calls is X_j exactly: no mass is gained or lost
  //     on average. A consequence: at rest a sublayer whose X_j is not an
  //     integer alternates between floor(X_j) and ceil(X_j).
  //  Particles inside Omega are never touched (those that left the band into
  //  Omega are the inflow), and particles deeper than w inside the reservoir
  //  domain are left alone. The count rule assumes particles of mass m_p.
  //
  // Dirichlet, Layer with absorb_exterior: particles outside Omega (sd > 0)
  // whose closest boundary point is on a Dirichlet patch are removed and
  // counted as absorbed before the papers' B_l^int projection, which is
  // otherwise unchanged (it draws the same random numbers).
  // Before inserting, each condition checks that its particles fit under
  // max_particles (set_max_particles; <= 0: kMaxParticleCount) and throws
  // ResourceLimitExceeded naming the patch and the count otherwise (the
  // particles may then be partly projected: otfp::Simulation puts the step back).
  PatchLedger apply(ParticleSet& particles, double t, double dt, Rng& rng);
  // Whether apply() may read a particle at x (s_max: the largest width
  // present): one it does not read is not counted, removed or moved, and the
  // reservoir's placement density does not see it, so apply() on the
  // particles it reads (in their storage order) does what it does on all of
  // them. Read: outside Omega; within b of the boundary (layer, Neumann);
  // within w plus the reach of a blob's mass tail and of the placement
  // kernel of a reservoir's wall; anywhere when an outlet may take the
  // particles nearest to it (NearestParticles). A distributed run projects
  // the gathered particles it reads.
  bool reads(const Vec3& x, double s_max) const;
  void set_max_particles(std::int64_t max_particles) { max_particles_ = max_particles; }
  // Particles apply() is not given (other processes' shares, which it does
  // not read): they count against max_particles, and the widest of them
  // (s_max) widens the placement density's cut-off as it would serially.
  void set_unseen(std::int64_t particles, double s_max) {
    unseen_particles_ = particles;
    unseen_s_max_ = s_max;
  }
  // Walls across which the blob density has image blobs (otfp::Simulation
  // passes its mirrored walls): the quiet reservoir's placement counts them.
  void set_mirror_walls(std::vector<MirrorWallPtr> walls) { walls_ = std::move(walls); }
  std::int64_t max_particles() const { return max_particles_; }

  const std::vector<PatchLedger>& ledger() const { return ledger_; }  // indexed by position in conditions()

  // What apply() carries from one call to the next (ledger with the Neumann
  // carry and deficit, reservoir carries): restoring it into a projection
  // built the same way continues bit for bit (checkpoints).
  struct State {
    std::vector<PatchLedger> ledger;                  // per condition
    std::vector<std::vector<double>> reservoir_carry;  // per condition, per sublayer (empty if none)
  };
  State state() const;
  void restore(const State& state);  // throws InvalidArgument when the shapes differ
  const std::vector<PatchCondition>& conditions() const { return conditions_; }
  // Patches that the barrier must inflate by b (the Dirichlet buffers B^ext).
  // In Reservoir mode the caller bounds the particles by reservoir_domain instead.
  std::vector<int> dirichlet_patches() const;
  // Target mass of B_l^int for a Dirichlet condition at time t.
  double dirichlet_target_mass(std::size_t condition_index, double t) const;
  const ProjectionOptions& options() const { return options_; }

  // Reservoir mode, for a Dirichlet condition (others throw InvalidArgument):
  // number of sublayers K, volume of sublayer j, its real target count X_j at
  // time t, its carry r_j, and how the volumes were obtained: "exterior_shell"
  // (differences of Domain::layer_cell_volume(patch, t, Exterior), exact for a
  // ball in a concentric ball), "slab" (patch area x thickness, exact for a
  // flat face extended straight out, e.g. a box face) or "monte_carlo".
  int reservoir_sublayer_count(std::size_t condition_index) const;
  double reservoir_sublayer_volume(std::size_t condition_index, int sublayer) const;
  double reservoir_target_count(std::size_t condition_index, int sublayer, double t) const;
  double reservoir_carry(std::size_t condition_index, int sublayer) const;
  const std::string& reservoir_volume_rule(std::size_t condition_index) const;

 private:
  std::int64_t max_particles_ = 0;
  std::int64_t unseen_particles_ = 0;  // set_unseen
  double unseen_s_max_ = 0.0;
  std::size_t counted(const ParticleSet& particles) const {  // against max_particles
    return particles.size() + static_cast<std::size_t>(unseen_particles_);
  }
  std::string patch_label(std::size_t condition_index, double t) const;  // for messages
  // Per Dirichlet condition in Reservoir mode.
  struct Reservoir {
    int sublayers = 0;                          // K
    Aabb box;                                   // sampling box around the band
    std::vector<double> volume;                 // |sublayer j|
    std::vector<std::vector<Vec3>> quadrature;  // uniform points of sublayer j (one for constant g)
    std::vector<double> carry;                  // r_j in [0, 1), in particles (Exact); the deficit's integral (Quiet)
    std::vector<std::vector<Vec3>> candidates;  // Quiet control: fixed placement candidates of sublayer j
    std::string volume_rule;                    // "exterior_shell" | "slab" | "monte_carlo"
    // Odd profile: the wall of the patch, the volume of each sublayer's
    // mirror image inside Omega and the particle mass found there.
    std::shared_ptr<const MirrorWall> wall;
    std::vector<double> mirror_volume;
    std::vector<double> mirror_mass;
  };
  void build_reservoir(std::size_t condition_index);
  // Sublayer of depth sd (0 < sd <= w) among K, or -1.
  int sublayer_of(double sd, int sublayers) const;
  const Reservoir& reservoir_of(std::size_t condition_index) const;
  // Sets every sublayer of condition i to its count (apply(), Reservoir mode).
  void project_reservoir(std::size_t i, std::vector<std::vector<std::size_t>>& sublayer_members,
                         ParticleSet& particles, double t_new, Rng& rng, PatchLedger& call,
                         std::vector<std::size_t>& to_remove);
  // The same with the quiet control (ProjectionOptions::reservoir_control).
  void project_reservoir_quiet(std::size_t i, std::vector<std::vector<std::size_t>>& sublayer_members,
                               ParticleSet& particles, double t_new, double dt, PatchLedger& call,
                               std::vector<std::size_t>& to_remove);
  // Real target count of sublayer j at t (odd profile applied).
  double reservoir_profile_count(std::size_t i, std::size_t j, double t) const;
  // Removes particles not yet taken, nearest A_l first, while condition i owes outflow.
  void remove_nearest(std::size_t i, const ParticleSet& particles, const std::vector<double>& sd_of,
                      const std::vector<int>& patch_of, std::vector<char>& taken, double threshold,
                      const std::function<double(std::size_t)>& remove);

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
  std::vector<Reservoir> reservoirs_;
  std::vector<MirrorWallPtr> walls_;  // set_mirror_walls
  // per condition; sublayers = 0 unless Dirichlet in Reservoir mode
  // NearestParticles: fixed-seed points on A_l per Neumann condition, and a
  // sphere (centre, radius) around them for the distance lower bound.
  std::vector<std::vector<Vec3>> surface_points_;
  std::vector<Vec3> surface_center_;
  std::vector<double> surface_radius_;
};

}  // namespace otfp
