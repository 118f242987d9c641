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
using detail::kMinCandidates;
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
// Points classified per batch by classify_in_order().
constexpr long kClassifyBatch = 16384;

// The Monte Carlo passes below: `count` points drawn one after another from
// one stream (draw()), each classified by classify(x) -> int (the domain
// queries, nearly all of the cost: 2 x 10^6 of them per Dirichlet patch),
// and handed to take(x, class) in the order drawn until take returns false.
// The classification runs on the OpenMP threads, a batch at a time; the
// draws and take() stay serial, so the outcome does not depend on the
// thread count (tests/test_reservoir.cpp). A batch may classify points past
// the one where take() stops; they are dropped.
template <class Draw, class Classify, class Take>
void classify_in_order(long count, Draw&& draw, Classify&& classify, Take&& take) {
  std::vector<Vec3> x;
  std::vector<int> cls;
  for (long done = 0; done < count;) {
    const long n = std::min(kClassifyBatch, count - done);
    x.resize(static_cast<std::size_t>(n));
    cls.resize(static_cast<std::size_t>(n));
    for (Vec3& y : x) y = draw();
#pragma omp parallel for schedule(static) if (n >= 4096)
    for (long k = 0; k < n; ++k) cls[static_cast<std::size_t>(k)] = classify(x[static_cast<std::size_t>(k)]);
    for (std::size_t k = 0; k < x.size(); ++k)
      if (!take(x[k], cls[k])) return;
    done += n;
  }
}

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
  classify_in_order(
      samples, [&] { return uniform_in(r.box, d, rng); },
      [&](const Vec3& x) { return sublayer_of(band_depth(x), sublayers); },
      [&](const Vec3& x, int j) {
        if (j < 0) return true;
        const auto jj = static_cast<std::size_t>(j);
        ++hits[jj];
        if (r.quadrature[jj].size() < cap) r.quadrature[jj].push_back(x);
        return true;
      });
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
    classify_in_order(
        samples, [&] { return uniform_in(mbox, d, mrng); },
        [&](const Vec3& x) {
          if (domain_->signed_distance(x) > 0.0) return -1;
          return sublayer_of(band_depth(r.wall->reflect(x, nullptr)), sublayers);
        },
        [&](const Vec3&, int jj) {
          if (jj >= 0) ++mhits[static_cast<std::size_t>(jj)];
          return true;
        });
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
    if (total_want > 0)
      classify_in_order(
          max_tries, [&] { return uniform_in(r.box, d, crng); },
          [&](const Vec3& x) { return sublayer_of(band_depth(x), sublayers); },
          [&](const Vec3& x, int j) {
            if (j < 0) return true;
            auto& pool = r.candidates[static_cast<std::size_t>(j)];
            if (pool.size() >= want[static_cast<std::size_t>(j)]) return true;
            pool.push_back(x);
            return ++placed < total_want;
          });
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
    require_particle_room(v, counted(particles), max_particles_, patch_label(i, t_new));
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
  require_particle_room(static_cast<double>(total_missing), counted(particles), max_particles_, patch_label(i, t_new));
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

}  // namespace otfp
