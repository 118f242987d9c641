// One diffusive step in 3D: n = 1e4 particles uniform in the unit ball,
// beta = 2/dr^2, barrier C = 1/dt_explicit. Implicit steps with both backends,
// fixed and per-particle widths, at dt = 1x, 10x and 100x the explicit limit,
// and one explicit step for comparison; BM_WidthCost (issue 15) puts fixed and
// per-particle widths side by side at a smaller n. Each benchmark iteration is one step
// (after two warm-up steps); counters give medians over the timed steps.
// BM_SimulationStep (issue 24) times a whole step of otfp::Simulation
// (the state kept for a failed step, the diffusive step, the walls and the
// projection) with a cheap explicit diffusive step.
//   ./otfp_bench_stepper --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <ctime>

#include "otfp/explicit_stepper.hpp"
#include "otfp/geometry.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/parameters.hpp"
#include "otfp/simulation.hpp"
#ifdef OTFP_WITH_TAO
#include "otfp/tao.hpp"
#endif

using namespace otfp;

namespace {

constexpr std::size_t kParticles = 10000;

struct Cloud {
  ParticleSet ps{3};
  PaperParameters pp;
  DomainPtr ball;
};

Cloud make_cloud(std::size_t n = kParticles) {
  Cloud c;
  c.ball = make_ball(3, Vec3::Zero(), 1.0);
  c.pp = paper_parameters(c.ball->volume(), n, 3, 1.0, 1.0, 2.0, SpacingRule::Cube);
  Rng rng(11);
  for (std::size_t i = 0; i < n; ++i) c.ps.add(c.ball->sample_interior(rng), c.pp.width_s, 1.0 / n);
  return c;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

template <class Stepper>
void run_steps(benchmark::State& state, Stepper& stepper, Cloud& c, double dt) {
  for (int k = 0; k < 2; ++k) stepper.step(c.ps, dt);  // warm-up: leave the random initial state
  std::vector<double> evals, iters, solver_share, builds, ms;
  for (auto _ : state) {
    const StepSummary s = stepper.step(c.ps, dt);
    if (!s.accepted) {
      state.SkipWithError(("step rejected: " + s.message).c_str());
      break;
    }
    evals.push_back(s.evaluations);
    iters.push_back(s.iterations);
    solver_share.push_back(s.wall_seconds > 0 ? s.solver_seconds / s.wall_seconds : 0.0);
    builds.push_back(s.list_builds);
    ms.push_back(1e3 * s.wall_seconds);
  }
  state.counters["evals/step"] = median(evals);
  state.counters["iters/step"] = median(iters);
  state.counters["solver_share"] = median(solver_share);
  state.counters["builds/step"] = median(builds);
  state.counters["ms/step"] = median(ms);
  state.counters["dt/dt_ex"] = dt / c.pp.dt_explicit;
}

// The figures in docs/performance.md were measured with the stopping rule
// 1e-2 / 1e-1 (the library's defaults until they were made the CLI's 1e-3 / 1e-2).
void set_measured_tolerances(ImplicitOptions& o) {
  o.displacement_tolerance = 1e-2;
  o.relative_tolerance = 1e-1;
  // OTFP_BENCH_STOPPING_NORM=energy|max: the stopping rule's norm (docs/stepper.md).
  if (const char* norm = std::getenv("OTFP_BENCH_STOPPING_NORM")) o.stopping_norm = stopping_norm_from_string(norm);
  // OTFP_BENCH_MAX_NORM_FACTOR=F: the energy rule's bound on the largest particle (docs/stepper.md).
  if (const char* f = std::getenv("OTFP_BENCH_MAX_NORM_FACTOR")) o.max_norm_factor = std::atof(f);
}

// The benchmarks' backend argument: 0 Ceres, 1 NLopt, 2 TAO (a build with otfp::mpi).
Backend bench_backend(std::int64_t arg) {
  if (arg == 0) return Backend::Ceres;
  if (arg == 1) return Backend::Nlopt;
#ifdef OTFP_WITH_TAO
  register_tao_backend();
#endif
  return Backend::Tao;
}

// Args: backend (0 Ceres, 1 NLopt, 2 TAO), widths (0 fixed, 1 per particle), dt factor.
void BM_ImplicitStep(benchmark::State& state) {
  Cloud c = make_cloud();
  ImplicitOptions o;
  set_measured_tolerances(o);
  o.minimizer.backend = bench_backend(state.range(0));
  o.width_mode = state.range(1) == 0 ? WidthMode::Fixed : WidthMode::PerParticle;
  o.rho_ref = 1.0 / c.ball->volume();
  if (const char* tol = std::getenv("OTFP_BENCH_TOLERANCE")) o.displacement_tolerance = std::atof(tol);
  ImplicitStepper stepper(3, o, Barrier(c.ball, c.pp.barrier_C));
  state.SetLabel(to_string(o.minimizer.backend) + "/" + to_string(o.width_mode));
  run_steps(state, stepper, c, static_cast<double>(state.range(2)) * c.pp.dt_explicit);
}

// Issue 11: the predictor and the time scheme at large steps. Args: backend
// (0 Ceres, 1 NLopt, 2 TAO), widths (0 fixed, 1 per particle), dt factor, predictor
// (0 none, 1 extrapolate, 2 damped), scheme (0 Euler, 1 BDF2). Settled: 5
// warm-up steps at the same dt before the 5 timed ones.
ImplicitOptions large_step_options(benchmark::State& state, const Cloud& c) {
  ImplicitOptions o;
  set_measured_tolerances(o);
  set_measured_tolerances(o);
  o.minimizer.backend = bench_backend(state.range(0));
  o.width_mode = state.range(1) == 0 ? WidthMode::Fixed : WidthMode::PerParticle;
  o.predictor = static_cast<Predictor>(state.range(3));
  o.time_scheme = state.range(4) == 0 ? TimeScheme::Euler : TimeScheme::Bdf2;
  o.rho_ref = 1.0 / c.ball->volume();
  state.SetLabel(to_string(o.minimizer.backend) + "/" + to_string(o.width_mode) + "/" + to_string(o.predictor) + "/" +
                 to_string(o.time_scheme));
  return o;
}

void BM_LargeStep(benchmark::State& state) {
  Cloud c = make_cloud();
  ImplicitStepper stepper(3, large_step_options(state, c), Barrier(c.ball, c.pp.barrier_C));
  const double dt = static_cast<double>(state.range(2)) * c.pp.dt_explicit;
  for (int k = 0; k < 3; ++k) stepper.step(c.ps, dt);  // + 2 in run_steps
  run_steps(state, stepper, c, dt);
}

// The first step after the step size grows 10x: 5 steps at dt/10, then each
// timed iteration is one step at dt from a copy of that state (same history).
void BM_FirstStepAfterDtChange(benchmark::State& state) {
  Cloud c = make_cloud();
  const ImplicitOptions o = large_step_options(state, c);
  ImplicitStepper settled(3, o, Barrier(c.ball, c.pp.barrier_C));
  const double dt = static_cast<double>(state.range(2)) * c.pp.dt_explicit;
  for (int k = 0; k < 5; ++k) settled.step(c.ps, dt / 10.0);
  std::vector<double> evals, ms;
  for (auto _ : state) {
    ImplicitStepper stepper = settled;
    ParticleSet ps = c.ps;
    const StepSummary s = stepper.step(ps, dt);
    if (!s.accepted) {
      state.SkipWithError(("step rejected: " + s.message).c_str());
      break;
    }
    evals.push_back(s.evaluations);
    ms.push_back(1e3 * s.wall_seconds);
  }
  state.counters["evals/step"] = median(evals);
  state.counters["ms/step"] = median(ms);
  state.counters["dt/dt_ex"] = dt / c.pp.dt_explicit;
}

// Issue 15: the cost of per-particle widths against fixed widths in the ball,
// both in one benchmark run (the machine is shared; only ratios within one run
// count). Args: n, width_skin in percent, max_width_factor in percent (0: off).
// Two steppers (Ceres, dt = dt_explicit, the measured tolerances) on copies
// of the same cloud; 3 warm-up steps each (the widths spread), then the timed
// steps alternate fixed / per-particle. Counters: medians per step, with
// "fx_" for fixed and "pp_" for per-particle widths; nbrs: list entries per
// particle after the step; pp/fx: ratio of the medians of ms/step.
void BM_WidthCost(benchmark::State& state) {
  const auto n = static_cast<std::size_t>(state.range(0));
  Cloud fixed_cloud = make_cloud(n);
  Cloud width_cloud = make_cloud(n);
  ImplicitOptions o;
  set_measured_tolerances(o);
  o.rho_ref = 1.0 / fixed_cloud.ball->volume();
  if (const char* tol = std::getenv("OTFP_BENCH_TOLERANCE")) o.displacement_tolerance = std::atof(tol);
  ImplicitOptions ow = o;
  ow.width_mode = WidthMode::PerParticle;
  ow.width_skin = static_cast<double>(state.range(1)) / 100.0;
  ow.max_width_factor = static_cast<double>(state.range(2)) / 100.0;
  ow.nominal_width = width_cloud.pp.width_s;
  ImplicitStepper fixed(3, o, Barrier(fixed_cloud.ball, fixed_cloud.pp.barrier_C));
  ImplicitStepper width(3, ow, Barrier(width_cloud.ball, width_cloud.pp.barrier_C));
  const double dt = fixed_cloud.pp.dt_explicit;
  for (int k = 0; k < 3; ++k) {
    fixed.step(fixed_cloud.ps, dt);
    width.step(width_cloud.ps, dt);
  }
  struct Series {
    std::vector<double> ms, cpu, evals, builds, nbrs;
  } fx, pp;
  auto record = [](Series& sr, const StepSummary& s, ImplicitStepper& st, double cpu_seconds) {
    const NeighborList& list = st.functional().list();
    sr.ms.push_back(1e3 * s.wall_seconds);
    sr.cpu.push_back(1e3 * cpu_seconds);
    sr.evals.push_back(s.evaluations);
    sr.builds.push_back(s.list_builds);
    sr.nbrs.push_back(list.size() ? static_cast<double>(list.num_entries()) / list.size() : 0.0);
  };
  for (auto _ : state) {
    // CPU time of the process too: on a loaded machine it is the steadier measure (run with OMP_NUM_THREADS=1).
    const std::clock_t c0 = std::clock();
    const StepSummary a = fixed.step(fixed_cloud.ps, dt);
    const std::clock_t c1 = std::clock();
    const StepSummary b = width.step(width_cloud.ps, dt);
    const std::clock_t c2 = std::clock();
    if (!a.accepted || !b.accepted) {
      state.SkipWithError(("step rejected: " + (a.accepted ? b.message : a.message)).c_str());
      break;
    }
    record(fx, a, fixed, static_cast<double>(c1 - c0) / CLOCKS_PER_SEC);
    record(pp, b, width, static_cast<double>(c2 - c1) / CLOCKS_PER_SEC);
  }
  double s_max = 0.0;
  for (double v : width_cloud.ps.widths()) s_max = std::max(s_max, v);
  state.counters["fx_ms"] = median(fx.ms);
  state.counters["pp_ms"] = median(pp.ms);
  state.counters["pp/fx"] = median(fx.ms) > 0 ? median(pp.ms) / median(fx.ms) : 0.0;
  state.counters["fx_cpu_ms"] = median(fx.cpu);
  state.counters["pp_cpu_ms"] = median(pp.cpu);
  state.counters["pp/fx_cpu"] = median(fx.cpu) > 0 ? median(pp.cpu) / median(fx.cpu) : 0.0;
  state.counters["fx_evals"] = median(fx.evals);
  state.counters["pp_evals"] = median(pp.evals);
  state.counters["fx_builds"] = median(fx.builds);
  state.counters["pp_builds"] = median(pp.builds);
  state.counters["fx_nbrs"] = median(fx.nbrs);
  state.counters["pp_nbrs"] = median(pp.nbrs);
  state.counters["pp_smax/s0"] = s_max / width_cloud.pp.width_s;
}

void BM_ExplicitStep(benchmark::State& state) {
  Cloud c = make_cloud();
  ExplicitOptions o;
  o.scheme = static_cast<ExplicitScheme>(state.range(0));
  ExplicitStepper stepper(3, o, Barrier(c.ball, c.pp.barrier_C));
  state.SetLabel(to_string(o.scheme));
  run_steps(state, stepper, c, c.pp.dt_explicit);
}

// One whole Simulation::advance: explicit Euler with the force (27) at
// dt = 0.25 dt_explicit (or an implicit Euler step, the library's defaults),
// the unit interval (d = 1) or cube (d = 3), all walls no-flux with image
// blobs, n particles uniform at random (no boundary data: the projection
// moves nothing), one thread. In 1-D a particle has a handful of neighbours,
// so the per-particle bookkeeping of the step shows. Args: dim, n, stepper
// (0 explicit, 1 implicit).
void BM_SimulationStep(benchmark::State& state) {
  const int dim = static_cast<int>(state.range(0));
  const auto n = static_cast<std::size_t>(state.range(1));
  const bool implicit = state.range(2) == 1;
  omp_set_num_threads(1);
  DomainPtr box = make_box(dim, Vec3::Zero(), Vec3::Ones());
  const PaperParameters pp = paper_parameters(box->volume(), n, dim, 1.0, 1.0, 2.0, SpacingRule::Cube);
  SimulationOptions o;
  o.particle_mass = 1.0 / static_cast<double>(n);
  o.width_s = pp.width_s;
  o.barrier_stiffness = pp.barrier_C;
  o.stepper = implicit ? StepperKind::Implicit : StepperKind::Explicit;
  Simulation sim(box, {}, o);
  Rng rng(5);
  ParticleSet ps(dim);
  ps.reserve(n);
  for (std::size_t i = 0; i < n; ++i) ps.add(box->sample_interior(rng), pp.width_s, o.particle_mass);
  sim.start(std::move(ps));
  const double dt = 0.25 * pp.dt_explicit;
  for (int k = 0; k < 2; ++k) sim.advance(dt);  // warm-up
  // The benchmark's own clock for the whole call; SimulationStep::wall_seconds
  // is the step inside it, so the difference ("guard_ms", median) is what
  // advance() does around the step: keeping the state for a failure.
  std::vector<double> guard;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    const SimulationStep s = sim.advance(dt);
    const double whole = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    guard.push_back(1e3 * (whole - s.wall_seconds));
  }
  state.counters["guard_ms"] = median(guard);
  state.counters["particles"] = static_cast<double>(sim.particles().size());
  state.SetLabel(implicit ? "implicit" : "explicit euler27");
}

}  // namespace

BENCHMARK(BM_SimulationStep)
    ->ArgsProduct({{1}, {10000, 100000}, {0}})
    ->ArgsProduct({{3}, {10000}, {0}})
    ->ArgsProduct({{1}, {100000}, {1}})
    ->Iterations(20)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_ImplicitStep)
    ->ArgsProduct({{0, 1}, {0, 1}, {1, 10, 100}})
#ifdef OTFP_WITH_TAO
    ->ArgsProduct({{2}, {0}, {1, 10, 100}})
#endif
    ->Iterations(5)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_LargeStep)
    ->ArgsProduct({{0, 1}, {0}, {10, 100}, {0, 1, 2}, {0, 1}})
#ifdef OTFP_WITH_TAO
    ->ArgsProduct({{2}, {0}, {10, 100}, {0}, {0, 1}})
#endif
    ->Iterations(5)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_LargeStep)
    ->ArgsProduct({{0}, {1}, {10}, {0, 1, 2}, {0, 1}})
    ->Iterations(3)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_FirstStepAfterDtChange)
    ->ArgsProduct({{0, 1}, {0}, {10, 100}, {0, 1, 2}, {0, 1}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_ExplicitStep)->DenseRange(0, 2)->Iterations(5)->Unit(benchmark::kMillisecond)->UseRealTime();
// Skins 0 / 10 / 25 / 50 / 100 % without a bound, then bounds of 1.25, 1.5, 2 and 3 s0 (x 100 here).
BENCHMARK(BM_WidthCost)
    ->ArgsProduct({{3000}, {0, 10, 25, 50, 100}, {0}})
    ->ArgsProduct({{3000}, {0, 10, 50}, {125, 150, 200, 300}})
    ->Iterations(5)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_MAIN();
