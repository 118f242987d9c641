#include "otfp_app/simulation.hpp"

#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <optional>

#include "configured_run_state.hpp"
#ifdef OTFP_WITH_TAO
#include "otfp/mpi_distribution.hpp"
#endif
#include "domain_setup.hpp"
#include "setup_keys.hpp"
#include "otfp/barrier.hpp"
#include "otfp/fractional.hpp"
#include "otfp/images.hpp"
#include "otfp/initial_fill.hpp"
#include "otfp/mass_measure.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/parameters.hpp"
#include "otfp/run_setup.hpp"
#include "otfp/particle_io.hpp"
#include "otfp/reference.hpp"
#include "otfp/simulation.hpp"
#include "otfp/stepper.hpp"
#include "otfp/time_step_control.hpp"

#ifndef OTFP_APP_VERSION
#define OTFP_APP_VERSION "unknown"
#endif

namespace otfp::app {

std::string version() { return OTFP_APP_VERSION; }

namespace {

constexpr double kPi = std::numbers::pi;

// The value as the message shows it (ConfigError makes the line one line).
std::string in_quotes(const std::string& s) { return "\"" + s + "\""; }

nlohmann::json to_json(const Vec3& v) { return nlohmann::json::array({v[0], v[1], v[2]}); }

template <class T>
nlohmann::json opt(const std::optional<T>& v) {
  return v ? nlohmann::json(*v) : nlohmann::json(nullptr);
}

// The rule that set M_inf, in the configuration's keys (summary.json).
std::string mass_rule_text(MassRule rule) {
  switch (rule) {
    case MassRule::Given: return "diagnostics.M_inf";
    case MassRule::Dirichlet: return "area-weighted mean Dirichlet g x |Omega|";
    case MassRule::GivenParticles: return "mass of particles.fill_file + net Neumann inflow over [0, t_end]";
    case MassRule::FillMass: return "particles.fill_mass + net Neumann inflow over [0, t_end]";
    case MassRule::ParticleMass: return "initial fill mass + net Neumann inflow over [0, t_end]";
    case MassRule::NInfParticleMass: return "particles.n_inf x particles.mass";
    case MassRule::NeumannInflow: return "net Neumann inflow over [0, t_end]";
    case MassRule::Unset: break;
  }
  return "default 1";
}

// particles.fill = "file": the particles of a CSV (the columns of
// particles_final.csv) or of one of our .vtp files, wrapped into a periodic
// cell (check_fill_file checks where they are once the buffers are known).
ParticleSet read_fill_file(const Config& c, const DomainPtr& domain) {
  const std::string& file = *c.particles.fill_file;
  ParticleSet ps(c.run.dim);
  try {
    ps = read_particles(file, c.run.dim);
  } catch (const InvalidArgument& e) {
    throw ConfigError("particles.fill_file", std::string("particles.fill_file: ") + e.what());
  }
  for (Vec3& x : ps.positions()) x = domain->wrap(x);
  return ps;
}

// Every particle of the file inside Omega or in the buffer outside a
// Dirichlet patch (a run's final state holds its reservoir band); free space
// takes any point.
void check_fill_file(const Config& c, const otfp::Simulation& sim, const ParticleSet& ps) {
  if (c.domain.type == DomainType::Free) return;
  for (std::size_t p = 0; p < ps.size(); ++p) {
    const Vec3& x = ps.positions()[p];
    if (region_of(sim.domain(), sim.buffer(), x) == otfp::Region::Elsewhere)
      throw ConfigError("particles.fill_file", in_quotes(*c.particles.fill_file),
                        fmt::format("particle id {} at ({}, {}, {}) lies outside the domain and its Dirichlet buffers "
                                    "(signed distance {})",
                                    ps.ids()[p], x[0], x[1], x[2], sim.domain().signed_distance(x)));
  }
}

}  // namespace


ConfiguredRun::~ConfiguredRun() = default;

int launched_ranks() {
  // Open MPI and PMI (MPICH, Slurm) tell the world size in the environment.
  for (const char* var : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE"})
    if (const char* ranks = std::getenv(var); ranks != nullptr) return std::max(1, std::atoi(ranks));
  return 1;
}

int launched_rank() {
  for (const char* var : {"OMPI_COMM_WORLD_RANK", "PMI_RANK"})
    if (const char* rank = std::getenv(var); rank != nullptr) return std::max(0, std::atoi(rank));
  return 0;
}

namespace {

// Started by mpirun on several ranks: the run is distributed
// (docs/distributed.md); otherwise serial.
std::shared_ptr<otfp::RunDistribution> launched_distribution() {
#ifdef OTFP_WITH_TAO
  if (launched_ranks() > 1) {
    auto d = std::make_shared<otfp::MpiDistribution>();
    // The variables inherited by a process that mpirun did not start as a
    // rank (a script run under mpirun starting otfp): MPI's world is this
    // process alone, and the run is serial.
    if (d->size() > 1) return d;
  }
#endif
  return nullptr;
}

}  // namespace

// Values that are finite but would fail at step 0 (an infinite advected
// position, a source that multiplies the particles past any limit, boundary
// data asking for more particles than the run may hold, a centre so far away
// that squared distances overflow) are refused before any work.
void ConfiguredRun::check_magnitudes(const std::vector<ConstantBoundaryData>& data) const {
  const Config& c = config_;
  const Derived& d = derived_;
  // Plain loops over the dim axes (GCC 12 warns about Eigen's head(dim) here).
  const Aabb box = domain_->bounding_box();
  auto length = [&](const Vec3& a, const Vec3& b) {
    double s2 = 0.0;
    for (int k = 0; k < c.run.dim; ++k) s2 += (a[k] - b[k]) * (a[k] - b[k]);
    return std::sqrt(s2);
  };
  const double far = 1e6 * std::max(length(box.hi, box.lo), d.dr);  // how far from the domain a point may be
  const Vec3 mid(0.5 * (box.lo[0] + box.hi[0]), 0.5 * (box.lo[1] + box.hi[1]), 0.5 * (box.lo[2] + box.hi[2]));
  auto vec = [](const Vec3& v) { return fmt::format("[{}, {}, {}]", v[0], v[1], v[2]); };
  auto point_near = [&](const char* key, const std::optional<Vec3>& p) {
    if (p && !(length(*p, mid) <= far))
      throw ConfigError(key, vec(*p),
                        fmt::format("must lie within 1e6 domain sizes ({:.4g}) of the domain's centre", far));
  };
  point_near("diagnostics.center", c.diagnostics.center);
  point_near("particles.fill_center", c.particles.fill_center);
  if (c.particles.fill == Fill::Gaussian && !(c.particles.fill_sigma <= far))
    throw ConfigError("particles.fill_sigma", fmt::format("{}", c.particles.fill_sigma),
                      fmt::format("must be at most 1e6 domain sizes ({:.4g})", far));
  const double speed = length(c.physics.velocity, Vec3::Zero());
  if (!(speed * c.run.t_end <= far))
    throw ConfigError("physics.velocity", vec(c.physics.velocity),
                      fmt::format("moves the particles {:.4g} over run.t_end = {}: at most 1e6 domain sizes ({:.4g})",
                                  speed * c.run.t_end, c.run.t_end, far));
  const double s_dt = std::abs(c.physics.source_rate) * d.dt;
  if (!(s_dt <= 36.0))
    throw ConfigError("physics.source_rate", fmt::format("{}", c.physics.source_rate),
                      fmt::format("|s| dt = {:.4g} (dt = {:.4g}): must be at most 36 (one step multiplies the mass by "
                                  "exp(s dt))",
                                  s_dt, d.dt));
  // Particles the data ask for: g over the layer (|A| x max(b, w)), or the
  // inflow -f |A| over the run, in particles of mass m_p.
  const double depth = std::max(d.layer_b, d.reservoir_width);
  for (const ConstantBoundaryData& b : data) {
    const double area = domain_->patch_area(b.patch);
    const double t_on = b.kind == PatchKind::Neumann
                            ? std::max(0.0, std::min(b.t_end, c.run.t_end) - std::min(b.t_start, c.run.t_end))
                            : 0.0;
    const double wanted = b.kind == PatchKind::Dirichlet ? std::abs(b.value) * area * depth / d.particle_mass
                                                         : std::max(0.0, -b.value) * area * t_on / d.particle_mass;
    if (!(wanted <= static_cast<double>(d.max_particles))) {
      std::size_t index = 0;
      for (std::size_t i = 0; i < c.boundary.size(); ++i)
        if (detail::resolve_patch(state_->built, c.boundary[i].patch) == b.patch) index = i;
      throw ConfigError(
          fmt::format("boundary[{}].value", index), fmt::format("{}", b.value),
          fmt::format("asks for about {:.4g} particles of mass {:.4g} on patch '{}' ({}): more than {} (run.max_particles)",
                      wanted,
                      d.particle_mass, domain_->patch_name(b.patch),
                      b.kind == PatchKind::Dirichlet ? "g x area x layer depth / m_p" : "-f x area x time on / m_p",
                      d.max_particles));
    }
  }
}

ConfiguredRun::ConfiguredRun(Config config) : config_(std::move(config)), state_(std::make_unique<State>()) {
  const Config& c = config_;
  const int dim = c.run.dim;
  State& st = *state_;
  st.built = detail::build_domain(c);
  domain_ = st.built.domain;
  free_space_ = st.built.free_space;

  // Patches and their conditions.
  for (int p = 0; p < domain_->num_patches(); ++p) {
    PatchInfo info;
    info.id = p;
    info.name = domain_->patch_name(p);
    info.area = domain_->patch_area(p);
    patches_.push_back(info);
  }
  for (std::size_t i = 0; i < c.boundary.size(); ++i) {
    const BoundarySpec& b = c.boundary[i];
    const int id = domain_->num_patches() > 0 ? detail::resolve_patch(st.built, b.patch) : -1;
    if (id < 0)
      throw ConfigError(fmt::format("boundary[{}].patch", i), in_quotes(b.patch),
                        "unknown patch (patches: " + detail::patch_names(st.built) + ")");
    for (std::size_t j = 0; j < i; ++j)
      if (detail::resolve_patch(st.built, c.boundary[j].patch) == id)
        throw ConfigError(fmt::format("boundary[{}].patch", i), in_quotes(b.patch),
                          fmt::format("same patch as boundary[{}]", j));
    PatchInfo& info = patches_[static_cast<std::size_t>(id)];
    if (!b.kind)  // a Config built in code, not read and validated
      throw ConfigError(fmt::format("boundary[{}].kind", i), "(missing)", "required: one of dirichlet, neumann, no_flux");
    info.kind = *b.kind;
    info.value = b.value.value_or(0.0);
    info.t_start = b.t_start;
    info.t_end = b.t_end;
  }
  bool any_dirichlet = false, any_layer = false;
  for (const PatchInfo& p : patches_) {
    any_dirichlet = any_dirichlet || p.kind == PatchKind::Dirichlet;
    // The layer b is used by Neumann patches and by Dirichlet patches unless
    // they use the reservoir, whose band width is w instead.
    const bool uses_layer = p.kind == PatchKind::Neumann ||
                            (p.kind == PatchKind::Dirichlet && c.treatment.dirichlet == DirichletMode::Layer);
    any_layer = any_layer || uses_layer;
  }

  // The library's data per patch (no-flux patches have none).
  std::vector<ConstantBoundaryData> data;
  for (PatchInfo& p : patches_) {
    if (p.kind == PatchKind::NoFlux) continue;
    ConstantBoundaryData bd;
    bd.patch = p.id;
    bd.kind = p.kind;
    bd.value = p.value;
    if (bd.kind == PatchKind::Neumann) {
      bd.t_start = p.t_start;
      bd.t_end = p.t_end.value_or(std::numeric_limits<double>::infinity());
    }
    p.condition = static_cast<int>(data.size());
    data.push_back(bd);
  }

  // Spacing, width, layer, time step, barrier (36)-(40), the band, the
  // masses and the fill's count: the library's rules (run_setup.hpp), its
  // fields named by their keys here.
  const ParticlesSection& pa = c.particles;
  if (pa.fill == Fill::File) st.file_particles = read_fill_file(c, domain_);
  Derived& d = derived_;
  d.length_L = c.particles.length_L > 0.0 ? c.particles.length_L : st.built.length_L;
  RunSetupOptions ro = detail::run_setup_options(c, d.length_L, !free_space_);
  if (st.file_particles) {
    ro.fill.given_count = static_cast<std::int64_t>(st.file_particles->size());
    ro.fill.given_mass = st.file_particles->total_mass();
  }
  RunParameters rp;
  try {
    rp = run_parameters(*domain_, data, ro);
  } catch (const InvalidArgument& e) {
    detail::throw_keyed(e, c);
  }
  d.volume = rp.volume;
  d.dr = rp.dr;
  d.beta = rp.beta;
  d.width_s = rp.width_s;
  d.width_reference_dr = rp.width_reference_dr;
  d.true_spacing = rp.true_spacing;
  d.beta_true_spacing2 = d.beta * d.true_spacing * d.true_spacing;
  d.layer_b = rp.layer_b;
  // Given where nothing uses it, it would only seem to have been applied.
  if (c.particles.layer_b > 0.0 && !any_layer)
    throw ConfigError("particles.layer_b", fmt::format("{}", c.particles.layer_b),
                      fmt::format("has no effect here: no patch uses the boundary layer (it serves Neumann patches, "
                                  "and Dirichlet patches with treatment.dirichlet = \"layer\"; here there is no Neumann "
                                  "patch and treatment.dirichlet = \"{}\"); remove it",
                                  to_string(c.treatment.dirichlet)));
  if (any_layer && !(d.layer_b < 0.5 * st.built.min_extent))
    throw ConfigError("particles.layer_b",
                      fmt::format("{}{}", d.layer_b, c.particles.layer_b > 0.0 ? "" : " (sqrt(length_L dr))"),
                      fmt::format("must be < half the smallest extent of the domain ({})", 0.5 * st.built.min_extent));
  d.dt_explicit = rp.dt_explicit;
  d.n_steps = rp.n_steps;
  d.dt = rp.dt;
  d.steps_to_run = c.run.max_steps > 0 ? std::min(d.n_steps, c.run.max_steps) : d.n_steps;
  d.barrier_C = rp.barrier_C;
  d.reservoir_width = rp.reservoir_width;
  d.reservoir_sublayers = rp.reservoir_sublayers;
  d.neumann_net_inflow = rp.neumann_net_inflow;
  d.M_inf = rp.M_inf;
  d.M_inf_rule = mass_rule_text(rp.M_inf_rule);
  if (rp.M_inf_rule == MassRule::Unset) {
    d.M_inf = 1.0;
    d.M_inf_rule = "default 1";
  }
  if (!(d.M_inf > 0.0) || !std::isfinite(d.M_inf))
    throw ConfigError("diagnostics.M_inf", fmt::format("{} ({})", d.M_inf, d.M_inf_rule),
                      "must be > 0: set diagnostics.M_inf or particles.mass");
  d.particle_mass = pa.mass ? *pa.mass : d.M_inf / static_cast<double>(pa.n_inf);
  d.fill_count = rp.fill_count;
  d.lattice_counts = rp.lattice_counts;
  if (d.fill_count > 100'000'000)
    throw ConfigError(pa.fill_count ? "particles.fill_count" : pa.fill_mass ? "particles.fill_mass" : "particles.n_inf",
                      fmt::format("{} particles", d.fill_count), "must give at most 1e8 particles");
  // Resource limit, before any work: the initial particles and the papers'
  // equilibrium count n_inf must fit (steps that go past it fail at run time).
  d.max_particles = std::min(c.run.max_particles > 0 ? c.run.max_particles : otfp::default_max_particles(),
                             kMaxParticleCount);
  const std::string limit_rule =
      c.run.max_particles > 0
          ? fmt::format("must be at most run.max_particles = {}", d.max_particles)
          : fmt::format("must be at most {} particles (half this machine's memory at {} bytes per particle; "
                        "set run.max_particles to change it)",
                        d.max_particles, kBytesPerParticle);
  if (d.fill_count > d.max_particles)
    throw ConfigError(pa.fill == Fill::File   ? "particles.fill_file"
                      : pa.fill_count         ? "particles.fill_count"
                      : pa.fill_mass          ? "particles.fill_mass"
                                              : "particles.n_inf",
                      fmt::format("{} initial particles", d.fill_count), limit_rule);
  if (pa.n_inf > d.max_particles) throw ConfigError("particles.n_inf", fmt::format("{}", pa.n_inf), limit_rule);
  // The free-space reference grows by 2 d kappa M t and its error is scaled
  // by that growth over the run: with no particles at t = 0 both are 0.
  if (c.diagnostics.reference == "free_space" && d.fill_count == 0)
    throw ConfigError("particles.fill", in_quotes(to_string(pa.fill)),
                      "diagnostics.reference = \"free_space\" needs particles at t = 0 (its growth 2 d kappa M t "
                      "scales with their mass M)");
  if (pa.fill == Fill::Cosine) {
    // At least two particle spacings per wavelength: a finer mode cannot be
    // sampled (its measured amplitude is noise about 0, and the error column,
    // scaled by a(0), would not be finite).
    const double length = c.domain.hi[0] - c.domain.lo[0];
    const double most = std::floor(length / (2.0 * d.dr));
    if (static_cast<double>(pa.fill_mode) > most)
      throw ConfigError("particles.fill_mode", fmt::format("{}", pa.fill_mode),
                        fmt::format("must be at most {} (two particle spacings dr = {:.4g} per wavelength along x; "
                                    "raise particles.n_inf for a finer mode)",
                                    most, d.dr));
    d.mode_wavenumber = 2.0 * kPi * static_cast<double>(pa.fill_mode) / length;
  }

  // Diagnostics centre, J_inf, and what the reference curves read from the
  // domain (reference.hpp).
  d.center = c.diagnostics.center ? *c.diagnostics.center : domain_->inertia_center();
  for (int k = dim; k < 3; ++k) d.center[k] = 0.0;
  if (c.diagnostics.J_inf) {
    d.J_inf = *c.diagnostics.J_inf;
    d.J_inf_rule = "diagnostics.J_inf";
  } else if (!free_space_) {
    d.J_inf = d.M_inf * domain_->mean_square_distance(d.center);
    d.J_inf_rule = "uniform density M_inf/|Omega| about diagnostics.center";
    if (!std::isfinite(*d.J_inf))
      throw ConfigError("diagnostics.center", fmt::format("[{}, {}, {}]", d.center[0], d.center[1], d.center[2]),
                        "gives a polar inertia J_inf that is not finite: set diagnostics.J_inf or a nearer centre");
  }
  const std::string& ref = c.diagnostics.reference;
  ReferenceSetup rs;
  rs.dim = dim;
  rs.center = d.center;
  rs.M_inf = d.M_inf;
  rs.radius = c.diagnostics.reference_radius.value_or(0.0);
  rs.length = c.diagnostics.reference_length.value_or(0.0);
  std::vector<int> held;
  for (const ConstantBoundaryData& b : data)
    if (b.kind == PatchKind::Dirichlet) held.push_back(b.patch);
  complete_reference_geometry(ref, *domain_, held, rs);
  if (ref == "crank_sphere") {
    if (!(rs.radius > 0.0))
      throw ConfigError("diagnostics.reference_radius", "(missing)",
                        "required for reference = \"crank_sphere\" on a domain that is not a ball");
    d.reference_radius = rs.radius;
  } else if (ref == "crank_slab") {
    if (!(rs.length > 0.0))
      throw ConfigError("diagnostics.reference_length", "(missing)",
                        "required for reference = \"crank_slab\" unless the domain is a box with one Dirichlet face");
    d.reference_length = rs.length;
  }
  d.reference_J_inf = rs.J_inf;
  d.slab_axis = rs.slab_axis;
  d.slab_held_at_hi = rs.slab_held_at_hi;

  // The library object: projection, barrier, walls and stepper (Algorithm 1).
  rp.M_inf = d.M_inf;
  rp.particle_mass = d.particle_mass;
  SimulationOptions so = simulation_options(rp, ro);
  so.seed = static_cast<std::uint64_t>(c.run.seed);
  so.max_particles = d.max_particles;
  so.projection.dirichlet_target = pa.dirichlet_target;
  const TreatmentSection& tr = c.treatment;
  const SolverSection& s = c.solver;
  NeighborOptions nb;
  nb.kernel_tolerance = s.kernel_tolerance;
  nb.skin = -1.0;
  nb.skin_factor = s.skin_factor;
  if (so.stepper == StepperKind::Implicit) {
    ImplicitOptions& io = so.implicit;
    io.minimizer.backend = s.backend;
    io.minimizer.algorithm = s.algorithm;
    io.minimizer.max_iterations = static_cast<int>(s.max_iterations);
    io.minimizer.max_evaluations = static_cast<int>(s.max_evaluations);
    io.minimizer.lbfgs_memory = static_cast<int>(s.lbfgs_memory);
    io.displacement_tolerance = s.displacement_tolerance;
    io.relative_tolerance = s.relative_tolerance;
    io.width_mode = s.width_mode;
    io.width_metric = s.width_metric;
    io.time_scheme = s.time_scheme;
    io.predictor = s.predictor;
    io.error_smoothing = s.error_smoothing;
    io.error_measure = s.error_measure;
    io.stopping_norm = s.stopping_norm;
    io.max_norm_factor = s.max_norm_factor;
    io.max_width_factor = s.max_width_factor;
    io.neighbor = nb;
    io.max_halvings = static_cast<int>(s.max_halvings);
    io.energy_tolerance = s.energy_tolerance;
  } else {
    ExplicitOptions& eo = so.explicit_options;
    eo.scheme = s.explicit_scheme;
    eo.neighbor = nb;
  }
  so.velocity = c.physics.velocity;
  so.source_rate = c.physics.source_rate;
  // Adaptive dt (run.dt_mode): the controller's bounds; dt_max is at least dt_min.
  TimeStepControlOptions& tco = so.time_control;
  tco.tolerance = c.run.time_tolerance;
  if (c.run.dt_min) tco.dt_min = *c.run.dt_min;  // else the library's 1e-3 dt
  tco.dt_max = std::max(c.run.dt_max ? *c.run.dt_max : c.run.t_end, tco.dt_min);
  check_magnitudes(data);
  try {
    st.data = data;
    st.options = so;
    st.sim = std::make_unique<otfp::Simulation>(domain_, std::move(data), so, launched_distribution());
  } catch (const SimulationSetupError& e) {
    using Stage = SimulationSetupError::Stage;
    switch (e.stage()) {
      case Stage::Reservoir:
        throw ConfigError("treatment.dirichlet", "\"reservoir\"", std::string("not available here: ") + e.what());
      case Stage::ReservoirMirror: {
        // The band w = reservoir_width x r_c (r_c from the kernel tolerance)
        // in reservoir_sublayers sublayers: the key at fault is one whose
        // default makes the setup work (tried here, on the error path only);
        // otherwise the band is too wide for this domain and spacing.
        auto band = [&](double tolerance, std::int64_t sublayers) {
          RunSetupOptions r = ro;
          r.kernel_tolerance = tolerance;
          r.treatment.reservoir_sublayers = static_cast<int>(sublayers);
          return run_parameters(*domain_, st.data, r);
        };
        auto works = [&](double tolerance, std::int64_t sublayers) {
          SimulationOptions o = so;
          const RunParameters b = band(tolerance, sublayers);
          o.projection.reservoir_thickness = b.reservoir_width;
          o.projection.reservoir_sublayers = b.reservoir_sublayers;
          o.implicit.neighbor.kernel_tolerance = o.explicit_options.neighbor.kernel_tolerance = tolerance;
          try {
            otfp::Simulation trial(domain_, st.data, o);
            return true;
          } catch (const std::exception&) {
            return false;
          }
        };
        const double default_tolerance = SolverSection{}.kernel_tolerance;
        if (tr.reservoir_sublayers > 0 && works(c.solver.kernel_tolerance, 0))
          throw ConfigError(
              "treatment.reservoir_sublayers", fmt::format("{}", tr.reservoir_sublayers),
              fmt::format("sublayers of {:.4g} (band {:.4g}, spacing dr = {:.4g}) are too thin for the odd profile to "
                          "mirror inside Omega ({}); use fewer (0: round(2 w / dr) = {} works)",
                          d.reservoir_width / static_cast<double>(tr.reservoir_sublayers), d.reservoir_width, d.dr,
                          e.what(), band(c.solver.kernel_tolerance, 0).reservoir_sublayers));
        if (c.solver.kernel_tolerance != default_tolerance && works(default_tolerance, tr.reservoir_sublayers))
          throw ConfigError(
              "solver.kernel_tolerance", fmt::format("{}", c.solver.kernel_tolerance),
              fmt::format("gives the kernel cut-off r_c = {:.4g} ({:.3g} widths) and so a reservoir band of "
                          "treatment.reservoir_width x r_c = {:.4g} that the odd profile cannot mirror inside Omega "
                          "({}); the default {} works",
                          d.reservoir_width / tr.reservoir_width, d.reservoir_width / tr.reservoir_width / d.width_s,
                          d.reservoir_width, e.what(), default_tolerance));
        throw ConfigError("treatment.reservoir_width", fmt::format("{}", tr.reservoir_width),
                          fmt::format("gives a band of {} that the odd profile cannot mirror inside Omega ({}); "
                                      "raise particles.n_inf or lower the width",
                                      d.reservoir_width, e.what()));
      }
      case Stage::Projection:
        throw ConfigError("boundary", std::string("boundary: ") + e.what());
      case Stage::Periodic:
        throw ConfigError("domain.hi", fmt::format("[{}, {}, {}]", c.domain.hi[0], c.domain.hi[1], c.domain.hi[2]),
                          std::string(e.what()) + ": enlarge the box or raise particles.n_inf");
      case Stage::Walls:
        throw ConfigError("treatment.no_flux", in_quotes(to_string(tr.no_flux)),
                          std::string("walls: ") + e.what() + "; set treatment.no_flux = \"barrier\"");
      case Stage::Stepper:
        break;
    }
    throw ConfigError("solver", std::string("solver: ") + e.what());
  } catch (const InvalidArgument& e) {
    throw ConfigError("solver", std::string("solver: ") + e.what());
  }
  if (st.file_particles) check_fill_file(c, *st.sim, *st.file_particles);
  d.barrier_domain = st.sim->barrier_domain_description();
  d.mirrored_walls = st.sim->mirrored_walls();
}

nlohmann::json ConfiguredRun::describe() const {
  const Config& c = config_;
  const Derived& d = derived_;
  // The resolved configuration: every key of the table, defaults filled in.
  const nlohmann::json cfg = config_to_json(c);

  nlohmann::json pj = nlohmann::json::array();
  for (const PatchInfo& pi : patches_)
    pj.push_back({{"id", pi.id},
                  {"name", pi.name},
                  {"area", pi.area},
                  {"kind", to_string(pi.kind)},
                  {"value", pi.value},
                  {"t_start", pi.t_start},
                  {"t_end", opt(pi.t_end)}});
  nlohmann::json der = {{"volume", d.volume},
                        {"dr", d.dr},
                        {"beta", d.beta},
                        {"width_s", d.width_s},
                        {"width_reference_dr", d.width_reference_dr},
                        {"true_spacing", d.true_spacing},
                        {"beta_true_spacing2", d.beta_true_spacing2},
                        {"mass_blob_method", to_string(blob_mass_method(*domain_))},
                        {"length_L", d.length_L},
                        {"layer_b", d.layer_b},
                        {"dt_explicit", d.dt_explicit},
                        {"dt", d.dt},
                        {"n_steps", d.n_steps},
                        {"steps_to_run", d.steps_to_run},
                        {"barrier_C", d.barrier_C},
                        {"barrier_domain", d.barrier_domain},
                        {"mirrored_walls", d.mirrored_walls},
                        {"reservoir_width", d.reservoir_width},
                        {"reservoir_sublayers", d.reservoir_sublayers},
                        {"particle_mass", d.particle_mass},
                        {"M_inf", d.M_inf},
                        {"M_inf_rule", d.M_inf_rule},
                        {"J_inf", opt(d.J_inf)},
                        {"J_inf_rule", d.J_inf_rule},
                        {"center", to_json(d.center)},
                        {"fill_count", d.fill_count},
                        {"max_particles", d.max_particles},
                        {"neumann_net_inflow", d.neumann_net_inflow},
                        {"reference_radius", opt(d.reference_radius)},
                        {"reference_length", opt(d.reference_length)},
                        {"reference_J_inf", opt(d.reference_J_inf)},
                        {"mode_wavenumber", d.mode_wavenumber},
                        {"lattice_counts", d.lattice_counts},
                        {"patches", pj}};
  return {{"config", cfg}, {"derived", der}};
}

ParticleSet ConfiguredRun::initial_particles(Rng& rng) const {
  const Config& c = config_;
  const Derived& d = derived_;
  ParticleSet fill(c.run.dim);
  if (state_->file_particles) {
    fill = *state_->file_particles;
  } else if (d.fill_count > 0) {  // a lattice is filled whatever particles.fill says
    FillOptions fo;
    fo.shape = c.particles.fill == Fill::Gaussian ? FillShape::Gaussian
               : c.particles.fill == Fill::Cosine ? FillShape::Cosine
                                                  : FillShape::Uniform;  // uniform, or a lattice with fill = "empty"
    fo.count = d.fill_count;
    fo.width_s = d.width_s;
    fo.mass = d.particle_mass;
    fo.lattice = c.particles.fill_arrangement != Arrangement::Random;
    fo.staggered = c.particles.fill_arrangement == Arrangement::StaggeredLattice;
    fo.lattice_counts = d.lattice_counts;
    fo.lo = c.domain.lo;
    fo.hi = c.domain.hi;
    fo.center = c.particles.fill_center.value_or(d.center);
    fo.sigma = c.particles.fill_sigma;
    fo.amplitude = c.particles.fill_amplitude;
    fo.wavenumber = d.mode_wavenumber;
    fill = fill_particles(*domain_, fo, rng);
  }
  return fill;
}

bool ConfiguredRun::root_process() const { return state_->sim->root_process(); }
bool ConfiguredRun::any_process(bool v) const { return state_->sim->any_process(v); }

std::unique_ptr<otfp::Simulation> ConfiguredRun::make_simulation() const {
  auto sim = std::make_unique<otfp::Simulation>(domain_, state_->data, state_->options);
  Rng rng(static_cast<std::uint64_t>(config_.run.seed));  // the stream run() uses
  ParticleSet fill = initial_particles(rng);
  sim->start(std::move(fill), rng, 0.0);
  return sim;
}

}  // namespace otfp::app
