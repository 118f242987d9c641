#pragma once
// The one table of series.csv's columns (and timing.csv's; docs/outputs.md
// lists the same, a test checks it): their names, meanings, where a
// StepRecord holds them and how they are written. It drives series.csv's
// header and rows, and the command line's summary.json "final" (runs.csv of
// `otfp sweep` reads "final").
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "otfp/run_record.hpp"

namespace otfp {

// How a column is written: an integer, a finite number, or a finite number
// that may be absent (an empty field; null in "final").
enum class ColumnKind { Integer, Number, OptionalNumber };
// Which runs have the column (the layout is fixed by the configuration).
enum class ColumnWhen {
  Always,
  WithJInf,           // derived.J_inf is defined
  WithMassBlobError,  // the reference compares mass_blob_ratio (crank_*)
};

struct SeriesColumn {
  const char* name;
  const char* meaning;  // one line; docs/outputs.md says more
  ColumnKind kind;
  ColumnWhen when;
  bool in_final;  // also in summary.json "final"
  std::int64_t StepRecord::*integer = nullptr;
  double StepRecord::*number = nullptr;
  std::optional<double> StepRecord::*optional = nullptr;
};

// The fixed columns of series.csv, in order; the reference's columns
// (Reference::columns()) follow them.
const std::vector<SeriesColumn>& series_columns();

// The columns of timing.csv: the wall-clock times, kept out of series.csv so
// that series.csv is the same on every run.
const std::vector<SeriesColumn>& timing_columns();

// The columns of one run's series.csv (or of timing.csv).
class SeriesLayout {
 public:
  SeriesLayout(bool has_j_inf, bool has_mass_blob_error, std::vector<std::string> reference_columns);
  static SeriesLayout timing();  // timing.csv
  // The header line, '\n' included.
  const std::string& header() const { return header_; }
  // The row of r, '\n' included; throws std::runtime_error naming the column
  // and step when a value is not finite (nothing non-finite is written).
  std::string row(const StepRecord& r) const;

 private:
  SeriesLayout() = default;
  std::vector<const SeriesColumn*> columns_;
  std::vector<std::string> reference_columns_;
  std::string header_;
};

}  // namespace otfp
