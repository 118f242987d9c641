// The checkpoint's driver state, and the checks of a resume: everything is
// read and checked before any file is touched, so that a refused resume
// leaves the run's directory as it was.
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <charconv>
#include <fstream>

#include "run_parts.hpp"

namespace otfp::app::detail {

namespace {

// Checkpoint state of the driver's running sums (doubles round-trip exactly in JSON).
nlohmann::json measures_state(const StateMeasures& m) {
  return {m.n_particles, m.n_inside, m.n_buffer, m.n_outside, m.mass_total, m.mass_inside, m.mass_with_layer,
          m.polar_inertia, m.polar_inertia_with_layer, m.polar_inertia_total, m.mean_age, m.max_age};
}
StateMeasures measures_from_state(const nlohmann::json& j) {
  StateMeasures m;
  m.n_particles = j.at(0).get<std::int64_t>();
  m.n_inside = j.at(1).get<std::int64_t>();
  m.n_buffer = j.at(2).get<std::int64_t>();
  m.n_outside = j.at(3).get<std::int64_t>();
  double* fields[] = {&m.mass_total, &m.mass_inside, &m.mass_with_layer, &m.polar_inertia, &m.polar_inertia_with_layer,
                      &m.polar_inertia_total, &m.mean_age, &m.max_age};
  for (std::size_t i = 0; i < 8; ++i) *fields[i] = j.at(4 + i).get<double>();
  return m;
}
nlohmann::json l1_state(const L1Norms& l) {
  return {l.mass_rectangle, l.polar_inertia_rectangle, l.mass_inside_trapezoid, l.mass_with_layer_trapezoid,
          l.polar_inertia_inside_trapezoid, l.polar_inertia_with_layer_trapezoid};
}
L1Norms l1_from_state(const nlohmann::json& j) {
  L1Norms l;
  double* fields[] = {&l.mass_rectangle, &l.polar_inertia_rectangle, &l.mass_inside_trapezoid,
                      &l.mass_with_layer_trapezoid, &l.polar_inertia_inside_trapezoid,
                      &l.polar_inertia_with_layer_trapezoid};
  for (std::size_t i = 0; i < 6; ++i) *fields[i] = j.at(i).get<double>();
  return l;
}

// The reference's state in a checkpoint's driver state (refused if it is not
// one of this reference: a nlohmann::json exception or InvalidArgument).
void load_reference_state(Reference& reference, const nlohmann::json& state, const std::filesystem::path& checkpoint) {
  try {
    reference.load_state(state.get<ReferenceState>());
  } catch (const InvalidArgument& e) {
    throw ResumeRefused(fmt::format("checkpoint {}: not written by otfp run (its driver state: {})", checkpoint.string(),
                                    e.what()));
  }
}

// The lines of a run's CSV file (series.csv, timing.csv) up to step k, header
// kept, for a resume to continue. Checked first, so that a resume never
// rewrites a file it cannot read: the header must be the one this
// configuration writes, every row must hold as many fields as the header and
// start with the step, one more than the row before (from step 0), and the
// rows must reach step k (rows after it, of a run killed between
// checkpoints, are dropped).
std::string csv_up_to_step(const std::filesystem::path& file, const std::string& header, std::int64_t k) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec))
    throw ResumeRefused(fmt::format("{}: {}", file.string(),
                                    std::filesystem::exists(file, ec) ? "not a regular file" : "missing"));
  std::ifstream f(file, std::ios::binary);
  if (!f) throw ResumeRefused(file.string() + ": cannot read");
  const auto fields = [](const std::string& line) { return std::count(line.begin(), line.end(), ',') + 1; };
  std::string line, text;
  std::int64_t line_no = 0, last_step = -1;
  while (std::getline(f, line)) {
    ++line_no;
    if (line_no == 1) {
      if (line + "\n" != header)
        throw ResumeRefused(fmt::format("{}: line 1 is not the header this configuration writes", file.string()));
      text += line + "\n";
      continue;
    }
    const std::string first = line.substr(0, line.find(','));
    std::int64_t step = -1;
    const auto [end, err] = std::from_chars(first.data(), first.data() + first.size(), step);
    if (err != std::errc() || end != first.data() + first.size() || fields(line) != fields(header) ||
        step != last_step + 1)
      throw ResumeRefused(fmt::format("{}: line {} is not the row of step {} ({} fields expected, starting with the "
                                      "step)",
                                      file.string(), line_no, last_step + 1, fields(header)));
    last_step = step;
    if (step <= k) text += line + "\n";
  }
  if (f.bad()) throw ResumeRefused(file.string() + ": cannot read");
  if (line_no == 0) throw ResumeRefused(file.string() + ": empty (no header)");
  if (last_step < k)
    throw ResumeRefused(fmt::format("{}: its rows end at step {}, before the checkpoint's step {} (rows missing)",
                                    file.string(), last_step, k));
  return text;
}

// The checkpoint's configuration against this one, key by key.
void check_fingerprint(const nlohmann::json& js, const std::map<std::string, std::string>& fingerprint,
                       const std::filesystem::path& out, const std::filesystem::path& checkpoint_file) {
  if (!js.contains("config") || !js["config"].is_object())
    throw ResumeRefused(fmt::format("checkpoint {}: holds no configuration to compare with (written by an "
                                    "older otfp?)",
                                    checkpoint_file.string()));
  std::map<std::string, std::string> theirs;
  try {
    theirs = js["config"].get<std::map<std::string, std::string>>();
  } catch (const nlohmann::json::exception& e) {
    throw ResumeRefused(fmt::format("checkpoint {}: its configuration is unreadable ({})", checkpoint_file.string(),
                                    e.what()));
  }
  if (theirs == fingerprint) return;
  std::vector<std::string> differ;
  auto shown = [](const std::map<std::string, std::string>& m, const std::string& k) {
    const auto it = m.find(k);
    return it == m.end() ? std::string("(absent)") : it->second;
  };
  for (const auto& [k, v] : fingerprint)
    if (shown(theirs, k) != v) differ.push_back(fmt::format("{} = {} (the checkpoint's: {})", k, v, shown(theirs, k)));
  for (const auto& [k, v] : theirs)
    if (!fingerprint.count(k)) differ.push_back(fmt::format("{} = (absent) (the checkpoint's: {})", k, v));
  const std::size_t more = differ.size() > 3 ? differ.size() - 3 : 0;
  differ.resize(std::min<std::size_t>(differ.size(), 3));
  std::string list;
  for (const std::string& x : differ) list += (list.empty() ? "" : "; ") + x;
  if (more > 0) list += fmt::format("; and {} more", more);
  throw ResumeRefused(fmt::format("{} differs from the run that wrote {}: {} (only {} may change on --resume, "
                                  "with --set)",
                                  (out / "config.toml").string(), checkpoint_file.string(), list,
                                  fmt::join(resume_keys(), ", ")));
}

}  // namespace

nlohmann::json driver_state(const RunRecorder& rows, const Reference* reference, const RunFiles& files,
                            const StepRecord& last, const std::map<std::string, std::string>& fingerprint) {
  nlohmann::json js;
  js["l1"] = l1_state(rows.sums.l1);
  js["prev_measures"] = measures_state(rows.sums.prev_measures);
  js["reference"] = reference ? nlohmann::json(reference->save_state()) : nlohmann::json::object();
  js["snapshots"] = files.snapshots;
  js["last_snapshot"] = files.last_snapshot;
  js["n0"] = rows.sums.n0;
  js["M0"] = rows.sums.M0;
  js["last_step"] = last.step;
  js["last_t"] = last.t;
  js["last_mass_ratio"] = last.mass_ratio;
  js["last_n"] = last.n_particles;
  js["config"] = fingerprint;
  return js;
}

ResumeStart read_resume(otfp::Simulation& sim, RunRecorder& rows, Reference* reference, RunFiles& files,
                        const RunControl& control, const Config& c, const std::string& series_header,
                        const std::string& timing_header, const std::map<std::string, std::string>& fingerprint) {
  const std::filesystem::path& out = files.dir();
  const std::filesystem::path checkpoint_file = out / "checkpoint.bin";
  ResumeStart start;
  // The driver's data first: a checkpoint of another configuration is
  // refused naming the key (the library would name its own field).
  nlohmann::json js;
  try {
    js = nlohmann::json::parse(otfp::Simulation::checkpoint_extra(checkpoint_file));
  } catch (const nlohmann::json::exception& e) {
    throw ResumeRefused(fmt::format("checkpoint {}: not written by otfp run (its driver state: {})",
                                    checkpoint_file.string(), e.what()));
  } catch (const std::exception& e) {
    throw ResumeRefused(e.what());
  }
  check_fingerprint(js, fingerprint, out, checkpoint_file);
  try {
    sim.load_checkpoint(checkpoint_file);
  } catch (const std::exception& e) {
    throw ResumeRefused(e.what());
  }
  StepRecord& last = start.last;
  try {
    rows.sums.l1 = l1_from_state(js.at("l1"));
    rows.sums.prev_measures = measures_from_state(js.at("prev_measures"));
    if (reference) load_reference_state(*reference, js.at("reference"), checkpoint_file);
    files.snapshots = js.at("snapshots").get<std::vector<std::pair<double, std::string>>>();
    files.last_snapshot = js.at("last_snapshot").get<std::int64_t>();
    rows.sums.n0 = js.at("n0").get<std::int64_t>();
    rows.sums.M0 = js.at("M0").get<double>();
    last.step = js.at("last_step").get<std::int64_t>();
    last.t = js.at("last_t").get<double>();
    last.mass_ratio = js.at("last_mass_ratio").get<double>();
    last.n_particles = js.at("last_n").get<std::int64_t>();
  } catch (const nlohmann::json::exception& e) {
    throw ResumeRefused(fmt::format("checkpoint {}: not written by otfp run (its driver state: {})",
                                    checkpoint_file.string(), e.what()));
  }
  const std::int64_t k_done = sim.step_count();
  if (!(c.run.t_end >= sim.time()))
    throw ResumeRefused(fmt::format("run.t_end = {}: must be >= the time t = {} of {} (step {})", c.run.t_end,
                                    sim.time(), checkpoint_file.string(), k_done));
  if (!(sim.time_grid().dt > 0.0) && !control.adaptive)
    throw ResumeRefused(fmt::format("checkpoint {}: holds no grid of steps (written by an older otfp?)",
                                    checkpoint_file.string()));
  rows.step_dt = sim.grid_for(control).dt;
  if (sim.finished(control)) {
    start.nothing_to_do = true;
    return start;
  }
  // The rows after the checkpoint (a run killed between checkpoints) are taken again.
  start.series_text = csv_up_to_step(out / "series.csv", series_header, k_done);
  start.timing_text = csv_up_to_step(out / "timing.csv", timing_header, k_done);
  return start;
}

}  // namespace otfp::app::detail
