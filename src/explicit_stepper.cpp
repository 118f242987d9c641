#include <chrono>
#include <stdexcept>
#include <string>
#include <cmath>

#include <fmt/format.h>

#include "otfp/explicit_stepper.hpp"
#include "step_objective.hpp"

namespace otfp {

void ExplicitOptions::validate() const {
  require(std::isfinite(kappa) && kappa > 0.0, "kappa", kappa, "must be finite and > 0");
  require(std::isfinite(rho_ref) && rho_ref > 0.0, "rho_ref", rho_ref, "must be finite and > 0");
  neighbor.validate();
}

namespace detail {
FunctionalOptions functional_options(const ExplicitOptions& o) {
  FunctionalOptions f;
  f.kappa = o.kappa;
  f.rho_ref = o.rho_ref;
  f.neighbor = o.neighbor;
  return f;
}
}  // namespace detail

ExplicitStepper::ExplicitStepper(int dim, ExplicitOptions options, Barrier barrier, Periodicity periodicity)
    : dim_(dim),
      options_((options.validate(), options)),
      functional_(dim, detail::functional_options(options), std::move(barrier), periodicity) {}

void ExplicitStepper::velocity(const std::vector<Vec3>& x, const std::vector<double>& s, std::vector<Vec3>& v) {
  if (options_.scheme == ExplicitScheme::EulerExactGradient) {
    // With the reference at x the transport gradient vanishes: v = -(1/m) d(E + B)/dx.
    functional_.set_reference(x, s, functional_.masses());
    Gradient g;
    functional_.evaluate(x, s, &g);
    v.resize(x.size());
    for (std::size_t p = 0; p < x.size(); ++p) v[p] = -g.x[p] / functional_.masses()[p];
  } else {
    functional_.explicit_velocity(x, s, v);
  }
  if (external_) {
    for (std::size_t p = 0; p < x.size(); ++p) {
      Vec3 g = Vec3::Zero();
      external_(x[p], &g);
      v[p] -= g;
    }
  }
}

void ExplicitStepper::add_external(const std::vector<Vec3>& x, const std::vector<double>& m,
                                   FunctionalParts& parts) const {
  if (!external_) return;
  for (std::size_t p = 0; p < x.size(); ++p) parts.barrier += m[p] * external_(x[p], nullptr);
}

StepSummary ExplicitStepper::step(ParticleSet& particles, double dt) {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  require(particles.dim() == dim_, "particles dim", particles.dim(),
          "must equal the stepper's dim " + std::to_string(dim_));
  const auto t0 = std::chrono::steady_clock::now();
  StepSummary summary;
  summary.dt = dt;
  summary.iterations = 1;
  auto reject = [&](const std::string& why) {
    summary.accepted = false;
    summary.reason = TerminationReason::NonFinite;
    summary.message = why;
    summary.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return summary;
  };
  // What the implicit stepper's objective refuses (its F is not finite there):
  // the step is rejected before anything is touched.
  const std::size_t n = particles.size();
  for (std::size_t p = 0; p < n; ++p) {
    const double mp = particles.masses()[p], sp = particles.widths()[p];
    if (!(std::isfinite(mp) && mp > 0.0))
      return reject(fmt::format("particle {}: mass = {}: must be finite and > 0", particles.ids()[p], mp));
    if (!(std::isfinite(sp) && sp > 0.0))
      return reject(fmt::format("particle {}: width s = {}: must be finite and > 0", particles.ids()[p], sp));
  }
  // Work on copies in spatial order (memory locality for the pair sweeps): a
  // rejected step neither moves nor reorders the particles.
  std::vector<std::size_t> order(n);
  for (std::size_t i = 0; i < n; ++i) order[i] = i;
  if (options_.sort_particles && n > 0) {
    double s_max = 0.0;
    for (double v : particles.widths()) s_max = std::max(s_max, v);
    order = spatial_order(particles.positions(), dim_, cutoff_radius(s_max, options_.neighbor.kernel_tolerance));
  }
  std::vector<Vec3> x0(n);
  std::vector<double> s(n), m(n);
  for (std::size_t i = 0; i < n; ++i) {
    x0[i] = particles.positions()[order[i]];
    s[i] = particles.widths()[order[i]];
    m[i] = particles.masses()[order[i]];
  }
  functional_.set_dt(dt);
  functional_.set_reference(x0, s, m);
  const int builds_before = functional_.list().build_count();
  const double list_seconds_before = functional_.list().build_seconds();
  const std::uint64_t pairs_before = functional_.entropy().pair_evaluations();
  functional_.rebuild_list(x0, s);  // particles may have moved in memory
  summary.parts_before = functional_.evaluate(x0, s, nullptr);
  add_external(x0, m, summary.parts_before);
  summary.f_before = summary.parts_before.total();

  std::vector<Vec3> x = x0, v;
  bool finite = std::isfinite(summary.f_before);
  std::string failure =
      finite ? "explicit update produced non-finite positions" : "non-finite F at the start of the step";
  try {
    if (!finite) {
      // Nothing to update from.
    } else if (options_.scheme == ExplicitScheme::Rk4Force27) {
      std::vector<Vec3> k1, k2, k3, k4, tmp(n);
      velocity(x0, s, k1);
      for (std::size_t p = 0; p < n; ++p) tmp[p] = x0[p] + 0.5 * dt * k1[p];
      velocity(tmp, s, k2);
      for (std::size_t p = 0; p < n; ++p) tmp[p] = x0[p] + 0.5 * dt * k2[p];
      velocity(tmp, s, k3);
      for (std::size_t p = 0; p < n; ++p) tmp[p] = x0[p] + dt * k3[p];
      velocity(tmp, s, k4);
      for (std::size_t p = 0; p < n; ++p) x[p] = x0[p] + dt / 6.0 * (k1[p] + 2.0 * k2[p] + 2.0 * k3[p] + k4[p]);
      summary.evaluations = 4;
    } else {
      velocity(x0, s, v);
      for (std::size_t p = 0; p < n; ++p) x[p] = x0[p] + dt * v[p];
      summary.evaluations = 1;
    }
    for (const auto& p : x) finite = finite && p.allFinite();
    if (finite) {
      functional_.set_reference(x0, s, m);
      summary.parts_after = functional_.evaluate(x, s, nullptr);
      add_external(x, m, summary.parts_after);
      summary.f_after = summary.parts_after.total();
      if (!std::isfinite(summary.f_after)) {
        finite = false;
        failure = "non-finite F after the explicit update";
      }
    }
  } catch (const std::runtime_error& e) {
    // An RK4 stage that diverged reaches the neighbour search first.
    finite = false;
    failure = std::string("explicit update diverged: ") + e.what();
  }
  if (finite) {
    const Periodicity& per = functional_.periodicity();
    for (auto& p : x) p = per.wrap(p);
    particles.reorder(order);
    particles.positions() = std::move(x);
    summary.accepted = true;
    summary.reason = TerminationReason::Converged;
  } else {
    summary.accepted = false;
    summary.reason = TerminationReason::NonFinite;
    summary.message = failure;
  }
  summary.list_builds = functional_.list().build_count() - builds_before;
  summary.list_seconds = functional_.list().build_seconds() - list_seconds_before;
  summary.pair_evaluations = functional_.entropy().pair_evaluations() - pairs_before;
  summary.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return summary;
}

}  // namespace otfp
