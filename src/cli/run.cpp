// ConfiguredRun::run(): the library's time loop with the CLI's rows, files,
// checkpoints and summary (the pieces: run_parts.hpp).
#include <omp.h>

#include <fmt/format.h>

#include <cstdio>
#include <exception>
#include <functional>

#include "configured_run_state.hpp"
#include "otfp/series_layout.hpp"
#include "otfp_app/series_columns.hpp"
#include "run_parts.hpp"

namespace otfp::app {

namespace {

// The library's time loop: fixed steps on its grid t_k = k dt (kept in the
// checkpoint: a resumed run keeps its grid when its dt is unchanged, and its
// step when run.t_end moved), or the adaptive controller.
RunControl run_control(const Config& c, const Derived& d, const RunOptions& options, const otfp::Simulation& sim) {
  RunControl control;
  control.t_end = c.run.t_end;
  control.dt = d.dt;
  control.adaptive = c.run.dt_mode == DtMode::Adaptive;
  control.max_steps = c.run.max_steps;
  control.checkpoint_interval = c.run.checkpoint_interval;
  // Over several ranks a signal may reach some of them first: all stop
  // after the step in which any did.
  control.stop = [stop_flag = options.stop_flag, stop_after_step = options.stop_after_step,
                  &sim](const SimulationStep& s) {
    return sim.any_process(stop_flag && *stop_flag) || (stop_after_step > 0 && s.step >= stop_after_step);
  };
  return control;
}

// Each step's row (the row of a stopped run's last step is final: snapshot
// and progress line), and the checkpoints at the run's cadence.
struct Observer : RunObserver {
  std::function<void(const SimulationStep&, bool)> row;
  std::function<void()> checkpoint;
  void on_step(const otfp::Simulation&, const SimulationStep& step, bool last_step) override { row(step, last_step); }
  void on_checkpoint(const otfp::Simulation&) override { checkpoint(); }
};

// summary.json at the end; a failure to write it fails a completed run, or
// is added to the error of one that failed already.
void write_final_summary(detail::RunFiles& files, RunResult& result) {
  if (!files.active()) return;
  try {
    files.write_summary(result.summary);
  } catch (const std::exception& e) {
    if (result.exit_code == 0) {
      result.status = "failed";
      result.error = e.what();
      result.exit_code = 1;
    } else {
      std::error_code ec;
      result.error += std::filesystem::exists(files.dir() / "summary.json", ec)
                          ? fmt::format("; summary.json could not be updated either ({}): it may still say "
                                        "\"running\"",
                                        e.what())
                          : fmt::format("; summary.json could not be written either ({}): there is no summary.json",
                                        e.what());
    }
  }
}

// Over several ranks a file may fail to be written on one rank only: every
// rank learns it after the write and throws (that rank its own error), so
// that none goes on alone into the next step's collectives.
template <class Write>
void on_every_rank(const otfp::Simulation& sim, Write&& write) {
  if (!sim.distributed()) {
    write();
    return;
  }
  std::exception_ptr failed;
  try {
    write();
  } catch (...) {
    failed = std::current_exception();
  }
  if (!sim.any_process(failed != nullptr)) return;
  if (failed && !sim.root_process()) {
    // Only rank 0 reports; the cause is this rank's, so it says it itself.
    try {
      std::rethrow_exception(failed);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "otfp: rank %d: %s\n", sim.process_rank(), e.what());
    }
  }
  if (failed) std::rethrow_exception(failed);
  throw detail::RunError("another rank could not write its files (its error is on stderr)");
}

// A fresh start (Algorithm 1 runs in the library): the initial particles'
// count and mass for the summary, every particle on rank 0 of a distributed
// run (start() hands them out), and the reservoir (if any) filled before the
// first step, counted as step 0's insertions.
void start_fresh(otfp::Simulation& sim, ParticleSet fill, Rng& rng, RunRecorder& rows) {
  rows.set_initial(fill);
  if (!sim.root_process()) {
    const ParticleId next = fill.next_id();
    fill = ParticleSet(fill.dim());
    fill.set_next_id(next);
  }
  sim.start(std::move(fill), rng, 0.0);
}

}  // namespace

RunResult ConfiguredRun::run(const RunOptions& options) {
  using namespace detail;
  const Config& c = config_;
  const Derived& d = derived_;
  otfp::Simulation& sim = *state_->sim;
  if (c.run.threads > 0) omp_set_num_threads(c.run.threads);
  const WallClock wall;
  RunResult result;
  Rng rng(static_cast<std::uint64_t>(c.run.seed));
  // The analytic reference: its columns, rows, error statistics and state (docs/outputs.md).
  const std::unique_ptr<Reference> reference = configured_reference(c, d);
  // Column layout of series.csv (fixed by the configuration, not by the run).
  const SeriesLayout layout(d.J_inf.has_value(), reference && reference->has_mass_blob_error(),
                            reference ? reference->columns() : std::vector<std::string>{});
  const SeriesLayout timing = SeriesLayout::timing();
  RecorderOptions ro;
  ro.center = d.center;
  ro.M_inf = d.M_inf;
  ro.J_inf = d.J_inf;
  RunRecorder rows(sim, ro, reference.get(), [&wall] { return wall(); });
  rows.step_dt = d.dt;
  ProgressLine progress(c, d, sim, wall, options.progress && sim.root_process());
  RunFiles files(*this, sim, options.out_dir, options.stop_flag != nullptr,
                 [&](const std::string& status, const std::string& error, const StepRecord& last) {
                   return run_summary(*this, sim, reference.get(), rows.sums, wall(), status, error, last);
                 });
  StepRecord last;
  try {
    auto emit = [&](const StepRecord& r, bool final_row) {
      const bool snapshot = r.step == 0 || final_row || (c.run.vtk_interval > 0 && r.step % c.run.vtk_interval == 0);
      on_every_rank(sim, [&] { files.append(layout.row(r), timing.row(r), r, snapshot, rows.region()); });
      if (options.keep_series) result.series.push_back(r);
      last = r;
      result.rows = true;
      progress.show(r, final_row);
      files.rearm_kill_summary(r);
    };
    const RunControl control = run_control(c, d, options, sim);
    // The configuration the checkpoints are written with (a resume must match it).
    const auto fingerprint = files.active() ? config_fingerprint(c) : std::map<std::string, std::string>{};
    if (!options.resume) {
      ParticleSet fill = initial_particles(rng);
      on_every_rank(sim, [&] { files.create(layout.header(), timing.header()); });
      start_fresh(sim, std::move(fill), rng, rows);
      emit(rows(0, 0.0, nullptr, sim.initial_step().inserted, sim.initial_step().removed), false);
    } else {
      ResumeStart start;
      try {
        start = read_resume(sim, rows, reference.get(), files, control, c, layout.header(), timing.header(),
                            fingerprint);
      } catch (const ResumeRefused& e) {
        result.status = "refused";
        result.error = e.what();
        result.exit_code = kExitRefused;
        return result;
      }
      last = start.last;
      if (start.nothing_to_do) {
        result.status = "completed";
        result.nothing_to_do = true;
        result.last = last;
        return result;
      }
      result.rows = true;  // the rows up to the checkpoint
      on_every_rank(sim, [&] { files.reopen(start.series_text, start.timing_text, last); });
    }
    Observer observer;
    observer.row = [&](const SimulationStep& step, bool last_step) {
      rows.step_dt = control.adaptive ? step.dt() : sim.time_grid().dt;
      rows.step_rejections = step.error_rejections;
      emit(rows(step.step, step.t_end, &step.diffusion, static_cast<long>(step.inserted),
                static_cast<long>(step.removed)),
           last_step);
    };
    observer.checkpoint = [&]() {
      if (files.active()) files.write_checkpoint(driver_state(rows, reference.get(), files, last, fingerprint));
    };
    if (sim.run(control, &observer) == RunEnd::Stopped) {
      result.status = "interrupted";
      result.error = fmt::format("interrupted after step {} (t = {}); continue with: otfp run --resume {}", last.step,
                                 last.t, options.out_dir.string());
      result.exit_code = kExitInterrupted;
    } else {
      on_every_rank(sim, [&] { files.write_final_particles(rows.region()); });
      result.status = "completed";
      result.exit_code = 0;
    }
  } catch (const std::exception& e) {
    result.status = "failed";
    result.error = e.what();
    result.exit_code = 1;
    if (progress.on()) std::fputc('\n', stderr);
    // The state the failing step started from (the library puts it back), for inspection.
    files.write_failed_particles(d, last.t);
  }
  result.last = last;
  result.summary = run_summary(*this, sim, reference.get(), rows.sums, wall(), result.status, result.error, last);
  write_final_summary(files, result);
  return result;
}

}  // namespace otfp::app
