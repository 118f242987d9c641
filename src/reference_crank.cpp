// Crank's sphere and slab (crank_sphere, crank_slab): the mass ratio M/M_inf
// inside Omega, the polar inertia where the setup gives J_ref(inf), and the
// blob-density mass M_rho/M_inf against the same mass curve.
#include <cmath>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "otfp/analytic.hpp"
#include "otfp/reference.hpp"

namespace otfp {

namespace {

const char* const kMassRule = "M_inf (the error is in units of M/M_inf)";

class CrankReference : public Reference {
 public:
  CrankReference(const ReferenceSetup& setup, bool sphere) : setup_(setup), sphere_(sphere) {
    const double L = sphere ? setup.radius : setup.length;
    require(std::isfinite(L) && L > 0.0, sphere ? "crank_sphere radius" : "crank_slab length", L,
            "must be finite and > 0");
    require(std::isfinite(setup.kappa) && setup.kappa > 0.0, "reference kappa", setup.kappa, "must be finite and > 0");
    require(std::isfinite(setup.M_inf) && setup.M_inf > 0.0, "reference M_inf", setup.M_inf, "must be finite and > 0");
    if (setup.J_inf) {
      require(std::isfinite(*setup.J_inf) && *setup.J_inf > 0.0, "reference J_inf", *setup.J_inf,
              "must be finite and > 0");
      if (!sphere)
        require(setup.slab_axis >= 0 && setup.slab_axis < setup.dim, "crank_slab slab_axis", setup.slab_axis,
                "must be an axis of the box (0 <= axis < dim) for its polar inertia");
      polar_ = ErrorStatistics("polar_inertia", *setup.J_inf, "analytic steady polar inertia J_ref(inf)");
    }
  }

  std::string name() const override { return sphere_ ? "crank_sphere" : "crank_slab"; }
  std::vector<std::string> columns() const override {
    if (!setup_.J_inf) return {"reference_mass_ratio", "error_mass_ratio"};
    return {"reference_mass_ratio", "error_mass_ratio", "reference_polar_inertia", "error_polar_inertia"};
  }
  bool has_mass_blob_error() const override { return true; }

  ReferenceRow row(const ReferenceSample& s) override {
    const double t = s.t;
    const double L = sphere_ ? setup_.radius : setup_.length;
    const double tau = setup_.kappa * t / (L * L);
    const double rm = sphere_ ? analytic::crank_sphere_uptake(tau) : analytic::crank_slab_uptake(tau);
    ReferenceRow row;
    row.values = {rm, mass_.add(t, s.measures.mass_inside / setup_.M_inf, rm)};
    if (setup_.J_inf) {
      double rj = 0.0;
      if (sphere_) {
        rj = *setup_.J_inf * analytic::crank_sphere_polar_inertia(tau);
      } else if (t > 0.0) {
        analytic::SlabBox slab;
        slab.dim = setup_.dim;
        slab.lo = setup_.lo;
        slab.hi = setup_.hi;
        slab.axis = setup_.slab_axis;
        slab.held_at_hi = setup_.slab_held_at_hi;
        slab.length = L;
        slab.center = setup_.center;
        slab.M_inf = setup_.M_inf;
        rj = analytic::crank_slab_polar_inertia(tau, slab);
      }
      row.values.push_back(rj);
      row.values.push_back(polar_.add(t, s.measures.polar_inertia, rj));
    }
    row.reference = rm;
    row.error_mass_blob = blob_.add(t, s.mass_blob / setup_.M_inf, rm);
    return row;
  }

  std::vector<ErrorStatistics> statistics() const override {
    if (!setup_.J_inf) return {mass_};
    return {mass_, polar_};
  }
  std::optional<ErrorStatistics> mass_blob_statistics() const override { return blob_; }

  ReferenceState save_state() const override {
    ReferenceState s{{"mass_ratio", mass_.state()}, {"mass_blob", blob_.state()}};
    if (setup_.J_inf) s["polar_inertia"] = polar_.state();
    return s;
  }
  void load_state(const ReferenceState& s) override {
    mass_.load_state(state_entry(s, "mass_ratio", ErrorStatistics::kStateSize));
    blob_.load_state(state_entry(s, "mass_blob", ErrorStatistics::kStateSize));
    if (setup_.J_inf) polar_.load_state(state_entry(s, "polar_inertia", ErrorStatistics::kStateSize));
  }

 private:
  ReferenceSetup setup_;
  bool sphere_;
  ErrorStatistics mass_{"mass_ratio", 1.0, kMassRule};
  ErrorStatistics polar_;
  ErrorStatistics blob_{"mass_blob_ratio", 1.0, kMassRule};
};

}  // namespace

void complete_reference_geometry(const std::string& name, const Domain& domain,
                                 const std::vector<int>& dirichlet_patches, ReferenceSetup& setup) {
  // The set-up's dim decides the 3-D polar inertia and which faces a slab may
  // hold: a default (3) left on a 2-D domain would give the wrong ones.
  require(setup.dim == domain.dim(), "reference dim", setup.dim,
          "must be the domain's dimension (" + std::to_string(domain.dim()) + ")");
  const std::optional<DomainShape> shape = domain.shape();
  if (name == "crank_sphere") {
    if (!shape || shape->kind != DomainShape::Kind::Ball) return;
    if (!(setup.radius > 0.0)) setup.radius = shape->radius;
    // (3/5) M_inf R^2: the polar inertia of a uniform 3-D ball about its centre.
    const double R = setup.radius;
    if (!setup.J_inf && setup.dim == 3 && (setup.center - shape->center).norm() <= 1e-12 * R &&
        std::abs(R - shape->radius) <= 1e-12 * R)
      setup.J_inf = 0.6 * setup.M_inf * R * R;
  } else if (name == "crank_slab") {
    if (setup.length > 0.0 || !shape || shape->kind != DomainShape::Kind::Box) return;
    if (dirichlet_patches.size() != 1) return;
    const int face = dirichlet_patches.front();
    if (face < 0 || face >= 2 * setup.dim) return;  // a sub-patch is not a whole face
    setup.length = shape->hi[face / 2] - shape->lo[face / 2];
    setup.lo = shape->lo;
    setup.hi = shape->hi;
    setup.slab_axis = face / 2;
    setup.slab_held_at_hi = face % 2 == 1;
    if (!setup.J_inf) setup.J_inf = setup.M_inf * domain.mean_square_distance(setup.center);
  }
}

std::unique_ptr<Reference> make_crank_sphere_reference(const ReferenceSetup& setup) {
  return std::make_unique<CrankReference>(setup, true);
}

std::unique_ptr<Reference> make_crank_slab_reference(const ReferenceSetup& setup) {
  return std::make_unique<CrankReference>(setup, false);
}

}  // namespace otfp
