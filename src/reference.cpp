// Error statistics, the decay-rate fit, and the table of references.
#include "otfp/reference.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace otfp {

// ---- The references, one file each. Adding one: its file and two lines here.

std::unique_ptr<Reference> make_crank_sphere_reference(const ReferenceSetup& setup);  // reference_crank.cpp
std::unique_ptr<Reference> make_crank_slab_reference(const ReferenceSetup& setup);    // reference_crank.cpp
std::unique_ptr<Reference> make_free_space_reference(const ReferenceSetup& setup);    // reference_free_space.cpp
std::unique_ptr<Reference> make_cosine_mode_reference(const ReferenceSetup& setup);   // reference_cosine_mode.cpp

namespace {
struct Registered {
  const char* name;
  std::unique_ptr<Reference> (*make)(const ReferenceSetup&);
};
const Registered kReferences[] = {
    {"crank_sphere", make_crank_sphere_reference},
    {"crank_slab", make_crank_slab_reference},
    {"free_space", make_free_space_reference},
    {"cosine_mode", make_cosine_mode_reference},
};
}  // namespace

std::vector<std::string> reference_names() {
  std::vector<std::string> names;
  for (const Registered& r : kReferences) names.emplace_back(r.name);
  return names;
}

std::unique_ptr<Reference> make_reference(const std::string& name, const ReferenceSetup& setup) {
  for (const Registered& r : kReferences)
    if (name == r.name) return r.make(setup);
  std::string known;
  for (const Registered& r : kReferences) known += (known.empty() ? "" : ", ") + std::string(r.name);
  require(false, "reference", name, "unknown (known: " + known + ")");
  return nullptr;
}

const std::vector<double>& Reference::state_entry(const ReferenceState& state, const std::string& key,
                                                  std::size_t size) {
  const auto it = state.find(key);
  require(it != state.end(), "reference state", key, "missing");
  if (size != static_cast<std::size_t>(-1))
    require(it->second.size() == size, "reference state " + key + " size", static_cast<double>(it->second.size()),
            "must be " + std::to_string(size));
  return it->second;
}

// ---- ErrorStatistics

ErrorStatistics::ErrorStatistics(std::string measured, double scale, std::string scale_rule)
    : measured_(std::move(measured)), scale_rule_(std::move(scale_rule)), scale_(scale) {}

double ErrorStatistics::add(double t, double m, double r) {
  const double e = (m - r) / scale_;
  if (started_) {
    const double h = t - t_prev_;
    // |e| is piecewise linear: integrate exactly across a sign change.
    if (e * e_prev_ >= 0.0)
      l1_time_ += 0.5 * (std::abs(e) + std::abs(e_prev_)) * h;
    else
      l1_time_ += 0.5 * (e * e + e_prev_ * e_prev_) / (std::abs(e) + std::abs(e_prev_)) * h;
    l1_measured_ += 0.5 * (m + m_prev_) * h;
    l1_reference_ += 0.5 * (r + r_prev_) * h;
  } else {
    t_first_ = t;
  }
  max_abs_ = std::max(max_abs_, std::abs(e));
  final_error_ = e;
  t_prev_ = t;
  e_prev_ = e;
  m_prev_ = m;
  r_prev_ = r;
  started_ = true;
  return e;
}

double ErrorStatistics::mean_abs_error() const {
  const double span = t_prev_ - t_first_;
  return span > 0.0 ? l1_time_ / span : 0.0;
}

double ErrorStatistics::l1_norm_relative_error() const {
  return l1_reference_ != 0.0 ? (l1_measured_ - l1_reference_) / l1_reference_ : 0.0;
}

std::vector<double> ErrorStatistics::state() const {
  return {scale_,  max_abs_, l1_time_, final_error_, l1_measured_, l1_reference_,
          t_prev_, e_prev_,  m_prev_,  r_prev_,      t_first_,     started_ ? 1.0 : 0.0};
}

void ErrorStatistics::load_state(const std::vector<double>& s) {
  require(s.size() == kStateSize, "error statistics state size", static_cast<double>(s.size()),
          "must be " + std::to_string(kStateSize));
  double* fields[] = {&scale_,  &max_abs_, &l1_time_, &final_error_, &l1_measured_, &l1_reference_,
                      &t_prev_, &e_prev_,  &m_prev_,  &r_prev_,      &t_first_};
  for (std::size_t i = 0; i + 1 < kStateSize; ++i) *fields[i] = s[i];
  started_ = s[kStateSize - 1] != 0.0;
}

// ---- Decay-rate fit

double decay_rate_fit(const std::vector<double>& t, const std::vector<double>& a) {
  require(t.size() == a.size(), "decay_rate_fit: samples of a", static_cast<double>(a.size()),
          "must be as many as the times (" + std::to_string(t.size()) + ")");
  if (t.size() < 3) return std::numeric_limits<double>::quiet_NaN();
  double st = 0.0, sy = 0.0, stt = 0.0, sty = 0.0;
  for (std::size_t i = 0; i < t.size(); ++i) {
    require(a[i] > 0.0, "decay_rate_fit: a[" + std::to_string(i) + "]", a[i], "must be > 0");
    const double y = std::log(a[i]);
    st += t[i];
    sy += y;
    stt += t[i] * t[i];
    sty += t[i] * y;
  }
  const double m = static_cast<double>(t.size());
  return -(m * sty - st * sy) / (m * stt - st * st);
}

}  // namespace otfp
