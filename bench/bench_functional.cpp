// Exact rho plus gradient of (28) in 3D: particles uniform in a box,
// beta = 2/dr^2, n = 1e4, 1e5, 1e6, on 1 and 2 threads. Reports pair
// evaluations per second, the neighbour-list build time and memory per particle.
// The "Tailed" variants give the blobs the spread of widths that optimised
// widths reach in the sphere (study 2: median 1.7 s0, 15% at 2-6 s0).
// The "Images" variant mirrors the blobs across the six walls of the unit box
// (docs/boundaries.md); its time includes choosing the images at each list
// build only in the list-build benchmark.
//   ./otfp_bench_functional --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>
#include <omp.h>

#include <cmath>
#include <map>
#include <tuple>
#include <memory>

#include "otfp/functional.hpp"
#include "otfp/geometry.hpp"
#include "otfp/images.hpp"

using namespace otfp;

namespace {

struct Setup {
  ParticleSet ps{3};
  std::vector<Vec3> x;
  std::vector<double> s;
  std::unique_ptr<Functional> f;
};

// One cached set-up per n and width distribution (building the 1e6 cloud is not what we time).
Setup& setup(std::size_t n, bool tailed = false, bool images = false) {
  static std::map<std::tuple<std::size_t, bool, bool>, std::unique_ptr<Setup>> cache;
  auto& slot = cache[{n, tailed, images}];
  if (!slot) {
    slot = std::make_unique<Setup>();
    const double side = 1.0;
    const double dr = side / std::cbrt(static_cast<double>(n));
    const double s = dr / std::sqrt(2.0);  // beta = 2/dr^2
    Rng rng(2024);
    slot->ps.reserve(n);
    Rng width_rng(77);
    for (std::size_t i = 0; i < n; ++i) {
      double si = s;
      if (tailed) si *= width_rng.uniform() < 0.85 ? width_rng.uniform(1.4, 2.0) : width_rng.uniform(2.0, 6.0);
      slot->ps.add(Vec3(rng.uniform(0, side), rng.uniform(0, side), rng.uniform(0, side)), si, 1.0 / n);
    }
    slot->ps.sort_spatially(4.0 * s);  // what the steppers do at each step
    FunctionalOptions o;
    o.dt = dr * dr;
    o.rho_ref = 1.0;
    slot->f = std::make_unique<Functional>(3, o);
    slot->x = slot->ps.positions();
    slot->s = slot->ps.widths();
    slot->f->set_reference(slot->x, slot->s, slot->ps.masses());
    if (images) slot->f->set_images(WallImages(mirror_walls(*make_box(3, Vec3::Zero(), Vec3::Ones()))));
    slot->f->rebuild_list(slot->x, slot->s);
  }
  return *slot;
}

void run_value_and_gradient(benchmark::State& state, bool tailed, bool images = false) {
  const auto n = static_cast<std::size_t>(state.range(0));
  omp_set_num_threads(static_cast<int>(state.range(1)));
  Setup& su = setup(n, tailed, images);
  Gradient g;
  const std::uint64_t pairs0 = su.f->entropy().pair_evaluations();
  for (auto _ : state) {
    auto parts = su.f->evaluate(su.x, su.s, &g);
    benchmark::DoNotOptimize(parts);
  }
  const double pairs = static_cast<double>(su.f->entropy().pair_evaluations() - pairs0);
  state.counters["pair_evals_per_s"] = benchmark::Counter(pairs, benchmark::Counter::kIsRate);
  state.counters["neighbours"] = static_cast<double>(su.f->list().num_entries()) / static_cast<double>(n);
  // Resident bytes per particle: list, particle arrays, reference copy, gradient and term scratch.
  const double per_particle_arrays = sizeof(Vec3) * 6 + sizeof(double) * 12 + sizeof(ParticleId);
  state.counters["bytes_per_particle"] =
      static_cast<double>(su.f->list().memory_bytes()) / static_cast<double>(n) + per_particle_arrays;
  state.counters["threads"] = static_cast<double>(state.range(1));
  state.counters["images_per_particle"] = static_cast<double>(su.f->images().size()) / static_cast<double>(n);
}

void run_list_build(benchmark::State& state, bool tailed) {
  const auto n = static_cast<std::size_t>(state.range(0));
  omp_set_num_threads(static_cast<int>(state.range(1)));
  Setup& su = setup(n, tailed);
  NeighborList list(su.f->options().neighbor);
  for (auto _ : state) {
    list.build(su.x, su.s, Periodicity::none(3));
    benchmark::DoNotOptimize(list.indices().data());
  }
  state.counters["neighbours"] = static_cast<double>(list.num_entries()) / static_cast<double>(n);
  state.counters["threads"] = static_cast<double>(state.range(1));
}

void BM_FunctionalValueAndGradient(benchmark::State& state) { run_value_and_gradient(state, false); }
void BM_FunctionalValueAndGradientTailed(benchmark::State& state) { run_value_and_gradient(state, true); }
void BM_FunctionalValueAndGradientImages(benchmark::State& state) { run_value_and_gradient(state, false, true); }
void BM_NeighborListBuild(benchmark::State& state) { run_list_build(state, false); }
// Image selection plus the list over particles and images.
void BM_NeighborListBuildImages(benchmark::State& state) {
  const auto n = static_cast<std::size_t>(state.range(0));
  omp_set_num_threads(static_cast<int>(state.range(1)));
  Setup& su = setup(n, false, true);
  for (auto _ : state) {
    su.f->rebuild_list(su.x, su.s);
    benchmark::DoNotOptimize(su.f->list().indices().data());
  }
  state.counters["images_per_particle"] = static_cast<double>(su.f->images().size()) / static_cast<double>(n);
}
void BM_NeighborListBuildTailed(benchmark::State& state) { run_list_build(state, true); }

}  // namespace

BENCHMARK(BM_FunctionalValueAndGradient)
    ->ArgsProduct({{10000, 100000, 1000000}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_NeighborListBuild)
    ->ArgsProduct({{10000, 100000, 1000000}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_FunctionalValueAndGradientImages)
    ->ArgsProduct({{10000, 100000}, {1}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_NeighborListBuildImages)
    ->ArgsProduct({{10000, 100000}, {1}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_FunctionalValueAndGradientTailed)
    ->ArgsProduct({{10000, 100000}, {1}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_NeighborListBuildTailed)
    ->ArgsProduct({{10000, 100000}, {1}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_MAIN();
