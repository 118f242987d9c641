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

namespace otfp {

namespace {

// Fixed seed for the quadrature points: targets must not change run to run.
constexpr std::uint64_t kQuadratureSeed = 0x626e647271756164ULL;
// Counts are floors of mass ratios; a ratio that is an integer up to
// round-off (e.g. 0.37 added 100 times) must count as that integer.
constexpr double kCountTolerance = 1e-9;

// Fixed seeds of the reservoir volumes / quadrature and of the points on A_l.
constexpr std::uint64_t kReservoirSeed = 0x7265736572766f69ULL;
constexpr std::uint64_t kSurfaceSeed = 0x7375726661636570ULL;
// Automatic sublayer count: at most this many.
constexpr int kMaxAutoSublayers = 64;
// Rejection sampling of reservoir insertions: give up after this many tries per particle.
constexpr long kMaxTriesPerInsert = 10'000'000;
// A closed-form sublayer volume is used only if it agrees with the Monte
// Carlo estimate within this many standard errors.
constexpr double kVolumeAgreementSigmas = 4.0;

Vec3 uniform_in(const Aabb& box, int dim, Rng& rng) {
  Vec3 x = Vec3::Zero();
  for (int k = 0; k < dim; ++k) x[k] = rng.uniform(box.lo[k], box.hi[k]);
  return x;
}

double box_measure(const Aabb& box, int dim) {
  double v = 1.0;
  for (int k = 0; k < dim; ++k) v *= std::max(box.hi[k] - box.lo[k], 0.0);
  return v;
}

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
  std::vector<double> shell(K), slab(K);
  bool shell_closed_form = true;
  double below = 0.0;
  for (std::size_t j = 0; j < K; ++j) {
    const double t = depth(j + 1);
    const double v1 = domain_->layer_cell_volume(c.patch, t, LayerPart::Exterior, 1000);
    const double v2 = domain_->layer_cell_volume(c.patch, t, LayerPart::Exterior, 1001);
    shell_closed_form = shell_closed_form && v1 == v2;
    shell[j] = v1 - below;
    below = v1;
    slab[j] = domain_->patch_area(c.patch) * (t - depth(j));
  }
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
    std::vector<double> inner_shell(K);
    double inner_below = 0.0;
    bool inner_closed_form = true;
    for (std::size_t jj = 0; jj < K; ++jj) {
      const double t = depth(jj + 1);
      const double v1 = domain_->layer_cell_volume(c.patch, t, LayerPart::Interior, 1000);
      const double v2 = domain_->layer_cell_volume(c.patch, t, LayerPart::Interior, 1001);
      inner_closed_form = inner_closed_form && v1 == v2;
      inner_shell[jj] = v1 - inner_below;
      inner_below = v1;
    }
    if (r.volume_rule != "monte_carlo" && agrees_m(r.volume))
      r.mirror_volume = r.volume;
    else if (inner_closed_form && agrees_m(inner_shell))
      r.mirror_volume = inner_shell;
    else
      r.mirror_volume = mmc;
    r.mirror_mass.assign(K, 0.0);
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
      if (!in_part(q.signed_distance, b, part)) continue;
      members[i].push_back(p);
      member_mass[i] += particles.masses()[p];
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
      project_reservoir(i, sublayer_members[i], particles, t_new, rng, call, to_remove);
    } else if (c.kind == PatchKind::Dirichlet) {
      // Sec. 4.2 after (34): insert floor((m - m_pre)/m_p) particles when the
      // cell is short, delete floor((m_pre - m)/m_p) random ones when it is over.
      const double target = dirichlet_target_mass(i, t_new);
      const double pre = member_mass[i];
      if (target > pre) {
        const double want = std::floor((target - pre) / mp + kCountTolerance);
        require_particle_room(want, particles.size(), max_particles_, patch_label(i, t_new));
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
        require_particle_room(std::floor(led.carry / mp), particles.size(), max_particles_, patch_label(i, t_new));
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

std::string BoundaryProjection::patch_label(std::size_t i, double t) const {
  const PatchCondition& c = conditions_[i];
  std::ostringstream os;
  os << "the " << to_string(c.kind) << " patch " << c.patch << " ('" << domain_->patch_name(c.patch) << "') at t = "
     << t;
  return os.str();
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
    double x_j = reservoir_target_count(i, static_cast<int>(j), t_new);
    if (r.wall && !r.mirror_volume.empty()) {
      // Odd parity about g: density 2 g - rho_in, clamped to [0, 2 g].
      const double rho_in = r.mirror_mass[j] / r.mirror_volume[j];
      const double g_mass = x_j * mp;  // g |sublayer j|
      const double want = std::clamp(2.0 * g_mass - rho_in * r.volume[j], 0.0, 2.0 * g_mass);
      x_j = want / mp;
    }
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
