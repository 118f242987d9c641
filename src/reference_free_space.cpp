// Free space (free_space): the second moment of the blob density about the
// centre grows by 2 d kappa M t (analytic::free_space_variance_growth per axis).
#include <cmath>
#include <memory>

#include "otfp/reference.hpp"

namespace otfp {

namespace {

const char* const kMomentMeasured = "second_moment";
const char* const kMomentScaleRule = "2 d kappa M t_end (the reference growth over the run)";

class FreeSpaceReference : public Reference {
 public:
  bool uses_particles() const override { return true; }
  explicit FreeSpaceReference(const ReferenceSetup& setup) : setup_(setup) {
    require(setup.dim >= 1 && setup.dim <= 3, "reference dim", setup.dim, "must be 1, 2 or 3");
  }

  std::string name() const override { return "free_space"; }
  std::vector<std::string> columns() const override {
    return {"second_moment", "reference_second_moment", "error_second_moment"};
  }

  // The first row sets S(0), the mass M(0) of the initial particles, and the
  // error scale 2 d kappa M t_end with the mass of that row.
  ReferenceRow row(const ReferenceSample& s) override {
    require(s.particles != nullptr, "free_space sample particles", "null", "must be given");
    const int dim = setup_.dim;
    const double S = blob_second_moment(*s.particles, setup_.center);
    if (!moment_.started()) {
      S0_ = S;
      M0_ = s.initial_mass;
      moment_ = ErrorStatistics(kMomentMeasured, 2.0 * dim * setup_.kappa * s.measures.mass_total * setup_.t_end, kMomentScaleRule);
    }
    const double rs = S0_ + 2.0 * dim * setup_.kappa * M0_ * s.t;
    ReferenceRow row;
    row.values = {S, rs, moment_.add(s.t, S, rs)};
    row.reference = rs;
    return row;
  }

  std::vector<ErrorStatistics> statistics() const override {
    if (!moment_.started()) return {};
    return {moment_};
  }
  // growth_ratio = (S(t) - S(0)) / (2 d kappa M t): an effective diffusivity over kappa.
  std::vector<ReferenceEntry> summary() const override {
    if (!moment_.started() || !(moment_.t_last() > 0.0)) return {};
    return {{"growth_ratio",
             (moment_.last_measured() - S0_) / (2.0 * setup_.dim * setup_.kappa * M0_ * moment_.t_last())}};
  }

  ReferenceState save_state() const override {
    return {{"second_moment", moment_.state()}, {"S0", {S0_}}, {"M0", {M0_}}};
  }
  void load_state(const ReferenceState& s) override {
    ErrorStatistics moment(kMomentMeasured, 1.0, kMomentScaleRule);
    moment.load_state(state_entry(s, "second_moment", ErrorStatistics::kStateSize));
    const double S0 = state_entry(s, "S0", 1)[0], M0 = state_entry(s, "M0", 1)[0];
    moment_ = moment;
    S0_ = S0;
    M0_ = M0;
  }

 private:
  ReferenceSetup setup_;
  ErrorStatistics moment_;  // second moment against S(0) + 2 d kappa M t (from the first row on)
  double S0_ = 0.0, M0_ = 0.0;
};

}  // namespace

std::unique_ptr<Reference> make_free_space_reference(const ReferenceSetup& setup) {
  return std::make_unique<FreeSpaceReference>(setup);
}

}  // namespace otfp
