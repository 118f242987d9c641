// Cosine mode (cosine_mode): in a periodic box the amplitude a(t) of the mode
// 1 + a cos(k (x - x0)) decays as a(0) exp(-kappa k^2 t); the summary adds the
// fitted decay rate and the rate of the time scheme alone.
#include <cmath>
#include <limits>
#include <memory>

#include "otfp/analytic.hpp"
#include "otfp/reference.hpp"

namespace otfp {

namespace {

const char* const kModeMeasured = "mode_amplitude";
const char* const kModeScaleRule = "the initial amplitude a(0)";

class CosineModeReference : public Reference {
 public:
  bool uses_particles() const override { return true; }
  explicit CosineModeReference(const ReferenceSetup& setup) : setup_(setup) {
    require(std::isfinite(setup.wavenumber) && setup.wavenumber > 0.0, "cosine_mode wavenumber", setup.wavenumber,
            "must be finite and > 0");
  }

  std::string name() const override { return "cosine_mode"; }
  std::vector<std::string> columns() const override {
    return {"mode_amplitude", "reference_mode_amplitude", "error_mode_amplitude"};
  }

  // The first row sets a(0) and the error scale |a(0)|.
  ReferenceRow row(const ReferenceSample& s) override {
    require(s.particles != nullptr, "cosine_mode sample particles", "null", "must be given");
    const double k = setup_.wavenumber;
    const double A = cosine_mode_amplitude(*s.particles, k, setup_.x0);
    if (!amplitude_.started()) {
      A0_ = A;
      amplitude_ = ErrorStatistics(kModeMeasured, std::abs(A0_), kModeScaleRule);
    }
    const double ra = A0_ * analytic::cosine_mode_decay(setup_.kappa, k, s.t);
    ReferenceRow row;
    row.values = {A, ra, amplitude_.add(s.t, A, ra)};
    row.reference = ra;
    // Fit window: from the first row until a(t) first falls to 5% of a(0)
    // (later rows are noise that may come back above it).
    if (fit_open_ && A > 0.05 * std::abs(A0_) && A0_ > 0.0) {
      fit_t_.push_back(s.t);
      fit_a_.push_back(A);
    } else {
      fit_open_ = false;
    }
    return row;
  }

  std::vector<ErrorStatistics> statistics() const override {
    if (!amplitude_.started()) return {};
    return {amplitude_};
  }

  // The least-squares rate over the fit window against kappa k^2 and against
  // the rate of the time scheme alone (constant steps only; BDF2's first step is Euler).
  std::vector<ReferenceEntry> summary() const override {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const double lambda = setup_.kappa * setup_.wavenumber * setup_.wavenumber;
    const double rate = decay_rate_fit(fit_t_, fit_a_);
    const double dt = setup_.constant_dt;
    const double discrete = !(dt > 0.0) ? nan
                            : setup_.stepper == StepperKind::Explicit
                                ? analytic::time_discrete_rate(setup_.explicit_scheme, lambda, dt)
                                : analytic::time_discrete_rate(setup_.time_scheme, lambda, dt);
    return {{"wavenumber", setup_.wavenumber},
            {"kappa_k2", lambda},
            {"rows_fitted", static_cast<std::int64_t>(fit_t_.size())},
            {"fitted_rate", rate},
            {"rate_ratio", rate / lambda},
            {"time_discrete_rate", discrete},
            {"rate_ratio_time_discrete", std::isfinite(rate) && std::isfinite(discrete) ? rate / discrete : nan}};
  }

  ReferenceState save_state() const override {
    return {{"mode_amplitude", amplitude_.state()},
            {"A0", {A0_}},
            {"fit_open", {fit_open_ ? 1.0 : 0.0}},
            {"fit_t", fit_t_},
            {"fit_a", fit_a_}};
  }
  void load_state(const ReferenceState& s) override {
    ErrorStatistics amplitude(kModeMeasured, 1.0, kModeScaleRule);
    amplitude.load_state(state_entry(s, "mode_amplitude", ErrorStatistics::kStateSize));
    const double A0 = state_entry(s, "A0", 1)[0];
    const bool open = state_entry(s, "fit_open", 1)[0] != 0.0;
    const std::vector<double>& t = state_entry(s, "fit_t");
    const std::vector<double>& a = state_entry(s, "fit_a", t.size());
    amplitude_ = amplitude;
    A0_ = A0;
    fit_open_ = open;
    fit_t_ = t;
    fit_a_ = a;
  }

 private:
  ReferenceSetup setup_;
  ErrorStatistics amplitude_;  // a(t) against a(0) exp(-kappa k^2 t) (from the first row on)
  double A0_ = 0.0;
  bool fit_open_ = true;
  std::vector<double> fit_t_, fit_a_;  // the rows of the fit window
};

}  // namespace

std::unique_ptr<Reference> make_cosine_mode_reference(const ReferenceSetup& setup) {
  return std::make_unique<CosineModeReference>(setup);
}

}  // namespace otfp
