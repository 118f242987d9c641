#pragma once
// summary.json "final" from the library's column table (otfp/series_layout.hpp).
#include <nlohmann/json.hpp>

#include "otfp/series_layout.hpp"

namespace otfp::app {

// summary.json "final": the in_final columns of r (absent optionals null).
nlohmann::json final_json(const StepRecord& r);

}  // namespace otfp::app
