// A Simulation over the ranks of the MPI world (otfp/mpi_distribution.hpp).
#include "otfp/mpi_distribution.hpp"

#include <mpi.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <limits>
#include <mutex>
#include <numeric>

#include "otfp/mpi.hpp"
#include "otfp/types.hpp"
#include "particle_exchange.hpp"
#include "petsc_session.hpp"

namespace otfp {

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// The particles `which` of every rank's `part`, on every rank, in id order.
ParticleSet gather_union(const ParticleSet& part, const std::vector<std::size_t>& which, MPI_Comm comm) {
  constexpr int kDoubles = detail::ParticleRecords::kDoubles;
  int size = 1;
  MPI_Comm_size(comm, &size);
  detail::ParticleRecords mine;
  for (std::size_t p : which) mine.append(part, p);
  const int n_mine = static_cast<int>(which.size());
  std::vector<int> counts(static_cast<std::size_t>(size)), offsets(static_cast<std::size_t>(size), 0);
  MPI_Allgather(&n_mine, 1, MPI_INT, counts.data(), 1, MPI_INT, comm);
  for (std::size_t r = 1; r < counts.size(); ++r) offsets[r] = offsets[r - 1] + counts[r - 1];
  detail::ParticleRecords all;
  all.ids.resize(static_cast<std::size_t>(offsets.back() + counts.back()));
  MPI_Allgatherv(mine.ids.data(), n_mine, MPI_INT64_T, all.ids.data(), counts.data(), offsets.data(), MPI_INT64_T,
                 comm);
  for (std::size_t r = 0; r < counts.size(); ++r) {
    counts[r] *= kDoubles;
    offsets[r] *= kDoubles;
  }
  all.values.resize(all.ids.size() * kDoubles);
  MPI_Allgatherv(mine.values.data(), n_mine * kDoubles, MPI_DOUBLE, all.values.data(), counts.data(), offsets.data(),
                 MPI_DOUBLE, comm);
  std::vector<std::size_t> order(all.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return all.ids[a] < all.ids[b]; });
  ParticleSet out(part.dim());
  out.reserve(all.size());
  for (std::size_t k : order) all.add_to(out, k);  // refuses an id held by two ranks
  return out;
}

}  // namespace

void MpiDistributionOptions::validate() const {
  require(std::isfinite(rebalance_tolerance) && rebalance_tolerance >= 0.0, "rebalance_tolerance",
          rebalance_tolerance, "must be finite and >= 0");
}

MpiDistribution::MpiDistribution(MpiDistributionOptions options) : options_(options) {
  options_.validate();
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  detail::world_comm();
}

MpiDistribution::~MpiDistribution() = default;

int MpiDistribution::rank() const { return world_rank(); }
int MpiDistribution::size() const { return world_size(); }

void MpiDistribution::configure(int dim, const ImplicitOptions& options, const Barrier& barrier,
                                const Periodicity& periodicity, const std::vector<MirrorWallPtr>& walls) {
  dim_ = dim;
  explicit_stepper_.reset();
  stepper_ = std::make_unique<DistributedImplicitStepper>(dim, options, barrier, periodicity);
  if (!walls.empty()) stepper_->functional().set_images(WallImages(walls));
}

void MpiDistribution::configure_explicit(int dim, const ExplicitOptions& options, const Barrier& barrier,
                                         const Periodicity& periodicity, const std::vector<MirrorWallPtr>& walls) {
  dim_ = dim;
  stepper_.reset();
  explicit_stepper_ = std::make_unique<DistributedExplicitStepper>(dim, options, barrier, periodicity);
  if (!walls.empty()) explicit_stepper_->functional().set_images(WallImages(walls));
}

StepSummary MpiDistribution::diffuse(ParticleSet& owned, double dt, double max_error) {
  if (explicit_stepper_) return explicit_stepper_->step(owned, dt);
  return stepper().step(owned, dt, max_error);
}

DistributedImplicitStepper& MpiDistribution::stepper() const {
  require(stepper_ != nullptr, "MpiDistribution", 0.0, "configure() must come first (the Simulation calls it)");
  return *stepper_;
}

// An explicit run keeps no history: its state is empty.
void MpiDistribution::reset_history() {
  if (!explicit_stepper_) stepper().history().reset();
}
void MpiDistribution::undo_last_history_update() {
  if (!explicit_stepper_) stepper().history().undo_last_update();
}
HistoryState MpiDistribution::local_history() const {
  return explicit_stepper_ ? HistoryState{} : stepper().history().state();
}
void MpiDistribution::restore_history(const HistoryState& state) {
  if (!explicit_stepper_) {
    stepper().history().restore(state);
    return;
  }
  require(state.entries.empty(), "history", static_cast<double>(state.entries.size()),
          "an explicit run keeps none: must be empty");
}

namespace {
constexpr int kHistoryDoubles = 9;  // d1, d2, ds1, ds2, count

void append_entry(detail::Rows& rows, const HistoryEntry& e) {
  rows.ids.push_back(e.id);
  rows.values.insert(rows.values.end(), {e.d1[0], e.d1[1], e.d1[2], e.d2[0], e.d2[1], e.d2[2], e.ds1, e.ds2,
                                         static_cast<double>(e.count)});
}

HistoryEntry entry_of(const detail::Rows& rows, std::size_t i) {
  const double* v = &rows.values[i * kHistoryDoubles];
  HistoryEntry e;
  e.id = rows.ids[i];
  e.d1 = Vec3(v[0], v[1], v[2]);
  e.d2 = Vec3(v[3], v[4], v[5]);
  e.ds1 = v[6];
  e.ds2 = v[7];
  e.count = static_cast<int>(v[8]);
  return e;
}
}  // namespace

HistoryState MpiDistribution::gathered_history() {
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  const MPI_Comm comm = detail::world_comm();
  const HistoryState mine = local_history();
  // Every rank's entries to every rank: an all-to-all of the same rows.
  detail::Rows rows;
  for (const HistoryEntry& e : mine.entries) append_entry(rows, e);
  const std::vector<detail::Rows> to(static_cast<std::size_t>(size()), rows);
  const detail::Rows in = detail::exchange_rows(to, kHistoryDoubles, comm);
  HistoryState all;
  all.dt1 = mine.dt1;
  all.dt2 = mine.dt2;
  for (std::size_t i = 0; i < in.ids.size(); ++i) all.entries.push_back(entry_of(in, i));
  std::sort(all.entries.begin(), all.entries.end(),
            [](const HistoryEntry& a, const HistoryEntry& b) { return a.id < b.id; });
  return all;
}

const ExchangeStats& MpiDistribution::exchange() const {
  static const ExchangeStats none;
  if (explicit_stepper_) return explicit_stepper_->functional().exchange();
  return stepper_ ? stepper_->exchange() : none;
}

ParticleSet MpiDistribution::gather(const ParticleSet& owned) { return all_particles(owned); }
bool MpiDistribution::root() const { return rank() == 0; }

ParticleSet MpiDistribution::nearby(const ParticleSet& owned, double radius, const Periodicity& periodicity) {
  require(std::isfinite(radius) && radius >= 0.0, "radius", radius, "must be finite and >= 0");
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  const MPI_Comm comm = detail::world_comm();
  const std::vector<double> boxes = detail::all_boxes(owned.positions(), comm);
  const int me = rank(), ranks = size();
  std::vector<std::vector<std::size_t>> to(static_cast<std::size_t>(ranks));
  for (int r = 0; r < ranks; ++r) {
    const double* b = &boxes[6 * static_cast<std::size_t>(r)];
    if (r == me || b[0] > b[3]) continue;
    const Vec3 lo(b[0], b[1], b[2]), hi(b[3], b[4], b[5]);
    for (std::size_t p = 0; p < owned.size(); ++p)
      if (detail::distance_to_box(owned.positions()[p], lo, hi, periodicity, owned.dim()) <= radius)
        to[static_cast<std::size_t>(r)].push_back(p);
  }
  const detail::ParticleRecords in = detail::exchange_particles(owned, to, comm);
  ParticleSet out(owned.dim());
  out.reserve(in.size());
  for (std::size_t i = 0; i < in.size(); ++i) in.add_to(out, i);
  return out;
}

double MpiDistribution::max(double v) {
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  double out = 0.0;
  MPI_Allreduce(&v, &out, 1, MPI_DOUBLE, MPI_MAX, detail::world_comm());
  return out;
}

double MpiDistribution::sum(double v) {
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  double out = 0.0;
  MPI_Allreduce(&v, &out, 1, MPI_DOUBLE, MPI_SUM, detail::world_comm());
  return out;
}

void MpiDistribution::sum(double* v, int n) {
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  MPI_Allreduce(MPI_IN_PLACE, v, n, MPI_DOUBLE, MPI_SUM, detail::world_comm());
}

std::int64_t MpiDistribution::sum(std::int64_t v) {
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  std::int64_t out = 0;
  MPI_Allreduce(&v, &out, 1, MPI_INT64_T, MPI_SUM, detail::world_comm());
  return out;
}

std::vector<std::int64_t> MpiDistribution::all_gather(const std::vector<std::int64_t>& mine) {
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  const MPI_Comm comm = detail::world_comm();
  const int n = static_cast<int>(mine.size());
  std::vector<int> counts(static_cast<std::size_t>(size())), offsets(counts.size(), 0);
  MPI_Allgather(&n, 1, MPI_INT, counts.data(), 1, MPI_INT, comm);
  for (std::size_t r = 1; r < counts.size(); ++r) offsets[r] = offsets[r - 1] + counts[r - 1];
  std::vector<std::int64_t> all(static_cast<std::size_t>(offsets.back() + counts.back()));
  MPI_Allgatherv(mine.data(), n, MPI_INT64_T, all.data(), counts.data(), offsets.data(), MPI_INT64_T, comm);
  return all;
}

PatchLedger MpiDistribution::project(BoundaryProjection& projection, ParticleSet& owned, double t, double dt,
                                     Rng& rng, std::int64_t max_particles) {
  const auto t0 = Clock::now();
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  const MPI_Comm comm = detail::world_comm();
  // What the projection reads, by the largest width anywhere.
  double s_max = 0.0;
  for (double s : owned.widths()) s_max = std::max(s_max, s);
  MPI_Allreduce(MPI_IN_PLACE, &s_max, 1, MPI_DOUBLE, MPI_MAX, comm);
  std::vector<std::size_t> near;
  for (std::size_t p = 0; p < owned.size(); ++p)
    if (projection.reads(owned.positions()[p], s_max)) near.push_back(p);
  ParticleSet band = gather_union(owned, near, comm);
  std::int64_t next = owned.next_id(), n_global = static_cast<std::int64_t>(owned.size());
  MPI_Allreduce(MPI_IN_PLACE, &next, 1, MPI_INT64_T, MPI_MAX, comm);
  MPI_Allreduce(MPI_IN_PLACE, &n_global, 1, MPI_INT64_T, MPI_SUM, comm);
  next = std::max<std::int64_t>(next, band.next_id());
  band.set_next_id(next);

  // The same call on every rank, with the global cap: the particles it does
  // not see count against it too, and the widest blob anywhere sets the
  // placement density's cut-off. Its errors (a cap exceeded, bad data) are
  // every rank's alike.
  const std::int64_t cap = projection.max_particles();
  projection.set_max_particles(max_particles);
  projection.set_unseen(n_global - static_cast<std::int64_t>(band.size()), s_max);
  PatchLedger ledger;
  try {
    ledger = projection.apply(band, t, dt, rng);
  } catch (...) {
    projection.set_max_particles(cap);
    projection.set_unseen(0, 0.0);
    throw;
  }
  projection.set_max_particles(cap);
  projection.set_unseen(0, 0.0);

  // This share: without its removed particles, with the inserted ones it owns.
  std::vector<std::size_t> gone;
  for (std::size_t p : near)
    if (band.index_of(owned.ids()[p]) < 0) gone.push_back(p);
  owned.remove_indices(std::move(gone));
  const int me = rank();
  for (std::size_t p = 0; p < band.size(); ++p) {
    if (band.ids()[p] < next) continue;
    const Vec3& y = band.positions()[p];
    if ((layout_ ? layout_->owner(y) : 0) != me) continue;
    owned.add_with_id(band.ids()[p], y, band.widths()[p], band.masses()[p], band.birth_times()[p]);
  }
  owned.set_next_id(band.next_id());
  ++stats_.projections;
  stats_.gathered = static_cast<std::int64_t>(band.size());
  stats_.projection_seconds += seconds_since(t0);
  return ledger;
}

void MpiDistribution::redistribute(ParticleSet& owned) {
  const auto t0 = Clock::now();
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  const MPI_Comm comm = detail::world_comm();
  std::int64_t counts[2] = {static_cast<std::int64_t>(owned.size()), static_cast<std::int64_t>(owned.size())};
  MPI_Allreduce(MPI_IN_PLACE, &counts[0], 1, MPI_INT64_T, MPI_MAX, comm);
  MPI_Allreduce(MPI_IN_PLACE, &counts[1], 1, MPI_INT64_T, MPI_SUM, comm);
  if (counts[1] == 0) return;  // nothing anywhere: no regions yet (the projection's first particles go to rank 0)
  const double mean = static_cast<double>(counts[1]) / static_cast<double>(size());
  if (!layout_ || static_cast<double>(counts[0]) > (1.0 + options_.rebalance_tolerance) * mean) {
    layout_ = std::make_unique<BisectionLayout>(balanced_bisection(owned.positions(), dim_));
    ++stats_.rebalances;
  }
  // The history's entries go with their particles, to the owner by the
  // layout migrate() uses: taken out before it, put back if it refuses (it
  // refuses on every rank alike, before moving any particle), sent once it
  // has moved the particles.
  std::vector<detail::Rows> to(static_cast<std::size_t>(size()));
  std::vector<HistoryEntry> taken;
  if (stepper_) {
    const int me = rank();
    std::vector<std::vector<ParticleId>> leaving(static_cast<std::size_t>(size()));
    for (std::size_t p = 0; p < owned.size(); ++p) {
      const int r = layout_->owner(owned.positions()[p]);
      if (r != me) leaving[static_cast<std::size_t>(r)].push_back(owned.ids()[p]);
    }
    for (std::size_t r = 0; r < leaving.size(); ++r)
      for (const HistoryEntry& e : stepper_->history().extract(leaving[r])) {
        append_entry(to[r], e);
        taken.push_back(e);
      }
  }
  std::size_t moved = 0;
  try {
    moved = migrate(owned, *layout_);
  } catch (...) {
    if (stepper_) stepper_->history().absorb(taken);
    throw;
  }
  stats_.migrated_out += static_cast<std::int64_t>(moved);
  const detail::Rows arrived = detail::exchange_rows(to, kHistoryDoubles, comm);
  std::vector<HistoryEntry> entries;
  for (std::size_t i = 0; i < arrived.ids.size(); ++i) entries.push_back(entry_of(arrived, i));
  // An entry refused here (an id held twice: ids not unique over the ranks)
  // is every rank's refusal, so that none goes on alone.
  std::exception_ptr bad;
  try {
    if (stepper_) stepper_->history().absorb(entries);
  } catch (...) {
    bad = std::current_exception();
  }
  int any_bad = bad ? 1 : 0;
  MPI_Allreduce(MPI_IN_PLACE, &any_bad, 1, MPI_INT, MPI_MAX, comm);
  if (bad) std::rethrow_exception(bad);
  require(any_bad == 0, "history", 0.0, "refused on another rank (its error names the entry)");
  stats_.redistribution_seconds += seconds_since(t0);
}

ParticleSet all_particles(const ParticleSet& owned) {
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  std::vector<std::size_t> every(owned.size());
  std::iota(every.begin(), every.end(), std::size_t{0});
  ParticleSet out = gather_union(owned, every, detail::world_comm());
  std::int64_t next = owned.next_id();
  MPI_Allreduce(MPI_IN_PLACE, &next, 1, MPI_INT64_T, MPI_MAX, detail::world_comm());
  out.set_next_id(std::max<std::int64_t>(next, out.next_id()));
  return out;
}

}  // namespace otfp
