// Evaluates F and its gradient for a few blobs through the installed package,
// then takes one implicit step (with TAO where the package has otfp::mpi).
#include <cstdio>

#include "otfp/functional.hpp"
#include "otfp/geometry.hpp"
#include "otfp/implicit_stepper.hpp"
#ifdef OTFP_WITH_TAO
#include "otfp/tao.hpp"
#endif

int main() {
  using namespace otfp;
  ParticleSet ps(3);
  Rng rng(7);
  DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  for (int i = 0; i < 200; ++i) ps.add(ball->sample_interior(rng), 0.15, 1.0 / 200);
  FunctionalOptions o;
  o.dt = 0.01;
  Functional f(3, o, Barrier(ball, 100.0));
  f.set_reference(ps.positions(), ps.widths(), ps.masses());
  Gradient g;
  const FunctionalParts parts = f.evaluate(ps.positions(), ps.widths(), &g);
  std::printf("F = %.6f (transport %.3g, entropy %.6f, barrier %.3g), |dF/dx_0| = %.4g\n", parts.total(),
              parts.transport, parts.entropy, parts.barrier, g.x[0].norm());
  if (parts.total() != parts.total()) return 1;

  ImplicitOptions io;
#ifdef OTFP_WITH_TAO
  register_tao_backend();
  io.minimizer.backend = Backend::Tao;
#endif
  ImplicitStepper stepper(3, io, Barrier(ball, 100.0));
  const StepSummary s = stepper.step(ps, 0.01);
  std::printf("one implicit step (%s): %s, %d evaluations\n", to_string(io.minimizer.backend).c_str(),
              s.accepted ? "accepted" : "rejected", s.evaluations);
  return s.accepted ? 0 : 1;
}
