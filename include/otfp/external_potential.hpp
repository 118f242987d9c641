#pragma once
// External potential per unit mass (the Psi of (15)) that both time steppers
// (implicit_stepper.hpp, explicit_stepper.hpp) add to the barrier. Its own
// header because it is an input of both steppers, not of one of them.
#include <functional>

#include "otfp/types.hpp"

namespace otfp {

// Optional external potential per unit mass (the Psi of (15)); returns its
// value at x and, if grad is not null, its gradient. Added to the barrier.
using ExternalPotential = std::function<double(const Vec3& x, Vec3* grad)>;

}  // namespace otfp
