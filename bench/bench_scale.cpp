// Whole implicit steps at scale: a Simulation in the unit cube (3D), n
// particles (a jittered cubic lattice of round(n^(1/3))^3 sites) at density 1, beta = 2/dr^2, the x- face Dirichlet at
// rho = 1, the other faces no-flux walls (image blobs), Ceres L-BFGS with the
// library's default tolerances. The Dirichlet face has the default treatment
// of otfp run (--treatment converging: the odd reservoir band one cut-off
// deep, quiet control, half a spacing per sublayer) or the papers' layer of
// Sec. 4.2 (--treatment papers, what this benchmark ran before issue 24).
// One process per size, so that its peak memory is that of this size only:
//   otfp_bench_scale --n 1000000 --dt-factor 1 --threads 2 --steps 2
// prints one line of key = value pairs per run: time per step (median of the
// timed steps after one warm-up step), evaluations and list builds per step,
// and the peak and final resident memory per particle (above the process's
// resident size before the set-up). bench/scaling.sh runs the ladder
// n = 1e3 ... 1e6 and fits the exponent.
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "process_memory.hpp"
#include "otfp/geometry.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/parameters.hpp"
#include "otfp/simulation.hpp"

using namespace otfp;

namespace {

using bench::status_bytes;

int usage(const char* why) {
  std::fprintf(stderr, "otfp_bench_scale: %s\nusage: otfp_bench_scale --n N [--dt-factor F] [--threads T] [--steps K] "
               "[--treatment converging|papers] [--stopping-norm energy|max] [--lattice cubic|bcc] [--max-norm-factor F] [--relative-tolerance R]\n",
               why);
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  long n = 0, threads = 1, steps = 2;
  double factor = 1.0, max_norm_factor = ImplicitOptions{}.max_norm_factor,
         relative_tolerance = ImplicitOptions{}.relative_tolerance;
  std::string treatment = "converging", norm = "energy", lattice = "cubic";
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    char* end = nullptr;
    if (key == "--stopping-norm") {
      norm = argv[i + 1];
      if (norm != "energy" && norm != "max") return usage("--stopping-norm must be energy or max");
      continue;
    }
    if (key == "--lattice") {
      lattice = argv[i + 1];
      if (lattice != "cubic" && lattice != "bcc") return usage("--lattice must be cubic or bcc");
      continue;
    }
    if (key == "--treatment") {
      treatment = argv[i + 1];
      if (treatment != "converging" && treatment != "papers") return usage("--treatment must be converging or papers");
      continue;
    }
    if (key == "--n") n = std::strtol(argv[i + 1], &end, 10);
    else if (key == "--threads") threads = std::strtol(argv[i + 1], &end, 10);
    else if (key == "--steps") steps = std::strtol(argv[i + 1], &end, 10);
    else if (key == "--dt-factor") factor = std::strtod(argv[i + 1], &end);
    else if (key == "--max-norm-factor") max_norm_factor = std::strtod(argv[i + 1], &end);
    else if (key == "--relative-tolerance") relative_tolerance = std::strtod(argv[i + 1], &end);
    else return usage(("unknown option " + key).c_str());
    if (end == nullptr || *end != '\0') return usage(("bad value for " + key).c_str());
  }
  if (argc % 2 == 0) return usage("options come in pairs");
  if (n < 8 || n > 100000000) return usage("--n must be in [8, 1e8]");
  if (threads < 1 || threads > 256) return usage("--threads must be in [1, 256]");
  if (steps < 1 || steps > 1000) return usage("--steps must be in [1, 1000]");
  if (!(factor > 0.0 && factor <= 1e4)) return usage("--dt-factor must be in (0, 1e4]");
  omp_set_num_threads(static_cast<int>(threads));

  const double rss0 = status_bytes("VmRSS");
  DomainPtr box = make_box(3, Vec3::Zero(), Vec3::Ones());
  // Cubic: side^3 sites; bcc: side^3 cells of two sites.
  const long per_cell = lattice == "bcc" ? 2 : 1;
  const auto side = std::max(1L, std::lround(std::cbrt(static_cast<double>(n) / static_cast<double>(per_cell))));
  n = per_cell * side * side * side;
  const auto count = static_cast<std::size_t>(n);
  const PaperParameters pp = paper_parameters(box->volume(), count, 3, 1.0, 1.0, 2.0);
  SimulationOptions o;
  o.particle_mass = 1.0 / static_cast<double>(count);
  o.width_s = pp.width_s;
  o.barrier_stiffness = pp.barrier_C;
  o.projection.layer_b = pp.layer_b;
  o.implicit.rho_ref = 1.0;
  o.implicit.stopping_norm = stopping_norm_from_string(norm);
  o.implicit.max_norm_factor = max_norm_factor;
  o.implicit.relative_tolerance = relative_tolerance;
  if (treatment == "converging") {
    o.projection.dirichlet_mode = DirichletMode::Reservoir;
    o.projection.reservoir_profile = ReservoirProfile::Odd;
    o.projection.reservoir_control = ReservoirControl::Quiet;
    o.projection.reservoir_thickness = cutoff_radius(pp.width_s, o.implicit.neighbor.kernel_tolerance);
    o.projection.reservoir_sublayers =
        std::max(1, static_cast<int>(std::lround(2.0 * o.projection.reservoir_thickness / pp.dr)));
  }
  Simulation sim(box, {{box->patch_by_name("x-"), PatchKind::Dirichlet, 1.0}}, o);
  // A lattice of ~n sites jittered by 0.1 spacing (a uniform random fill
  // needs many steps and several times the evaluations per step to relax
  // first). The cubic lattice (the default, what the figures in
  // docs/performance.md used) is not a minimum of the entropy at
  // beta dr^2 = 2: its steps also measure its rearrangement; the bcc
  // lattice is one (docs/stepper.md, "The step's Hessian").
  ParticleSet ps(3);
  ps.reserve(count);
  Rng rng(2026);
  const double h = 1.0 / static_cast<double>(side), spacing = lattice == "bcc" ? pp.dr : h;
  const std::vector<Vec3> basis = lattice == "bcc" ? std::vector<Vec3>{Vec3(0.25, 0.25, 0.25), Vec3(0.75, 0.75, 0.75)}
                                                   : std::vector<Vec3>{Vec3(0.5, 0.5, 0.5)};
  for (long i = 0; i < side; ++i)
    for (long j = 0; j < side; ++j)
      for (long k = 0; k < side; ++k)
        for (const Vec3& b : basis) {
          Vec3 x = h * (Vec3(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)) + b);
          for (int a = 0; a < 3; ++a) x[a] += 0.1 * spacing * rng.uniform(-1.0, 1.0);
          ps.add(x, pp.width_s, o.particle_mass);
        }
  sim.start(std::move(ps));

  const double dt = factor * pp.dt_explicit;
  std::vector<double> wall, evals, builds;
  for (long k = 0; k <= steps; ++k) {
    const SimulationStep st = sim.advance(dt);
    if (k == 0) {  // warm-up: leave the random fill
      std::fprintf(stderr, "step 0 (warm-up): %d evaluations\n", st.diffusion.evaluations);
      continue;
    }
    wall.push_back(st.wall_seconds);
    evals.push_back(st.diffusion.evaluations);
    std::fprintf(stderr, "step %ld: %d evaluations\n", k, st.diffusion.evaluations);
    builds.push_back(st.diffusion.list_builds);
  }
  auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  const double hwm = status_bytes("VmHWM");
  const Functional& f = sim.implicit_stepper()->functional();
  std::printf(
      "n = %ld lattice = %s treatment = %s threads = %ld dt_factor = %g steps = %ld particles_now = %zu seconds_per_step = %.3f "
      "evaluations_per_step = %.0f list_builds_per_step = %.0f peak_bytes_per_particle = %.0f "
      "resident_bytes_per_particle = %.0f list_rows = %zu images = %zu entries_per_row = %.1f\n",
      n, lattice.c_str(), treatment.c_str(), threads, factor, steps, sim.particles().size(), median(wall), median(evals), median(builds),
      (hwm - rss0) / static_cast<double>(n), (status_bytes("VmRSS") - rss0) / static_cast<double>(n), f.list().size(), f.images().size(),
      static_cast<double>(f.list().num_entries()) / static_cast<double>(std::max<std::size_t>(1, f.list().size())));
  return 0;
}
