// The quiet control of the Dirichlet reservoir (ProjectionOptions::
// reservoir_control = Quiet; docs/boundaries.md, "Quiet reservoir"): deficits
// measured on blob masses, groups of sublayers held within a tolerance, an
// integral action within it, and deterministic placement and removal. The
// band itself (sublayers, volumes, candidates) and the exact control are in
// reservoir.cpp.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <queue>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "boundary_internal.hpp"
#include "cell_grid.hpp"
#include "placement_density.hpp"
#include "otfp/boundary.hpp"
#include "otfp/images.hpp"
#include "otfp/mass_measure.hpp"

namespace otfp {

using detail::kMinCandidates;
using detail::kPlacementKernelTolerance;
using detail::kTailWidths;
using detail::PlacementDensity;

namespace {

// Quiet control: the sublayer next to the band's back wall is corrected only
// when its deficit exceeds this fraction of its target (see project_reservoir_quiet).
constexpr double kBackTolerance = 0.05;
// Quiet control: candidate points ranked per particle to insert.
constexpr std::size_t kCandidatesPerInsertion = 16;

}  // namespace

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
    require_particle_room(std::max(x[j], 0.0), counted(particles), max_particles_, patch_label(i, t_new));
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
  // |I| >= 1, so that D averages to within q of zero. One particle, once
  // spread over Omega and the band, moves D by only the held sublayers'
  // share of that volume, q = |held| / (|Omega| + |band|), and before it
  // has spread by up to a whole particle: a D within
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
  require_particle_room(static_cast<double>(total_insert), counted(particles), max_particles_, patch_label(i, t_new));

  // Where particles go and leave: the blob density (images included) against
  // the pointwise target T(c) = clamp(2 g - rho(R c), 0, 2 g) (odd) or g.
  const PlacementDensity density(particles, walls_, kPlacementKernelTolerance, unseen_s_max_);
  const double r2 = density.radius() * density.radius();
  auto target = [&](const Vec3& y, double g) {
    if (!odd) return g;
    return std::clamp(2.0 * g - density.at(r.wall->reflect(y, nullptr)), 0.0, 2.0 * std::max(g, 0.0));
  };
  // rho(y_k) - T(y_k) at many points: the data g serially (a caller's
  // function need not be thread-safe), the densities, nearly all of the cost,
  // on the OpenMP threads (each point's value is computed alone, so the
  // result does not depend on the thread count).
  auto excess_at = [&](const auto& point, std::size_t count, std::vector<double>& out) {
    out.resize(count);
    for (std::size_t k = 0; k < count; ++k) out[k] = c.data(point(k), t_new);
    const auto n = static_cast<std::ptrdiff_t>(count);
#pragma omp parallel for schedule(dynamic, 16) if (n >= 64)
    for (std::ptrdiff_t kk = 0; kk < n; ++kk) {
      const auto k = static_cast<std::size_t>(kk);
      const Vec3& y = point(k);
      out[k] = density.at(y) - target(y, out[k]);
    }
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
    std::vector<double> excess;
    excess_at([&](std::size_t k) -> const Vec3& { return particles.positions()[in_j[k]]; }, in_j.size(), excess);
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
  std::vector<double> deficit;
  excess_at([&](std::size_t k) -> const Vec3& { return cand[k]; }, cand.size(), deficit);
  for (double& v : deficit) v = -v;
  // A placed particle lowers the deficit within its own kernel's cut-off
  // (not the density's: with no particle yet, as when the band is filled
  // at the start, that is the cut-off of a unit width, and every candidate
  // was updated with exponentials that underflow: 80 s of the sphere's
  // set-up at n_inf = 25600).
  const double r_insert = cutoff_radius(width_s_, kPlacementKernelTolerance);
  const double r2_insert = r_insert * r_insert;
  CellGrid grid;
  grid.build(cand, r_insert, Periodicity::none(dim), 1);
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
        if (!used[l] && (cand[l] - y).squaredNorm() < r2_insert) deficit[l] -= kernel(cand[l], y);
      });
      ++led.inserted;
      ++call.inserted;
      led.mass_inserted += mp;
      call.mass_inserted += mp;
    }
  }
}

}  // namespace otfp
