#pragma once
// ConfiguredRun's library objects (simulation.cpp builds them, run.cpp steps).
#include <memory>
#include <optional>
#include <vector>

#include "domain_setup.hpp"
#include "otfp/simulation.hpp"
#include "otfp_app/simulation.hpp"

namespace otfp::app {

// Everything that changes while running.
struct ConfiguredRun::State {
  detail::BuiltDomain built;
  std::unique_ptr<otfp::Simulation> sim;  // Algorithm 1
  std::vector<ConstantBoundaryData> data;  // what sim was built from (make_simulation())
  SimulationOptions options;
  std::optional<ParticleSet> file_particles;  // particles.fill = "file": read (and checked) once
};

}  // namespace otfp::app
