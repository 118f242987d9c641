// The sphere of [2025] Sec. 5.1 from C++ through otfp::Simulation: a ball of
// radius 1, empty at t = 0, held at rho = g on its surface; prints t, M/M_inf
// (43) and Crank's uptake. Usage: ./sphere_simulation [n_inf] [t_end]
#include <cmath>
#include <cstdio>
#include <string>

#include "otfp/analytic.hpp"
#include "otfp/parameters.hpp"
#include "otfp/simulation.hpp"

int main(int argc, char** argv) {
  using namespace otfp;
  const std::size_t n_inf = argc > 1 ? std::stoul(argv[1]) : 400;
  const double t_end = argc > 2 ? std::stod(argv[2]) : 0.5, g = 1.0;
  const DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  const PaperParameters pp = paper_parameters(ball->volume(), n_inf, 3, 1.0, 1.0);  // (36)-(40), kappa = 1
  SimulationOptions o;
  o.particle_mass = g * ball->volume() / static_cast<double>(n_inf);  // M_inf / n_inf
  o.width_s = pp.width_s;
  o.barrier_stiffness = pp.barrier_C;
  o.projection.layer_b = pp.layer_b;
  // The converging treatment of `otfp run` (docs/boundaries.md): a reservoir band of
  // one cut-off radius, half a spacing per sublayer.
  o.projection.dirichlet_mode = DirichletMode::Reservoir;
  o.projection.reservoir_thickness = cutoff_radius(pp.width_s, o.implicit.neighbor.kernel_tolerance);
  o.projection.reservoir_sublayers = static_cast<int>(std::lround(2.0 * o.projection.reservoir_thickness / pp.dr));
  o.projection.reservoir_profile = ReservoirProfile::Odd;
  Simulation sim(ball, {{0, PatchKind::Dirichlet, g}}, o);
  sim.start(ParticleSet(3));
  sim.run_until(t_end, pp.dt_explicit, [&](const Simulation& s, const SimulationStep& step) {
    const double ratio = s.measure(Vec3::Zero()).mass_inside / (g * ball->volume());
    std::printf("t = %.4f  M/M_inf = %.4f  Crank %.4f  (%d evaluations)\n", step.t_end, ratio,
                analytic::crank_sphere_uptake(step.t_end), step.diffusion.evaluations);
  });
}
