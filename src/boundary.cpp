#include "otfp/boundary.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace otfp {

namespace {

// Fixed seed for the quadrature points: targets must not change run to run.
constexpr std::uint64_t kQuadratureSeed = 0x626e647271756164ULL;
// Counts are floors of mass ratios; a ratio that is an integer up to
// round-off (e.g. 0.37 added 100 times) must count as that integer.
constexpr double kCountTolerance = 1e-9;

// Same rule as Domain::in_layer_cell, applied to a query already made.
bool in_part(double sd, double b, LayerPart part) {
  switch (part) {
    case LayerPart::Interior: return sd >= -b && sd <= 0.0;
    case LayerPart::Exterior: return sd > 0.0 && sd <= b;
    case LayerPart::Whole: return std::abs(sd) <= b;
  }
  return false;
}

double mean_of(const BoundaryData& g, const std::vector<Vec3>& points, double t) {
  double sum = 0.0;
  for (const Vec3& y : points) sum += g(y, t);
  return sum / static_cast<double>(points.size());
}

// Draws one not-yet-drawn entry of pool[k..] uniformly (partial Fisher-Yates),
// so repeated calls with k = 0, 1, ... sample without replacement.
std::size_t draw_without_replacement(std::vector<std::size_t>& pool, std::size_t k, Rng& rng) {
  const std::size_t j = k + static_cast<std::size_t>(rng.below(pool.size() - k));
  std::swap(pool[k], pool[j]);
  return pool[k];
}

}  // namespace

std::string to_string(PatchKind k) {
  switch (k) {
    case PatchKind::NoFlux: return "no_flux";
    case PatchKind::Dirichlet: return "dirichlet";
    case PatchKind::Neumann: return "neumann";
  }
  return "unknown";
}

PatchKind patch_kind_from_string(const std::string& s) {
  if (s == "no_flux") return PatchKind::NoFlux;
  if (s == "dirichlet") return PatchKind::Dirichlet;
  if (s == "neumann") return PatchKind::Neumann;
  require(false, "boundary.kind", s, "must be one of no_flux, dirichlet, neumann");
  return PatchKind::NoFlux;
}

void ProjectionOptions::validate() const {
  require(std::isfinite(layer_b) && layer_b > 0.0, "boundary.layer_b", layer_b, "must be finite and > 0");
  require(quadrature_samples >= 1000, "boundary.quadrature_samples", quadrature_samples, "must be >= 1000");
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
    // METHOD-NOTES 2.7: the integral of g over B_l^int itself.
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

  // Layer-cell members of every active condition, from one query per particle.
  // Cells of different patches are disjoint and inserted particles are only
  // appended, so these indices stay valid until the single removal at the end.
  std::vector<int> condition_of_patch(static_cast<std::size_t>(domain_->num_patches()), -1);
  bool any_active = false;
  for (std::size_t i = 0; i < nc; ++i) {
    if (conditions_[i].kind == PatchKind::NoFlux) continue;
    condition_of_patch[static_cast<std::size_t>(conditions_[i].patch)] = static_cast<int>(i);
    any_active = true;
  }
  std::vector<std::vector<std::size_t>> members(nc);
  std::vector<double> member_mass(nc, 0.0);
  if (any_active) {
    const std::size_t n0 = particles.size();
    for (std::size_t p = 0; p < n0; ++p) {
      const BoundaryQuery q = domain_->query(particles.positions()[p]);
      if (q.patch < 0) continue;
      const int ci = condition_of_patch[static_cast<std::size_t>(q.patch)];
      if (ci < 0) continue;
      const auto i = static_cast<std::size_t>(ci);
      // Dirichlet acts on B_l^int, Neumann on the whole B_l (Algorithm 1, lines 8 and 18-20).
      const LayerPart part = conditions_[i].kind == PatchKind::Dirichlet ? LayerPart::Interior : LayerPart::Whole;
      if (!in_part(q.signed_distance, b, part)) continue;
      members[i].push_back(p);
      member_mass[i] += particles.masses()[p];
    }
  }

  PatchLedger call;
  std::vector<std::size_t> to_remove;
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
    auto remove = [&](std::size_t index) {
      const double m = particles.masses()[index];
      to_remove.push_back(index);
      ++led.removed;
      ++call.removed;
      led.mass_removed += m;
      call.mass_removed += m;
      return m;
    };

    if (c.kind == PatchKind::Dirichlet) {
      // Sec. 4.2 after (34): insert floor((m - m_pre)/m_p) particles when the
      // cell is short, delete floor((m_pre - m)/m_p) random ones when it is over.
      const double target = dirichlet_target_mass(i, t_new);
      const double pre = member_mass[i];
      if (target > pre) {
        const auto n = static_cast<long>(std::floor((target - pre) / mp + kCountTolerance));
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
      // METHOD-NOTES 2.6: move whole particles and carry the remainder, instead
      // of dropping floor's fraction every step as (50) does.
      led.carry += inflow;
      const double threshold = mp * (1.0 - kCountTolerance);
      while (led.carry >= threshold) {
        insert(LayerPart::Whole);
        led.carry -= mp;
      }
      std::size_t k = 0;
      while (led.carry <= -threshold && k < members[i].size()) {
        led.carry += remove(draw_without_replacement(members[i], k, rng));
        ++k;
      }
      // Whatever could not be removed stays in carry; deficit flags it.
      led.deficit = led.carry <= -threshold ? -led.carry : 0.0;
    }
    if (c.kind == PatchKind::Neumann) {
      call.carry += led.carry;
      call.deficit += led.deficit;
    }
  }

  if (!to_remove.empty()) particles.remove_indices(std::move(to_remove));
  return call;
}

}  // namespace otfp
