// Taking implicit steps far beyond the explicit limit, from your own code.
//
// Fills the inner half of the unit ball with blobs, keeps them in the ball
// with the one-sided barrier, and takes implicit steps of 10x and 50x the
// explicit limit dr^2/kappa. Each step minimises the functional (28) with
// L-BFGS (Ceres, or NLopt with --nlopt) and prints its summary. With
// --adaptive the steps are variational BDF2 and their size is chosen by the
// local error estimate (TimeStepController), from 1x to t = 100 dt_explicit.
//   ./implicit_large_steps [n] [--nlopt] [--widths] [--adaptive [tolerance]]
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "otfp/geometry.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/parameters.hpp"
#include "otfp/time_step_control.hpp"

int main(int argc, char** argv) {
  using namespace otfp;
  std::size_t n = 2000;
  Backend backend = Backend::Ceres;
  WidthMode widths = WidthMode::Fixed;
  bool adaptive = false;
  double tolerance = 1e-2;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--nlopt")) backend = Backend::Nlopt;
    else if (!std::strcmp(argv[i], "--widths")) widths = WidthMode::PerParticle;
    else if (!std::strcmp(argv[i], "--adaptive")) {
      adaptive = true;
      if (i + 1 < argc && std::strtod(argv[i + 1], nullptr) > 0.0) tolerance = std::strtod(argv[++i], nullptr);
    } else n = std::strtoul(argv[i], nullptr, 10);
  }
  const int dim = 3;
  const double kappa = 1.0;

  // 1. Geometry and the papers' parameter rules (36)-(40) for n particles in the ball.
  DomainPtr ball = make_ball(dim, Vec3::Zero(), 1.0);
  const PaperParameters pp = paper_parameters(ball->volume(), n, dim, 1.0, kappa, 2.0, SpacingRule::SphereRadius);

  // 2. Particles: uniform in the inner half of the ball, total mass 1.
  ParticleSet particles(dim);
  Rng rng(1);
  DomainPtr core = make_ball(dim, Vec3::Zero(), 0.5);
  for (std::size_t i = 0; i < n; ++i) particles.add(core->sample_interior(rng), pp.width_s, 1.0 / n);

  // 3. The implicit stepper: barrier C = 1/dt_explicit as in (40), L-BFGS.
  ImplicitOptions options;
  options.kappa = kappa;
  options.rho_ref = 1.0 / ball->volume();
  options.minimizer.backend = backend;
  options.width_mode = widths;
  // Looser than the defaults (1e-3 / 1e-2): a large step needs fewer digits.
  options.displacement_tolerance = 1e-2;
  options.relative_tolerance = 1e-1;
  if (adaptive) options.time_scheme = TimeScheme::Bdf2;
  ImplicitStepper stepper(dim, options, Barrier(ball, pp.barrier_C));

  if (adaptive) {
    // 4'. Adaptive BDF2: the controller proposes each step from the last one's
    // error estimate; a rejected step leaves the particles as they were.
    TimeStepControlOptions control;
    control.tolerance = tolerance;
    const TimeStepController controller(control);
    const double t_end = 100.0 * pp.dt_explicit;
    double t = 0.0, dt = pp.dt_explicit;
    int accepted = 0, rejected = 0, evaluations = 0;
    std::printf("%4s %10s %10s %12s %6s\n", "step", "dt/dt_ex", "t/dt_ex", "error", "evals");
    while (t < t_end * (1.0 - 1e-12)) {
      const double h = std::min(dt, t_end - t);
      const StepSummary s = stepper.step(particles, h, controller.error_limit(h));
      evaluations += s.evaluations;
      dt = controller.decide(h, s.error_estimate, s.error_order).dt_next;
      if (!s.accepted && !s.error_rejected) {
        std::fprintf(stderr, "step failed: %s\n", s.message.c_str());
        return 1;
      }
      if (!s.accepted) {
        ++rejected;
        continue;
      }
      t += h;
      std::printf("%4d %10.2f %10.2f %12.3e %6d\n", accepted++, h / pp.dt_explicit, t / pp.dt_explicit,
                  s.error_estimate, s.evaluations);
    }
    std::printf("%d steps accepted, %d rejected, %d evaluations\n", accepted, rejected, evaluations);
    return 0;
  }

  // 4. Steps of 10x and 50x the explicit limit; the explicit scheme would blow up here.
  std::printf("n = %zu, dr = %.4f, explicit limit dt = %.3e\n", n, pp.dr, pp.dt_explicit);
  std::printf("%4s %8s %10s %12s %12s %6s %6s %8s %8s %s\n", "step", "dt/dt_ex", "t", "F_before", "F_after", "iter",
              "evals", "builds", "ms", "termination");
  double t = 0.0;
  for (int k = 0; k < 10; ++k) {
    const double factor = k < 5 ? 10.0 : 50.0;
    const StepSummary s = stepper.step(particles, factor * pp.dt_explicit);
    if (!s.accepted) {
      std::fprintf(stderr, "step %d rejected: %s\n", k, s.message.c_str());
      return 1;
    }
    t += s.dt;
    std::printf("%4d %8.0f %10.4f %12.6f %12.6f %6d %6d %8d %8.1f %s\n", k, factor, t, s.f_before, s.f_after,
                s.iterations, s.evaluations, s.list_builds, 1e3 * s.wall_seconds, to_string(s.reason).c_str());
  }
  double outside = 0.0;
  for (const Vec3& x : particles.positions()) outside = std::max(outside, ball->signed_distance(x));
  std::printf("largest excursion outside the ball: %.2e (barrier-limited)\n", outside);
  return 0;
}
