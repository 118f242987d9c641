// The Dirichlet reservoir of BoundaryProjection (docs/boundaries.md, "The
// Dirichlet reservoir"): a band of thickness w outside each Dirichlet patch,
// split into K sublayers by depth, each held at its target count.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <optional>
#include <queue>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "boundary_internal.hpp"
#include "cell_grid.hpp"
#include "placement_density.hpp"
#include "otfp/images.hpp"
#include "otfp/mass_measure.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/boundary.hpp"

namespace otfp {

using detail::box_measure;
using detail::draw_without_replacement;
using detail::kCountTolerance;
using detail::kReservoirSeed;
using detail::mean_of;
using detail::PlacementDensity;
using detail::uniform_in;

namespace {

// Automatic sublayer count: at most this many.
constexpr int kMaxAutoSublayers = 64;
// Rejection sampling of reservoir insertions: give up after this many tries per particle.
constexpr long kMaxTriesPerInsert = 10'000'000;
// A closed-form sublayer volume is used only if it agrees with the Monte
// Carlo estimate within this many standard errors.
constexpr double kVolumeAgreementSigmas = 4.0;
// Quiet control: the sublayer next to the band's back wall is corrected only
// when its deficit exceeds this fraction of its target (see project_reservoir_quiet).
constexpr double kBackTolerance = 0.05;
// Quiet control: blobs farther than this many widths from a depth interval put no mass in it.
constexpr double kTailWidths = 7.0;
// Quiet control: candidate points ranked per particle to insert.
constexpr std::size_t kCandidatesPerInsertion = 16;
// Quiet control: at least this many candidate points per sublayer.
constexpr std::size_t kMinCandidates = 64;

}  // namespace

int BoundaryProjection::sublayer_of(double sd, int sublayers) const {
  const double w = options_.reservoir_thickness;
  if (!(sd > 0.0) || sd > w) return -1;
  const int j = static_cast<int>(std::ceil(sd * static_cast<double>(sublayers) / w)) - 1;
  return std::clamp(j, 0, sublayers - 1);
}

// Sublayer volumes. One fixed-seed Monte Carlo pass over a box around the
// band (Omega's layer box of the patch inflated by w, intersected with
// Omega_ext's box) gives the volume of every sublayer with its standard error,
// and the quadrature points of g. Two closed forms are then tried, and one is
// used only if the domain gives it in closed form and it agrees with the Monte
// Carlo estimate within 4 standard errors in every sublayer:
//  - "exterior_shell": differences of Domain::layer_cell_volume(patch, t,
//    Exterior). Exact for a ball in a concentric ball of radius R + w. For a
//    box or cylinder it includes the edge wedges / rim torus, which lie
//    outside a face-extended box or cylinder, so it fails the check there.
//    "In closed form" is tested by asking twice with different sample counts:
//    a Monte Carlo implementation answers differently.
//  - "slab": patch area x sublayer thickness, exact for a flat patch whose
//    reservoir domain extends straight out over it (a box face with its lo or
//    hi moved by w).
// Otherwise ("monte_carlo") the Monte Carlo values are used, with relative
// error about sqrt(|box| / (N |sublayer|)).
void BoundaryProjection::build_reservoir(std::size_t i) {
  const PatchCondition& c = conditions_[i];
  const Domain& ext = *options_.reservoir_domain;
  const double w = options_.reservoir_thickness;
  const int d = domain_->dim();
  const int samples = options_.reservoir_volume_samples;
  Reservoir& r = reservoirs_[i];
  const Aabb layer_box = domain_->layer_bounding_box(c.patch, w);
  const Aabb ext_box = ext.bounding_box();
  r.box = Aabb{layer_box.lo.cwiseMax(ext_box.lo), layer_box.hi.cwiseMin(ext_box.hi)};
  const double box_volume = box_measure(r.box, d);
  const std::string name = "'" + domain_->patch_name(c.patch) + "'";
  require(box_volume > 0.0, "boundary.reservoir_domain", "bounding box",
          "must overlap the layer box of the Dirichlet patch " + name);
  // Depth in Omega of a point of the band of this patch, or -1.
  auto band_depth = [&](const Vec3& x) {
    const BoundaryQuery q = domain_->query(x);
    if (q.patch != c.patch || !(q.signed_distance > 0.0) || q.signed_distance > w) return -1.0;
    if (ext.signed_distance(x) > 0.0) return -1.0;
    return q.signed_distance;
  };
  const std::size_t cap = c.data_is_constant ? 1 : static_cast<std::size_t>(options_.quadrature_samples);

  int sublayers = options_.reservoir_sublayers;
  if (sublayers == 0) {
    // About one particle spacing (m_p / g0)^(1/d) per sublayer, g0 the mean
    // of g over the band at t = 0; one sublayer if g0 <= 0.
    Rng rng(kReservoirSeed + static_cast<std::uint64_t>(c.patch));
    double sum = 0.0;
    std::size_t found = 0;
    for (int k = 0; k < samples && found < cap; ++k) {
      const Vec3 x = uniform_in(r.box, d, rng);
      if (band_depth(x) < 0.0) continue;
      sum += c.data(x, 0.0);
      ++found;
    }
    require(found > 0, "boundary.reservoir_domain", "band of patch " + name,
            "is empty: the reservoir domain must extend beyond the Dirichlet patch by boundary.reservoir_thickness");
    const double g0 = sum / static_cast<double>(found);
    sublayers = 1;
    if (std::isfinite(g0) && g0 > 0.0) {
      const double spacing = std::pow(particle_mass_ / g0, 1.0 / static_cast<double>(d));
      sublayers = static_cast<int>(std::clamp(std::lround(w / spacing), 1L, static_cast<long>(kMaxAutoSublayers)));
    }
  }
  const auto K = static_cast<std::size_t>(sublayers);
  r.sublayers = sublayers;
  r.carry.assign(K, 0.0);
  r.quadrature.assign(K, {});
  std::vector<long> hits(K, 0);
  Rng rng(kReservoirSeed + static_cast<std::uint64_t>(c.patch));
  for (int k = 0; k < samples; ++k) {
    const Vec3 x = uniform_in(r.box, d, rng);
    const int j = sublayer_of(band_depth(x), sublayers);
    if (j < 0) continue;
    const auto jj = static_cast<std::size_t>(j);
    ++hits[jj];
    if (r.quadrature[jj].size() < cap) r.quadrature[jj].push_back(x);
  }
  long total = 0;
  for (long h : hits) total += h;
  require(total > 0, "boundary.reservoir_domain", "band of patch " + name,
          "is empty: the reservoir domain must extend beyond the Dirichlet patch by boundary.reservoir_thickness");

  std::vector<double> mc(K), se(K);
  for (std::size_t j = 0; j < K; ++j) {
    const double p = static_cast<double>(hits[j]) / static_cast<double>(samples);
    mc[j] = box_volume * p;
    se[j] = box_volume * std::sqrt(p * (1.0 - p) / static_cast<double>(samples));
  }
  auto depth = [&](std::size_t j) { return w * static_cast<double>(j) / static_cast<double>(sublayers); };
  auto agrees = [&](const std::vector<double>& v) {
    for (std::size_t j = 0; j < K; ++j)
      if (!(std::abs(v[j] - mc[j]) <= kVolumeAgreementSigmas * se[j] + 1e-9 * std::max(v[j], mc[j]))) return false;
    return true;
  };
  // Sublayer volumes as differences of the layer cell's volume at depths
  // j w / K, on the given side of the patch; `closed` is whether the domain
  // gives them in closed form (asked twice with different sample counts: a
  // Monte Carlo implementation answers differently).
  auto shell_volumes = [&](LayerPart part, bool& closed) {
    std::vector<double> v(K);
    double below = 0.0;
    closed = true;
    for (std::size_t j = 0; j < K; ++j) {
      const double v1 = domain_->layer_cell_volume(c.patch, depth(j + 1), part, 1000);
      const double v2 = domain_->layer_cell_volume(c.patch, depth(j + 1), part, 1001);
      closed = closed && v1 == v2;
      v[j] = v1 - below;
      below = v1;
    }
    return v;
  };
  bool shell_closed_form = true;
  const std::vector<double> shell = shell_volumes(LayerPart::Exterior, shell_closed_form);
  std::vector<double> slab(K);
  for (std::size_t j = 0; j < K; ++j) slab[j] = domain_->patch_area(c.patch) * (depth(j + 1) - depth(j));
  if (shell_closed_form && agrees(shell)) {
    r.volume = shell;
    r.volume_rule = "exterior_shell";
  } else if (agrees(slab)) {
    r.volume = slab;
    r.volume_rule = "slab";
  } else {
    r.volume = mc;
    r.volume_rule = "monte_carlo";
  }
  if (options_.reservoir_profile == ReservoirProfile::Odd) {
    // Mirror image of sublayer j inside Omega: the points whose reflection
    // across the patch's wall lies in sublayer j. Volumes by the same fixed-seed
    // Monte Carlo over the layer box inside Omega (a plane keeps volumes: there
    // they equal the band's; a sphere's inner shells are smaller).
    r.wall = domain_->patch_wall(c.patch);
    require(r.wall != nullptr, "boundary.reservoir_profile", "odd",
            "needs a wall surface for patch " + name + " (this domain has none)");
    const Aabb inner = domain_->layer_bounding_box(c.patch, w);
    const Aabb dom = domain_->bounding_box();
    const Aabb mbox{inner.lo.cwiseMax(dom.lo), inner.hi.cwiseMin(dom.hi)};
    const double mbox_volume = box_measure(mbox, d);
    std::vector<long> mhits(K, 0);
    Rng mrng(kReservoirSeed + 0x9e37ULL + static_cast<std::uint64_t>(c.patch));
    for (int k = 0; k < samples; ++k) {
      const Vec3 x = uniform_in(mbox, d, mrng);
      if (domain_->signed_distance(x) > 0.0) continue;
      const int jj = sublayer_of(band_depth(r.wall->reflect(x, nullptr)), sublayers);
      if (jj >= 0) ++mhits[static_cast<std::size_t>(jj)];
    }
    std::vector<double> mmc(K), mse(K);
    for (std::size_t jj = 0; jj < K; ++jj) {
      const double p = static_cast<double>(mhits[jj]) / static_cast<double>(samples);
      mmc[jj] = mbox_volume * p;
      mse[jj] = mbox_volume * std::sqrt(p * (1.0 - p) / static_cast<double>(samples));
      require(mmc[jj] > 0.0, "boundary.reservoir_profile", "odd",
              "the mirror image of sublayer " + std::to_string(jj) + " of patch " + name + " (" +
                  std::to_string(mhits[jj]) + " of " + std::to_string(samples) +
                  " samples) inside Omega is empty (domain too thin?)");
    }
    // Closed forms where they are exact, checked against the Monte Carlo
    // estimate as for the band: a plane keeps volumes (the band's own), a
    // sphere maps the shell (R + a, R + b] onto [R - b, R - a) (interior layer
    // cells of a ball); otherwise the Monte Carlo values.
    auto agrees_m = [&](const std::vector<double>& v) {
      for (std::size_t jj = 0; jj < K; ++jj)
        if (!(std::abs(v[jj] - mmc[jj]) <= kVolumeAgreementSigmas * mse[jj] + 1e-9 * std::max(v[jj], mmc[jj])))
          return false;
      return true;
    };
    bool inner_closed_form = true;
    const std::vector<double> inner_shell = shell_volumes(LayerPart::Interior, inner_closed_form);
    if (r.volume_rule != "monte_carlo" && agrees_m(r.volume))
      r.mirror_volume = r.volume;
    else if (inner_closed_form && agrees_m(inner_shell))
      r.mirror_volume = inner_shell;
    else
      r.mirror_volume = mmc;
    r.mirror_mass.assign(K, 0.0);
  }
  if (options_.reservoir_control == ReservoirControl::Quiet) {
    // The quiet control measures depths from the patch's wall surface.
    if (!r.wall) r.wall = domain_->patch_wall(c.patch);
    require(r.wall != nullptr, "boundary.reservoir_control", "quiet",
            "needs a wall surface for patch " + name + " (this domain has none; use exact)");
    // Fixed candidate points of each sublayer, reservoir_candidates per
    // particle of its largest target (2 g with the odd profile), at least
    // kMinCandidates: the quiet control places particles only there, so that
    // no random number is drawn while running.
    const double factor = options_.reservoir_profile == ReservoirProfile::Odd ? 2.0 : 1.0;
    std::vector<std::size_t> want(K);
    std::size_t total_want = 0;
    for (std::size_t j = 0; j < K; ++j) {
      const double x = r.quadrature[j].empty() ? 0.0 : r.volume[j] * mean_of(c.data, r.quadrature[j], 0.0) / particle_mass_;
      const double n = std::isfinite(x) ? std::ceil(factor * std::max(x, 0.0) * options_.reservoir_candidates) : 0.0;
      want[j] = static_cast<std::size_t>(std::clamp(n, static_cast<double>(kMinCandidates), 1e8));
      total_want += want[j];
    }
    r.candidates.assign(K, {});
    Rng crng(kReservoirSeed + 0x5143ULL + static_cast<std::uint64_t>(c.patch));
    std::size_t placed = 0;
    const long max_tries = kMaxTriesPerInsert * static_cast<long>(std::min<std::size_t>(total_want, 1000));
    for (long tries = 0; placed < total_want && tries < max_tries; ++tries) {
      const Vec3 x = uniform_in(r.box, d, crng);
      const int j = sublayer_of(band_depth(x), sublayers);
      if (j < 0) continue;
      auto& pool = r.candidates[static_cast<std::size_t>(j)];
      if (pool.size() >= want[static_cast<std::size_t>(j)]) continue;
      pool.push_back(x);
      ++placed;
    }
    for (std::size_t j = 0; j < K; ++j)
      require(!r.candidates[j].empty(), "boundary.reservoir_control", "quiet",
              "found no candidate point in sublayer " + std::to_string(j) + " of patch " + name);
  }
}

const BoundaryProjection::Reservoir& BoundaryProjection::reservoir_of(std::size_t condition_index) const {
  require(condition_index < conditions_.size(), "boundary condition index", static_cast<double>(condition_index),
          "must be < number of conditions = " + std::to_string(conditions_.size()));
  require(reservoirs_[condition_index].sublayers > 0, "boundary condition " + std::to_string(condition_index),
          to_string(conditions_[condition_index].kind) + ", dirichlet_mode " + to_string(options_.dirichlet_mode),
          "must be a dirichlet condition with dirichlet_mode = reservoir");
  return reservoirs_[condition_index];
}

int BoundaryProjection::reservoir_sublayer_count(std::size_t condition_index) const {
  return reservoir_of(condition_index).sublayers;
}

double BoundaryProjection::reservoir_sublayer_volume(std::size_t condition_index, int sublayer) const {
  const Reservoir& r = reservoir_of(condition_index);
  require(sublayer >= 0 && sublayer < r.sublayers, "reservoir sublayer", sublayer,
          "must be in [0, " + std::to_string(r.sublayers) + ")");
  return r.volume[static_cast<std::size_t>(sublayer)];
}

double BoundaryProjection::reservoir_target_count(std::size_t condition_index, int sublayer, double t) const {
  const Reservoir& r = reservoir_of(condition_index);
  require(sublayer >= 0 && sublayer < r.sublayers, "reservoir sublayer", sublayer,
          "must be in [0, " + std::to_string(r.sublayers) + ")");
  const auto j = static_cast<std::size_t>(sublayer);
  if (r.quadrature[j].empty() || r.volume[j] <= 0.0) return 0.0;
  const PatchCondition& c = conditions_[condition_index];
  const double x = r.volume[j] * mean_of(c.data, r.quadrature[j], t) / particle_mass_;
  require(std::isfinite(x), "reservoir target count (patch " + std::to_string(c.patch) + ")", x,
          "must be finite (check g)");
  return x;
}

double BoundaryProjection::reservoir_carry(std::size_t condition_index, int sublayer) const {
  const Reservoir& r = reservoir_of(condition_index);
  require(sublayer >= 0 && sublayer < r.sublayers, "reservoir sublayer", sublayer,
          "must be in [0, " + std::to_string(r.sublayers) + ")");
  return r.carry[static_cast<std::size_t>(sublayer)];
}

const std::string& BoundaryProjection::reservoir_volume_rule(std::size_t condition_index) const {
  return reservoir_of(condition_index).volume_rule;
}

double BoundaryProjection::reservoir_profile_count(std::size_t i, std::size_t j, double t) const {
  const Reservoir& r = reservoirs_[i];
  double x_j = reservoir_target_count(i, static_cast<int>(j), t);
  if (r.wall && !r.mirror_volume.empty()) {
    // Odd parity about g: density 2 g - rho_in, clamped to [0, 2 g].
    const double rho_in = r.mirror_mass[j] / r.mirror_volume[j];
    const double g_mass = x_j * particle_mass_;  // g |sublayer j|
    const double want = std::clamp(2.0 * g_mass - rho_in * r.volume[j], 0.0, 2.0 * g_mass);
    x_j = want / particle_mass_;
  }
  return x_j;
}

void BoundaryProjection::project_reservoir(std::size_t i, std::vector<std::vector<std::size_t>>& sublayer_members,
                                           ParticleSet& particles, double t_new, Rng& rng, PatchLedger& call,
                                           std::vector<std::size_t>& to_remove) {
  const PatchCondition& c = conditions_[i];
  PatchLedger& led = ledger_[i];
  Reservoir& r = reservoirs_[i];
  const auto K = static_cast<std::size_t>(r.sublayers);
  const double mp = particle_mass_;
  std::vector<long> missing(K, 0);
  long total_missing = 0;
  for (std::size_t j = 0; j < K; ++j) {
    // Error diffusion: T_j = floor(X_j + r_j), r_j <- X_j + r_j - T_j, so
    // the mean of T_j over calls is X_j. A negative target acts as zero.
    const double x_j = reservoir_profile_count(i, j, t_new);
    const double v = x_j + r.carry[j];
    long target = 0;
    require_particle_room(v, particles.size(), max_particles_, patch_label(i, t_new));
    if (v > 0.0) {
      target = static_cast<long>(std::floor(v + kCountTolerance));
      r.carry[j] = v - static_cast<double>(target);
    } else {
      r.carry[j] = 0.0;
    }
    std::vector<std::size_t>& in_j = sublayer_members[j];
    const auto have = static_cast<long>(in_j.size());
    if (have > target) {
      // Surplus: uniformly at random among the sublayer's particles.
      for (long k = 0; k < have - target; ++k) {
        const std::size_t p = draw_without_replacement(in_j, static_cast<std::size_t>(k), rng);
        const double m = particles.masses()[p];
        to_remove.push_back(p);
        ++led.removed;
        ++call.removed;
        led.mass_removed += m;
        call.mass_removed += m;
      }
    } else {
      missing[j] = target - have;
      total_missing += missing[j];
    }
  }
  if (total_missing == 0) return;
  require_particle_room(static_cast<double>(total_missing), particles.size(), max_particles_, patch_label(i, t_new));
  // Missing particles: uniform in their sublayer, by rejection from the box
  // around the band; one loop fills every sublayer of the patch.
  const Domain& ext = *options_.reservoir_domain;
  const double w = options_.reservoir_thickness;
  const int d = domain_->dim();
  particles.reserve(particles.size() + static_cast<std::size_t>(total_missing));
  long tries = 0;
  while (total_missing > 0) {
    if (++tries > kMaxTriesPerInsert * total_missing)
      throw std::runtime_error("reservoir of patch '" + domain_->patch_name(c.patch) +
                               "': no point of a sublayer found in " + std::to_string(tries) +
                               " tries (empty sublayer?)");
    const Vec3 x = uniform_in(r.box, d, rng);
    const BoundaryQuery q = domain_->query(x);
    if (q.patch != c.patch || !(q.signed_distance > 0.0) || q.signed_distance > w) continue;
    const int j = sublayer_of(q.signed_distance, r.sublayers);
    if (j < 0 || missing[static_cast<std::size_t>(j)] == 0) continue;
    if (ext.signed_distance(x) > 0.0) continue;
    particles.add(x, width_s_, mp, t_new);
    --missing[static_cast<std::size_t>(j)];
    --total_missing;
    ++led.inserted;
    ++call.inserted;
    led.mass_inserted += mp;
    call.mass_inserted += mp;
  }
}

// Nearest particles to A_l, nearest first, by branch and bound: every
// candidate gets a lower bound of its distance (|sd|, exact when its closest
// boundary point is on A_l; otherwise also |x - c| - rho for the sphere
// (c, rho) around the points on A_l), and exact distances are evaluated in
// Quiet control (docs/boundaries.md, "Quiet reservoir"). What the face must
// see is the blob density (29), not a count of centres: a settled band layers
// parallel to its walls, a sublayer half a spacing thick catches one layer or
// the gap between two, and holding such counts fights the dynamics every step
// (the exact control's churn). With the odd profile the smoothed form of
// "u - g is odd across the face" is rho(c) + rho(R c) = 2 g (the kernel is
// even), which over sublayer j reads
//   M_j = 2 g |sublayer j| - M'_j |sublayer j| / |mirror j|,
// M_j the blob mass in the sublayer (its tail beyond the back wall folded
// back, as the image there does) and M'_j the blob mass in its mirror image
// inside Omega. The deficit D_j = (target - M_j) / m_p is left alone while
// |D_j| <= reservoir_tolerance; otherwise round(D_j) particles leave where
// the blob density (images included) exceeds the pointwise target
// T(c) = clamp(2 g - rho(R c), 0, 2 g) most, or are put at the fixed
// candidate points where it falls short most, the densities updated after
// each particle. The sublayer next to the back wall (K >= 2) is corrected
// only when it is off by more than 5% of its target: its density is what the
// wall makes of it (at the sphere's curved back wall the settled state reads
// 1-2% off, and holding it to one particle cost 11 insertions and removals per
// step in a steady state), and its neighbour, which is held, feeds it.
// Deterministic: no random numbers; and no density is evaluated unless a
// sublayer is corrected (the masses are one pass over the particles near the
// face).
void BoundaryProjection::project_reservoir_quiet(std::size_t i,
                                                 std::vector<std::vector<std::size_t>>& sublayer_members,
                                                 ParticleSet& particles, double t_new, double dt, PatchLedger& call,
                                                 std::vector<std::size_t>& to_remove) {
  PatchLedger& led = ledger_[i];
  Reservoir& r = reservoirs_[i];
  const PatchCondition& c = conditions_[i];
  const auto K = static_cast<std::size_t>(r.sublayers);
  const int dim = domain_->dim();
  const bool odd = options_.reservoir_profile == ReservoirProfile::Odd && r.wall != nullptr;

  // Each sublayer's deficit from the blob masses of the particles, in
  // the normal coordinate xi of the patch's wall (xi > 0 in the band): a blob
  // of width s puts the mass of N(xi_q, s^2/2) into each depth interval (exact
  // for a plane; on a wall of radius R off by O(s^2/R) in the mean depth).
  // Band sublayer j is (a_j, b_j]; its mirror inside Omega is [-b_j, -a_j);
  // the back wall at depth w folds each blob's tail back in (its image).
  // Tangential spill is not lost: images at the side walls fold it back, and
  // the normal coordinate integrates over the tangential ones.
  const double w = options_.reservoir_thickness;
  std::vector<double> band_mass(K, 0.0), mirror_mass(K, 0.0);
  {
    const std::vector<Vec3>& x = particles.positions();
    const std::vector<double>& sw = particles.widths();
    const std::vector<double>& m = particles.masses();
    // A sphere (3-D ball): the exact mass of the blob in the shell between
    // radii R + lo and R + hi (gaussian_in_ball, closed form); the 1-D normal
    // model put the sphere's steady state 2% low (its mean depth is off by
    // about s^2 / (2 R)). The disc's exact form is a quadrature, 5x the cost
    // of a whole step here, so a circle keeps the 1-D model.
    const std::optional<DomainShape> shape = domain_->shape();
    const bool ball = shape && shape->kind == DomainShape::Kind::Ball && dim == 3;
    for (std::size_t p = 0; p < particles.size(); ++p) {
      const double xi = r.wall->distance(x[p]);
      const double reach = kTailWidths * sw[p];
      if (!(xi > -w - reach && xi < w + reach)) continue;
      const double r0 = ball ? (x[p] - shape->center).norm() : 0.0;
      auto in_depths = [&](double lo, double hi) {
        if (!ball) return gaussian_in_interval(xi, sw[p], lo, hi);
        const double R = shape->radius;
        const double outer = gaussian_in_ball(3, r0, sw[p], R + hi);
        const double inner = R + lo > 0.0 ? gaussian_in_ball(3, r0, sw[p], R + lo) : 0.0;
        return std::max(outer - inner, 0.0);
      };
      for (std::size_t j = 0; j < K; ++j) {
        const double a = w * static_cast<double>(j) / static_cast<double>(K);
        const double b = w * static_cast<double>(j + 1) / static_cast<double>(K);
        band_mass[j] += m[p] * (in_depths(a, b) + in_depths(2.0 * w - b, 2.0 * w - a));
        mirror_mass[j] += m[p] * in_depths(-b, -a);
      }
    }
  }
  std::vector<double> x(K, 0.0), d(K, 0.0);
  for (std::size_t j = 0; j < K; ++j) {
    // The target's mean over the sublayer: g (uniform), or 2 g minus the
    // interior's mean density at the mirror depths (odd; the mirror shell of
    // a sphere is smaller than the band's, so its mean density is taken).
    const double g_mass = reservoir_target_count(i, static_cast<int>(j), t_new) * particle_mass_;  // g |sublayer j|
    double target_mass = g_mass;
    if (odd) {
      const double interior = r.mirror_volume[j] > 0.0 ? mirror_mass[j] * r.volume[j] / r.mirror_volume[j] : 0.0;
      target_mass = std::clamp(2.0 * g_mass - interior, 0.0, 2.0 * std::max(g_mass, 0.0));
    }
    x[j] = target_mass / particle_mass_;
    d[j] = (target_mass - band_mass[j]) / particle_mass_;
    require(std::isfinite(d[j]), "reservoir deficit (patch " + std::to_string(c.patch) + ")", d[j],
            "must be finite (check g)");
    require_particle_room(std::max(x[j], 0.0), particles.size(), max_particles_, patch_label(i, t_new));
  }
  // Sublayers are held in groups of consecutive ones whose targets add up to
  // at least reservoir_group_target particles (each sublayer on its own
  // wherever it is that large: the 3-D sphere). A group rests anywhere
  // within the tolerance, so the band's mass is biased by up to one particle
  // per group: with groups of 8 (the former rule) the 2-D slab's band of 9
  // groups held 9% too little and the run ended 5% low; a sublayer of less
  // than a particle could never leave the tolerance at all (the 1-D box: 9
  // sublayers of 0.95 particles, never filled). Where particles go within a
  // group is still decided point by point against the odd profile.
  std::vector<std::size_t> group_of(K, 0);
  std::size_t groups = 0;
  {
    double sum = 0.0;
    for (std::size_t j = 0; j < K; ++j) {
      group_of[j] = groups;
      sum += std::max(x[j], 0.0);
      if (sum >= options_.reservoir_group_target && j + 1 < K) {
        ++groups;
        sum = 0.0;
      }
    }
    ++groups;
    // A last group below the minimum joins the one before it.
    if (groups > 1 && sum < options_.reservoir_group_target) {
      for (std::size_t j = 0; j < K; ++j)
        if (group_of[j] == groups - 1) group_of[j] = groups - 2;
      --groups;
    }
  }
  std::vector<double> x_group(groups, 0.0), d_group(groups, 0.0);
  std::vector<std::size_t> members(groups, 0), layers(groups, 0);
  for (std::size_t j = 0; j < K; ++j) {
    x_group[group_of[j]] += x[j];
    d_group[group_of[j]] += d[j];
    members[group_of[j]] += sublayer_members[j].size();
    ++layers[group_of[j]];
  }
  std::vector<long> change(groups, 0);
  std::vector<char> held(groups, 0);
  bool corrected = false;
  for (std::size_t q = 0; q < groups; ++q) {
    // The sublayer next to the back wall, held on its own, only within
    // kBackTolerance of its target: enough to fill it at the start and
    // refill it when the band runs low, loose enough to leave the wall's own
    // 1-2% alone.
    const bool back = K >= 2 && layers[q] == 1 && group_of[K - 1] == q;
    const double tolerance =
        back ? std::max(options_.reservoir_tolerance, kBackTolerance * std::abs(x_group[q])) : options_.reservoir_tolerance;
    if (std::abs(d_group[q]) > tolerance) {
      change[q] = std::max(std::lround(d_group[q]), -static_cast<long>(members[q]));
      corrected = true;
    } else {
      held[q] = back ? 0 : 1;
    }
  }
  // Integral action (reservoir_integral_time tau > 0). Within the tolerance
  // a group rests wherever the flux left it, on average half the tolerance
  // on the side the flux came from: the 1-D slab's band of ~4 particles held
  // a quarter too little and the slab settled 10% low at every n. The
  // integral I of the held groups' summed deficit D, I <- I + sign(D)
  // max(|D| - q, 0) min(1, dt / tau), adds (removes) a particle whenever
  // |I| >= 1, so that D averages to within q of zero. One particle, once spread over Omega and the band, moves D by only
  // the held sublayers' share of that volume, q = |held| / (|Omega| +
  // |band|), and before it has spread by up to a whole particle: a D within
  // q of zero is not integrated (one particle more or less is no closer once
  // the step's response is counted), so that a settled state stays a fixed
  // point instead of cycling one particle in and out. The integral is
  // reset whenever the tolerance rule acts (large deficits are its own).
  // It lives in the carry of sublayer 0 (saved with the projection's state).
  if (options_.reservoir_integral_time > 0.0) {
    double d_held = 0.0, v_held = 0.0, v_band = 0.0;
    for (std::size_t j = 0; j < K; ++j) {
      v_band += r.volume[j];
      if (held[group_of[j]]) v_held += r.volume[j];
    }
    for (std::size_t q = 0; q < groups; ++q)
      if (held[q]) d_held += d_group[q];
    const double carry_before = r.carry.empty() ? 0.0 : r.carry[0];
    std::fill(r.carry.begin(), r.carry.end(), 0.0);
    if (!corrected && v_held > 0.0) {
      const double quantum = v_held / (domain_->volume() + v_band);
      const double excess = std::max(std::abs(d_held) - quantum, 0.0);
      const double gain = std::min(1.0, dt / options_.reservoir_integral_time);
      double integral = carry_before + std::copysign(excess, d_held) * gain;
      if (std::abs(integral) >= 1.0) {
        // One particle, to the held group furthest off in that direction.
        const double sign = integral > 0.0 ? 1.0 : -1.0;
        std::size_t best = groups;
        for (std::size_t q = 0; q < groups; ++q)
          if (held[q] && (sign > 0.0 || members[q] > 0) &&
              (best == groups || sign * d_group[q] > sign * d_group[best]))
            best = q;
        if (best < groups) {
          change[best] = static_cast<long>(sign);
          integral -= sign;
        }
      }
      // At most one particle a call: what a long step adds beyond that is
      // dropped, not owed (no wind-up to pay off later as an overshoot).
      r.carry[0] = std::clamp(integral, -1.0, 1.0);
    }
  }
  long total_insert = 0;
  for (std::size_t q = 0; q < groups; ++q) total_insert += std::max(change[q], 0L);
  if (std::all_of(change.begin(), change.end(), [](long v) { return v == 0; })) return;
  require_particle_room(static_cast<double>(total_insert), particles.size(), max_particles_, patch_label(i, t_new));

  // Where particles go and leave: the blob density (images included) against
  // the pointwise target T(c) = clamp(2 g - rho(R c), 0, 2 g) (odd) or g.
  const PlacementDensity density(particles, walls_);
  const double r2 = density.radius() * density.radius();
  auto target = [&](const Vec3& y) {
    const double g = c.data(y, t_new);
    if (!odd) return g;
    return std::clamp(2.0 * g - density.at(r.wall->reflect(y, nullptr)), 0.0, 2.0 * std::max(g, 0.0));
  };

  // Each group's change goes to its sublayers by their own deficits
  // (largest remainders of max(+-D_j, 0)), so that a group of several
  // sublayers keeps the odd profile across them: the tolerance is the
  // group's, the profile the sublayers'.
  std::vector<long> quota(K, 0);
  for (std::size_t q = 0; q < groups; ++q) {
    if (change[q] == 0) continue;
    const double sign = change[q] > 0 ? 1.0 : -1.0;
    const long total = std::labs(change[q]);
    std::vector<std::size_t> js;
    std::vector<double> weight;
    double sum = 0.0;
    for (std::size_t j = 0; j < K; ++j)
      if (group_of[j] == q) {
        js.push_back(j);
        // Removals only where there are particles to take.
        const double wj = sign > 0 ? std::max(d[j], 0.0)
                                   : (sublayer_members[j].empty() ? 0.0 : std::max(-d[j], 0.0));
        weight.push_back(wj);
        sum += wj;
      }
    if (!(sum > 0.0)) {  // no sublayer on the side of the change: by target (insertions) or by members (removals)
      sum = 0.0;
      for (std::size_t k = 0; k < js.size(); ++k) {
        weight[k] = sign > 0 ? std::max(x[js[k]], 0.0) : static_cast<double>(sublayer_members[js[k]].size());
        sum += weight[k];
      }
      if (!(sum > 0.0)) {
        for (double& wk : weight) wk = 1.0;
        sum = static_cast<double>(weight.size());
      }
    }
    std::vector<std::pair<double, std::size_t>> remainder;
    long given = 0;
    for (std::size_t k = 0; k < js.size(); ++k) {
      const double share = static_cast<double>(total) * weight[k] / sum;
      long whole = static_cast<long>(std::floor(share));
      if (sign < 0) whole = std::min(whole, static_cast<long>(sublayer_members[js[k]].size()));
      quota[js[k]] = whole;
      given += whole;
      remainder.emplace_back(share - static_cast<double>(whole), k);
    }
    std::stable_sort(remainder.begin(), remainder.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
    // Largest remainders first, then round-robin over the sublayers that
    // can still take one: a removal capped by a sublayer's members goes to
    // the others (|change| is at most the group's members, so this ends).
    for (std::size_t pass = 0; given < total; ++pass) {
      long before = given;
      for (const auto& [frac, k] : remainder) {
        if (given == total) break;
        if (pass == 0 && !(frac > 0.0)) continue;
        if (sign < 0 && quota[js[k]] >= static_cast<long>(sublayer_members[js[k]].size())) continue;
        ++quota[js[k]];
        ++given;
      }
      if (pass > 0 && given == before) break;  // nothing can take more
    }
    for (std::size_t j : js) quota[j] *= static_cast<long>(sign);
  }

  // Removals: in each sublayer, the particles with the largest excess rho - T first.
  for (std::size_t j = 0; j < K; ++j) {
    if (quota[j] >= 0) continue;
    const std::vector<std::size_t>& in_j = sublayer_members[j];
    std::vector<double> excess(in_j.size());
    for (std::size_t k = 0; k < in_j.size(); ++k) {
      const Vec3& y = particles.positions()[in_j[k]];
      excess[k] = density.at(y) - target(y);
    }
    for (long n = 0; n < -quota[j]; ++n) {
      const auto k = static_cast<std::size_t>(std::max_element(excess.begin(), excess.end()) - excess.begin());
      const std::size_t p = in_j[k];
      const Vec3 xp = particles.positions()[p];
      const double mp = particles.masses()[p];
      const PlacementDensity::Kernel kernel(particles.widths()[p], mp, dim);
      excess[k] = -std::numeric_limits<double>::infinity();
      for (std::size_t l = 0; l < in_j.size(); ++l)
        if (std::isfinite(excess[l]) && (particles.positions()[in_j[l]] - xp).squaredNorm() < r2)
          excess[l] -= kernel(particles.positions()[in_j[l]], xp);
      to_remove.push_back(p);
      ++led.removed;
      ++call.removed;
      led.mass_removed += mp;
      call.mass_removed += mp;
    }
  }
  if (total_insert == 0) return;

  // Insertions: each sublayer's candidates ranked by their deficit T - rho,
  // lowered as particles are placed (a particle in one sublayer also lowers
  // the deficit at the candidates of its neighbours). A candidate is used at
  // most once per call. Each sublayer ranks kCandidatesPerInsertion
  // candidates per particle it needs (its whole pool if smaller, at least
  // kMinCandidates), taken evenly through its pool from an offset that
  // depends on t (deterministic, and a resumed run takes the same ones):
  // evaluating the whole pool for a few particles cost 40% of an explicit
  // run while the sphere filled.
  std::vector<Vec3> cand;
  std::vector<std::size_t> sub_of_cand;
  const std::uint64_t offset_seed = std::bit_cast<std::uint64_t>(t_new) * 0x9e3779b97f4a7c15ULL;
  for (std::size_t j = 0; j < K; ++j) {
    if (quota[j] <= 0) continue;
    const std::vector<Vec3>& pool = r.candidates[j];
    const auto want = kCandidatesPerInsertion * static_cast<std::size_t>(quota[j]);
    const std::size_t take = std::min(pool.size(), std::max(want, std::min(pool.size(), kMinCandidates)));
    if (take == 0) continue;
    const std::size_t stride = pool.size() / take;
    const std::size_t start = static_cast<std::size_t>((offset_seed >> 17) % std::max<std::size_t>(1, stride));
    for (std::size_t k = 0; k < take; ++k) {
      cand.push_back(pool[(start + k * stride) % pool.size()]);
      sub_of_cand.push_back(j);
    }
  }
  std::vector<double> deficit(cand.size());
  for (std::size_t k = 0; k < cand.size(); ++k) deficit[k] = target(cand[k]) - density.at(cand[k]);
  CellGrid grid;
  grid.build(cand, density.radius(), Periodicity::none(dim), 1);
  // Per group, a max-heap of (deficit, candidate) with lazy updates:
  // deficits only fall as particles are placed, so a popped entry whose
  // deficit has fallen goes back in with its new value.
  using Entry = std::pair<double, std::size_t>;
  std::vector<std::priority_queue<Entry>> heap(K);
  for (std::size_t k = 0; k < cand.size(); ++k) heap[sub_of_cand[k]].emplace(deficit[k], k);
  std::vector<char> used(cand.size(), 0);
  particles.reserve(particles.size() + static_cast<std::size_t>(total_insert));
  const double mp = particle_mass_;
  const PlacementDensity::Kernel kernel(width_s_, mp, dim);
  for (std::size_t q = 0; q < K; ++q) {
    for (long n = 0; n < quota[q]; ++n) {
      std::size_t k = cand.size();
      while (!heap[q].empty()) {
        const Entry e = heap[q].top();
        heap[q].pop();
        if (used[e.second]) continue;
        if (deficit[e.second] < e.first) {
          heap[q].emplace(deficit[e.second], e.second);
          continue;
        }
        k = e.second;
        break;
      }
      if (k == cand.size())
        throw std::runtime_error("reservoir of patch '" + domain_->patch_name(c.patch) +
                                 "': a sublayer needs more particles than its candidate points "
                                 "(raise reservoir_candidates)");
      used[k] = 1;
      const Vec3 y = cand[k];
      particles.add(y, width_s_, mp, t_new);
      grid.for_each_candidate(y, [&](std::uint32_t l) {
        if (!used[l] && (cand[l] - y).squaredNorm() < r2)
          deficit[l] -= kernel(cand[l], y);
      });
      ++led.inserted;
      ++call.inserted;
      led.mass_inserted += mp;
      call.mass_inserted += mp;
    }
  }
}

}  // namespace otfp
