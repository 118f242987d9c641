#include "otfp/particles.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <string>

namespace otfp {

ParticleSet::ParticleSet(int dim) : dim_(dim) {
  require(dim >= 1 && dim <= 3, "dim", dim, "must be 1, 2 or 3");
}

ParticleId ParticleSet::add(const Vec3& x, double width_s, double mass, double birth_time) {
  // Past kMaxParticleId only by add() itself: 2^62 more particles before this.
  require(next_id_ < std::numeric_limits<ParticleId>::max(), "next particle id", std::to_string(next_id_),
          "is the largest id there is: no more particles can be added");
  return insert(next_id_, x, width_s, mass, birth_time);
}

ParticleId ParticleSet::add_with_id(ParticleId id, const Vec3& x, double width_s, double mass, double birth_time) {
  require(id <= kMaxParticleId, "particle id", std::to_string(id),
          "must be <= 2^62 = " + std::to_string(kMaxParticleId));
  return insert(id, x, width_s, mass, birth_time);
}

ParticleId ParticleSet::insert(ParticleId id, const Vec3& x, double width_s, double mass, double birth_time) {
  require(std::isfinite(width_s) && width_s > 0.0, "particle width s", width_s, "must be finite and > 0");
  require(std::isfinite(mass) && mass > 0.0, "particle mass", mass, "must be finite and > 0");
  require(x.allFinite(), "particle position", x.norm(), "must be finite");
  require(id >= 0, "particle id", std::to_string(id), "must be >= 0");
  require(index_.find(id) == index_.end(), "particle id", std::to_string(id), "is already present");
  Vec3 y = x;
  for (int k = dim_; k < 3; ++k) y[k] = 0.0;
  next_id_ = std::max(next_id_, id + 1);
  index_.emplace(id, x_.size());
  x_.push_back(y);
  s_.push_back(width_s);
  m_.push_back(mass);
  birth_.push_back(birth_time);
  id_.push_back(id);
  return id;
}

void ParticleSet::remove(std::size_t index) {
  require(index < size(), "particle index", static_cast<double>(index), "must be < number of particles");
  const std::size_t last = size() - 1;
  index_.erase(id_[index]);
  if (index != last) {
    x_[index] = x_[last];
    s_[index] = s_[last];
    m_[index] = m_[last];
    birth_[index] = birth_[last];
    id_[index] = id_[last];
    index_[id_[index]] = index;
  }
  x_.pop_back();
  s_.pop_back();
  m_.pop_back();
  birth_.pop_back();
  id_.pop_back();
}

void ParticleSet::remove_indices(std::vector<std::size_t> indices) {
  // Highest index first, so that swapping the last particle in never moves a
  // particle that is still to be removed.
  std::sort(indices.begin(), indices.end(), std::greater<>());
  require(std::adjacent_find(indices.begin(), indices.end()) == indices.end(), "particle indices", 0.0,
          "must not contain duplicates");
  for (std::size_t i : indices) remove(i);
}

void ParticleSet::clear() {
  x_.clear();
  s_.clear();
  m_.clear();
  birth_.clear();
  id_.clear();
  index_.clear();
}

void ParticleSet::reserve(std::size_t n) {
  x_.reserve(n);
  s_.reserve(n);
  m_.reserve(n);
  birth_.reserve(n);
  id_.reserve(n);
  index_.reserve(n);
}

void ParticleSet::set_next_id(ParticleId next) {
  require(next >= 0, "next particle id", std::to_string(next), "must be >= 0");
  require(next <= kMaxParticleId + 1, "next particle id", std::to_string(next),
          "must be <= 2^62 + 1 = " + std::to_string(kMaxParticleId + 1));
  for (ParticleId id : id_)
    require(next > id, "next particle id", std::to_string(next),
            "must be > every id present (id " + std::to_string(id) + " is)");
  next_id_ = next;
}

std::ptrdiff_t ParticleSet::index_of(ParticleId id) const {
  auto it = index_.find(id);
  return it == index_.end() ? -1 : static_cast<std::ptrdiff_t>(it->second);
}

void ParticleSet::set_beta(std::size_t p, double beta) {
  require(p < size(), "set_beta: particle index", std::to_string(p),
          "must be < the number of particles (" + std::to_string(size()) + ")");
  require(std::isfinite(beta) && beta > 0.0, "beta", beta, "must be finite and > 0");
  s_[p] = 1.0 / std::sqrt(beta);
}

void ParticleSet::set_uniform_beta(double beta) {
  require(std::isfinite(beta) && beta > 0.0, "beta", beta, "must be finite and > 0");
  std::fill(s_.begin(), s_.end(), 1.0 / std::sqrt(beta));
}

void ParticleSet::reorder(const std::vector<std::size_t>& order) {
  require(order.size() == size(), "reorder: order size", static_cast<double>(order.size()),
          "must equal the number of particles");
  // A permutation of 0..n-1: every index in range and none twice.
  std::vector<char> seen(order.size(), 0);
  for (std::size_t i : order) {
    require(i < order.size(), "reorder: index", std::to_string(i),
            "must be < the number of particles (" + std::to_string(order.size()) + ")");
    require(!seen[i], "reorder: index", std::to_string(i), "appears twice (order must be a permutation)");
    seen[i] = 1;
  }
  auto permute = [&](auto& v) {
    std::remove_reference_t<decltype(v)> out;
    out.reserve(v.size());
    for (std::size_t i : order) out.push_back(v[i]);
    v.swap(out);
  };
  permute(x_);
  permute(s_);
  permute(m_);
  permute(birth_);
  permute(id_);
  for (std::size_t i = 0; i < id_.size(); ++i) index_[id_[i]] = i;
}

std::vector<std::size_t> spatial_order(const std::vector<Vec3>& x, int dim, double cell_size) {
  require(std::isfinite(cell_size) && cell_size > 0.0, "cell_size", cell_size, "must be finite and > 0");
  const std::size_t n = x.size();
  std::vector<std::size_t> order(n);
  for (std::size_t i = 0; i < n; ++i) order[i] = i;
  if (n < 2) return order;
  Vec3 lo = x[0];
  for (const Vec3& p : x) lo = lo.cwiseMin(p);
  std::vector<std::uint64_t> key(n);
  for (std::size_t i = 0; i < n; ++i) {
    std::uint64_t k = 0;  // 21 bits per axis
    for (int a = dim - 1; a >= 0; --a) {
      const double c = std::floor((x[i][a] - lo[a]) / cell_size);
      k = (k << 21) | static_cast<std::uint64_t>(std::min(c, 2097151.0));
    }
    key[i] = k;
  }
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return key[a] < key[b]; });
  return order;
}

double ParticleSet::total_mass() const {
  double m = 0.0;
  for (double v : m_) m += v;
  return m;
}

void ParticleSet::assign_in_place(const ParticleSet& other) {
  require(other.dim_ == dim_, "assign_in_place: dim", other.dim_,
          "must equal this set's dim " + std::to_string(dim_));
  require(other.size() == size(), "assign_in_place: size", static_cast<double>(other.size()),
          "must equal this set's size " + std::to_string(size()));
  if (&other == this) return;
  std::copy(other.x_.begin(), other.x_.end(), x_.begin());
  std::copy(other.s_.begin(), other.s_.end(), s_.begin());
  std::copy(other.m_.begin(), other.m_.end(), m_.begin());
  std::copy(other.birth_.begin(), other.birth_.end(), birth_.begin());
  std::copy(other.id_.begin(), other.id_.end(), id_.begin());
  index_ = other.index_;
  next_id_ = other.next_id_;
}

}  // namespace otfp
