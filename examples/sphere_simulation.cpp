// The sphere of [2025] Sec. 5.1 from C++ through library calls only: a ball of
// radius 1, empty at t = 0, held at rho = g on its surface, with the set-up of
// `otfp run examples/sphere_dirichlet.toml` (the converging treatment,
// run_setup.hpp) and its time grid t_k = k dt. Prints per step t, M inside
// Omega (43) (series.csv's mass_inside, the same doubles), M/M_inf and Crank's
// uptake. Usage: ./sphere_simulation [n_inf] [t_end]
#include <cstdint>
#include <cstdio>
#include <string>

#include "otfp/analytic.hpp"
#include "otfp/run_setup.hpp"
#include "otfp/simulation.hpp"

int main(int argc, char** argv) {
  using namespace otfp;
  const double g = 0.238732;  // rho_inf = 3 M_inf / (4 pi R^3) with M_inf = 1, as the configuration gives it
  const DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  const std::vector<ConstantBoundaryData> boundary = {{0, PatchKind::Dirichlet, g}};
  RunSetupOptions o;  // kappa = 1, beta dr^2 = 2, the converging preset
  o.n_inf = argc > 1 ? std::stoll(argv[1]) : 400;
  o.t_end = argc > 2 ? std::stod(argv[2]) : 1.0;
  o.M_inf = 1.0;      // diagnostics.M_inf of the configuration: m_p = M_inf / n_inf
  o.length_L = 1.0;   // L = R
  const RunSetup setup = setup_run(*ball, boundary, o);  // (36)-(40), the band, the options
  Simulation sim(ball, boundary, setup.options);
  sim.start(ParticleSet(3));
  const RunParameters& p = setup.parameters;
  for (std::int64_t k = 1; k <= p.n_steps; ++k) {
    const SimulationStep step = sim.advance_to(k == p.n_steps ? o.t_end : static_cast<double>(k) * p.dt);
    const double mass = sim.measure(Vec3::Zero()).mass_inside;
    std::printf("t = %.17g  M = %.17g  M/M_inf = %.4f  Crank %.4f  (%d evaluations)\n", step.t_end, mass,
                mass / p.M_inf, analytic::crank_sphere_uptake(step.t_end), step.diffusion.evaluations);
  }
}
