#pragma once
// The implicit stepper's memory of each particle's last two diffusive
// displacements, by id, with the last two step sizes: what the predictor,
// variational BDF2 and the local error estimate extrapolate from
// (docs/stepper.md). The serial ImplicitStepper keeps one for all particles;
// a distributed step keeps one per rank for the particles it owns, and the
// entries travel with their particles between ranks.
#include <cstddef>
#include <unordered_map>
#include <vector>

#include "otfp/particles.hpp"
#include "otfp/types.hpp"

namespace otfp {

// One particle's record.
struct DisplacementHistory {
  Vec3 d1 = Vec3::Zero(), d2 = Vec3::Zero();  // x^k - x^{k-1}, x^{k-1} - x^{k-2} (diffusive part)
  double ds1 = 0.0, ds2 = 0.0;                // the same for widths
  int count = 0;                              // how many of d1, d2 are known (0, 1, 2)
};

// The history as data (checkpoints, migration between ranks).
struct HistoryEntry {
  ParticleId id = 0;
  Vec3 d1 = Vec3::Zero(), d2 = Vec3::Zero();
  double ds1 = 0.0, ds2 = 0.0;
  int count = 0;
};
struct HistoryState {
  std::vector<HistoryEntry> entries;  // sorted by id
  double dt1 = 0.0, dt2 = 0.0;        // the last two step sizes (0: none)
};

class StepHistory {
 public:
  void reset();
  std::size_t size() const { return map_.size(); }
  double dt1() const { return dt1_; }
  double dt2() const { return dt2_; }

  // The records of these particles, in their order (zero records for ids
  // with none: particles inserted since the last step).
  std::vector<DisplacementHistory> lookup(const std::vector<ParticleId>& ids) const;
  const DisplacementHistory* find(ParticleId id) const;

  // An accepted step: the records of exactly these particles (every other
  // id is forgotten) and the step sizes after it. The old history is moved
  // aside, not dropped, so that undo_last_update() can put it back in O(1).
  void commit(const std::vector<ParticleId>& ids, const std::vector<DisplacementHistory>& records, double dt1,
              double dt2);
  // Throws std::logic_error unless the last change was a commit().
  void undo_last_update();

  HistoryState state() const;              // entries sorted by id
  void restore(const HistoryState& state);  // throws InvalidArgument for a bad entry

  // Migration: removes and returns the entries of `ids` that have one;
  // absorb() adds entries (an id already held is refused: InvalidArgument).
  // Neither touches the step sizes or the undo record's ability.
  std::vector<HistoryEntry> extract(const std::vector<ParticleId>& ids);
  void absorb(const std::vector<HistoryEntry>& entries);

 private:
  std::unordered_map<ParticleId, DisplacementHistory> map_;
  double dt1_ = 0.0, dt2_ = 0.0;
  std::unordered_map<ParticleId, DisplacementHistory> previous_;
  double previous_dt1_ = 0.0, previous_dt2_ = 0.0;
  bool can_undo_ = false;
};

}  // namespace otfp
