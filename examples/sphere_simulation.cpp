// The sphere of [2025] Sec. 5.1 from C++ through library calls only: a ball of
// radius 1, empty at t = 0, held at rho = g on its surface, with the set-up of
// `otfp run examples/sphere_dirichlet.toml` (the converging treatment,
// run_setup.hpp) and its time grid t_k = k dt. Prints per step t, M inside
// Omega (43), M/M_inf and Crank's uptake; with a third argument it also
// writes that run's series.csv there (the same text `otfp run` writes: the
// rows of run_record.hpp with the Crank reference of reference.hpp).
// Usage: ./sphere_simulation [n_inf] [t_end] [series.csv]
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>

#include "otfp/analytic.hpp"
#include "otfp/reference.hpp"
#include "otfp/run_record.hpp"
#include "otfp/run_setup.hpp"
#include "otfp/series_layout.hpp"
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
  const RunParameters& p = setup.parameters;
  Simulation sim(ball, boundary, setup.options);

  // Crank's sphere (its R and (3/5) M_inf R^2 from the ball) and the rows.
  ReferenceSetup rs;
  rs.M_inf = p.M_inf;
  rs.t_end = o.t_end;
  rs.constant_dt = p.dt;
  complete_reference_geometry("crank_sphere", *ball, {0}, rs);
  const std::unique_ptr<Reference> crank = make_reference("crank_sphere", rs);
  RecorderOptions ro;
  ro.M_inf = p.M_inf;
  ro.J_inf = rs.J_inf;  // diagnostics.J_inf = 0.6 of the configuration
  RunRecorder rows(sim, ro, crank.get());
  rows.step_dt = p.dt;
  const SeriesLayout layout(true, crank->has_mass_blob_error(), crank->columns());
  std::ofstream series;
  if (argc > 3) series.open(argv[3]);

  sim.start(ParticleSet(3));
  const StepRecord first = rows(0, 0.0, nullptr, sim.initial_step().inserted, sim.initial_step().removed);
  if (series) series << layout.header() << layout.row(first);
  for (std::int64_t k = 1; k <= p.n_steps; ++k) {
    const SimulationStep step = sim.advance_to(k == p.n_steps ? o.t_end : static_cast<double>(k) * p.dt);
    const StepRecord r = rows(k, step.t_end, &step.diffusion, step.inserted, step.removed);
    if (series) series << layout.row(r);
    std::printf("t = %.17g  M = %.17g  M/M_inf = %.4f  Crank %.4f  (%d evaluations)\n", step.t_end, r.mass_inside,
                r.mass_ratio, analytic::crank_sphere_uptake(step.t_end), step.diffusion.evaluations);
  }
}
