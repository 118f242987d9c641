// summary.json "final" from the library's column table.
#include "otfp_app/series_columns.hpp"

namespace otfp::app {

nlohmann::json final_json(const StepRecord& r) {
  nlohmann::json j = nlohmann::json::object();
  for (const SeriesColumn& c : series_columns()) {
    if (!c.in_final) continue;
    switch (c.kind) {
      case ColumnKind::Integer:
        j[c.name] = r.*(c.integer);
        break;
      case ColumnKind::Number:
        j[c.name] = r.*(c.number);
        break;
      case ColumnKind::OptionalNumber: {
        const std::optional<double>& v = r.*(c.optional);
        j[c.name] = v ? nlohmann::json(*v) : nlohmann::json(nullptr);
        break;
      }
    }
  }
  return j;
}

}  // namespace otfp::app
