// The reference of a configuration and the progress line (the rows
// themselves are the library's RunRecorder, otfp/run_record.hpp).
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
