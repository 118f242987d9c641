#include "otfp/boundary.hpp"

#include <algorithm>
#include <sstream>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <queue>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "boundary_internal.hpp"
#include "otfp/neighbor_list.hpp"
#include "placement_density.hpp"

namespace otfp {

using detail::draw_without_replacement;
using detail::kCountTolerance;
using detail::kQuadratureSeed;
using detail::kSurfaceSeed;
using detail::mean_of;

void ProjectionOptions::validate(bool require_reservoir_domain) const {
  require(std::isfinite(layer_b) && layer_b > 0.0, "boundary.layer_b", layer_b, "must be finite and > 0");
  require(quadrature_samples >= 1000, "boundary.quadrature_samples", quadrature_samples, "must be >= 1000");
  require(neumann_outflow == NeumannOutflow::Layer || neumann_outflow == NeumannOutflow::NearestParticles,
          "boundary.neumann_outflow", static_cast<double>(static_cast<int>(neumann_outflow)),
          "must be layer or nearest_particles");
  require(nearest_surface_points >= 16, "boundary.nearest_surface_points", nearest_surface_points, "must be >= 16");
  require(dirichlet_mode == DirichletMode::Layer || dirichlet_mode == DirichletMode::Reservoir,
          "boundary.dirichlet_mode", static_cast<double>(static_cast<int>(dirichlet_mode)),
          "must be layer or reservoir");
  if (dirichlet_mode != DirichletMode::Reservoir) return;
  require(reservoir_domain != nullptr || !require_reservoir_domain, "boundary.reservoir_domain", "null",
          "must be set when boundary.dirichlet_mode = reservoir (Omega extended outward by w)");
  require(std::isfinite(reservoir_thickness) && reservoir_thickness > 0.0, "boundary.reservoir_thickness",
          reservoir_thickness, "must be finite and > 0 when boundary.dirichlet_mode = reservoir");
  require(reservoir_sublayers >= 0 && reservoir_sublayers <= 1000, "boundary.reservoir_sublayers",
          reservoir_sublayers, "must be in [0, 1000] (0: about one particle spacing per sublayer)");
  require(reservoir_control == ReservoirControl::Quiet || reservoir_control == ReservoirControl::Exact,
          "boundary.reservoir_control", static_cast<double>(static_cast<int>(reservoir_control)),
          "must be quiet or exact");
  require(std::isfinite(reservoir_tolerance) && reservoir_tolerance >= 0.5 && reservoir_tolerance <= 1e6,
          "boundary.reservoir_tolerance", reservoir_tolerance,
          "must be in [0.5, 1e6] (particles; below 0.5 a correction could round to none)");
  require(std::isfinite(reservoir_integral_time) && reservoir_integral_time >= 0.0, "boundary.reservoir_integral_time",
          reservoir_integral_time, "must be finite and >= 0 (0: no integral action)");
  require(std::isfinite(reservoir_group_target) && reservoir_group_target >= 1.0 && reservoir_group_target <= 1e9,
          "boundary.reservoir_group_target", reservoir_group_target, "must be in [1, 1e9] (particles)");
  require(reservoir_candidates >= 1 && reservoir_candidates <= 1000, "boundary.reservoir_candidates",
          reservoir_candidates, "must be in [1, 1000] (candidate points per target particle)");
  require(reservoir_volume_samples >= 10000, "boundary.reservoir_volume_samples", reservoir_volume_samples,
          "must be >= 10000");
  require(!absorb_exterior, "boundary.absorb_exterior", "true",
          "applies to dirichlet_mode = layer only (the reservoir always absorbs beyond boundary.reservoir_domain)");
}

BoundaryProjection::BoundaryProjection(DomainPtr domain, std::vector<PatchCondition> conditions,
                                       ProjectionOptions options, double particle_mass, double width_s)
    : domain_(std::move(domain)),
      conditions_(std::move(conditions)),
      options_(options),
      particle_mass_(particle_mass),
      width_s_(width_s) {
  options_.validate();
  require(domain_ != nullptr, "boundary.domain", "null", "must be set");
  require(std::isfinite(particle_mass_) && particle_mass_ > 0.0, "boundary.particle_mass", particle_mass_,
          "must be finite and > 0");
  require(std::isfinite(width_s_) && width_s_ > 0.0, "boundary.width_s", width_s_, "must be finite and > 0");
  const int np = domain_->num_patches();
  std::vector<bool> seen(static_cast<std::size_t>(std::max(np, 0)), false);
  for (const PatchCondition& c : conditions_) {
    require(c.patch >= 0 && c.patch < np, "boundary.patch", c.patch,
            "must be in [0, " + std::to_string(np) + ") (patches of the domain)");
    require(!seen[static_cast<std::size_t>(c.patch)], "boundary.patch", c.patch,
            "appears more than once (at most one condition per patch)");
    seen[static_cast<std::size_t>(c.patch)] = true;
    if (c.kind != PatchKind::NoFlux)
      require(static_cast<bool>(c.data), "boundary.data", "missing",
              "must be given for the " + to_string(c.kind) + " patch " + std::to_string(c.patch) + " ('" +
                  domain_->patch_name(c.patch) + "')");
  }

  const double b = options_.layer_b;
  const std::size_t n = conditions_.size();
  ledger_.assign(n, PatchLedger{});
  interior_cell_volume_.assign(n, 0.0);
  quadrature_points_.assign(n, {});
  for (std::size_t i = 0; i < n; ++i) {
    const PatchCondition& c = conditions_[i];
    if (c.kind == PatchKind::NoFlux) continue;
    const bool cell_integral =
        c.kind == PatchKind::Dirichlet && options_.dirichlet_target == DirichletTarget::CellIntegral;
    if (c.kind == PatchKind::Dirichlet)
      interior_cell_volume_[i] = domain_->layer_cell_volume(c.patch, b, LayerPart::Interior);
    // An empty interior cell has target 0 whatever g is; sampling it would never succeed.
    if (cell_integral && interior_cell_volume_[i] <= 0.0) continue;
    Rng rng(kQuadratureSeed + static_cast<std::uint64_t>(c.patch));
    const int count = c.data_is_constant ? 1 : options_.quadrature_samples;
    std::vector<Vec3>& pts = quadrature_points_[i];
    pts.reserve(static_cast<std::size_t>(count));
    for (int k = 0; k < count; ++k) {
      if (cell_integral) {
        pts.push_back(domain_->sample_layer_cell(c.patch, b, LayerPart::Interior, rng));
      } else {
        // Surface integrals over A_l: closest points of uniform samples of the
        // whole layer B_l. The layer is symmetric about A_l, so the
        // first-order curvature bias of the projected density cancels.
        pts.push_back(domain_->closest_point(domain_->sample_layer_cell(c.patch, b, LayerPart::Whole, rng)));
      }
    }
  }

  reservoirs_.assign(n, Reservoir{});
  if (options_.dirichlet_mode == DirichletMode::Reservoir) {
    const Domain& ext = *options_.reservoir_domain;
    require(ext.dim() == domain_->dim(), "boundary.reservoir_domain dim", ext.dim(),
            "must equal the domain dim = " + std::to_string(domain_->dim()));
    require(!ext.is_periodic(), "boundary.reservoir_domain", "periodic", "must have a boundary");
    const Aabb own = domain_->bounding_box(), outer = ext.bounding_box();
    const double tol = 1e-12 * (1.0 + (own.hi - own.lo).norm());
    bool contains = true;
    for (int k = 0; k < domain_->dim(); ++k)
      contains = contains && outer.lo[k] <= own.lo[k] + tol && outer.hi[k] >= own.hi[k] - tol;
    require(contains, "boundary.reservoir_domain", "bounding box",
            "must contain the domain's bounding box (Omega extended outward by w over the Dirichlet patches)");
    for (std::size_t i = 0; i < n; ++i)
      if (conditions_[i].kind == PatchKind::Dirichlet) build_reservoir(i);
  }

  surface_points_.assign(n, {});
  surface_center_.assign(n, Vec3::Zero());
  surface_radius_.assign(n, 0.0);
  if (options_.neumann_outflow == NeumannOutflow::NearestParticles) {
    for (std::size_t i = 0; i < n; ++i) {
      const PatchCondition& c = conditions_[i];
      if (c.kind != PatchKind::Neumann) continue;
      // Closest points of uniform samples of B_l: points of A_l, denser
      // where A_l is (about uniform in area for b small against curvature).
      Rng rng(kSurfaceSeed + static_cast<std::uint64_t>(c.patch));
      std::vector<Vec3>& pts = surface_points_[i];
      pts.reserve(static_cast<std::size_t>(options_.nearest_surface_points));
      Vec3 sum = Vec3::Zero();
      for (int k = 0; k < options_.nearest_surface_points; ++k) {
        pts.push_back(domain_->closest_point(domain_->sample_layer_cell(c.patch, b, LayerPart::Whole, rng)));
        sum += pts.back();
      }
      surface_center_[i] = sum / static_cast<double>(pts.size());
      for (const Vec3& y : pts) surface_radius_[i] = std::max(surface_radius_[i], (y - surface_center_[i]).norm());
    }
  }
}


BoundaryProjection::State BoundaryProjection::state() const {
  State st;
  st.ledger = ledger_;
  for (const Reservoir& r : reservoirs_) st.reservoir_carry.push_back(r.carry);
  return st;
}

void BoundaryProjection::restore(const State& st) {
  require(st.ledger.size() == ledger_.size(), "projection state: conditions", static_cast<double>(st.ledger.size()),
          "must equal the projection's " + std::to_string(ledger_.size()));
  require(st.reservoir_carry.size() == reservoirs_.size(), "projection state: reservoirs",
          static_cast<double>(st.reservoir_carry.size()), "must equal " + std::to_string(reservoirs_.size()));
  for (std::size_t i = 0; i < reservoirs_.size(); ++i)
    require(st.reservoir_carry[i].size() == reservoirs_[i].carry.size(), "projection state: sublayers of condition " + std::to_string(i),
            static_cast<double>(st.reservoir_carry[i].size()), "must equal " + std::to_string(reservoirs_[i].carry.size()));
  ledger_ = st.ledger;
  for (std::size_t i = 0; i < reservoirs_.size(); ++i) reservoirs_[i].carry = st.reservoir_carry[i];
}

std::vector<int> BoundaryProjection::dirichlet_patches() const {
  std::vector<int> out;
  for (const PatchCondition& c : conditions_)
    if (c.kind == PatchKind::Dirichlet) out.push_back(c.patch);
  return out;
}

double BoundaryProjection::dirichlet_target_mass(std::size_t condition_index, double t) const {
  require(condition_index < conditions_.size(), "boundary condition index", static_cast<double>(condition_index),
          "must be < number of conditions = " + std::to_string(conditions_.size()));
  const PatchCondition& c = conditions_[condition_index];
  require(c.kind == PatchKind::Dirichlet, "boundary condition kind", to_string(c.kind), "must be dirichlet");
  const std::vector<Vec3>& pts = quadrature_points_[condition_index];
  double target = 0.0;
  if (options_.dirichlet_target == DirichletTarget::CellIntegral) {
    // docs/method_notes.md#dirichlet-target: the integral of g over B_l^int itself.
    if (interior_cell_volume_[condition_index] > 0.0)
      target = interior_cell_volume_[condition_index] * mean_of(c.data, pts, t);
  } else {
    // (34): b times the integral of g over A_l.
    target = options_.layer_b * domain_->patch_area(c.patch) * mean_of(c.data, pts, t);
  }
  require(std::isfinite(target), "dirichlet target mass (patch " + std::to_string(c.patch) + ")", target,
          "must be finite (check g)");
  return target;
}

PatchLedger BoundaryProjection::apply(ParticleSet& particles, double t, double dt, Rng& rng) {
  require(std::isfinite(t), "t", t, "must be finite");
  require(std::isfinite(dt) && dt >= 0.0, "dt", dt, "must be finite and >= 0");
  require(particles.dim() == domain_->dim(), "particle dim", particles.dim(),
          "must equal the domain dim = " + std::to_string(domain_->dim()));
  const double t_new = t + dt;
  const double b = options_.layer_b;
  const double mp = particle_mass_;
  const std::size_t nc = conditions_.size();
  const bool reservoir_mode = options_.dirichlet_mode == DirichletMode::Reservoir;
  const bool nearest_outflow = options_.neumann_outflow == NeumannOutflow::NearestParticles;
  const double threshold = mp * (1.0 - kCountTolerance);

  // Layer-cell members of every active condition, from one query per particle.
  // Cells of different patches are disjoint and inserted particles are only
  // appended, so these indices stay valid until the single removal at the end.
  std::vector<int> condition_of_patch(static_cast<std::size_t>(domain_->num_patches()), -1);
  bool any_active = false, any_outflow_fallback = false;
  for (std::size_t i = 0; i < nc; ++i) {
    if (conditions_[i].kind == PatchKind::NoFlux) continue;
    condition_of_patch[static_cast<std::size_t>(conditions_[i].patch)] = static_cast<int>(i);
    any_active = true;
    any_outflow_fallback = any_outflow_fallback || (nearest_outflow && conditions_[i].kind == PatchKind::Neumann);
  }
  const std::size_t n0 = particles.size();
  std::vector<std::vector<std::size_t>> members(nc);
  std::vector<double> member_mass(nc, 0.0);
  std::vector<std::vector<std::vector<std::size_t>>> sublayer_members(nc);  // Reservoir: [condition][j]
  std::vector<std::vector<std::size_t>> absorbed(nc);                       // beyond the controlled region
  for (std::size_t i = 0; i < nc; ++i) sublayer_members[i].resize(static_cast<std::size_t>(reservoirs_[i].sublayers));
  // Signed distance and patch of every particle, kept for the outflow fallback.
  std::vector<double> sd_of;
  std::vector<int> patch_of;
  if (any_outflow_fallback) {
    sd_of.resize(n0);
    patch_of.resize(n0);
  }
  if (reservoir_mode && options_.reservoir_profile == ReservoirProfile::Odd) {
    // Particle mass in the mirror image of each sublayer (odd profile).
    const double w = options_.reservoir_thickness;
    for (std::size_t i = 0; i < nc; ++i) {
      Reservoir& r = reservoirs_[i];
      if (!r.wall) continue;
      std::fill(r.mirror_mass.begin(), r.mirror_mass.end(), 0.0);
      for (std::size_t p = 0; p < n0; ++p) {
        const Vec3& x = particles.positions()[p];
        if (r.wall->distance(x) < -w) continue;
        if (domain_->signed_distance(x) > 0.0) continue;
        const BoundaryQuery q = domain_->query(r.wall->reflect(x, nullptr));
        if (q.patch != conditions_[i].patch || !(q.signed_distance > 0.0) || q.signed_distance > w) continue;
        const int j = sublayer_of(q.signed_distance, r.sublayers);
        if (j >= 0) r.mirror_mass[static_cast<std::size_t>(j)] += particles.masses()[p];
      }
    }
  }
  if (any_active) {
    for (std::size_t p = 0; p < n0; ++p) {
      const Vec3& x = particles.positions()[p];
      const BoundaryQuery q = domain_->query(x);
      if (any_outflow_fallback) {
        sd_of[p] = q.signed_distance;
        patch_of[p] = q.patch;
      }
      if (q.patch < 0) continue;
      const int ci = condition_of_patch[static_cast<std::size_t>(q.patch)];
      if (ci < 0) continue;
      const auto i = static_cast<std::size_t>(ci);
      if (conditions_[i].kind == PatchKind::Dirichlet) {
        if (reservoir_mode) {
          // Inside Omega: never touched. Beyond Omega_ext: absorbed. In the
          // band: a member of its sublayer. Deeper than w inside Omega_ext: left alone.
          if (!(q.signed_distance > 0.0)) continue;
          if (options_.reservoir_domain->signed_distance(x) > 0.0) {
            absorbed[i].push_back(p);
            continue;
          }
          const int j = sublayer_of(q.signed_distance, reservoirs_[i].sublayers);
          if (j >= 0) sublayer_members[i][static_cast<std::size_t>(j)].push_back(p);
          continue;
        }
        if (options_.absorb_exterior && q.signed_distance > 0.0) {
          absorbed[i].push_back(p);
          continue;
        }
      }
      // Dirichlet acts on B_l^int, Neumann on the whole B_l (Algorithm 1, lines 8 and 18-20).
      const LayerPart part = conditions_[i].kind == PatchKind::Dirichlet ? LayerPart::Interior : LayerPart::Whole;
      if (!in_layer_part(q.signed_distance, b, part)) continue;
      members[i].push_back(p);
      member_mass[i] += particles.masses()[p];
    }
  }

  if (options_.draw_by_id) {
    // The candidates in id order: the same draws whatever the storage order
    // (a distributed run gathers its particles in another order).
    const std::vector<ParticleId>& ids = particles.ids();
    auto by_id = [&](std::vector<std::size_t>& pool) {
      std::sort(pool.begin(), pool.end(), [&](std::size_t u, std::size_t v) { return ids[u] < ids[v]; });
    };
    for (std::size_t i = 0; i < nc; ++i) {
      by_id(members[i]);
      for (auto& pool : sublayer_members[i]) by_id(pool);
    }
  }

  PatchLedger call;
  std::vector<std::size_t> to_remove;
  auto remove_for = [&](std::size_t i, std::size_t index) {
    PatchLedger& led = ledger_[i];
    const double m = particles.masses()[index];
    to_remove.push_back(index);
    ++led.removed;
    ++call.removed;
    led.mass_removed += m;
    call.mass_removed += m;
    return m;
  };
  for (std::size_t i = 0; i < nc; ++i) {
    const PatchCondition& c = conditions_[i];
    PatchLedger& led = ledger_[i];
    auto insert = [&](LayerPart part) {
      const Vec3 x = domain_->sample_layer_cell(c.patch, b, part, rng);
      particles.add(x, width_s_, mp, t_new);
      ++led.inserted;
      ++call.inserted;
      led.mass_inserted += mp;
      call.mass_inserted += mp;
    };
    auto remove = [&](std::size_t index) { return remove_for(i, index); };

    for (std::size_t p : absorbed[i]) {
      const double m = remove(p);
      ++led.absorbed;
      ++call.absorbed;
      led.mass_absorbed += m;
      call.mass_absorbed += m;
    }

    if (c.kind == PatchKind::Dirichlet && reservoir_mode) {
      if (options_.reservoir_control == ReservoirControl::Quiet)
        project_reservoir_quiet(i, sublayer_members[i], particles, t_new, dt, call, to_remove);
      else
        project_reservoir(i, sublayer_members[i], particles, t_new, rng, call, to_remove);
    } else if (c.kind == PatchKind::Dirichlet) {
      // Sec. 4.2 after (34): insert floor((m - m_pre)/m_p) particles when the
      // cell is short, delete floor((m_pre - m)/m_p) random ones when it is over.
      const double target = dirichlet_target_mass(i, t_new);
      const double pre = member_mass[i];
      if (target > pre) {
        const double want = std::floor((target - pre) / mp + kCountTolerance);
        require_particle_room(want, counted(particles), max_particles_, patch_label(i, t_new));
        const auto n = static_cast<long>(want);
        particles.reserve(particles.size() + static_cast<std::size_t>(n));
        for (long k = 0; k < n; ++k) insert(LayerPart::Interior);
      } else if (pre > target) {
        const double want = std::floor((pre - target) / mp + kCountTolerance);
        // Particles heavier than m_p could ask for more than are there.
        const auto n = std::min(static_cast<std::size_t>(want), members[i].size());
        for (std::size_t k = 0; k < n; ++k) remove(draw_without_replacement(members[i], k, rng));
      }
    } else if (c.kind == PatchKind::Neumann) {
      // (35) with f the outward flux: the inward mass of [t, t + dt] is
      // -int_t^{t+dt} int_{A_l} f. Simpson in time (exact for f linear or
      // quadratic in t), the fixed quadrature points over A_l in space.
      const double area = domain_->patch_area(c.patch);
      const std::vector<Vec3>& pts = quadrature_points_[i];
      const double f0 = mean_of(c.data, pts, t);
      const double fm = mean_of(c.data, pts, t + 0.5 * dt);
      const double f1 = mean_of(c.data, pts, t_new);
      const double inflow = -area * dt * (f0 + 4.0 * fm + f1) / 6.0;
      require(std::isfinite(inflow), "neumann flux integral (patch " + std::to_string(c.patch) + ")", inflow,
              "must be finite (check f)");
      led.flux_integral += inflow;
      call.flux_integral += inflow;
      // docs/method_notes.md#neumann-carry: move whole particles and carry the remainder, instead
      // of dropping floor's fraction every step as (50) does.
      led.carry += inflow;
      // Checked before the loop: a carry past 2^53 m_p would never decrease.
      if (led.carry >= threshold)
        require_particle_room(std::floor(led.carry / mp), counted(particles), max_particles_, patch_label(i, t_new));
      while (led.carry >= threshold) {
        insert(LayerPart::Whole);
        led.carry -= mp;
      }
      std::size_t k = 0;
      while (led.carry <= -threshold && k < members[i].size()) {
        led.carry += remove(draw_without_replacement(members[i], k, rng));
        ++k;
      }
    }
  }

  // NearestParticles: what B_l could not supply comes from the particles
  // nearest A_l, after every condition has taken its own particles.
  if (any_outflow_fallback) {
    std::vector<char> taken(n0, 0);
    for (std::size_t p : to_remove) taken[p] = 1;
    for (std::size_t i = 0; i < nc; ++i) {
      if (conditions_[i].kind != PatchKind::Neumann || ledger_[i].carry > -threshold) continue;
      remove_nearest(i, particles, sd_of, patch_of, taken, threshold, [&](std::size_t p) { return remove_for(i, p); });
    }
  }

  // Whatever could not be removed stays in carry; deficit flags it.
  for (std::size_t i = 0; i < nc; ++i) {
    if (conditions_[i].kind != PatchKind::Neumann) continue;
    PatchLedger& led = ledger_[i];
    led.deficit = led.carry <= -threshold ? -led.carry : 0.0;
    call.carry += led.carry;
    call.deficit += led.deficit;
  }

  if (!to_remove.empty()) particles.remove_indices(std::move(to_remove));
  return call;
}

bool BoundaryProjection::reads(const Vec3& x, double s_max) const {
  const double sd = domain_->signed_distance(x);
  if (!(sd <= 0.0)) return true;  // outside Omega (or undecided): absorbed, a band member, or beyond
  const bool reservoir_mode = options_.dirichlet_mode == DirichletMode::Reservoir;
  // The band's mass sums follow a blob kTailWidths widths (reservoir_quiet.cpp);
  // the placement density is evaluated in the band and at its mirror points
  // inside (depth <= w), over blobs within its kernel's cut-off.
  const double cutoff = cutoff_radius(s_max, detail::kPlacementKernelTolerance);
  double reach = std::max(detail::kTailWidths * s_max, cutoff);
  // An obstacle's reflection can bring a blob's image up to two cut-offs
  // nearer the points where the placement density is evaluated.
  for (const MirrorWallPtr& w : walls_)
    if (!w->keeps_images_farther()) {
      reach += 2.0 * cutoff;
      break;
    }
  for (std::size_t i = 0; i < conditions_.size(); ++i) {
    const PatchCondition& c = conditions_[i];
    if (c.kind == PatchKind::NoFlux) continue;
    if (c.kind == PatchKind::Neumann && options_.neumann_outflow == NeumannOutflow::NearestParticles) return true;
    if (c.kind == PatchKind::Dirichlet && reservoir_mode) {
      const Reservoir& r = reservoirs_[i];
      const double xi = r.wall ? r.wall->distance(x) : sd;  // both 1-Lipschitz, < 0 inside
      if (xi > -(options_.reservoir_thickness + reach)) return true;
    } else if (sd > -options_.layer_b) {
      return true;  // B_l and B_l^int lie within b of the boundary
    }
  }
  return false;
}

std::string BoundaryProjection::patch_label(std::size_t i, double t) const {
  const PatchCondition& c = conditions_[i];
  std::ostringstream os;
  os << "the " << to_string(c.kind) << " patch " << c.patch << " ('" << domain_->patch_name(c.patch) << "') at t = "
     << t;
  return os.str();
}

// order of the bound only while the bound can still beat the best found.
void BoundaryProjection::remove_nearest(std::size_t i, const ParticleSet& particles, const std::vector<double>& sd_of,
                                        const std::vector<int>& patch_of, std::vector<char>& taken, double threshold,
                                        const std::function<double(std::size_t)>& remove) {
  const int patch = conditions_[i].patch;
  const std::vector<Vec3>& pts = surface_points_[i];
  const Vec3& center = surface_center_[i];
  const double radius = surface_radius_[i];
  const std::vector<Vec3>& x = particles.positions();
  auto exact = [&](std::size_t p) {
    if (patch_of[p] == patch) return std::abs(sd_of[p]);
    double best = std::numeric_limits<double>::infinity();
    for (const Vec3& y : pts) best = std::min(best, (x[p] - y).squaredNorm());
    return std::sqrt(best);
  };
  std::vector<std::pair<double, std::size_t>> bound;
  for (std::size_t p = 0; p < taken.size(); ++p) {
    if (taken[p]) continue;
    const double lb = patch_of[p] == patch ? std::abs(sd_of[p])
                                           : std::max(std::abs(sd_of[p]), (x[p] - center).norm() - radius);
    bound.emplace_back(std::isfinite(lb) ? lb : 0.0, p);
  }
  std::sort(bound.begin(), bound.end());
  using Entry = std::pair<double, std::size_t>;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<>> evaluated;
  std::size_t next = 0;
  PatchLedger& led = ledger_[i];
  while (led.carry <= -threshold) {
    while (next < bound.size() && (evaluated.empty() || bound[next].first <= evaluated.top().first)) {
      evaluated.emplace(exact(bound[next].second), bound[next].second);
      ++next;
    }
    if (evaluated.empty()) break;  // no particle left: the debt stays in carry
    const std::size_t p = evaluated.top().second;
    evaluated.pop();
    taken[p] = 1;
    led.carry += remove(p);
  }
}

}  // namespace otfp
