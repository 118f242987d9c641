// The one table of series.csv's columns (otfp_app/series_columns.hpp): the
// docs list exactly its columns, and it gives the header, the rows and
// summary.json's "final".
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "otfp/run_record.hpp"
#include "otfp/run_setup.hpp"
#include "otfp/series_layout.hpp"
#include "otfp_app/config.hpp"
#include "otfp_app/series_columns.hpp"
#include "otfp_app/simulation.hpp"

namespace {

using otfp::ColumnKind;
using otfp::ColumnWhen;
using otfp::SeriesLayout;
using otfp::StepRecord;
using otfp::series_columns;

// The first cells of the `| column | unit | meaning |` table of the
// "## `<file>`" section of docs/outputs.md, backticks removed.
std::vector<std::string> documented_columns(const std::string& file_name) {
  const std::filesystem::path file = std::filesystem::path(OTFP_SOURCE_DIR) / "docs" / "outputs.md";
  std::ifstream in(file);
  EXPECT_TRUE(in) << file;
  std::string line;
  bool section = false, table = false;
  std::vector<std::string> names;
  while (std::getline(in, line)) {
    if (line.rfind("## ", 0) == 0) {
      if (section) break;
      section = line == "## `" + file_name + "`";
      continue;
    }
    if (!section) continue;
    if (!table) {
      table = line.rfind("| column |", 0) == 0;
      continue;
    }
    if (line.rfind("|---", 0) == 0) continue;
    if (line.rfind("| ", 0) != 0) break;  // the end of the table
    const std::string cell = line.substr(2, line.find(" |", 2) - 2);
    EXPECT_TRUE(cell.size() > 2 && cell.front() == '`' && cell.back() == '`') << line;
    names.push_back(cell.substr(1, cell.size() - 2));
  }
  return names;
}

TEST(OutputSchema, DocsListExactlyTheColumnsOfTheTable) {
  std::vector<std::string> table;
  for (const auto& c : series_columns()) table.push_back(c.name);
  EXPECT_EQ(documented_columns("series.csv"), table);
}

// timing.csv from the same kind of table: the docs list its columns, and its
// header and rows are written from it.
TEST(OutputSchema, TimingColumnsAreDocumentedAndWritten) {
  std::vector<std::string> table;
  for (const auto& c : otfp::timing_columns()) table.push_back(c.name);
  EXPECT_EQ(documented_columns("timing.csv"), table);
  const SeriesLayout timing = SeriesLayout::timing();
  std::string joined;
  for (const std::string& n : table) joined += (joined.empty() ? "" : ",") + n;
  EXPECT_EQ(timing.header(), joined + "\n");
  StepRecord r;
  r.step = 7;
  r.t = 0.25;
  r.wall_seconds = 1.5;
  r.step_seconds = 0.125;
  r.solver_seconds = 0.0625;
  r.list_seconds = 0.03125;
  r.reference_values = {0.5, 0.25};  // not timing.csv's: left out
  EXPECT_EQ(timing.row(r), "7,0.25,1.5,0.125,0.0625,0.03125\n");
}

TEST(OutputSchema, EveryColumnHasOneGetterOfItsKindAndAMeaning) {
  std::set<std::string> names;
  for (const auto& c : series_columns()) {
    EXPECT_TRUE(names.insert(c.name).second) << c.name;
    EXPECT_FALSE(std::string(c.meaning).empty()) << c.name;
    EXPECT_EQ(c.integer != nullptr, c.kind == ColumnKind::Integer) << c.name;
    EXPECT_EQ(c.number != nullptr, c.kind == ColumnKind::Number) << c.name;
    EXPECT_EQ(c.optional != nullptr, c.kind == ColumnKind::OptionalNumber) << c.name;
  }
}

TEST(OutputSchema, HeaderRowsAndFinalFollowTheTable) {
  const SeriesLayout plain(false, false, {});
  const SeriesLayout full(true, true, {"reference_mass_ratio", "error_mass_ratio"});
  EXPECT_EQ(plain.header().rfind("step,t,dt,n_particles,", 0), 0u);
  EXPECT_EQ(plain.header().find("polar_inertia_ratio"), std::string::npos);
  EXPECT_EQ(plain.header().find("error_mass_blob"), std::string::npos);
  EXPECT_NE(full.header().find(",mass_ratio,polar_inertia_ratio,mass_blob,mass_blob_ratio,error_mass_blob,"
                               "reference_mass_ratio,error_mass_ratio\n"),
            std::string::npos);

  StepRecord r;
  r.step = 7;
  r.t = 0.5;
  r.n_particles = 12;
  r.polar_inertia_ratio = 0.25;
  r.error_mass_blob = -0.125;
  r.reference_values = {1.5, 2.5};
  const std::string row = full.row(r);
  auto fields = [](const std::string& s) { return std::count(s.begin(), s.end(), ',') + 1; };
  EXPECT_EQ(fields(row), fields(full.header()));
  EXPECT_EQ(row.rfind("7,0.5,0,12,", 0), 0u);
  EXPECT_NE(row.find(",0,0,0.25,0,0,-0.125,1.5,2.5\n"), std::string::npos) << row;
  // A record without the layout's reference values is refused, naming them.
  r.reference_values = {1.5};
  try {
    (void)full.row(r);
    ADD_FAILURE() << "a row with 1 value for 2 reference columns was written";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("1 reference values for the 2 reference columns (reference_mass_ratio"),
              std::string::npos)
        << e.what();
  }
  // No estimate: an empty field.
  r.reference_values.clear();
  EXPECT_NE(plain.row(r).find(",0,0,,0,"), std::string::npos) << plain.row(r);
  r.t = std::numeric_limits<double>::quiet_NaN();
  try {
    (void)plain.row(r);
    ADD_FAILURE() << "a NaN was written";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()).rfind("non-finite t = nan at step 7", 0), 0u) << e.what();
  }

  r.t = 0.5;
  const nlohmann::json f = otfp::app::final_json(r);
  std::size_t in_final = 0;
  for (const auto& c : series_columns()) {
    EXPECT_EQ(f.contains(c.name), c.in_final) << c.name;
    in_final += c.in_final ? 1 : 0;
  }
  EXPECT_EQ(f.size(), in_final);
  EXPECT_EQ(f["step"], 7);
  EXPECT_EQ(f["polar_inertia_ratio"], 0.25);
  r.polar_inertia_ratio.reset();
  EXPECT_TRUE(otfp::app::final_json(r)["polar_inertia_ratio"].is_null());
}

}  // namespace

// series.csv from library calls alone: setup_run, a Simulation stepped on the
// grid t_k = k dt, the Crank reference from the domain's geometry, and a
// RunRecorder whose rows SeriesLayout writes; the command line's rows of the
// same configuration are the same text, row for row.
TEST(RunRecorder, LibraryRowsAreTheCommandLineSeries) {
  const std::string text =
      "[domain]\ntype = \"ball\"\nradius = 1.0\n"
      "[[boundary]]\npatch = \"surface\"\nkind = \"dirichlet\"\nvalue = 0.3\n"
      "[run]\nt_end = 0.25\n"
      "[particles]\nn_inf = 150\n"
      "[diagnostics]\nreference = \"crank_sphere\"\n";
  otfp::app::ConfiguredRun cli(otfp::app::parse_config_string(text));
  otfp::app::RunOptions ro;
  const otfp::app::RunResult theirs = cli.run(ro);
  ASSERT_EQ(theirs.status, "completed") << theirs.error;

  const otfp::DomainPtr ball = otfp::make_ball(3, otfp::Vec3::Zero(), 1.0);
  const std::vector<otfp::ConstantBoundaryData> data = {{0, otfp::PatchKind::Dirichlet, 0.3}};
  otfp::RunSetupOptions o;
  o.n_inf = 150;
  o.t_end = 0.25;
  const otfp::RunSetup setup = otfp::setup_run(*ball, data, o);
  otfp::Simulation sim(ball, data, setup.options);
  otfp::ReferenceSetup rs;
  rs.center = ball->inertia_center();
  rs.M_inf = setup.parameters.M_inf;
  rs.t_end = o.t_end;
  rs.constant_dt = setup.parameters.dt;
  otfp::complete_reference_geometry("crank_sphere", *ball, {0}, rs);
  const std::unique_ptr<otfp::Reference> reference = otfp::make_reference("crank_sphere", rs);
  otfp::RecorderOptions rec;
  rec.center = rs.center;
  rec.M_inf = setup.parameters.M_inf;
  rec.J_inf = setup.parameters.M_inf * ball->mean_square_distance(rs.center);
  otfp::RunRecorder rows(sim, rec, reference.get());
  rows.step_dt = setup.parameters.dt;
  const SeriesLayout layout(true, reference->has_mass_blob_error(), reference->columns());
  sim.start(otfp::ParticleSet(3));
  std::vector<std::string> mine = {layout.row(rows(0, 0.0, nullptr, sim.initial_step().inserted,
                                                   sim.initial_step().removed))};
  ASSERT_EQ(setup.parameters.n_steps, 3);
  ASSERT_EQ(theirs.series.size(), 4u);
  for (std::int64_t k = 1; k <= 3; ++k) {
    const otfp::SimulationStep s = sim.advance_to(static_cast<double>(k) * setup.parameters.dt);
    mine.push_back(layout.row(rows(k, s.t_end, &s.diffusion, s.inserted, s.removed)));
  }
  for (std::size_t i = 0; i < mine.size(); ++i) EXPECT_EQ(mine[i], layout.row(theirs.series[i])) << "row " << i;
}
