#pragma once
// Analytic references as objects: each compares measured quantities of a run
// with an analytic curve (analytic.hpp) row by row, keeps the running error
// statistics, names the entries it adds to a run's summary, and saves its
// state for a checkpoint. `otfp run`'s diagnostics.reference is
// make_reference(name, setup); docs/outputs.md defines the columns.
//
//   otfp::ReferenceSetup setup;         // R = kappa = M_inf = 1
//   setup.radius = 1.0;
//   auto ref = otfp::make_reference("crank_sphere", setup);
//   otfp::ReferenceSample s;            // per row: t and the measures of the state
//   s.t = sim.time();
//   s.measures = sim.measure(setup.center);
//   s.mass_blob = sim.blob_mass();
//   const otfp::ReferenceRow row = ref->row(s);  // row.values: one per ref->columns()
//
// Adding a reference: a class derived from Reference in a file of its own
// (src/reference_<name>.cpp, with a factory function) and its registration
// in the table of src/reference.cpp.
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "otfp/diagnostics.hpp"
#include "otfp/geometry.hpp"
#include "otfp/enums.hpp"
#include "otfp/particles.hpp"
#include "otfp/types.hpp"

namespace otfp {

// Running error statistics of one measured quantity against its reference:
// error = (measured - reference) / scale per row, integrated over time by the
// trapezoid rule.
class ErrorStatistics {
 public:
  ErrorStatistics() = default;
  // `measured` names the quantity, `scale_rule` says what the scale is.
  ErrorStatistics(std::string measured, double scale, std::string scale_rule);

  // Adds the row at time t (not before the previous row's) and returns its error.
  double add(double t, double measured, double reference);

  const std::string& measured() const { return measured_; }
  const std::string& scale_rule() const { return scale_rule_; }
  double scale() const { return scale_; }
  bool started() const { return started_; }  // at least one row
  double t_first() const { return t_first_; }
  double t_last() const { return t_prev_; }
  double last_measured() const { return m_prev_; }
  double last_reference() const { return r_prev_; }

  double max_abs_error() const { return max_abs_; }   // max over the rows of |error|
  double l1_time_error() const { return l1_time_; }   // integral of |error| dt (exact across a sign change)
  double mean_abs_error() const;                      // l1_time_error / (t_last - t_first); 0 over no time
  double final_error() const { return final_error_; }  // error of the last row
  double l1_norm() const { return l1_measured_; }     // integral of the measured quantity dt
  double l1_norm_reference() const { return l1_reference_; }  // integral of the reference dt
  double l1_norm_relative_error() const;              // (l1_norm - l1_norm_reference) / l1_norm_reference; 0 if that is 0

  // Checkpoint: the scale and the running sums, kStateSize numbers that
  // load_state reads back exactly (the names are not part of it).
  static constexpr std::size_t kStateSize = 12;
  std::vector<double> state() const;
  void load_state(const std::vector<double>& state);  // throws InvalidArgument for another size

 private:
  std::string measured_, scale_rule_;
  double scale_ = 1.0;
  double max_abs_ = 0.0, l1_time_ = 0.0, final_error_ = 0.0, l1_measured_ = 0.0, l1_reference_ = 0.0;
  double t_prev_ = 0.0, e_prev_ = 0.0, m_prev_ = 0.0, r_prev_ = 0.0, t_first_ = 0.0;
  bool started_ = false;
};

// The decay rate of a(t) = a(0) exp(-rate t): minus the least-squares slope
// of log a_i against t_i (a_i > 0). NaN for fewer than 3 samples.
double decay_rate_fit(const std::vector<double>& t, const std::vector<double>& a);

// What a reference is set up with; each reference reads its own fields.
struct ReferenceSetup {
  int dim = 3;
  double kappa = 1.0;           // diffusivity
  double t_end = 1.0;           // end of the run (free_space: its error scale is the growth over [0, t_end])
  Vec3 center = Vec3::Zero();   // centre of the polar inertia (crank_*) and of the second moment (free_space)
  double M_inf = 1.0;           // crank_*: the mass ratios are M / M_inf
  double radius = 0.0;          // crank_sphere: R of the ball
  double length = 0.0;          // crank_slab: depth L from the held face to the no-flux face
  // crank_*: the analytic steady polar inertia J_ref(inf) about `center`
  // (sphere: (3/5) M_inf R^2, a 3-D ball about its centre; slab: M_inf times
  // the box's mean squared distance to `center`). Unset: no polar-inertia columns.
  std::optional<double> J_inf;
  // crank_slab with J_inf: the box [lo, hi] (dim axes) and its held face,
  // normal to slab_axis at hi (slab_held_at_hi) or lo.
  Vec3 lo = Vec3::Zero(), hi = Vec3::Ones();
  int slab_axis = -1;
  bool slab_held_at_hi = false;
  // cosine_mode: the mode 1 + a cos(k (x - x0)) along the first axis.
  double wavenumber = 0.0;
  double x0 = 0.0;
  // cosine_mode's time_discrete_rate: the constant step (0: not constant,
  // no rate) and the time scheme of the stepper.
  double constant_dt = 0.0;
  StepperKind stepper = StepperKind::Implicit;
  TimeScheme time_scheme = TimeScheme::Euler;
  ExplicitScheme explicit_scheme = ExplicitScheme::EulerForce27;
};

// What a reference reads at one row: the run's state at time t.
struct ReferenceSample {
  double t = 0.0;
  StateMeasures measures;                  // (43)-(44) about the setup's centre (crank_*; free_space: mass_total)
  double mass_blob = 0.0;                  // M_rho, the blob density over Omega (crank_*: error_mass_blob)
  const ParticleSet* particles = nullptr;  // free_space (second moment), cosine_mode (mode amplitude)
  double initial_mass = 0.0;               // mass of the initial particles (free_space: its growth 2 d kappa M t)
};

// What a reference gives for one row.
struct ReferenceRow {
  std::vector<double> values;             // one per Reference::columns(), in order
  double reference = 0.0;                 // the curve's value (Crank's M/M_inf, the reference second moment, amplitude)
  std::optional<double> error_mass_blob;  // has_mass_blob_error(): M_rho / M_inf minus the mass reference
};

// One entry a reference adds to a run's summary: a number (not finite: none)
// or a count.
struct ReferenceEntry {
  std::string key;
  std::variant<double, std::int64_t> value;
};

// A reference's checkpoint state: named lists of numbers (read back exactly).
using ReferenceState = std::map<std::string, std::vector<double>>;

class Reference {
 public:
  virtual ~Reference() = default;
  virtual std::string name() const = 0;                  // as make_reference takes it
  virtual std::vector<std::string> columns() const = 0;  // the series columns of ReferenceRow::values
  // A column error_mass_blob (M_rho / M_inf against the mass reference).
  virtual bool has_mass_blob_error() const { return false; }
  // Whether row() reads ReferenceSample::particles (all of them: a
  // distributed run gathers them for it).
  virtual bool uses_particles() const { return false; }

  // The row of sample.t: rows come in time order, the first at the run's
  // start (free_space and cosine_mode take their initial values from it).
  // Updates the statistics.
  virtual ReferenceRow row(const ReferenceSample& sample) = 0;

  // The statistics per measured quantity over the rows so far.
  virtual std::vector<ErrorStatistics> statistics() const = 0;
  // M_rho / M_inf against the mass reference (has_mass_blob_error()).
  virtual std::optional<ErrorStatistics> mass_blob_statistics() const { return std::nullopt; }
  // The entries of its own (free_space: growth_ratio; cosine_mode: the fitted rate).
  virtual std::vector<ReferenceEntry> summary() const { return {}; }

  // Checkpoint: after load_state(save_state()) the next rows are the same bit for bit.
  virtual ReferenceState save_state() const = 0;
  virtual void load_state(const ReferenceState& state) = 0;  // throws InvalidArgument naming what is wrong

 protected:
  // state[key], which must hold `size` numbers (any number for size = npos).
  static const std::vector<double>& state_entry(const ReferenceState& state, const std::string& key,
                                                std::size_t size = static_cast<std::size_t>(-1));
};

// What the Crank references read from the domain and the ids of its
// Dirichlet patches, filled where
// `setup` leaves it unset (radius and length 0, J_inf empty; set dim, center
// and M_inf first):
// - crank_sphere: R is the ball's; J_inf = (3/5) M_inf R^2 where the domain is
//   a 3-D ball of that radius and `center` is its centre;
// - crank_slab on a box with exactly one Dirichlet face (and no length given):
//   L is the box's extent across that face, the held face is slab_axis /
//   slab_held_at_hi, [lo, hi] the box, and J_inf = M_inf times the box's mean
//   squared distance to `center`.
// Other names are left as they are.
void complete_reference_geometry(const std::string& name, const Domain& domain,
                                 const std::vector<int>& dirichlet_patches, ReferenceSetup& setup);

// The registered references, in registration order:
// crank_sphere, crank_slab, free_space, cosine_mode.
std::vector<std::string> reference_names();
// The reference `name` set up from `setup`; throws InvalidArgument for an
// unknown name or a setup it cannot use (e.g. crank_sphere without a radius).
std::unique_ptr<Reference> make_reference(const std::string& name, const ReferenceSetup& setup);

}  // namespace otfp
