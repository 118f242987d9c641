#include "otfp/types.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <sstream>

namespace otfp {

namespace {
// The shortest text that reads back as v (1e-12, not 9.9999999999999998e-13):
// a message shows the value as the user wrote it.
std::string format_double(double v) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}
std::uint64_t splitmix64(std::uint64_t& x) {
  std::uint64_t z = (x += 0x9e3779b97f4a7c15ULL);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}
std::uint64_t rotl(std::uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
}  // namespace

void require(bool ok, const std::string& field, double value, const std::string& rule) {
  if (!ok) throw InvalidArgument(field + " = " + format_double(value) + ": " + rule);
}
void require(bool ok, const std::string& field, const std::string& value, const std::string& rule) {
  if (!ok) throw InvalidArgument(field + " = '" + value + "': " + rule);
}

void require_particle_room(double count, std::size_t current, std::int64_t limit, const std::string& what) {
  const std::int64_t cap = limit > 0 ? std::min(limit, kMaxParticleCount) : kMaxParticleCount;
  const double room = static_cast<double>(cap) - static_cast<double>(current);
  if (count <= room) return;  // false for NaN: refused below
  throw ResourceLimitExceeded(what + " would add " + format_double(count) + " particles to " + std::to_string(current) +
                              ": more than the limit of " + std::to_string(cap) + " particles" +
                              (limit > 0 ? " (max_particles)" : " (2^53, past which counts are inexact)"));
}

Rng::Rng(std::uint64_t seed) {
  std::uint64_t x = seed;
  for (auto& s : s_) s = splitmix64(x);
}

std::uint64_t Rng::next_u64() {
  const std::uint64_t result = rotl(s_[1] * 5, 7) * 9;
  const std::uint64_t t = s_[1] << 17;
  s_[2] ^= s_[0];
  s_[3] ^= s_[1];
  s_[1] ^= s_[2];
  s_[0] ^= s_[3];
  s_[2] ^= t;
  s_[3] = rotl(s_[3], 45);
  return result;
}

Rng::State Rng::state() const {
  State st;
  for (int i = 0; i < 4; ++i) st.s[i] = s_[i];
  st.has_spare = has_spare_;
  st.spare = spare_;
  return st;
}

void Rng::set_state(const State& st) {
  // xoshiro256** never leaves the all-zero state: it cannot come from state().
  require((st.s[0] | st.s[1] | st.s[2] | st.s[3]) != 0, "Rng state", 0.0, "must not be all zero");
  for (int i = 0; i < 4; ++i) s_[i] = st.s[i];
  has_spare_ = st.has_spare;
  spare_ = st.spare;
}

double Rng::uniform() { return static_cast<double>(next_u64() >> 11) * 0x1.0p-53; }
double Rng::uniform(double a, double b) { return a + (b - a) * uniform(); }

double Rng::normal() {
  if (has_spare_) {
    has_spare_ = false;
    return spare_;
  }
  double u1 = uniform();
  while (u1 <= 0.0) u1 = uniform();
  const double u2 = uniform();
  const double r = std::sqrt(-2.0 * std::log(u1));
  const double a = 2.0 * M_PI * u2;
  spare_ = r * std::sin(a);
  has_spare_ = true;
  return r * std::cos(a);
}

std::uint64_t Rng::below(std::uint64_t n) {
  // Lemire-style rejection keeps it unbiased.
  if (n == 0) return 0;
  const std::uint64_t limit = ~std::uint64_t{0} - (~std::uint64_t{0} % n);
  std::uint64_t v;
  do { v = next_u64(); } while (v >= limit);
  return v % n;
}

}  // namespace otfp
