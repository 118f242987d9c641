#pragma once
// The particle and mass ledger of a run: every particle inserted or deleted
// is counted, and n(t) = n(0) + inserted - removed (and the same for the
// mass) is checked after every step (otfp::Simulation). The per-patch
// ledger of the projection is PatchLedger (boundary.hpp).
#include <cstdint>

namespace otfp {

struct SimulationLedger {
  std::int64_t initial_particles = 0;
  double initial_mass = 0.0;
  std::int64_t inserted = 0, removed = 0;  // all causes
  double mass_inserted = 0.0, mass_removed = 0.0;
  std::int64_t source_inserted = 0, source_removed = 0;
  double source_mass_inserted = 0.0, source_mass_removed = 0.0;
  std::int64_t reflected = 0;  // particles put back across mirrored walls (moved, not removed)
  // n(0) + inserted - removed and M(0) + mass inserted - mass removed.
  std::int64_t expected_particles() const { return initial_particles + inserted - removed; }
  double expected_mass() const { return initial_mass + mass_inserted - mass_removed; }
};

}  // namespace otfp
