// Particles between ranks (particle_exchange.hpp).
#include "particle_exchange.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace otfp::detail {

void ParticleRecords::append(const ParticleSet& from, std::size_t p) {
  const Vec3& y = from.positions()[p];
  values.insert(values.end(), {y[0], y[1], y[2], from.widths()[p], from.masses()[p], from.birth_times()[p]});
  ids.push_back(from.ids()[p]);
}

void ParticleRecords::add_to(ParticleSet& into, std::size_t i) const {
  const double* v = &values[i * kDoubles];
  into.add_with_id(ids[i], Vec3(v[0], v[1], v[2]), v[3], v[4], v[5]);
}

Rows exchange_rows(const std::vector<Rows>& to, int k, MPI_Comm comm) {
  int size = 1;
  MPI_Comm_size(comm, &size);
  const auto ranks = static_cast<std::size_t>(size);
  Rows out, in;
  std::vector<int> send_n(ranks, 0), recv_n(ranks, 0);
  for (std::size_t r = 0; r < ranks && r < to.size(); ++r) {
    send_n[r] = static_cast<int>(to[r].ids.size());
    out.ids.insert(out.ids.end(), to[r].ids.begin(), to[r].ids.end());
    out.values.insert(out.values.end(), to[r].values.begin(), to[r].values.end());
  }
  MPI_Alltoall(send_n.data(), 1, MPI_INT, recv_n.data(), 1, MPI_INT, comm);
  std::vector<int> send_off(ranks, 0), recv_off(ranks, 0);
  for (std::size_t r = 1; r < ranks; ++r) {
    send_off[r] = send_off[r - 1] + send_n[r - 1];
    recv_off[r] = recv_off[r - 1] + recv_n[r - 1];
  }
  in.ids.resize(static_cast<std::size_t>(recv_off.back() + recv_n.back()));
  MPI_Alltoallv(out.ids.data(), send_n.data(), send_off.data(), MPI_INT64_T, in.ids.data(), recv_n.data(),
                recv_off.data(), MPI_INT64_T, comm);
  for (std::size_t r = 0; r < ranks; ++r) {
    send_n[r] *= k;
    send_off[r] *= k;
    recv_n[r] *= k;
    recv_off[r] *= k;
  }
  in.values.resize(in.ids.size() * static_cast<std::size_t>(k));
  MPI_Alltoallv(out.values.data(), send_n.data(), send_off.data(), MPI_DOUBLE, in.values.data(), recv_n.data(),
                recv_off.data(), MPI_DOUBLE, comm);
  return in;
}

ParticleRecords exchange_particles(const ParticleSet& from, const std::vector<std::vector<std::size_t>>& to,
                                   MPI_Comm comm) {
  std::vector<Rows> rows(to.size());
  for (std::size_t r = 0; r < to.size(); ++r) {
    ParticleRecords mine;
    for (std::size_t p : to[r]) mine.append(from, p);
    rows[r].ids = std::move(mine.ids);
    rows[r].values = std::move(mine.values);
  }
  Rows in = exchange_rows(rows, ParticleRecords::kDoubles, comm);
  ParticleRecords out;
  out.ids = std::move(in.ids);
  out.values = std::move(in.values);
  return out;
}

double distance_to_box(const Vec3& y, const Vec3& lo, const Vec3& hi, const Periodicity& per, int dim) {
  double d2 = 0.0;
  for (int k = 0; k < dim; ++k) {
    auto gap = [&](double v) { return std::max({0.0, lo[k] - v, v - hi[k]}); };
    double g = gap(y[k]);
    if (per.period[k] > 0.0) g = std::min({g, gap(y[k] - per.period[k]), gap(y[k] + per.period[k])});
    d2 += g * g;
  }
  return std::sqrt(d2);
}

std::vector<double> all_boxes(const std::vector<Vec3>& x, MPI_Comm comm) {
  int size = 1;
  MPI_Comm_size(comm, &size);
  std::vector<double> box(6), boxes(6 * static_cast<std::size_t>(size));
  for (int k = 0; k < 3; ++k) {
    box[static_cast<std::size_t>(k)] = std::numeric_limits<double>::infinity();
    box[static_cast<std::size_t>(3 + k)] = -std::numeric_limits<double>::infinity();
  }
  for (const Vec3& y : x)
    for (int k = 0; k < 3; ++k) {
      box[static_cast<std::size_t>(k)] = std::min(box[static_cast<std::size_t>(k)], y[k]);
      box[static_cast<std::size_t>(3 + k)] = std::max(box[static_cast<std::size_t>(3 + k)], y[k]);
    }
  MPI_Allgather(box.data(), 6, MPI_DOUBLE, boxes.data(), 6, MPI_DOUBLE, comm);
  return boxes;
}

}  // namespace otfp::detail
