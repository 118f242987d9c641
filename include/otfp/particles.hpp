#pragma once
// A set of Gaussian blobs ("finite particles") in d = 1, 2 or 3 dimensions.
#include <cstddef>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "otfp/types.hpp"

namespace otfp {

using ParticleId = std::int64_t;
// The largest id add_with_id() and set_next_id() take (2^62): ids given from
// outside (a file, a checkpoint) leave 2^62 more add() calls before the
// counter could overflow.
constexpr ParticleId kMaxParticleId = ParticleId{1} << 62;

// Permutation that sorts points by the cell of a grid of the given cell size
// (z-major, then y, then x), so that neighbours end up close in memory.
std::vector<std::size_t> spatial_order(const std::vector<Vec3>& x, int dim, double cell_size);

// Structure-of-arrays particle storage.
//
// The width of blob p is stored as s_p = beta_p^(-1/2) (a length): the
// transport term of (28) is quadratic in s, and s > 0 is the only constraint.
// beta(p) = 1 / s_p^2. Positions have three components; those beyond dim() are
// kept at zero. Removal swaps the last particle into the hole (O(1)); ids stay
// attached to their particles, index_of() maps an id to its current index.
class ParticleSet {
 public:
  explicit ParticleSet(int dim = 3);

  int dim() const { return dim_; }
  std::size_t size() const { return x_.size(); }
  bool empty() const { return x_.empty(); }

  // Appends a particle and returns its new id.
  ParticleId add(const Vec3& x, double width_s, double mass, double birth_time = 0.0);
  // Appends a particle with a given id (restoring a checkpoint); returns it.
  // Throws InvalidArgument if id < 0, id > kMaxParticleId or already
  // present; next_id() becomes max(next_id(), id + 1), so later add() calls
  // never reuse it.
  ParticleId add_with_id(ParticleId id, const Vec3& x, double width_s, double mass, double birth_time = 0.0);
  // Removes the particle at `index`; the last particle takes its index.
  void remove(std::size_t index);
  // Removes several particles given by index (any order, no duplicates).
  void remove_indices(std::vector<std::size_t> indices);
  void clear();
  void reserve(std::size_t n);

  // Index of the particle with this id, or -1 if it is gone.
  std::ptrdiff_t index_of(ParticleId id) const;

  std::vector<Vec3>& positions() { return x_; }
  const std::vector<Vec3>& positions() const { return x_; }
  std::vector<double>& widths() { return s_; }  // s = beta^-1/2
  const std::vector<double>& widths() const { return s_; }
  std::vector<double>& masses() { return m_; }
  const std::vector<double>& masses() const { return m_; }
  const std::vector<double>& birth_times() const { return birth_; }
  std::vector<double>& birth_times() { return birth_; }
  const std::vector<ParticleId>& ids() const { return id_; }

  double beta(std::size_t p) const { return 1.0 / (s_[p] * s_[p]); }
  // Throws InvalidArgument unless p < size() and beta is finite and > 0.
  void set_beta(std::size_t p, double beta);
  double total_mass() const;
  ParticleId next_id() const { return next_id_; }
  // Sets the id the next add() gives (a checkpoint's counter, which may be
  // past the largest id present). Throws InvalidArgument unless 0 <= next <=
  // kMaxParticleId + 1 and next > every id present.
  void set_next_id(ParticleId next);

  // Reorders the particles: new index i holds the particle that had index order[i].
  // Ids move with their particles. Throws InvalidArgument (and changes
  // nothing) unless order is a permutation of 0, ..., size() - 1.
  void reorder(const std::vector<std::size_t>& order);
  // Reorders the particles by spatial_order(); ids are kept.
  void sort_spatially(double cell_size) { reorder(spatial_order(x_, dim_, cell_size)); }

  // Sets every width to s = beta^-1/2.
  void set_uniform_beta(double beta);

  // Takes other's particles (positions, widths, masses, birth times, ids and
  // the id counter) into the existing arrays: no array is reallocated, so
  // pointers into them (e.g. numpy views) stay valid. Throws InvalidArgument
  // unless other has the same dim() and size().
  void assign_in_place(const ParticleSet& other);

 private:
  // add() and add_with_id() after their own checks of the id.
  ParticleId insert(ParticleId id, const Vec3& x, double width_s, double mass, double birth_time);
  int dim_;
  std::vector<Vec3> x_;
  std::vector<double> s_, m_, birth_;
  std::vector<ParticleId> id_;
  std::unordered_map<ParticleId, std::size_t> index_;
  ParticleId next_id_ = 0;
};

}  // namespace otfp
