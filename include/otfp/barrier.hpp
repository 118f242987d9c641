#pragma once
// One-sided barrier Psi(x) = C/2 dist(x, Omega')^2 of (20) (docs/method_notes.md#one-sided-barrier).
// dist is zero inside Omega', so the barrier never pulls interior particles
// towards the wall. Omega' is Omega inflated by b over the chosen patches
// (the Dirichlet buffer B^ext of Sec. 4.2): a point whose closest boundary
// patch is inflated feels the barrier only beyond sd(x) = b.
#include <vector>

#include "otfp/geometry.hpp"

namespace otfp {

class Barrier {
 public:
  Barrier() = default;  // inactive: Psi = 0
  Barrier(DomainPtr domain, double stiffness_C, std::vector<int> inflated_patches = {}, double inflation_b = 0.0);

  bool active() const { return domain_ != nullptr && !domain_->is_periodic() && stiffness_ > 0.0; }
  double stiffness() const { return stiffness_; }
  void set_stiffness(double stiffness_C);
  double inflation() const { return inflation_; }
  const std::vector<int>& inflated_patches() const { return inflated_; }
  const DomainPtr& domain() const { return domain_; }

  // dist(x, Omega') >= 0.
  double distance(const Vec3& x) const;
  // Psi(x) per unit mass and, if grad != nullptr, its gradient (zero inside).
  double value(const Vec3& x, Vec3* grad = nullptr) const;

 private:
  DomainPtr domain_;
  double stiffness_ = 0.0;
  double inflation_ = 0.0;
  std::vector<int> inflated_;
  std::vector<char> is_inflated_;  // by patch id
};

}  // namespace otfp
