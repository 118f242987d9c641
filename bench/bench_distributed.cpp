// The functional and an implicit step over MPI ranks (otfp::mpi;
// docs/distributed.md, "Figures"). Run under mpiexec, one thread per rank:
//
//   OMP_NUM_THREADS=1 mpiexec -n 2 build/bench/otfp_bench_distributed [n] [dim] [dt_factor] [slabs|bisection]
//                                                                      [lbfgs_memory]
//
// Every rank draws the same cloud (n particles uniform in the unit ball,
// widths of the papers' rule at beta dr^2 = 2), keeps its slab (equal counts
// along x) or its leaf of the recursive bisection, and times: 20 evaluations of F and its gradient at fixed
// positions (the ghosts built once), then one implicit Euler step with TAO at
// dt_factor x dt_explicit. Rank 0 prints the slowest rank's times and every
// rank's ghosts, bytes sent and memory: the peak resident size during the
// evaluations and the step above the resident size once its particles are
// drawn (the whole cloud freed), per particle it owns.
#include <mpi.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "otfp/decomposition.hpp"
#include "process_memory.hpp"
#include "otfp/distributed_functional.hpp"
#include "otfp/distributed_stepper.hpp"
#include "otfp/geometry.hpp"
#include "otfp/mpi.hpp"
#include "otfp/parameters.hpp"

namespace {

double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

double slowest(double v) {
  MPI_Allreduce(MPI_IN_PLACE, &v, 1, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
  return v;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace otfp;
  const std::size_t n = argc > 1 ? std::stoul(argv[1]) : 100000;
  const int dim = argc > 2 ? std::stoi(argv[2]) : 3;
  const double dt_factor = argc > 3 ? std::stod(argv[3]) : 1.0;
  const bool bisection = argc > 4 && std::string(argv[4]) == "bisection";
  const int lbfgs_memory = argc > 5 ? std::stoi(argv[5]) : MinimizerOptions{}.lbfgs_memory;  // TAO LMVM's history
  const int rank = world_rank(), size = world_size();

  DomainPtr ball = make_ball(dim, Vec3::Zero(), 1.0);
  const double volume = ball->volume();
  const PaperParameters pp = paper_parameters_from_spacing(std::pow(volume / static_cast<double>(n), 1.0 / dim), 1.0, 1.0);
  const double s = pp.width_s;  // beta dr^2 = 2
  Rng rng(2026);
  std::vector<Vec3> x_all(n);
  for (auto& y : x_all) y = ball->sample_interior(rng);
  std::vector<int> owner = partition_slabs(x_all, 0, size);
  if (bisection) {
    std::vector<Vec3> share;  // any split of the cloud will do for the collective
    for (std::size_t p = static_cast<std::size_t>(rank); p < n; p += static_cast<std::size_t>(size))
      share.push_back(x_all[p]);
    const BisectionLayout tree = balanced_bisection(share, dim);
    for (std::size_t p = 0; p < n; ++p) owner[p] = tree.owner(x_all[p]);
  }
  ParticleSet mine(dim);
  for (std::size_t p = 0; p < n; ++p)
    if (owner[p] == rank) mine.add(x_all[p], s, 1.0 / static_cast<double>(n));
  std::vector<Vec3>().swap(x_all);
  std::vector<int>().swap(owner);
  const double resident_before = bench::status_bytes("VmRSS");

  FunctionalOptions fo;
  fo.dt = dt_factor * pp.dt_explicit;
  fo.rho_ref = 1.0 / volume;
  double per_eval = 0.0, exchange = 0.0, bytes = 0.0;
  ExchangeStats first;
  {  // the functional alone (freed before the step, whose memory is measured)
    DistributedFunctional f(dim, fo, Barrier(ball, pp.barrier_C));
    f.set_reference(mine.positions(), mine.widths(), mine.masses());
    Gradient g;
    f.evaluate(mine.positions(), mine.widths(), &g);  // ghosts and list
    first = f.exchange();
    MPI_Barrier(MPI_COMM_WORLD);
    const int evaluations = 20;
    const double t0 = now();
    for (int k = 0; k < evaluations; ++k) f.evaluate(mine.positions(), mine.widths(), &g);
    per_eval = slowest((now() - t0) / evaluations);
    const ExchangeStats& st = f.exchange();
    exchange = slowest((st.seconds - first.seconds) / evaluations);
    bytes = (st.bytes_sent - first.bytes_sent) / evaluations;
  }

  ImplicitOptions io;
  io.minimizer.backend = Backend::Tao;
  io.minimizer.lbfgs_memory = lbfgs_memory;
  io.rho_ref = fo.rho_ref;
  DistributedImplicitStepper stepper(dim, io, Barrier(ball, pp.barrier_C));
  MPI_Barrier(MPI_COMM_WORLD);
  const double t1 = now();
  const StepSummary step = stepper.step(mine, fo.dt);
  const double step_seconds = slowest(now() - t1);

  for (int r = 0; r < size; ++r) {
    MPI_Barrier(MPI_COMM_WORLD);
    if (r == rank)
      std::printf("rank %d: %zu owned, %zu ghosts (%.1f%%), %.3g MB sent per evaluation; peak memory %.0f B per "
                  "owned particle above the particles' (resident after the step %.0f B; the step's neighbour list %.0f B)\n",
                  rank, mine.size(), first.ghosts,
                  100.0 * static_cast<double>(first.ghosts) / static_cast<double>(mine.size()), bytes / 1e6,
                  (bench::status_bytes("VmHWM") - resident_before) / static_cast<double>(mine.size()),
                  (bench::status_bytes("VmRSS") - resident_before) / static_cast<double>(mine.size()),
                  static_cast<double>(stepper.functional().list().indices().capacity() * sizeof(std::uint32_t) +
                                      stepper.functional().list().offsets().capacity() * sizeof(std::uint32_t)) /
                      static_cast<double>(mine.size()));
    std::fflush(stdout);
  }
  MPI_Barrier(MPI_COMM_WORLD);
  if (rank == 0)
    std::printf("%s: n = %zu, %d-D, %d rank(s): F and gradient %.1f ms per evaluation (exchange and sums %.2f ms); "
                "one step at %.3g x dt_explicit (L-BFGS memory %d): %s, %d evaluations, %.3f s\n",
                bisection ? "bisection" : "slabs", n, dim, size, 1e3 * per_eval, 1e3 * exchange, dt_factor, lbfgs_memory,
                step.accepted ? "accepted" : "rejected", step.evaluations, step_seconds);
  return step.accepted ? 0 : 1;
}
