// The stepper's memory of displacements by id (otfp/step_history.hpp).
#include "otfp/step_history.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace otfp {

void StepHistory::reset() {
  map_.clear();
  dt1_ = dt2_ = 0.0;
  previous_.clear();
  can_undo_ = false;
}

std::vector<DisplacementHistory> StepHistory::lookup(const std::vector<ParticleId>& ids) const {
  std::vector<DisplacementHistory> out(ids.size());
  for (std::size_t i = 0; i < ids.size(); ++i)
    if (const DisplacementHistory* h = find(ids[i])) out[i] = *h;
  return out;
}

const DisplacementHistory* StepHistory::find(ParticleId id) const {
  const auto it = map_.find(id);
  return it == map_.end() ? nullptr : &it->second;
}

void StepHistory::commit(const std::vector<ParticleId>& ids, const std::vector<DisplacementHistory>& records,
                         double dt1, double dt2) {
  require(ids.size() == records.size(), "history records", static_cast<double>(records.size()),
          "must be one per particle id");
  previous_.swap(map_);
  previous_dt1_ = dt1_;
  previous_dt2_ = dt2_;
  can_undo_ = true;
  map_.clear();
  map_.reserve(ids.size());
  for (std::size_t i = 0; i < ids.size(); ++i) map_.emplace(ids[i], records[i]);
  dt1_ = dt1;
  dt2_ = dt2;
}

void StepHistory::undo_last_update() {
  if (!can_undo_)
    throw std::logic_error("undo_last_history_update: the history's last change was not an accepted step");
  map_.swap(previous_);
  dt1_ = previous_dt1_;
  dt2_ = previous_dt2_;
  previous_.clear();
  can_undo_ = false;
}

HistoryState StepHistory::state() const {
  HistoryState st;
  st.dt1 = dt1_;
  st.dt2 = dt2_;
  st.entries.reserve(map_.size());
  for (const auto& [id, h] : map_) st.entries.push_back({id, h.d1, h.d2, h.ds1, h.ds2, h.count});
  std::sort(st.entries.begin(), st.entries.end(),
            [](const HistoryEntry& a, const HistoryEntry& b) { return a.id < b.id; });
  return st;
}

namespace {
void check_entry(const HistoryEntry& e) {
  require(e.count >= 0 && e.count <= 2, "history count of particle " + std::to_string(e.id), e.count,
          "must be 0, 1 or 2");
  require(e.d1.allFinite() && e.d2.allFinite() && std::isfinite(e.ds1) && std::isfinite(e.ds2),
          "history of particle " + std::to_string(e.id), 0.0, "must be finite");
}
}  // namespace

void StepHistory::restore(const HistoryState& st) {
  require(std::isfinite(st.dt1) && st.dt1 >= 0.0, "history dt1", st.dt1, "must be finite and >= 0");
  require(std::isfinite(st.dt2) && st.dt2 >= 0.0, "history dt2", st.dt2, "must be finite and >= 0");
  std::unordered_map<ParticleId, DisplacementHistory> map;
  map.reserve(st.entries.size());
  for (const HistoryEntry& e : st.entries) {
    check_entry(e);
    require(map.emplace(e.id, DisplacementHistory{e.d1, e.d2, e.ds1, e.ds2, e.count}).second,
            "history of particle " + std::to_string(e.id), static_cast<double>(e.id), "appears twice");
  }
  map_ = std::move(map);
  dt1_ = st.dt1;
  dt2_ = st.dt2;
  previous_.clear();
  can_undo_ = false;
}

std::vector<HistoryEntry> StepHistory::extract(const std::vector<ParticleId>& ids) {
  std::vector<HistoryEntry> out;
  for (ParticleId id : ids) {
    const auto it = map_.find(id);
    if (it == map_.end()) continue;
    const DisplacementHistory& h = it->second;
    out.push_back({id, h.d1, h.d2, h.ds1, h.ds2, h.count});
    map_.erase(it);
  }
  return out;
}

void StepHistory::absorb(const std::vector<HistoryEntry>& entries) {
  for (const HistoryEntry& e : entries) {
    check_entry(e);
    require(map_.emplace(e.id, DisplacementHistory{e.d1, e.d2, e.ds1, e.ds2, e.count}).second,
            "history of particle " + std::to_string(e.id), static_cast<double>(e.id), "is already held");
  }
}

}  // namespace otfp
