// The column table of series.csv and timing.csv and their CSV rows.
#include "otfp/series_layout.hpp"

#include <fmt/format.h>

#include <cmath>
#include <stdexcept>

namespace otfp {

namespace {

using R = StepRecord;
constexpr bool kFinal = true, kSeriesOnly = false;

SeriesColumn col(const char* name, const char* meaning, std::int64_t R::*m, bool in_final,
                 ColumnWhen when = ColumnWhen::Always) {
  SeriesColumn c{name, meaning, ColumnKind::Integer, when, in_final};
  c.integer = m;
  return c;
}
SeriesColumn col(const char* name, const char* meaning, double R::*m, bool in_final,
                 ColumnWhen when = ColumnWhen::Always) {
  SeriesColumn c{name, meaning, ColumnKind::Number, when, in_final};
  c.number = m;
  return c;
}
SeriesColumn col(const char* name, const char* meaning, std::optional<double> R::*m, bool in_final,
                 ColumnWhen when = ColumnWhen::Always) {
  SeriesColumn c{name, meaning, ColumnKind::OptionalNumber, when, in_final};
  c.optional = m;
  return c;
}

}  // namespace

const std::vector<SeriesColumn>& series_columns() {
  static const std::vector<SeriesColumn> columns = {
      col("step", "step number k", &R::step, kFinal),
      col("t", "time t_k", &R::t, kFinal),
      col("dt", "step length (0 in row 0)", &R::dt, kSeriesOnly),
      col("n_particles", "all particles", &R::n_particles, kFinal),
      col("mass_total", "mass of all particles", &R::mass_total, kFinal),
      col("mass_inside", "M(t) (43): particles with sd <= 0", &R::mass_inside, kFinal),
      col("polar_inertia", "J_G(t) (44) about diagnostics.center, particles inside", &R::polar_inertia, kFinal),
      col("inserted", "particles inserted in this step", &R::inserted, kSeriesOnly),
      col("removed", "particles removed in this step", &R::removed, kSeriesOnly),
      col("energy", "F at the solution of the diffusive step (28)", &R::energy, kSeriesOnly),
      col("iterations", "minimiser iterations of the step", &R::iterations, kSeriesOnly),
      col("evaluations", "value+gradient evaluations of the step", &R::evaluations, kSeriesOnly),
      col("mass_with_layer", "mass inside Omega or in B^ext", &R::mass_with_layer, kFinal),
      col("polar_inertia_with_layer", "J_G over the same particles", &R::polar_inertia_with_layer, kFinal),
      col("polar_inertia_total", "J_G over all particles", &R::polar_inertia_total, kFinal),
      col("n_inside", "particles inside Omega (region 0)", &R::n_inside, kFinal),
      col("n_buffer", "particles in B^ext (region 1)", &R::n_buffer, kFinal),
      col("n_outside", "other particles (region 2)", &R::n_outside, kFinal),
      col("inserted_total", "inserted since t = 0", &R::inserted_total, kSeriesOnly),
      col("removed_total", "removed since t = 0", &R::removed_total, kSeriesOnly),
      col("transport", "transport part of F", &R::transport, kSeriesOnly),
      col("entropy", "entropy part of F", &R::entropy, kSeriesOnly),
      col("barrier", "barrier part of F", &R::barrier, kSeriesOnly),
      col("residual_displacement", "final stopping measure of the solve", &R::residual_displacement, kSeriesOnly),
      col("list_builds", "neighbour-list builds in the step", &R::list_builds, kSeriesOnly),
      col("halvings", "times the step was retried with halved substeps", &R::halvings, kSeriesOnly),
      col("error_estimate", "local time-error estimate of the step in widths (empty: none)", &R::error_estimate,
          kSeriesOnly),
      col("rejected_steps", "adaptive dt: tries rejected by the error test", &R::rejected_steps, kSeriesOnly),
      col("mean_age", "mean of t - t_birth", &R::mean_age, kFinal),
      col("max_age", "largest t - t_birth", &R::max_age, kFinal),
      col("l1_mass", "(46a) as printed, running", &R::l1_mass, kSeriesOnly),
      col("l1_polar_inertia", "(46b) as printed, running", &R::l1_polar_inertia, kSeriesOnly),
      col("mass_ratio", "mass_inside / M_inf", &R::mass_ratio, kFinal),
      col("polar_inertia_ratio", "polar_inertia / J_inf (only when J_inf is defined)", &R::polar_inertia_ratio,
          kFinal, ColumnWhen::WithJInf),
      col("mass_blob", "M_rho(t): the blob density integrated over Omega", &R::mass_blob, kFinal),
      col("mass_blob_ratio", "mass_blob / M_inf", &R::mass_blob_ratio, kFinal),
      col("error_mass_blob", "mass_blob_ratio - reference_mass_ratio (crank_* references)", &R::error_mass_blob,
          kSeriesOnly, ColumnWhen::WithMassBlobError),
  };
  return columns;
}

const std::vector<SeriesColumn>& timing_columns() {
  static const std::vector<SeriesColumn> columns = {
      col("step", "step number k", &R::step, kSeriesOnly),
      col("t", "time t_k", &R::t, kSeriesOnly),
      col("wall_seconds", "wall time since the run (or the resumed run) started", &R::wall_seconds, kSeriesOnly),
      col("step_seconds", "wall time of the step", &R::step_seconds, kSeriesOnly),
      col("solver_seconds", "time inside the minimiser itself", &R::solver_seconds, kSeriesOnly),
      col("list_seconds", "time building neighbour lists", &R::list_seconds, kSeriesOnly),
  };
  return columns;
}

SeriesLayout SeriesLayout::timing() {
  SeriesLayout layout;
  for (const SeriesColumn& c : timing_columns()) {
    layout.columns_.push_back(&c);
    if (!layout.header_.empty()) layout.header_ += ',';
    layout.header_ += c.name;
  }
  layout.header_ += "\n";
  return layout;
}

SeriesLayout::SeriesLayout(bool has_j_inf, bool has_mass_blob_error, std::vector<std::string> reference_columns)
    : reference_columns_(std::move(reference_columns)) {
  for (const SeriesColumn& c : series_columns()) {
    if ((c.when == ColumnWhen::WithJInf && !has_j_inf) ||
        (c.when == ColumnWhen::WithMassBlobError && !has_mass_blob_error))
      continue;
    columns_.push_back(&c);
    if (!header_.empty()) header_ += ',';
    header_ += c.name;
  }
  for (const std::string& name : reference_columns_) {
    header_ += ',';
    header_ += name;
  }
  header_ += "\n";
}

std::string SeriesLayout::row(const StepRecord& r) const {
  std::string line;
  auto num = [&](double v, const char* name) {
    if (!std::isfinite(v))
      throw std::runtime_error(fmt::format("non-finite {} = {} at step {} (t = {}); nothing non-finite is written",
                                           name, v, r.step, r.t));
    line += fmt::format("{},", v);
  };
  for (const SeriesColumn* c : columns_) {
    switch (c->kind) {
      case ColumnKind::Integer:
        line += fmt::format("{},", r.*(c->integer));
        break;
      case ColumnKind::Number:
        num(r.*(c->number), c->name);
        break;
      case ColumnKind::OptionalNumber:
        if (const std::optional<double>& v = r.*(c->optional))
          num(*v, c->name);
        else
          line += ",";  // absent (error_estimate: the first steps, explicit steppers): empty
        break;
    }
  }
  // The reference's columns (none in timing.csv); a row of a run with a
  // reference holds one value per column.
  if (!reference_columns_.empty() && r.reference_values.size() != reference_columns_.size())
    throw std::invalid_argument(fmt::format("SeriesLayout::row: step {} has {} reference values for the {} reference "
                                            "columns ({} ...): record the rows with the layout's reference",
                                            r.step, r.reference_values.size(), reference_columns_.size(),
                                            reference_columns_.front()));
  for (std::size_t i = 0; i < reference_columns_.size(); ++i) num(r.reference_values.at(i), reference_columns_[i].c_str());
  line.back() = '\n';
  return line;
}

}  // namespace otfp
