#pragma once
// The discrete energy-dissipation functional (28) and its exact gradient.
//
//   F(x, s) = T(x, s) + E(x, s) + B(x)
//   T = sum_p m_p / (2 dt) (|x_p - x_p^k|^2 + c_w (s_p - s_p^k)^2)   transport
//   E = kappa sum_p m_p log(rho(x_p) / rho_ref)                       entropy
//   B = sum_p m_p Psi(x_p)                                            barrier
//   rho(y) = sum_q m_q (beta_q/pi)^(d/2) exp(-beta_q |y - x_q|^2)     (29)
//
// Widths are s = beta^-1/2; gradients are with respect to x and s. Each term
// has its own value and gradient; Functional sums them.
#include <cstdint>
#include <vector>

#include "otfp/barrier.hpp"
#include "otfp/images.hpp"
#include "otfp/neighbor_list.hpp"
#include "otfp/particles.hpp"
#include "otfp/enums.hpp"

namespace otfp {

double width_metric_coefficient(WidthMetric metric, int dim);

// Gradient storage: position gradient per particle and, optionally, width gradient.
struct Gradient {
  std::vector<Vec3> x;
  std::vector<double> s;
  void resize(std::size_t n, bool with_widths);
  void set_zero();
};

struct FunctionalParts {
  double transport = 0.0;
  double entropy = 0.0;
  double barrier = 0.0;
  double total() const { return transport + entropy + barrier; }
};

// Transport term T: quadratic in x and s.
class TransportTerm {
 public:
  TransportTerm(double dt, double c_w);
  // x_ref, s_ref: the configuration at t_k. grad may be null. weights: a
  // factor a_p per particle (m_p -> a_p m_p; empty: all 1), used by the
  // variational BDF2 step (docs/stepper.md).
  double evaluate(const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m,
                  const std::vector<Vec3>& x_ref, const std::vector<double>& s_ref, Gradient* grad,
                  const std::vector<double>& weights = {}) const;
  double dt() const { return dt_; }
  double c_w() const { return c_w_; }

 private:
  double dt_, c_w_;
};

// Entropy term E with the exact gradient in two pair sweeps (docs/method_notes.md#exact-gradient):
// the first gives rho_p and grad rho, the second gathers term 2 with the 1/rho_p factors.
class EntropyTerm {
 public:
  EntropyTerm(int dim, double kappa, double rho_ref);
  // The neighbour list must be valid for (x, s). grad may be null; grad->s is
  // filled only if it has the right size. Only the first `rows` blobs carry an
  // entropy term (all if rows > size); the rest (image blobs) only add to rho,
  // and their gradient is that of their position as a kernel centre (term 2).
  double evaluate(const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m,
                  const NeighborList& list, Gradient* grad, std::size_t rows = static_cast<std::size_t>(-1));
  // The same with the plain O(n^2) sum over all pairs (reference; periodic via minimum image).
  double evaluate_all_pairs(const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m,
                            const Periodicity& periodicity, Gradient* grad,
                            std::size_t rows = static_cast<std::size_t>(-1));
  // rho_p and grad rho(x_p) from the last evaluation.
  const std::vector<double>& density() const { return rho_; }
  const std::vector<Vec3>& density_gradient() const { return grad_rho_; }
  std::uint64_t pair_evaluations() const { return pair_evals_; }
  double kappa() const { return kappa_; }
  double rho_ref() const { return rho_ref_; }
  int dim() const { return dim_; }

 private:
  void prepare(const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<double>& m);
  double value_from_density(const std::vector<double>& m, std::size_t rows) const;
  int dim_;
  double kappa_, rho_ref_;
  std::vector<double> rho_, beta_, mc_, a_, t0_, t1_, t2_, t3_, t4_;
  std::vector<double> xyzb_, xyza_;  // packed records of the pair sweeps (src/pair_kernels.hpp)
  std::vector<Vec3> grad_rho_;
  std::uint64_t pair_evals_ = 0;
};

// Barrier term B = sum_p m_p Psi(x_p).
class BarrierTerm {
 public:
  explicit BarrierTerm(Barrier barrier = {});
  double evaluate(const std::vector<Vec3>& x, const std::vector<double>& m, Gradient* grad) const;
  const Barrier& barrier() const { return barrier_; }
  Barrier& barrier() { return barrier_; }

 private:
  Barrier barrier_;
};

struct FunctionalOptions {
  double dt = 1e-3;                             // time step (> 0)
  double kappa = 1.0;                           // diffusivity (> 0)
  double rho_ref = 1.0;                         // reference density of the entropy (> 0)
  WidthMetric width_metric = WidthMetric::AsPrinted;  // c_w = 1 (default) or d/2
  bool optimise_widths = false;                 // gradient with respect to s as well
  NeighborOptions neighbor;                     // cut-off tolerance and skin
  double width_skin = 0.0;                      // optimise_widths: list built for widths s (1 + width_skin), >= 0
  void validate() const;                        // throws InvalidArgument naming the field
};

// F = T + E + B for one diffusive step from the reference state (x^k, s^k).
class Functional {
 public:
  Functional(int dim, FunctionalOptions options, Barrier barrier = {}, Periodicity periodicity = {});

  // Sets the reference configuration (x^k, s^k) and the masses, and
  // optionally a transport weight a_p per particle: T = sum_p a_p m_p/(2 dt) |..|^2
  // (empty: a_p = 1, the implicit Euler step (28)).
  void set_reference(const std::vector<Vec3>& x_ref, const std::vector<double>& s_ref, const std::vector<double>& m,
                     std::vector<double> transport_weights = {});
  // Value of F at (x, s) and, if grad != nullptr, its gradient. Rebuilds the
  // neighbour list when needed (counted in list().build_count()).
  FunctionalParts evaluate(const std::vector<Vec3>& x, const std::vector<double>& s, Gradient* grad);
  // Same, by the O(n^2) sweep without a neighbour list (for tests).
  FunctionalParts evaluate_all_pairs(const std::vector<Vec3>& x, const std::vector<double>& s, Gradient* grad);
  // Explicit velocity of (27) plus barrier: v_r = -(kappa grad rho(x_r)/rho(x_r) + grad Psi(x_r)).
  void explicit_velocity(const std::vector<Vec3>& x, const std::vector<double>& s, std::vector<Vec3>& v);
  // Builds the neighbour list for (x, s) now (and chooses the image blobs when walls are mirrored).
  void rebuild_list(const std::vector<Vec3>& x, const std::vector<double>& s);

  // Image blobs at no-flux walls (images.hpp): rho includes the images of the
  // blobs near the walls; the list then covers particles and images.
  void set_images(WallImages images);
  const WallImages& images() const { return images_; }

  const FunctionalOptions& options() const { return options_; }
  void set_dt(double dt);
  int dim() const { return dim_; }
  const TransportTerm& transport() const { return transport_; }
  const EntropyTerm& entropy() const { return entropy_; }
  const BarrierTerm& barrier() const { return barrier_; }
  BarrierTerm& barrier() { return barrier_; }
  const NeighborList& list() const { return list_; }
  NeighborList& list() { return list_; }
  const Periodicity& periodicity() const { return per_; }
  const std::vector<double>& masses() const { return m_; }

 private:
  int dim_;
  FunctionalOptions options_;
  TransportTerm transport_;
  EntropyTerm entropy_;
  BarrierTerm barrier_;
  Periodicity per_;
  NeighborList list_;
  std::vector<Vec3> x_ref_;
  std::vector<double> s_ref_, m_, weights_;
  Gradient scratch_;
  // Image blobs: the extended arrays (particles first, then images) and the
  // number of particles the list was built for.
  WallImages images_;
  std::vector<Vec3> x_ext_, grad_image_;
  std::vector<double> s_ext_, m_ext_, reach_;
  std::size_t images_built_for_ = 0;
  void extend(const std::vector<Vec3>& x, const std::vector<double>& s);
  void select_images(const std::vector<Vec3>& x, const std::vector<double>& s);  // chooses images, then extend()
  void ensure_list(const std::vector<Vec3>& x, const std::vector<double>& s);
  // The widths the list is built for: s itself, or s (1 + width_skin) when
  // widths are unknowns (width growth within that margin needs no rebuild).
  const std::vector<double>& list_widths(const std::vector<double>& s);
  bool inflates_widths() const { return options_.optimise_widths && options_.width_skin > 0.0; }
  std::vector<double> s_list_;
  FunctionalParts evaluate_impl(const std::vector<Vec3>& x, const std::vector<double>& s, Gradient* grad,
                                bool all_pairs);
};

}  // namespace otfp
