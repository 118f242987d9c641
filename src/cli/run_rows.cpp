// The rows of a run: the diagnostics of each step and the progress line.
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "otfp/stepper.hpp"
#include "run_parts.hpp"

namespace otfp::app::detail {

namespace {

std::string hms(double seconds) {
  const long s = std::lround(std::max(0.0, seconds));
  return s >= 3600 ? fmt::format("{}:{:02}:{:02}", s / 3600, (s / 60) % 60, s % 60)
                   : fmt::format("{}:{:02}", s / 60, s % 60);
}

}  // namespace

std::unique_ptr<Reference> configured_reference(const Config& c, const Derived& d) {
  if (c.diagnostics.reference == "none") return nullptr;
  ReferenceSetup s;
  s.dim = c.run.dim;
  s.kappa = c.physics.kappa;
  s.t_end = c.run.t_end;
  s.center = d.center;
  s.M_inf = d.M_inf;
  s.radius = d.reference_radius.value_or(0.0);
  s.length = d.reference_length.value_or(0.0);
  s.J_inf = d.reference_J_inf;
  s.lo = c.domain.lo;
  s.hi = c.domain.hi;
  s.slab_axis = d.slab_axis;
  s.slab_held_at_hi = d.slab_held_at_hi;
  s.wavenumber = d.mode_wavenumber;
  s.x0 = c.domain.lo[0];
  s.constant_dt = c.run.dt_mode == DtMode::Fixed ? d.dt : 0.0;
  s.stepper = c.solver.stepper;
  s.time_scheme = c.solver.time_scheme;
  s.explicit_scheme = c.solver.explicit_scheme;
  return make_reference(c.diagnostics.reference, s);
}

RowMaker::RowMaker(const Derived& d, const otfp::Simulation& sim, Reference* reference, const WallClock& wall)
    : step_dt(d.dt), d_(d), sim_(sim), reference_(reference), wall_(wall) {
  // Closed forms cost ~0.1 us per particle (disc and cylinder ~3 us near the
  // wall); the quadrature path (square_pipe_obstacle) runs 4 x 4 normal lines
  // per blob near a wall instead of the library's 10 x 10 (6x cheaper, about
  // 1e-3 of the near-wall blob mass either way, docs/outputs.md).
  blob_options_.hermite_nodes = 4;
}

StepRecord RowMaker::operator()(std::int64_t step, double t, const StepSummary* sum, long ins, long rem) {
  StepRecord r;
  r.step = step;
  r.t = t;
  r.dt = step == 0 ? 0.0 : step_dt;
  // (43)-(44) inside Omega and with the buffer outside the Dirichlet faces.
  const StateMeasures ms = sim_.measure(d_.center, &region_);
  r.n_particles = ms.n_particles;
  r.n_inside = ms.n_inside;
  r.n_buffer = ms.n_buffer;
  r.n_outside = ms.n_outside;
  r.mass_total = ms.mass_total;
  r.mass_inside = ms.mass_inside;
  r.mass_with_layer = ms.mass_with_layer;
  r.polar_inertia = ms.polar_inertia;
  r.polar_inertia_with_layer = ms.polar_inertia_with_layer;
  r.polar_inertia_total = ms.polar_inertia_total;
  r.mean_age = ms.mean_age;
  r.max_age = ms.max_age;
  r.inserted = ins;
  r.removed = rem;
  r.inserted_total = sim_.ledger().inserted;
  r.removed_total = sim_.ledger().removed;
  if (sum) {
    r.energy = sum->f_after;
    r.transport = sum->parts_after.transport;
    r.entropy = sum->parts_after.entropy;
    r.barrier = sum->parts_after.barrier;
    r.residual_displacement = sum->residual_displacement;
    r.iterations = sum->iterations;
    r.evaluations = sum->evaluations;
    r.list_builds = sum->list_builds;
    r.halvings = sum->halvings;
    if (std::isfinite(sum->error_estimate)) r.error_estimate = sum->error_estimate;
    r.rejected_steps = step_rejections;
    r.step_seconds = sum->wall_seconds;
    r.solver_seconds = sum->solver_seconds;
    r.list_seconds = sum->list_seconds;
  }
  // (46a)-(46b) as printed: sum over k = 0..K of the value at t_k times dt, all particles.
  if (step == 0)
    sums.l1.add_first(ms, step_dt);
  else
    sums.l1.add(sums.prev_measures, ms, step_dt);
  sums.prev_measures = ms;
  r.l1_mass = sums.l1.mass_rectangle;
  r.l1_polar_inertia = sums.l1.polar_inertia_rectangle;
  r.mass_ratio = r.mass_inside / d_.M_inf;
  if (d_.J_inf) r.polar_inertia_ratio = r.polar_inertia / *d_.J_inf;
  r.mass_blob = sim_.blob_mass(blob_options_);
  r.mass_blob_ratio = r.mass_blob / d_.M_inf;
  // Analytic reference: measured, reference, error (scaled) per row.
  if (reference_) {
    ReferenceSample sample;
    sample.t = t;
    sample.measures = ms;
    sample.mass_blob = r.mass_blob;
    // A distributed run's particles are shares: the reference reads all.
    ParticleSet gathered;
    if (sim_.distributed() && reference_->uses_particles()) gathered = sim_.gathered_particles();
    sample.particles = sim_.distributed() && reference_->uses_particles() ? &gathered : &sim_.particles();
    sample.initial_mass = sums.M0;
    ReferenceRow row = reference_->row(sample);
    r.reference_values = std::move(row.values);
    r.reference = row.reference;
    r.error_mass_blob = row.error_mass_blob;
  }
  r.wall_seconds = wall_();
  return r;
}

ProgressLine::ProgressLine(const Config& c, const Derived& d, const otfp::Simulation& sim, const WallClock& wall,
                           bool on)
    : c_(c), d_(d), sim_(sim), wall_(wall), on_(on) {}

void ProgressLine::show(const StepRecord& r, bool final_line) {
  if (!on_) return;
  const auto now = Clock::now();
  if (!final_line && now - last_ < std::chrono::milliseconds(200)) return;
  last_ = now;
  // Adaptive dt: the number of steps is not known; time is.
  const bool by_time = c_.run.dt_mode == DtMode::Adaptive;
  const double done = by_time ? r.t : static_cast<double>(r.step);
  const double total = by_time ? c_.run.t_end : static_cast<double>(d_.steps_to_run);
  recent_.emplace_back(wall_(), done);
  if (recent_.size() > 20) recent_.pop_front();
  const double dw = recent_.back().first - recent_.front().first, dp = recent_.back().second - recent_.front().second;
  const double eta = dp > 0.0 ? dw / dp * std::max(0.0, total - done) : 0.0;
  const double its = r.step > 0 ? static_cast<double>(sim_.totals().iterations) / static_cast<double>(r.step) : 0.0;
  std::fprintf(stderr, "\rstep %lld/%s  t=%.4g  n=%lld  M/M_inf=%.4f  it/step=%.1f  ETA %s   ",
               static_cast<long long>(r.step),
               by_time ? "?" : std::to_string(d_.steps_to_run).c_str(), r.t,
               static_cast<long long>(r.n_particles), r.mass_ratio, its, hms(eta).c_str());
  if (final_line) std::fputc('\n', stderr);
  std::fflush(stderr);
}

}  // namespace otfp::app::detail
