// The time loop of otfp::Simulation: run() on its grid of fixed steps (kept
// in checkpoints) or adaptive, with max_steps, a stop predicate and a
// checkpoint cadence; run_until() is its shorthand on a grid of its own.
#include <algorithm>
#include <cmath>
#include <charconv>
#include <string>

#include "otfp/simulation.hpp"

namespace otfp {

namespace {
std::string format_number(double v) {  // shortest round trip, as the other messages of Simulation
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}
}  // namespace

std::string to_string(RunEnd e) {
  switch (e) {
    case RunEnd::Completed: return "completed";
    case RunEnd::MaxSteps: return "max_steps";
    case RunEnd::Stopped: return "stopped";
  }
  return "unknown";
}

void RunControl::validate() const {
  require(std::isfinite(t_end), "t_end", t_end, "must be finite");
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(max_steps >= 0, "max_steps", static_cast<double>(max_steps), "must be >= 0 (0: no limit)");
  require(checkpoint_interval >= 0, "checkpoint_interval", static_cast<double>(checkpoint_interval),
          "must be >= 0 (0: at the end only)");
}

TimeGrid Simulation::grid_for(const RunControl& control) const {
  // n equal steps of at most about h from (t0, k0), the last on t_end.
  auto grid_from = [&](double t0, std::int64_t k0, double h) {
    TimeGrid g;
    g.t_origin = t0;
    g.k_origin = k0;
    const std::int64_t n =
        std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil((control.t_end - t0) / h * (1.0 - 1e-12))));
    g.dt = (control.t_end - t0) / static_cast<double>(n);
    g.k_end = k0 + n;
    g.t_end = control.t_end;
    return g;
  };
  if (grid_.dt > 0.0 && grid_.dt == control.dt) {
    // The same grid, its end moved to t_end (the steps already taken stand).
    TimeGrid g = grid_;
    g.k_end = g.k_origin + std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil(
                                                          (control.t_end - g.t_origin) / g.dt * (1.0 - 1e-12))));
    g.t_end = control.t_end;
    return g;
  }
  // A new grid from now: a continued run keeps its step, a new one takes control.dt.
  return grid_from(time_, step_, grid_.dt > 0.0 ? grid_.dt : control.dt);
}

bool Simulation::finished(const RunControl& control) const {
  if (time_ >= control.t_end) return true;
  if (control.adaptive) return control.max_steps > 0 && step_ >= control.max_steps;
  const std::int64_t k_end = grid_for(control).k_end;
  return step_ >= (control.max_steps > 0 ? std::min(k_end, control.max_steps) : k_end);
}

RunEnd Simulation::run(const RunControl& control, RunObserver* observer) {
  require_started("run");
  control.validate();
  if (finished(control)) return time_ >= control.t_end ? RunEnd::Completed : RunEnd::MaxSteps;
  const bool adaptive = control.adaptive;
  std::int64_t k_last = 0;
  if (!adaptive) {
    grid_ = grid_for(control);
    k_last = control.max_steps > 0 ? std::min(grid_.k_end, control.max_steps) : grid_.k_end;
  } else if (!(dt_next_ > 0.0)) {
    const TimeStepControlOptions& tc = options_.time_control;
    set_next_dt(std::min(std::max(control.dt, tc.dt_min), tc.dt_max));
  }
  RunEnd end = RunEnd::Completed;
  for (std::int64_t k = step_ + 1;; ++k) {
    SimulationStep s;
    if (!adaptive) {
      if (k > k_last) break;
      s = advance_to(grid_.time_of(k));
    } else {
      if (time_ >= control.t_end || (control.max_steps > 0 && k > control.max_steps)) break;
      s = advance_adaptive(control.t_end);
    }
    const bool last = adaptive ? s.t_end >= control.t_end || k == control.max_steps : k == k_last;
    const bool stop = control.stop && control.stop(s);
    if (observer) observer->on_step(*this, s, last || stop);
    if (last) end = time_ >= control.t_end ? RunEnd::Completed : RunEnd::MaxSteps;
    if (stop && !last) {
      end = RunEnd::Stopped;
      break;
    }
    if (!last && control.checkpoint_interval > 0 && k % control.checkpoint_interval == 0 && observer)
      observer->on_checkpoint(*this);
  }
  if (observer) observer->on_checkpoint(*this);
  return end;
}

void Simulation::run_until(double t_end, double dt, const Observer& observer, bool adaptive) {
  require_started("run_until");
  require(std::isfinite(t_end) && t_end > time_, "t_end", t_end,
          "must be finite and > the current time " + format_number(time_));
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  // run() on a grid of its own from now: n = ceil((t_end - time()) / dt) equal steps.
  struct Forward : RunObserver {
    const Observer& f;
    explicit Forward(const Observer& fn) : f(fn) {}
    void on_step(const Simulation& sim, const SimulationStep& step, bool) override {
      if (f) f(sim, step);
    }
  } forward(observer);
  if (adaptive && !(dt_next_ > 0.0)) dt_next_ = dt;  // the first try as given (run() would bound it)
  grid_ = TimeGrid{};
  RunControl c;
  c.t_end = t_end;
  c.dt = dt;
  c.adaptive = adaptive;
  run(c, &forward);
}

}  // namespace otfp
