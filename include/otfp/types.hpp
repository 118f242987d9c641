#pragma once
// Basic types shared by all of otfp.
#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>

namespace otfp {

// Points always have three components; in d < 3 the unused ones are zero.
using Vec3 = Eigen::Vector3d;

// Axis-aligned bounding box.
struct Aabb {
  Vec3 lo = Vec3::Zero();
  Vec3 hi = Vec3::Zero();
  Vec3 extent() const { return hi - lo; }
};

// Error for invalid user input: the message names the field, the value and the rule.
class InvalidArgument : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// A step would create more particles than allowed (SimulationOptions::
// max_particles, or kMaxParticleCount): the message names what asked for
// them and the figures. otfp::Simulation turns it into a StepFailure with the
// state the step started from.
class ResourceLimitExceeded : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Largest particle count otfp handles: 2^53, past which counts held in
// doubles (masses over m_p, carries) are no longer exact integers.
constexpr std::int64_t kMaxParticleCount = std::int64_t{1} << 53;

// Throws ResourceLimitExceeded unless `count` (a real number of particles to
// add, possibly huge or non-finite) fits beside `current` under `limit`
// (<= 0: kMaxParticleCount); `what` names the cause in the message.
void require_particle_room(double count, std::size_t current, std::int64_t limit, const std::string& what);

// Throws InvalidArgument("<field> = <value>: <rule>") unless ok.
void require(bool ok, const std::string& field, double value, const std::string& rule);
void require(bool ok, const std::string& field, const std::string& value, const std::string& rule);

// Reproducible random numbers: SplitMix64-seeded xoshiro256**; the uniform
// doubles are made from the top 53 bits, so a seed gives the same stream on
// every platform (std::uniform_real_distribution does not promise that).
class Rng {
 public:
  explicit Rng(std::uint64_t seed = 0x5eed);
  std::uint64_t next_u64();
  double uniform();                        // in [0, 1)
  double uniform(double a, double b);      // in [a, b)
  double normal();                         // standard normal (Box-Muller)
  std::uint64_t below(std::uint64_t n);    // uniform integer in [0, n)

  // The whole generator state (for checkpoints): restoring it continues the
  // stream exactly where state() was taken.
  struct State {
    std::uint64_t s[4] = {0, 0, 0, 0};
    bool has_spare = false;
    double spare = 0.0;
  };
  State state() const;
  void set_state(const State& state);  // throws InvalidArgument for the all-zero state

 private:
  std::uint64_t s_[4];
  bool has_spare_ = false;
  double spare_ = 0.0;
};

}  // namespace otfp
