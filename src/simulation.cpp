#include "otfp/simulation.hpp"
#include "otfp/run_distribution.hpp"

#include <algorithm>
#include <charconv>
#include <string_view>
#include <type_traits>
#include <chrono>
#include <cmath>
#include <cstring>
#include <exception>
#include <fstream>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <system_error>
#include <unistd.h>

#include "otfp/barrier.hpp"
#include "otfp/density.hpp"
#include "otfp/fractional.hpp"
#include "otfp/images.hpp"
#include "otfp/neighbor_list.hpp"

namespace otfp {

namespace {

using Clock = std::chrono::steady_clock;

double overlap(double a, double b, double lo, double hi) { return std::max(0.0, std::min(b, hi) - std::max(a, lo)); }

// "{}" placeholders filled in order; doubles in their shortest round-trip
// form (as the CLI's messages print them).
void append(std::string& out, double v) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v);
  out.append(buf, r.ptr);
}
// A double for people: six significant digits (printf's %.6g).
struct Sig6 {
  double v;
};
void append(std::string& out, Sig6 v) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v.v, std::chars_format::general, 6);
  out.append(buf, r.ptr);
}
void append(std::string& out, const std::string& v) { out += v; }
void append(std::string& out, const char* v) { out += v; }
void append(std::string& out, char v) { out += v; }
template <class I, std::enable_if_t<std::is_integral_v<I>, int> = 0>
void append(std::string& out, I v) {
  out += std::to_string(v);
}
void format_rest(std::string& out, std::string_view pattern) { out.append(pattern); }
template <class T, class... Rest>
void format_rest(std::string& out, std::string_view pattern, const T& first, const Rest&... rest) {
  const std::size_t at = pattern.find("{}");
  if (at == std::string_view::npos) {
    out.append(pattern);
    return;
  }
  out.append(pattern.substr(0, at));
  append(out, first);
  format_rest(out, pattern.substr(at + 2), rest...);
}
template <class... Args>
std::string format(std::string_view pattern, const Args&... args) {
  std::string out;
  format_rest(out, pattern, args...);
  return out;
}

}  // namespace

namespace {
// The fields Simulation itself uses; the projection and stepper options are
// checked by their own validate().
void validate_own_fields(const SimulationOptions& o) {
  const double particle_mass = o.particle_mass, width_s = o.width_s, barrier_stiffness = o.barrier_stiffness;
  const double source_rate = o.source_rate;
  const Vec3& velocity = o.velocity;
  const int max_error_rejections = o.max_error_rejections;
  require(std::isfinite(particle_mass) && particle_mass > 0.0, "particle_mass", particle_mass, "must be finite and > 0");
  require(std::isfinite(width_s) && width_s > 0.0, "width_s", width_s, "must be finite and > 0");
  require(std::isfinite(barrier_stiffness) && barrier_stiffness >= 0.0, "barrier_stiffness", barrier_stiffness,
          "must be finite and >= 0");
  require(velocity.allFinite(), "velocity", velocity.norm(), "must be finite");
  require(std::isfinite(source_rate), "source_rate", source_rate, "must be finite");
  require(max_error_rejections >= 1, "max_error_rejections", max_error_rejections, "must be >= 1");
  require(o.max_particles >= 0 && o.max_particles <= kMaxParticleCount, "max_particles",
          static_cast<double>(o.max_particles), "must be in [0, 2^53] (0: default_max_particles())");
  o.time_control.validate();
}
}  // namespace

std::int64_t default_max_particles() {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  const double bytes = pages > 0 && page > 0 ? static_cast<double>(pages) * static_cast<double>(page) : 4e9;
  return std::max<std::int64_t>(1000, static_cast<std::int64_t>(0.5 * bytes / kBytesPerParticle));
}

void SimulationOptions::validate() const {
  validate_own_fields(*this);
  projection.validate(/*require_reservoir_domain=*/false);  // the Simulation builds it
  if (stepper == StepperKind::Implicit)
    implicit.validate();
  else
    explicit_options.validate();
}

// ------------------------------------------------------------------ building

struct Simulation::Saved {
  ParticleSet particles;
  Rng rng;
  SimulationLedger ledger;
  SimulationTotals totals;
  BoundaryProjection::State projection;
  double time = 0.0, dt_next = 0.0;
  std::int64_t step = 0;
};

Simulation::Simulation(DomainPtr domain, std::vector<ConstantBoundaryData> boundary, SimulationOptions options)
    : Simulation(std::move(domain), std::move(boundary), std::move(options), nullptr) {}

Simulation::Simulation(DomainPtr domain, std::vector<ConstantBoundaryData> boundary, SimulationOptions options,
                       std::shared_ptr<RunDistribution> distribution)
    : domain_(std::move(domain)),
      boundary_(std::move(boundary)),
      distribution_(std::move(distribution)),
      particles_(domain_ ? domain_->dim() : 3),
      options_(std::move(options)),
      rng_(options_.seed),
      step_window_(std::make_shared<std::pair<double, double>>(0.0, 0.0)),
      saved_(std::make_unique<Saved>()) {
  if (!domain_) throw InvalidArgument("domain: must not be null");
  // The projection and stepper options are checked where they are used, so
  // that their errors carry their stage.
  validate_own_fields(options_);
  const int dim = domain_->dim();
  const SimulationOptions& o = options_;
  // Conditions, in the order of `boundary`.
  condition_of_patch_.assign(static_cast<std::size_t>(domain_->num_patches()), -1);
  buffer_.buffer_patch.assign(static_cast<std::size_t>(domain_->num_patches()), 0);
  std::vector<PatchCondition> conditions;
  std::vector<int> dirichlet_ids;
  for (std::size_t i = 0; i < boundary_.size(); ++i) {
    const ConstantBoundaryData& b = boundary_[i];
    require(b.patch >= 0 && b.patch < domain_->num_patches(), format("boundary[{}].patch", i), b.patch,
            format("must be a patch id in [0, {})", domain_->num_patches()));
    require(condition_of_patch_[static_cast<std::size_t>(b.patch)] < 0, format("boundary[{}].patch", i), b.patch,
            "appears twice");
    require(std::isfinite(b.value), format("boundary[{}].value", i), b.value, "must be finite");
    require(b.t_end >= b.t_start, format("boundary[{}].t_end", i), b.t_end, "must be >= t_start");
    require(o.bounded, format("boundary[{}]", i), b.patch, "free space (bounded = false) takes no boundary data");
    PatchCondition pc;
    pc.patch = b.patch;
    pc.kind = b.kind;
    pc.data_is_constant = true;
    if (b.kind == PatchKind::Dirichlet) {
      const double g = b.value;
      pc.data = [g](const Vec3&, double) { return g; };
      dirichlet_ids.push_back(b.patch);
      buffer_.buffer_patch[static_cast<std::size_t>(b.patch)] = 1;
    } else {
      // Neumann data is handed to the projection as its average over the
      // step being projected, so that windows [t_start, t_end) that end inside
      // a step still give the exact integral of f.
      const double f = b.value, a = b.t_start, e = b.t_end;
      const auto window = step_window_;
      pc.data = [f, a, e, window](const Vec3&, double) {
        const double t0 = window->first, t1 = window->second;
        return t1 > t0 ? f * overlap(t0, t1, a, e) / (t1 - t0) : 0.0;
      };
    }
    condition_of_patch_[static_cast<std::size_t>(b.patch)] = static_cast<int>(conditions.size());
    conditions.push_back(std::move(pc));
  }

  // Reservoir treatment (docs/boundaries.md): Omega_ext = Omega extended by a
  // band of width w over the Dirichlet patches.
  ProjectionOptions po = o.projection;
  // Over several processes the gathered particles come in another order, and
  // each rank holds its own share: only draws in id order (projection) and
  // per-id streams (source) give the same particles on any rank count.
  // Refused rather than overridden, so that a run never silently does other
  // than its options say.
  if (distribution_) {
    require(po.draw_by_id, "projection.draw_by_id", "false",
            "must be true on several processes (storage-order draws are serial only)");
    require(o.source_draws_by_id, "source_draws_by_id", "false",
            "must be true on several processes (one stream in storage order is serial only)");
  }
  if (po.dirichlet_mode == DirichletMode::Reservoir && !dirichlet_ids.empty()) {
    try {
      reservoir_domain_ = domain_->extended(dirichlet_ids, po.reservoir_thickness);
    } catch (const InvalidArgument& e) {
      throw SimulationSetupError(SimulationSetupError::Stage::Reservoir, e.what());
    }
    po.reservoir_domain = reservoir_domain_;
  } else {
    po.dirichlet_mode = DirichletMode::Layer;
  }
  buffer_.buffer_width = reservoir_domain_ ? po.reservoir_thickness : po.layer_b;
  try {
    po.validate();
    projection_ = std::make_unique<BoundaryProjection>(domain_, std::move(conditions), po, o.particle_mass, o.width_s);
    projection_->set_max_particles(max_particles());
  } catch (const InvalidArgument& e) {
    // The odd profile mirrors the band inside Omega: a band deeper than the domain has no mirror.
    if (reservoir_domain_ && std::string(e.what()).find("mirror image") != std::string::npos)
      throw SimulationSetupError(SimulationSetupError::Stage::ReservoirMirror, e.what());
    throw SimulationSetupError(SimulationSetupError::Stage::Projection, e.what());
  } catch (const std::runtime_error& e) {
    // The rejection sampler of a layer cell found no point (b far beyond the
    // domain, say): the options cannot be used, as for InvalidArgument.
    throw SimulationSetupError(SimulationSetupError::Stage::Projection, e.what());
  }

  const Periodicity periodicity = domain_->is_periodic() ? Periodicity::from_domain(*domain_) : Periodicity::none(dim);
  const NeighborOptions& nb = o.stepper == StepperKind::Implicit ? o.implicit.neighbor : o.explicit_options.neighbor;
  if (domain_->is_periodic()) {
    // The neighbour list needs two list radii per period (minimum image).
    const double radius = cutoff_radius(o.width_s, nb.kernel_tolerance) +
                          (nb.skin >= 0.0 ? nb.skin : nb.skin_factor * o.width_s);
    for (int k = 0; k < dim; ++k) {
      const double side = domain_->period()[k];
      if (side < 2.0 * radius)
        throw SimulationSetupError(
            SimulationSetupError::Stage::Periodic,
            format("the periodic box side {} (axis {}) must be at least twice the neighbour-list radius {}", side,
                        "xyz"[k], radius));
    }
  }

  Barrier barrier;
  if (o.bounded && !domain_->is_periodic()) {
    try {
      const std::vector<int> inflated = projection_->dirichlet_patches();
      if (reservoir_domain_) {
        // The band's back faces are no-flux walls with image blobs (a band
        // without them over-fills); the other walls are mirrored only with Images.
        barrier = Barrier(reservoir_domain_, o.barrier_stiffness);
        barrier_description_ = "Omega extended by the reservoir band over the Dirichlet patches";
        std::vector<int> open;
        if (o.no_flux != NoFluxTreatment::Images)
          for (int p = 0; p < domain_->num_patches(); ++p)
            if (!buffer_.buffer_patch[static_cast<std::size_t>(p)]) open.push_back(p);
        walls_ = mirror_walls(*reservoir_domain_, open);
      } else {
        const std::optional<DomainShape> shape = domain_->shape();
        if (shape && shape->kind == DomainShape::Kind::Box && domain_->num_patches() == 2 * dim && !inflated.empty()) {
          // Omega' = Omega u B^ext is again a box: the box extended by b over its
          // Dirichlet faces. Its distance is exact and continuous, whereas
          // inflating by patch jumps by up to b where the closest face changes
          // next to a Dirichlet face.
          Vec3 lo = shape->lo, hi = shape->hi;
          for (int p : inflated) (p % 2 == 0 ? lo : hi)[p / 2] += (p % 2 == 0 ? -po.layer_b : po.layer_b);
          barrier = Barrier(make_box(dim, lo, hi), o.barrier_stiffness);
          barrier_description_ = "box extended by b over its Dirichlet faces";
        } else {
          barrier = Barrier(domain_, o.barrier_stiffness, inflated, po.layer_b);
          barrier_description_ = inflated.empty() ? "Omega" : "Omega inflated by b over the Dirichlet patches";
        }
        if (o.no_flux == NoFluxTreatment::Images) walls_ = mirror_walls(*domain_, inflated);
      }
    } catch (const InvalidArgument& e) {
      throw SimulationSetupError(SimulationSetupError::Stage::Walls, e.what());
    }
  }
  // The quiet reservoir places particles by the density the functional sees.
  if (!walls_.empty()) projection_->set_mirror_walls(walls_);
  try {
    if (distribution_ && o.stepper == StepperKind::Implicit) {
      distribution_->configure(dim, o.implicit, barrier, periodicity, walls_);
    } else if (distribution_) {
      distribution_->configure_explicit(dim, o.explicit_options, barrier, periodicity, walls_);
    } else if (o.stepper == StepperKind::Implicit) {
      implicit_ = std::make_unique<ImplicitStepper>(dim, o.implicit, barrier, periodicity);
      if (!walls_.empty()) implicit_->functional().set_images(WallImages(walls_));
    } else {
      explicit_ = std::make_unique<ExplicitStepper>(dim, o.explicit_options, barrier, periodicity);
      if (!walls_.empty()) explicit_->functional().set_images(WallImages(walls_));
    }
  } catch (const InvalidArgument& e) {
    throw SimulationSetupError(SimulationSetupError::Stage::Stepper, e.what());
  }
}

Simulation::~Simulation() = default;

void RunDistribution::configure_explicit(int, const ExplicitOptions&, const Barrier&, const Periodicity&,
                                         const std::vector<MirrorWallPtr>&) {
  throw InvalidArgument("stepper = explicit: this distribution steps implicitly only");
}

int Simulation::mirrored_walls() const { return static_cast<int>(walls_.size()); }

int Simulation::condition_of(int patch) const {
  return patch >= 0 && static_cast<std::size_t>(patch) < condition_of_patch_.size()
             ? condition_of_patch_[static_cast<std::size_t>(patch)]
             : -1;
}

void Simulation::set_next_dt(double dt) {
  require(std::isfinite(dt) && dt > 0.0, "next dt", dt, "must be finite and > 0");
  dt_next_ = dt;
}

// ------------------------------------------------------------------ stepping

void Simulation::start(ParticleSet particles, double t0) { start(std::move(particles), Rng(options_.seed), t0); }

void Simulation::start(ParticleSet particles, Rng rng, double t0) {
  // Over several processes a refusal on one is every process's (before any
  // other collective).
  std::exception_ptr refused;
  try {
    require(particles.dim() == domain_->dim(), "particles dim", particles.dim(),
            "must equal the domain's dim " + std::to_string(domain_->dim()));
    require(std::isfinite(t0), "t0", t0, "must be finite");
  } catch (...) {
    refused = std::current_exception();
  }
  if (distribution_ && distribution_->sum(std::int64_t{refused ? 1 : 0}) > 0 && !refused)
    throw InvalidArgument("particles: refused by another process (its error names the field)");
  if (refused) std::rethrow_exception(refused);
  const std::int64_t cap = max_particles();
  const std::int64_t given = distribution_ ? distribution_->sum(static_cast<std::int64_t>(particles.size()))
                                            : static_cast<std::int64_t>(particles.size());
  require(given <= cap, "particles", static_cast<double>(given),
          "must be at most max_particles = " + std::to_string(cap));
  particles_ = std::move(particles);
  rng_ = rng;
  time_ = t0;
  step_ = 0;
  grid_ = TimeGrid{};
  ledger_ = SimulationLedger{};
  totals_ = SimulationTotals{};
  ledger_.initial_particles = given;
  ledger_.initial_mass = distribution_ ? distribution_->sum(particles_.total_mass()) : particles_.total_mass();
  if (implicit_) implicit_->reset_history();
  if (distribution_) distribution_->reset_history();
  initial_ = SimulationStep{};
  initial_.t_start = initial_.t_end = t0;
  initial_.diffusion.accepted = true;
  // The reservoir is the bath outside the Dirichlet face: it holds density g
  // from t = 0, so it is filled before the first step (a zero-length
  // projection: Neumann patches move nothing). Otherwise nothing can cross the
  // face during step 1 and M lags Crank by a whole step. The papers' layer
  // starts empty, as in Algorithm 1.
  if (options_.fill_reservoir_at_start && reservoir_domain_) {
    *step_window_ = {t0, t0};
    const PatchLedger pl = project(t0, 0.0);
    initial_.inserted = pl.inserted;
    initial_.removed = pl.removed;
    ledger_.inserted += pl.inserted;
    ledger_.removed += pl.removed;
    ledger_.mass_inserted += pl.mass_inserted;
    ledger_.mass_removed += pl.mass_removed;
  }
  // Each particle to its rank, the reservoir's too.
  if (distribution_) distribution_->redistribute(particles_);
  started_ = true;
}

bool Simulation::changes_before_solve() const {
  return options_.velocity.head(domain_->dim()).squaredNorm() > 0.0 || options_.source_rate != 0.0;
}

// Lines 2-4 of one try over [t0, t1]; the totals count every try. Runs
// inside guarded(): every try starts from the state save_state() took
// (undo_try() puts back what advection and the source changed).
SimulationStep Simulation::take_step(double t0, double t1, double max_error) {
  const int dim = domain_->dim();
  const bool advect_on = options_.velocity.head(dim).squaredNorm() > 0.0;
  const double s_rate = options_.source_rate;
  SimulationStep s;
  s.step = step_ + 1;
  s.t_start = t0;
  s.t_end = t1;
  const double h = t1 - t0;
  // Line 2: advection.
  if (advect_on) {
    const Vec3 u = options_.velocity;
    advect(particles_, [u](const Vec3&, double) { return u; }, t0, h, 1);
    for (Vec3& x : particles_.positions()) x = domain_->wrap(x);
  }
  // Line 3: source.
  if (s_rate != 0.0) {
    const SourceField field = [s_rate](const Vec3&, double) { return s_rate; };
    SourceResult sr;
    if (options_.source_draws_by_id) {
      // Each particle's draws from its own stream (decomposition-independent):
      // over several processes the counts come back summed over all of them.
      SourceDraws draws;
      draws.key = rng_.next_u64();
      draws.first_id = particles_.next_id();
      if (distribution_) {
        for (std::int64_t id : distribution_->all_gather({particles_.next_id()}))
          draws.first_id = std::max<ParticleId>(draws.first_id, id);
        draws.global_size = global_size();
        draws.gather = [this](const std::vector<std::int64_t>& v) { return distribution_->all_gather(v); };
        draws.sum = [this](double* v, int n) { distribution_->sum(v, n); };
      }
      sr = apply_source_by_id(particles_, field, t0, h, draws, max_particles());
    } else {
      sr = apply_source(particles_, field, t0, h, rng_, max_particles());
    }
    for (Vec3& x : particles_.positions()) x = domain_->wrap(x);
    ledger_.source_inserted += sr.inserted;
    ledger_.source_removed += sr.removed;
    ledger_.source_mass_inserted += sr.mass_inserted;
    ledger_.source_mass_removed += sr.mass_removed;
    ledger_.mass_inserted += sr.mass_inserted;
    ledger_.mass_removed += sr.mass_removed;
    s.inserted += sr.inserted;
    s.removed += sr.removed;
  }
  // Line 4: diffusion. Nothing to move in an empty set (over all processes).
  if (global_size() == 0) {
    s.diffusion = StepSummary{};
    s.diffusion.accepted = true;
    s.diffusion.dt = h;
  } else if (distribution_) {
    s.diffusion = distribution_->diffuse(particles_, h, max_error);
    if (s.diffusion.accepted) history_updated_ = true;
  } else if (implicit_) {
    s.diffusion = implicit_->step(particles_, h, max_error);
    if (s.diffusion.accepted) history_updated_ = true;
  } else {
    s.diffusion = explicit_->step(particles_, h);
  }
  totals_.iterations += s.diffusion.iterations;
  totals_.evaluations += s.diffusion.evaluations;
  totals_.rejected_solves += s.diffusion.rejected_solves;
  totals_.halvings += s.diffusion.halvings;
  totals_.step_seconds += s.diffusion.wall_seconds;
  totals_.solver_seconds += s.diffusion.solver_seconds;
  totals_.list_seconds += s.diffusion.list_seconds;
  return s;
}

// A rejected try: the particles, random numbers and ledger the try started
// from are the step's, in saved_ (the totals keep counting the try).
void Simulation::undo_try() {
  if (!changes_before_solve()) return;  // the solve left them as they were
  particles_ = saved_->particles;
  rng_ = saved_->rng;
  ledger_ = saved_->ledger;
}

// Lines 5-23 and the ledger, after an accepted diffusive step.
void Simulation::finish_step(SimulationStep& s) {
  const double h = s.t_end - s.t_start;
  totals_.dt_min_used = std::min(totals_.dt_min_used, h);
  totals_.dt_max_used = std::max(totals_.dt_max_used, h);
  *step_window_ = {s.t_start, s.t_end};
  // Mirrored walls: a particle that crossed one is reflected back (its image
  // would push it further out); moved, not removed, so counted apart. Before
  // the projection: the reservoir band's back face is such a wall, and a band
  // particle that crossed it is the band's, not one to absorb (with
  // beta dr^2 = 1 the sphere's band lost 170 particles a step that way, each
  // put back by the projection at once). And after it: the papers' Neumann
  // rule inserts inflow in the outer half of B_l, beyond the wall.
  auto reflect = [&] {
    if (walls_.empty()) return;
    const auto k = static_cast<std::int64_t>(reflect_inside(walls_, particles_.positions()));
    s.reflected += distribution_ ? distribution_->sum(k) : k;
  };
  reflect();
  const PatchLedger pl = project(s.t_start, h);
  reflect();
  ledger_.reflected += s.reflected;
  s.inserted += pl.inserted;
  s.removed += pl.removed;
  ledger_.mass_inserted += pl.mass_inserted;
  ledger_.mass_removed += pl.mass_removed;
  ledger_.inserted += s.inserted;
  ledger_.removed += s.removed;
  s.diffusion.inserted = s.inserted;
  s.diffusion.removed = s.removed;
  time_ = s.t_end;
  step_ = s.step;
  check_ledger(s.step, s.t_end);
  if (distribution_) distribution_->redistribute(particles_);
}

PatchLedger Simulation::project(double t, double dt) {
  if (distribution_) return distribution_->project(*projection_, particles_, t, dt, rng_, max_particles());
  return projection_->apply(particles_, t, dt, rng_);
}

std::int64_t Simulation::global_size() const {
  const auto n = static_cast<std::int64_t>(particles_.size());
  return distribution_ ? distribution_->sum(n) : n;
}

void Simulation::check_ledger(std::int64_t k, double t) const {
  const SimulationLedger& l = ledger_;
  const std::int64_t expect_n = l.expected_particles();
  const std::int64_t n = global_size();
  if (n != expect_n)
    throw StepFailure(format("particle ledger violated at step {} (t = {}): n = {} but n(0) + inserted - removed "
                                  "= {} + {} - {} = {}",
                                  k, t, n, l.initial_particles, l.inserted, l.removed, expect_n));
  const double mass_now = distribution_ ? distribution_->sum(particles_.total_mass()) : particles_.total_mass();
  const double mass_expect = l.expected_mass();
  if (!(std::abs(mass_now - mass_expect) <= 1e-9 * (l.initial_mass + l.mass_inserted + options_.particle_mass)))
    throw StepFailure(format("mass ledger violated at step {} (t = {}): mass = {} but M(0) + inserted - removed "
                                  "= {}",
                                  k, t, mass_now, mass_expect));
}

std::string SimulationStep::brief_report() const {
  // Six significant digits: a report for people (t = 0.1 + 0.2 reads 0.3).
  return format("step {}: t = {} (dt = {}), F = {}, {} evaluations, +{} -{} particles", step, Sig6{t_end}, Sig6{dt()},
                Sig6{diffusion.f_after}, diffusion.evaluations, inserted, removed);
}

std::string SimulationStep::full_report() const {
  std::string r = brief_report() + "\n";
  r += format("  diffusion: {} ({} iterations, {} halvings, {} list builds), F {} -> {}\n", to_string(diffusion.reason),
              diffusion.iterations, diffusion.halvings, diffusion.list_builds, diffusion.f_before, diffusion.f_after);
  r += format("  parts after: transport {}, entropy {}, barrier {}\n", diffusion.parts_after.transport,
              diffusion.parts_after.entropy, diffusion.parts_after.barrier);
  if (std::isfinite(diffusion.error_estimate))
    r += format("  error estimate {} (order {})\n", diffusion.error_estimate, diffusion.error_order);
  if (error_rejections > 0 || forced_at_dt_min || dt_next > 0.0)
    r += format("  adaptive: {} tries rejected, {}next dt {}\n", error_rejections,
                forced_at_dt_min ? "forced at dt_min, " : "", dt_next);
  r += format("  reflected {}, wall {} s\n", reflected, wall_seconds);
  return r;
}

std::string Simulation::full_report() const {
  const SimulationLedger& l = ledger_;
  const SimulationTotals& t = totals_;
  std::string r = format("t = {} after {} steps: {} particles, mass {}\n", time_, step_, particles_.size(),
                         particles_.total_mass());
  r += format("  ledger: n(0) = {} + inserted {} - removed {} (source +{} -{}), reflected {}\n", l.initial_particles,
              l.inserted, l.removed, l.source_inserted, l.source_removed, l.reflected);
  r += format("  mass: M(0) = {} + {} - {}\n", l.initial_mass, l.mass_inserted, l.mass_removed);
  r += format("  solver: {} iterations, {} evaluations, {} rejected solves, {} halvings\n", t.iterations,
              t.evaluations, t.rejected_solves, t.halvings);
  if (t.error_rejected_steps > 0 || t.steps_forced_at_dt_min > 0)
    r += format("  adaptive: {} tries rejected, {} steps forced at dt_min\n", t.error_rejected_steps,
                t.steps_forced_at_dt_min);
  r += format("  time: {} s in diffusion steps ({} s solver, {} s neighbour lists)\n", t.step_seconds,
              t.solver_seconds, t.list_seconds);
  return r;
}

void Simulation::require_started(const char* what) const {
  if (!started_) throw std::logic_error(std::string("Simulation::") + what + ": call start() or load_checkpoint() first");
}

void Simulation::save_state() {
  Saved& s = *saved_;
  s.particles = particles_;  // copy assignment: the arrays (and the id map's nodes) are reused
  s.rng = rng_;
  s.ledger = ledger_;
  s.totals = totals_;
  s.projection = projection_->state();
  s.time = time_;
  s.dt_next = dt_next_;
  s.step = step_;
  history_updated_ = false;
}

void Simulation::restore_state() {
  Saved& s = *saved_;
  std::swap(particles_, s.particles);  // saved_'s copy is taken afresh before the next step
  rng_ = s.rng;
  ledger_ = s.ledger;
  totals_ = s.totals;
  projection_->restore(s.projection);
  time_ = s.time;
  dt_next_ = s.dt_next;
  step_ = s.step;
  if (history_updated_) {
    if (distribution_)
      distribution_->undo_last_history_update();
    else
      implicit_->undo_last_history_update();
  }
  history_updated_ = false;
}

// Runs one step; whatever fails inside it (the solve, the error test, a
// resource limit in the source or the projection, the ledger) puts back the
// state the step started from and reaches the caller as a StepFailure (bad
// data, e.g. a non-finite flux, stays an InvalidArgument).
SimulationStep Simulation::guarded(const std::function<SimulationStep()>& body) {
  save_state();
  try {
    return body();
  } catch (const StepFailure&) {
    restore_state();
    throw;
  } catch (const InvalidArgument&) {
    restore_state();
    throw;
  } catch (const std::exception& e) {
    restore_state();
    throw StepFailure(format("step {} (t = {}): {}", step_ + 1, time_, e.what()));
  }
}

SimulationStep Simulation::advance_to(double t1) {
  require_started("advance_to");
  require(std::isfinite(t1) && t1 > time_, "step end t", t1, format("must be finite and > the current time {}", time_));
  return guarded([&] { return advance_to_impl(t1); });
}

SimulationStep Simulation::advance_to_impl(double t1) {
  const auto wall0 = Clock::now();
  SimulationStep s = take_step(time_, t1, std::numeric_limits<double>::infinity());
  if (!s.diffusion.accepted) {
    // guarded() puts back the state (advection and source included).
    throw StepFailure(format("step {} (t = {} -> {}): diffusion step not accepted ({}; {} halvings): {}", s.step,
                                  s.t_start, s.t_end, to_string(s.diffusion.reason), s.diffusion.halvings,
                                  s.diffusion.message));
  }
  finish_step(s);
  s.wall_seconds = std::chrono::duration<double>(Clock::now() - wall0).count();
  return s;
}

SimulationStep Simulation::advance_adaptive(double t_limit) {
  require_started("advance_adaptive");
  require(std::isfinite(t_limit) && t_limit > time_, "t_limit", t_limit,
          format("must be finite and > the current time {}", time_));
  if (options_.stepper != StepperKind::Implicit)
    throw InvalidArgument("stepper = \"explicit\": adaptive steps need the implicit stepper's error estimate");
  require(dt_next_ > 0.0, "next dt", dt_next_, "must be set (set_next_dt) before the first adaptive step");
  return guarded([&] { return advance_adaptive_impl(t_limit); });
}

SimulationStep Simulation::advance_adaptive_impl(double t_limit) {
  const auto wall0 = Clock::now();
  const TimeStepController controller(options_.time_control);
  // The last step ends on t_limit exactly; one a little longer than proposed
  // beats a sliver of a step after it.
  auto step_end = [&](double t0, double h) { return t0 + h >= t_limit * (1.0 - 1e-12) - 0.1 * h ? t_limit : t0 + h; };
  const double t0 = time_;
  double t1 = step_end(t0, dt_next_);
  std::int64_t rejections = 0;
  for (;;) {
    const double h = t1 - t0;
    SimulationStep s = take_step(t0, t1, controller.error_limit(h));
    const TimeStepDecision dec = controller.decide(h, s.diffusion.error_estimate, s.diffusion.error_order);
    dt_next_ = dec.dt_next;
    if (s.diffusion.accepted) {
      if (dec.forced) {
        ++totals_.steps_forced_at_dt_min;
        s.forced_at_dt_min = true;
      }
      s.error_rejections = rejections;
      s.dt_next = dt_next_;
      finish_step(s);
      s.wall_seconds = std::chrono::duration<double>(Clock::now() - wall0).count();
      return s;
    }
    undo_try();
    if (!s.diffusion.error_rejected)
      throw StepFailure(format("step {} (t = {} -> {}): diffusion step not accepted ({}; {} halvings): {}", s.step,
                                    t0, t1, to_string(s.diffusion.reason), s.diffusion.halvings, s.diffusion.message));
    ++rejections;
    ++totals_.error_rejected_steps;
    if (rejections > options_.max_error_rejections)
      throw StepFailure(format("step {} (t = {}): {} tries rejected by the error test", s.step, t0, rejections));
    t1 = step_end(t0, dt_next_);
  }
}

}  // namespace otfp
