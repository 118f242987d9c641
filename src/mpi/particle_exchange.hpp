#pragma once
// Particles between ranks (otfp::mpi, internal): what migrate(), the gathered
// projection and the neighbour exchange of MpiDistribution send. A particle
// travels as its id and six doubles: position, width, mass, birth time.
#include <mpi.h>

#include <cstddef>
#include <cstdint>
#include <vector>

#include "otfp/neighbor_list.hpp"
#include "otfp/particles.hpp"
#include "otfp/types.hpp"

namespace otfp::detail {

struct ParticleRecords {
  static constexpr int kDoubles = 6;  // x, y, z, s, m, birth
  std::vector<std::int64_t> ids;
  std::vector<double> values;  // kDoubles per particle
  std::size_t size() const { return ids.size(); }
  void append(const ParticleSet& from, std::size_t p);
  void add_to(ParticleSet& into, std::size_t i) const;  // add_with_id of record i
};

// Rows of an all-to-all: an id and k doubles each.
struct Rows {
  std::vector<std::int64_t> ids;
  std::vector<double> values;  // k per row
};

// Sends to[r] to rank r (one entry per rank of comm, k doubles per row) and
// returns what this rank receives, in rank order (collective).
Rows exchange_rows(const std::vector<Rows>& to, int k, MPI_Comm comm);

// Sends from's particles to[r] to rank r (one list per rank of comm) and
// returns what this rank receives, in rank order (collective).
ParticleRecords exchange_particles(const ParticleSet& from, const std::vector<std::vector<std::size_t>>& to,
                                   MPI_Comm comm);

// Distance from y to the box [lo, hi] (per axis: 0 inside; periodic axes by
// the nearest image of y).
double distance_to_box(const Vec3& y, const Vec3& lo, const Vec3& hi, const Periodicity& per, int dim);

// Every rank's bounding box of its points, lo then hi (6 doubles per rank;
// lo > hi for a rank with none), on every rank (collective).
std::vector<double> all_boxes(const std::vector<Vec3>& x, MPI_Comm comm);

}  // namespace otfp::detail
