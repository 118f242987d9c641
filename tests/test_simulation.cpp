// otfp::Simulation: Algorithm 1 as a library object (ledger, failed steps,
// observers, checkpoints).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include "otfp/images.hpp"
#include "otfp/parameters.hpp"
#include "otfp/simulation.hpp"

using namespace otfp;

namespace {

// A disc of radius 1 held at g on its boundary, the papers' rules (36)-(40)
// for n_inf particles; the reservoir band or the papers' layer.
struct Disc {
  int dim = 2;
  std::size_t n_inf = 150;
  DomainPtr domain = make_ball(2, Vec3::Zero(), 1.0);
  PaperParameters pp;
  SimulationOptions options;
  Disc(bool reservoir, TimeScheme scheme = TimeScheme::Euler) {
    pp = paper_parameters(domain->volume(), n_inf, dim, 1.0, 1.0, 2.0);
    options.particle_mass = 1.0 / static_cast<double>(n_inf);
    options.width_s = pp.width_s;
    options.barrier_stiffness = pp.barrier_C;
    options.projection.layer_b = pp.layer_b;
    options.implicit.time_scheme = scheme;
    options.implicit.rho_ref = 1.0;
    if (reservoir) {
      options.projection.dirichlet_mode = DirichletMode::Reservoir;
      options.projection.reservoir_thickness = cutoff_radius(pp.width_s, 1e-8);
      options.projection.reservoir_sublayers = 2;
    }
  }
  std::unique_ptr<Simulation> make() const {
    return std::make_unique<Simulation>(domain, std::vector<ConstantBoundaryData>{{0, PatchKind::Dirichlet, 1.0 / domain->volume()}},
                                        options);
  }
  ParticleSet cloud(std::size_t n, std::uint64_t seed) const {
    Rng rng(seed);
    ParticleSet ps(dim);
    for (std::size_t i = 0; i < n; ++i) ps.add(0.6 * domain->sample_interior(rng), pp.width_s, options.particle_mass);
    return ps;
  }
};

bool same_state(const ParticleSet& a, const ParticleSet& b) {
  return a.positions() == b.positions() && a.widths() == b.widths() && a.masses() == b.masses() &&
         a.ids() == b.ids() && a.birth_times() == b.birth_times() && a.next_id() == b.next_id();
}

std::filesystem::path temp_file(const std::string& name) {
  return std::filesystem::temp_directory_path() / ("otfp_test_simulation_" + std::to_string(::getpid()) + "_" + name);
}

}  // namespace

// n(t) = n(0) + inserted - removed and the same for the mass, step by step,
// from the per-step counts the library reports (the library checks it too;
// here it is recounted from outside).
TEST(Simulation, LedgerBalancesEveryStep) {
  Disc disc(true);
  auto sim = disc.make();
  sim->start(disc.cloud(40, 3));
  std::int64_t n = 40 + sim->initial_step().inserted - sim->initial_step().removed;
  EXPECT_GT(sim->initial_step().inserted, 0) << "the reservoir band is filled before the first step";
  EXPECT_EQ(static_cast<std::int64_t>(sim->particles().size()), n);
  for (int k = 1; k <= 4; ++k) {
    const SimulationStep s = sim->advance(disc.pp.dt_explicit);
    n += s.inserted - s.removed;
    EXPECT_EQ(s.step, k);
    EXPECT_EQ(s.brief_report().rfind("step " + std::to_string(k) + ": t = ", 0), 0u) << s.brief_report();
    EXPECT_EQ(s.brief_report().find('\n'), std::string::npos);
    EXPECT_EQ(s.diffusion.inserted, s.inserted) << "StepSummary carries the step's counts";
    EXPECT_EQ(s.diffusion.removed, s.removed);
    EXPECT_EQ(static_cast<std::int64_t>(sim->particles().size()), n);
  }
  const SimulationLedger& l = sim->ledger();
  EXPECT_NEAR(sim->particles().total_mass(), l.initial_mass + l.mass_inserted - l.mass_removed, 1e-12);
  // The reports say what the ledger says.
  const std::string report = sim->full_report();
  EXPECT_NE(report.find("inserted " + std::to_string(l.inserted)), std::string::npos) << report;
  EXPECT_NE(report.find("after 4 steps"), std::string::npos) << report;
  EXPECT_DOUBLE_EQ(sim->time(), 4 * disc.pp.dt_explicit);
}

// run_until: equal steps ending on t_end exactly, every step observed.
TEST(Simulation, RunUntilShowsEveryStepAndEndsOnTheTime) {
  Disc disc(false);
  auto sim = disc.make();
  sim->start(disc.cloud(30, 5));
  std::vector<double> ends;
  const double t_end = 2.5 * disc.pp.dt_explicit;
  sim->run_until(t_end, disc.pp.dt_explicit, [&](const Simulation& s, const SimulationStep& step) {
    EXPECT_EQ(s.time(), step.t_end);
    ends.push_back(step.t_end);
  });
  ASSERT_EQ(ends.size(), 3u) << "ceil(2.5) steps";
  EXPECT_EQ(ends.back(), t_end);
  EXPECT_NEAR(ends[0], t_end / 3.0, 1e-15);
}

// run(): the time loop. Fixed steps on the grid t_k = k dt (the last on t_end
// exactly), observed in order, with checkpoints at the cadence and at the end.
namespace {
struct Recorder : RunObserver {
  std::vector<std::pair<std::int64_t, double>> steps;  // (k, t_k)
  std::vector<bool> last;
  std::vector<std::int64_t> checkpoints;                // step_count() at each on_checkpoint
  void on_step(const Simulation& sim, const SimulationStep& step, bool is_last) override {
    EXPECT_EQ(sim.time(), step.t_end);
    steps.emplace_back(step.step, step.t_end);
    last.push_back(is_last);
  }
  void on_checkpoint(const Simulation& sim) override { checkpoints.push_back(sim.step_count()); }
};
}  // namespace

TEST(Simulation, RunStepsOnItsGridAndCheckpointsAtTheCadence) {
  Disc disc(true);
  auto sim = disc.make();
  sim->start(disc.cloud(30, 5));
  RunControl c;
  c.t_end = 0.07;
  c.dt = 0.01;
  c.checkpoint_interval = 3;
  Recorder r;
  EXPECT_FALSE(sim->finished(c));
  EXPECT_EQ(sim->run(c, &r), RunEnd::Completed);
  ASSERT_EQ(r.steps.size(), 7u);
  for (std::size_t i = 0; i < 7; ++i) {
    EXPECT_EQ(r.steps[i].first, static_cast<std::int64_t>(i + 1));
    // 0 + k h with h = t_end / n, the last on t_end itself.
    EXPECT_EQ(r.steps[i].second, i == 6 ? 0.07 : static_cast<double>(i + 1) * (0.07 / 7.0)) << i;
    EXPECT_EQ(r.last[i], i == 6);
  }
  EXPECT_EQ(r.checkpoints, (std::vector<std::int64_t>{3, 6, 7}));
  EXPECT_EQ(sim->time_grid().dt, 0.07 / 7.0);
  EXPECT_EQ(sim->time_grid().k_end, 7);
  EXPECT_TRUE(sim->finished(c));
  Recorder none;
  EXPECT_EQ(sim->run(c, &none), RunEnd::Completed);  // nothing left: no step, no checkpoint
  EXPECT_TRUE(none.steps.empty() && none.checkpoints.empty());
  // A later end on the same step extends the grid: t_k = k h still.
  c.t_end = 0.1;
  EXPECT_EQ(sim->grid_for(c).k_end, 10);
  sim->run(c, &none);
  EXPECT_EQ(none.steps.front().second, 8.0 * (0.07 / 7.0));
  EXPECT_EQ(sim->time(), 0.1);
}

// A run stopped after a step and continued from its checkpoint by another
// Simulation is the run taken in one go, to the bit (the grid travels in the
// checkpoint); max_steps ends a run early and says so.
TEST(Simulation, RunStoppedAndResumedIsTheRunInOneGo) {
  Disc disc(true);
  RunControl c;
  c.t_end = 0.05;
  c.dt = 0.007;  // not a divisor: the grid's step is 0.05 / 8
  auto whole = disc.make();
  whole->start(disc.cloud(30, 9));
  Recorder all;
  EXPECT_EQ(whole->run(c, &all), RunEnd::Completed);
  ASSERT_EQ(all.steps.size(), 8u);

  auto first = disc.make();
  first->start(disc.cloud(30, 9));
  RunControl part = c;
  part.stop = [](const SimulationStep& s) { return s.step == 3; };
  Recorder head;
  EXPECT_EQ(first->run(part, &head), RunEnd::Stopped);
  EXPECT_EQ(head.last, (std::vector<bool>{false, false, true}));  // the stop makes step 3 the last
  EXPECT_EQ(head.checkpoints, (std::vector<std::int64_t>{3}));    // and checkpoints it
  const auto file = temp_file("run_resume.bin");
  first->save_checkpoint(file);
  auto second = disc.make();
  second->load_checkpoint(file);
  std::filesystem::remove(file);
  EXPECT_EQ(second->time_grid().dt, first->time_grid().dt);
  RunControl capped = c;
  capped.max_steps = 6;
  Recorder mid, tail;
  EXPECT_EQ(second->run(capped, &mid), RunEnd::MaxSteps);
  EXPECT_EQ(mid.steps.back().first, 6);
  EXPECT_TRUE(second->finished(capped));
  EXPECT_EQ(second->run(c, &tail), RunEnd::Completed);
  EXPECT_EQ(tail.steps.size(), 2u);
  EXPECT_EQ(second->time(), 0.05);
  EXPECT_TRUE(same_state(second->particles(), whole->particles()));
  for (std::size_t i = 0; i < 3; ++i) EXPECT_EQ(head.steps[i], all.steps[i]);
  for (std::size_t i = 0; i < 3; ++i) EXPECT_EQ(mid.steps[i], all.steps[i + 3]);
  for (std::size_t i = 0; i < 2; ++i) EXPECT_EQ(tail.steps[i], all.steps[i + 6]);
}

// A continued run asked for another end keeps its step (not the new dt):
// equal steps of about the grid's step from where it stands.
TEST(Simulation, RunToAnotherEndKeepsItsStep) {
  Disc disc(false);
  auto sim = disc.make();
  sim->start(disc.cloud(20, 4));
  RunControl c;
  c.t_end = 0.04;
  c.dt = 0.01;
  sim->run(c);
  RunControl later = c;
  later.t_end = 0.065;
  later.dt = 0.02;  // another dt: the grid keeps its own 0.01
  const TimeGrid g = sim->grid_for(later);
  EXPECT_EQ(g.t_origin, 0.04);
  EXPECT_EQ(g.k_origin, 4);
  EXPECT_EQ(g.k_end, 7);  // ceil(0.025 / 0.01) = 3 steps
  EXPECT_EQ(g.dt, (0.065 - 0.04) / 3.0);
  Recorder r;
  sim->run(later, &r);
  ASSERT_EQ(r.steps.size(), 3u);
  EXPECT_EQ(r.steps[0].second, 0.04 + g.dt);
  EXPECT_EQ(r.steps[2].second, 0.065);
  // Bad controls are refused naming the field.
  RunControl bad = c;
  bad.dt = 0.0;
  try {
    sim->run(bad);
    ADD_FAILURE() << "no error";
  } catch (const InvalidArgument& e) {
    EXPECT_EQ(std::string(e.what()).rfind("dt = 0: must be finite and > 0", 0), 0u) << e.what();
  }
}

// A failed diffusive step throws and leaves the state the step started from,
// even after advection and the source have run.
TEST(Simulation, FailedStepKeepsTheState) {
  Disc disc(false);
  disc.options.velocity = Vec3(0.3, 0.0, 0.0);
  disc.options.source_rate = 2.0;
  disc.options.implicit.max_halvings = 0;
  auto sim = disc.make();
  sim->start(disc.cloud(30, 7));
  sim->advance(disc.pp.dt_explicit);
  const ParticleSet before = sim->particles();
  const SimulationLedger ledger = sim->ledger();
  sim->implicit_stepper()->set_external_potential([](const Vec3&, Vec3* g) {
    if (g) g->setZero();
    return std::nan("");
  });
  EXPECT_THROW(sim->advance(disc.pp.dt_explicit), StepFailure);
  EXPECT_TRUE(same_state(sim->particles(), before));
  EXPECT_EQ(sim->ledger().source_inserted, ledger.source_inserted);
  EXPECT_EQ(sim->step_count(), 1);
}

// A checkpoint taken after k steps and loaded into a fresh Simulation
// continues bit for bit: particles, ledger, projection carries, the stepper's
// BDF2 history, the adaptive step and the random numbers (source, reservoir).
TEST(Simulation, CheckpointContinuesBitForBit) {
  for (bool adaptive : {false, true}) {
    Disc disc(true, adaptive ? TimeScheme::Bdf2 : TimeScheme::Euler);
    disc.options.source_rate = 0.5;
    disc.options.velocity = Vec3(0.05, 0.0, 0.0);
    disc.options.time_control.dt_min = 0.01 * disc.pp.dt_explicit;
    const double dt = disc.pp.dt_explicit;
    auto step = [&](Simulation& s) { return adaptive ? s.advance_adaptive(1e9) : s.advance(dt); };
    auto a = disc.make();
    a->start(disc.cloud(50, 11));
    if (adaptive) a->set_next_dt(dt);
    for (int k = 0; k < 3; ++k) step(*a);
    const auto file = temp_file("ckpt");
    a->save_checkpoint(file, "caller's data");
    for (int k = 0; k < 3; ++k) step(*a);

    auto b = disc.make();
    std::string extra;
    b->load_checkpoint(file, &extra);
    EXPECT_EQ(extra, "caller's data");
    EXPECT_EQ(b->step_count(), 3);
    for (int k = 0; k < 3; ++k) step(*b);
    EXPECT_TRUE(same_state(a->particles(), b->particles())) << (adaptive ? "adaptive BDF2" : "fixed Euler");
    EXPECT_EQ(a->time(), b->time());
    EXPECT_EQ(a->ledger().inserted, b->ledger().inserted);
    EXPECT_EQ(a->ledger().source_inserted, b->ledger().source_inserted);
    EXPECT_EQ(a->totals().evaluations, b->totals().evaluations);
    EXPECT_EQ(a->projection().reservoir_carry(0, 0), b->projection().reservoir_carry(0, 0));
    EXPECT_EQ(a->next_dt(), b->next_dt());
    std::filesystem::remove(file);
  }
}

// A damaged or foreign checkpoint is refused with one line and changes nothing.
TEST(Simulation, BadCheckpointIsRefusedAndStateKept) {
  Disc disc(false);
  auto a = disc.make();
  a->start(disc.cloud(20, 13));
  a->advance(disc.pp.dt_explicit);
  const auto file = temp_file("bad");
  a->save_checkpoint(file);
  std::string bytes;
  {
    std::ifstream f(file, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(f), {});
  }
  auto b = disc.make();
  b->start(disc.cloud(10, 17));
  const ParticleSet before = b->particles();
  auto expect_refused = [&](const std::string& content, const std::string& why) {
    {
      std::ofstream f(file, std::ios::binary | std::ios::trunc);
      f << content;
    }
    try {
      b->load_checkpoint(file);
      ADD_FAILURE() << "accepted: " << why;
    } catch (const InvalidArgument& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find("checkpoint"), std::string::npos) << msg;
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
    }
    EXPECT_TRUE(same_state(b->particles(), before)) << why;
    EXPECT_EQ(b->step_count(), 0) << why;
  };
  std::string flipped = bytes;
  flipped[bytes.size() / 2] ^= 0x10;
  expect_refused(flipped, "one flipped bit");
  expect_refused(bytes.substr(0, bytes.size() - 9), "truncated");
  expect_refused("not a checkpoint at all", "foreign file");
  // The same file into a simulation of another stepper.
  Disc other(false);
  other.options.stepper = StepperKind::Explicit;
  auto c = other.make();
  {
    std::ofstream f(file, std::ios::binary | std::ios::trunc);
    f << bytes;
  }
  EXPECT_THROW(c->load_checkpoint(file), InvalidArgument);
  std::filesystem::remove(file);
}

// Setup errors say which part failed.
TEST(Simulation, SetupErrorsNameTheirStage) {
  SimulationOptions o;
  o.particle_mass = 0.01;
  o.width_s = 0.2;  // neighbour-list radius ~1.4: a periodic box of side 1 cannot hold two
  try {
    Simulation sim(make_periodic_box(2, Vec3::Zero(), Vec3(1.0, 1.0, 0.0)), {}, o);
    ADD_FAILURE() << "accepted a periodic box smaller than two list radii";
  } catch (const SimulationSetupError& e) {
    EXPECT_EQ(e.stage(), SimulationSetupError::Stage::Periodic);
  }
  o.width_s = 0.0;
  EXPECT_THROW(Simulation(make_ball(2, Vec3::Zero(), 1.0), {}, o), InvalidArgument);
  o.width_s = 0.05;
  EXPECT_THROW(Simulation(make_ball(2, Vec3::Zero(), 1.0), {{3, PatchKind::Dirichlet, 1.0}}, o), InvalidArgument);
  Simulation ok(make_ball(2, Vec3::Zero(), 1.0), {}, o);
  EXPECT_THROW(ok.advance(0.1), std::logic_error) << "no start()";
}

TEST(Simulation, ReservoirOptionsValidateWithoutTheBandDomain) {
  // The Simulation builds the reservoir band itself, so its options must not
  // ask the caller for one; a lone ProjectionOptions still does by default.
  otfp::SimulationOptions o;
  o.particle_mass = 0.01;
  o.width_s = 0.1;
  o.barrier_stiffness = 10.0;
  o.projection.dirichlet_mode = otfp::DirichletMode::Reservoir;
  o.projection.reservoir_thickness = 0.3;
  EXPECT_NO_THROW(o.validate());
  EXPECT_THROW(o.projection.validate(), otfp::InvalidArgument);
  o.projection.reservoir_thickness = -1.0;
  EXPECT_THROW(o.validate(), otfp::InvalidArgument);
}

namespace {
// A disc whose Dirichlet data (papers' layer) is g; data that ask for more
// particles than allowed must fail the step, not exhaust memory.
std::unique_ptr<Simulation> disc_with_data(const Disc& disc, PatchKind kind, double value) {
  return std::make_unique<Simulation>(disc.domain, std::vector<ConstantBoundaryData>{{0, kind, value}}, disc.options);
}

// The step fails as a StepFailure naming the patch, and the state (particles,
// history, carries, ledger, random numbers) is the one it started from: the
// next step with sane limits equals the step of a run that never failed.
void expect_limit_failure_keeps_state(Simulation& sim, double dt, const std::string& needle) {
  const ParticleSet before = sim.particles();
  const SimulationLedger ledger = sim.ledger();
  const std::int64_t steps = sim.step_count();
  try {
    sim.advance(dt);
    ADD_FAILURE() << "the step did not fail";
  } catch (const StepFailure& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
  EXPECT_TRUE(same_state(sim.particles(), before));
  EXPECT_EQ(sim.ledger().inserted, ledger.inserted);
  EXPECT_EQ(sim.step_count(), steps);
}
}  // namespace

TEST(Simulation, HugeDirichletDataFailTheStepNotTheMachine) {
  Disc disc(false);
  auto sim = disc_with_data(disc, PatchKind::Dirichlet, 1e300);  // 1e300 / m_p particles: no integer holds it
  sim->start(disc.cloud(20, 3));
  expect_limit_failure_keeps_state(*sim, disc.pp.dt_explicit, "dirichlet patch 0");
}

TEST(Simulation, NeumannCarryPast2To53FailsInsteadOfLooping) {
  // An inflow of 1e18 |A| dt / m_p > 2^53 particles: carry - m_p == carry, so
  // the old insertion loop never ended.
  Disc disc(false);
  disc.options.max_particles = kMaxParticleCount;
  auto sim = disc_with_data(disc, PatchKind::Neumann, -1e18);
  sim->start(disc.cloud(20, 3));
  expect_limit_failure_keeps_state(*sim, disc.pp.dt_explicit, "limit of 9007199254740992 particles");  // 2^53
}

TEST(Simulation, MaxParticlesStopsARunawayAndKeepsTheLastState) {
  Disc disc(true);
  disc.options.max_particles = 400;
  auto sim = disc_with_data(disc, PatchKind::Dirichlet, 1.0 / disc.domain->volume());
  sim->start(disc.cloud(20, 3));
  sim->advance(disc.pp.dt_explicit);  // the normal data fit
  ASSERT_LT(sim->particles().size(), 400u);
  // Raising g tenfold asks for more than 400 particles in the band.
  auto big = disc_with_data(disc, PatchKind::Dirichlet, 10.0 / disc.domain->volume());
  EXPECT_THROW(big->start(disc.cloud(20, 3)), ResourceLimitExceeded);  // the band fill at t = 0
  // The source: growth exp(s dt) - 1 copies per particle.
  Disc src(false);
  src.options.max_particles = 100;
  src.options.source_rate = 1e3;
  auto s = disc_with_data(src, PatchKind::Dirichlet, 1.0 / src.domain->volume());
  s->start(src.cloud(20, 3));
  expect_limit_failure_keeps_state(*s, src.pp.dt_explicit, "the source");
  // The initial particles themselves.
  src.options.source_rate = 0.0;
  src.options.max_particles = 10;
  auto few = disc_with_data(src, PatchKind::Dirichlet, 1.0);
  EXPECT_THROW(few->start(src.cloud(20, 3)), InvalidArgument);
  src.options.max_particles = -1;
  EXPECT_THROW(src.options.validate(), InvalidArgument);
}

TEST(Simulation, FailedProjectionRestoresHistoryAndCarries) {
  // Run A: two steps. Run B: the same, but with a limit that fails step 2 at
  // first; after raising the limit the retried step 2 must equal A's.
  Disc disc(false, TimeScheme::Bdf2);
  auto a = disc_with_data(disc, PatchKind::Dirichlet, 1.0 / disc.domain->volume());
  a->start(disc.cloud(40, 9));
  a->advance(disc.pp.dt_explicit);
  a->advance(disc.pp.dt_explicit);
  auto b = disc_with_data(disc, PatchKind::Dirichlet, 1.0 / disc.domain->volume());
  b->start(disc.cloud(40, 9));
  b->advance(disc.pp.dt_explicit);
  const auto saved = temp_file("limit.ckpt");
  b->save_checkpoint(saved);
  // The same state in a Simulation with a limit at the current count: step 2 fails.
  Disc tight = disc;
  tight.options.max_particles = static_cast<std::int64_t>(b->particles().size());
  auto c = disc_with_data(tight, PatchKind::Dirichlet, 1.0 / disc.domain->volume());
  c->load_checkpoint(saved);
  EXPECT_THROW(c->advance(disc.pp.dt_explicit), StepFailure);
  c->save_checkpoint(saved);  // what the failed step left: must be b's state
  b->load_checkpoint(saved);
  b->advance(disc.pp.dt_explicit);
  EXPECT_TRUE(same_state(b->particles(), a->particles()));
  std::filesystem::remove(saved);
}

namespace {

// Everything a step may change that a caller can read: a failed step must
// leave all of it as it was, bit for bit.
struct Observed {
  ParticleSet particles;
  SimulationLedger ledger;
  SimulationTotals totals;
  BoundaryProjection::State projection;
  ImplicitStepper::HistoryState history;
  double time = 0.0, next_dt = 0.0;
  std::int64_t steps = 0;
};

Observed observe(Simulation& sim) {
  Observed o{sim.particles(), sim.ledger(), sim.totals(), sim.projection().state(), {}, sim.time(), sim.next_dt(),
             sim.step_count()};
  if (sim.implicit_stepper()) o.history = sim.implicit_stepper()->history_state();
  return o;
}

// Plain structs of 8-byte fields (no padding): compared bytewise.
template <class T>
bool same_bytes(const T& a, const T& b) {
  return std::memcmp(&a, &b, sizeof(T)) == 0;
}

bool same_history(const ImplicitStepper::HistoryState& a, const ImplicitStepper::HistoryState& b) {
  if (a.dt1 != b.dt1 || a.dt2 != b.dt2 || a.entries.size() != b.entries.size()) return false;
  for (std::size_t i = 0; i < a.entries.size(); ++i) {
    const auto &x = a.entries[i], &y = b.entries[i];
    if (x.id != y.id || x.d1 != y.d1 || x.d2 != y.d2 || x.ds1 != y.ds1 || x.ds2 != y.ds2 || x.count != y.count)
      return false;
  }
  return true;
}

void expect_unchanged(const Observed& a, const Observed& b) {
  EXPECT_TRUE(same_state(a.particles, b.particles));
  EXPECT_TRUE(same_bytes(a.ledger, b.ledger));
  EXPECT_TRUE(same_bytes(a.totals, b.totals)) << "totals: iterations " << a.totals.iterations << " -> "
                                              << b.totals.iterations << ", tries rejected "
                                              << a.totals.error_rejected_steps << " -> " << b.totals.error_rejected_steps;
  ASSERT_EQ(a.projection.ledger.size(), b.projection.ledger.size());
  for (std::size_t i = 0; i < a.projection.ledger.size(); ++i)
    EXPECT_TRUE(same_bytes(a.projection.ledger[i], b.projection.ledger[i])) << "condition " << i;
  EXPECT_EQ(a.projection.reservoir_carry, b.projection.reservoir_carry);
  EXPECT_TRUE(same_history(a.history, b.history)) << "history: " << a.history.entries.size() << " -> "
                                                  << b.history.entries.size() << " entries";
  EXPECT_EQ(a.time, b.time);
  EXPECT_EQ(a.next_dt, b.next_dt);
  EXPECT_EQ(a.steps, b.steps);
}

}  // namespace

// The paths by which a step can fail, for each kind of step: the state
// after the failure is the one before it (particles, ledger, totals,
// projection, the implicit stepper's history, time, step, next dt), and
// after it the run continues bit for bit as one that never failed.
// Advection is on, so that every try changes the state before its solve.
//  - the diffusive step fails (explicit: a non-finite potential);
//  - the projection fails after an accepted diffusive step (explicit,
//    implicit BDF2, adaptive BDF2: the history must be put back);
//  - an adaptive step runs out of tries (BDF2).
TEST(Simulation, FailedExplicitStepKeepsTheStateAndContinuesBitForBit) {
  Disc disc(false);
  disc.options.stepper = StepperKind::Explicit;
  disc.options.velocity = Vec3(0.3, 0.0, 0.0);
  disc.options.source_rate = 2.0;
  const double dt = 0.5 * disc.pp.dt_explicit;
  auto a = disc.make();
  auto b = disc.make();
  a->start(disc.cloud(30, 7));
  b->start(disc.cloud(30, 7));
  a->advance(dt);
  b->advance(dt);
  const Observed before = observe(*b);
  b->explicit_stepper()->set_external_potential([](const Vec3&, Vec3* g) {
    if (g) g->setZero();
    return std::nan("");
  });
  EXPECT_THROW(b->advance(dt), StepFailure);
  expect_unchanged(before, observe(*b));
  b->explicit_stepper()->set_external_potential({});
  a->advance(dt);
  b->advance(dt);
  EXPECT_TRUE(same_state(a->particles(), b->particles()));
  EXPECT_TRUE(same_bytes(a->ledger(), b->ledger()));
}

TEST(Simulation, FailedProjectionKeepsTheStateOfEveryStepper) {
  struct Kind {
    std::string name;
    StepperKind stepper;
    bool adaptive;
  };
  for (const Kind& kind : {Kind{"explicit", StepperKind::Explicit, false}, Kind{"implicit BDF2", StepperKind::Implicit, false},
                           Kind{"adaptive BDF2", StepperKind::Implicit, true}}) {
    SCOPED_TRACE(kind.name);
    Disc disc(false, TimeScheme::Bdf2);
    disc.options.stepper = kind.stepper;
    disc.options.velocity = Vec3(0.05, 0.0, 0.0);
    disc.options.time_control.dt_min = 0.01 * disc.pp.dt_explicit;
    const double dt = 0.5 * disc.pp.dt_explicit;
    const double g = 1.0 / disc.domain->volume();
    auto step = [&](Simulation& s) { return kind.adaptive ? s.advance_adaptive(1e9) : s.advance(dt); };
    // Run a: three steps. Run b: two; then, in a Simulation with a limit at
    // b's particle count, the third step fails in the projection (after an
    // accepted diffusive step); then b takes it from what the failure left.
    auto a = disc_with_data(disc, PatchKind::Dirichlet, g);
    auto b = disc_with_data(disc, PatchKind::Dirichlet, g);
    for (Simulation* s : {a.get(), b.get()}) {
      s->start(disc.cloud(40, 9));
      s->set_next_dt(dt);
      step(*s);
      step(*s);
    }
    const auto saved = temp_file("projection_" + std::to_string(static_cast<int>(kind.adaptive)) + ".ckpt");
    b->save_checkpoint(saved);
    Disc tight = disc;
    tight.options.max_particles = static_cast<std::int64_t>(b->particles().size());
    auto c = disc_with_data(tight, PatchKind::Dirichlet, g);
    c->load_checkpoint(saved);
    const Observed before = observe(*c);
    if (kind.stepper == StepperKind::Implicit) {
      ASSERT_GT(before.history.entries.size(), 0u);
    }
    try {
      step(*c);
      ADD_FAILURE() << "the step did not fail";
    } catch (const StepFailure& e) {
      EXPECT_NE(std::string(e.what()).find("dirichlet patch 0"), std::string::npos) << e.what();
    }
    expect_unchanged(before, observe(*c));
    c->save_checkpoint(saved);
    b->load_checkpoint(saved);
    step(*a);
    step(*b);
    EXPECT_TRUE(same_state(a->particles(), b->particles()));
    if (kind.stepper == StepperKind::Implicit) {
      EXPECT_TRUE(same_history(a->implicit_stepper()->history_state(), b->implicit_stepper()->history_state()));
    }
    EXPECT_EQ(a->next_dt(), b->next_dt());
    std::filesystem::remove(saved);
  }
}

TEST(Simulation, AdaptiveStepOutOfTriesKeepsTheState) {
  Disc disc(false, TimeScheme::Bdf2);
  disc.options.velocity = Vec3(0.05, 0.0, 0.0);
  disc.options.time_control.dt_min = 1e-6 * disc.pp.dt_explicit;
  const double dt = 0.5 * disc.pp.dt_explicit;
  const double g = 1.0 / disc.domain->volume();
  auto a = disc_with_data(disc, PatchKind::Dirichlet, g);
  auto b = disc_with_data(disc, PatchKind::Dirichlet, g);
  for (Simulation* s : {a.get(), b.get()}) {
    s->start(disc.cloud(40, 9));
    s->set_next_dt(dt);
    s->advance_adaptive(1e9);
    s->advance_adaptive(1e9);
  }
  const auto saved = temp_file("tries.ckpt");
  b->save_checkpoint(saved);
  // A controller no try can satisfy, and two retries allowed.
  Disc strict = disc;
  strict.options.time_control.tolerance = 1e-300;
  strict.options.max_error_rejections = 2;
  auto c = disc_with_data(strict, PatchKind::Dirichlet, g);
  c->load_checkpoint(saved);
  const Observed before = observe(*c);
  try {
    c->advance_adaptive(1e9);
    ADD_FAILURE() << "the step did not fail";
  } catch (const StepFailure& e) {
    EXPECT_NE(std::string(e.what()).find("3 tries rejected"), std::string::npos) << e.what();
  }
  expect_unchanged(before, observe(*c));
  c->save_checkpoint(saved);
  b->load_checkpoint(saved);
  a->advance_adaptive(1e9);
  b->advance_adaptive(1e9);
  EXPECT_TRUE(same_state(a->particles(), b->particles()));
  EXPECT_TRUE(same_history(a->implicit_stepper()->history_state(), b->implicit_stepper()->history_state()));
  std::filesystem::remove(saved);
}

// A try rejected by the error test is undone (advection, the source's
// particles and random numbers, its ledger counts) before the next: the
// accepted try equals the same step tried first, bit for bit.
TEST(Simulation, AdaptiveRetryStartsFromTheStepsState) {
  Disc disc(false, TimeScheme::Bdf2);
  disc.options.velocity = Vec3(0.05, 0.0, 0.0);
  disc.options.source_rate = 0.5;
  disc.options.time_control.dt_min = 1e-3 * disc.pp.dt_explicit;
  const double dt = 0.5 * disc.pp.dt_explicit;
  const double g = 1.0 / disc.domain->volume();
  auto a = disc_with_data(disc, PatchKind::Dirichlet, g);
  a->start(disc.cloud(40, 9));
  a->set_next_dt(dt);
  a->advance_adaptive(1e9);
  a->advance_adaptive(1e9);
  const auto saved = temp_file("retry.ckpt");
  a->save_checkpoint(saved);
  a->set_next_dt(50.0 * dt);
  const SimulationStep sa = a->advance_adaptive(1e9);
  ASSERT_GT(sa.error_rejections, 0);
  auto b = disc_with_data(disc, PatchKind::Dirichlet, g);
  b->load_checkpoint(saved);
  b->set_next_dt(sa.t_end - sa.t_start);
  const SimulationStep sb = b->advance_adaptive(1e9);
  EXPECT_EQ(sb.error_rejections, 0);
  EXPECT_EQ(sb.t_end, sa.t_end);
  EXPECT_TRUE(same_state(a->particles(), b->particles()));
  EXPECT_TRUE(same_bytes(a->ledger(), b->ledger()));
  // The random numbers too: the next steps (source and projection) agree.
  a->advance_adaptive(1e9);
  b->advance_adaptive(1e9);
  EXPECT_TRUE(same_state(a->particles(), b->particles()));
  std::filesystem::remove(saved);
}

// A particle set of another dimension is refused by start() with one line
// naming both dimensions (the domain is 2-d here).
TEST(Simulation, StartRefusesParticlesOfAnotherDimension) {
  Disc disc(false);
  auto sim = disc.make();
  ParticleSet ps3(3);
  ps3.add(Vec3(0.1, 0.1, 0.1), disc.pp.width_s, disc.options.particle_mass);
  try {
    sim->start(ps3);
    FAIL() << "a 3-d particle set was started in a 2-d domain";
  } catch (const InvalidArgument& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("dim = 3"), std::string::npos) << msg;
    EXPECT_NE(msg.find("dim 2"), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
  }
}
