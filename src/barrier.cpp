#include "otfp/barrier.hpp"

#include <cmath>

namespace otfp {

Barrier::Barrier(DomainPtr domain, double stiffness_C, std::vector<int> inflated_patches, double inflation_b)
    : domain_(std::move(domain)), inflation_(inflation_b), inflated_(std::move(inflated_patches)) {
  require(domain_ != nullptr, "barrier.domain", "null", "must be set");
  set_stiffness(stiffness_C);
  require(std::isfinite(inflation_b) && inflation_b >= 0.0, "barrier.inflation_b", inflation_b, "must be finite and >= 0");
  is_inflated_.assign(static_cast<std::size_t>(std::max(0, domain_->num_patches())), 0);
  for (int l : inflated_) {
    require(l >= 0 && l < domain_->num_patches(), "barrier.inflated_patch", l,
            "must be a patch id of the domain (0.." + std::to_string(domain_->num_patches() - 1) + ")");
    is_inflated_[static_cast<std::size_t>(l)] = 1;
  }
}

void Barrier::set_stiffness(double stiffness_C) {
  require(std::isfinite(stiffness_C) && stiffness_C >= 0.0, "barrier.stiffness", stiffness_C, "must be finite and >= 0");
  stiffness_ = stiffness_C;
}

double Barrier::distance(const Vec3& x) const {
  if (!domain_ || domain_->is_periodic()) return 0.0;
  const BoundaryQuery q = domain_->query(x);
  const double shift = (q.patch >= 0 && is_inflated_.size() > static_cast<std::size_t>(q.patch) &&
                        is_inflated_[static_cast<std::size_t>(q.patch)])
                           ? inflation_
                           : 0.0;
  return std::max(0.0, q.signed_distance - shift);
}

double Barrier::value(const Vec3& x, Vec3* grad) const {
  if (grad) grad->setZero();
  if (!active()) return 0.0;
  const BoundaryQuery q = domain_->query(x);
  const double shift = (q.patch >= 0 && static_cast<std::size_t>(q.patch) < is_inflated_.size() &&
                        is_inflated_[static_cast<std::size_t>(q.patch)])
                           ? inflation_
                           : 0.0;
  const double dist = q.signed_distance - shift;
  if (!(dist > 0.0)) return 0.0;
  if (grad) {
    // Outside Omega the gradient of sd is the unit vector from the closest point.
    Vec3 n = x - q.closest_point;
    const double len = n.norm();
    if (len > 0.0) *grad = stiffness_ * dist * (n / len);
  }
  return 0.5 * stiffness_ * dist * dist;
}

}  // namespace otfp
