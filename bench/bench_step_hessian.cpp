// The implicit step's Hessian, probed on small periodic sets (docs/stepper.md,
// "The step's Hessian"). Dense linear algebra: a research tool for a few
// hundred particles, not a benchmark of the library's speed.
//
//   otfp_bench_step_hessian spectrum DIM N BETA_FACTOR LATTICE [JITTER] [KERNEL_TOL]
//     H = (dt/m) D^2 F at x = x^k (the Hessian in the stepper's scaled
//     unknowns, transport part = I) by central differences of the exact
//     gradient, at dt = 1, 10 and 100 x dr^2 / kappa; prints its smallest
//     and largest eigenvalue. LATTICE: N^DIM particles on a square/cubic
//     lattice ("square") or with every other row shifted by half a spacing
//     ("shifted"), or (3-D) N^3 cubic cells of 2 ("bcc") or 4 ("fcc")
//     sites; each moved by up to JITTER x dr at random (fixed seed), in the
//     periodic unit cube; dr = n^(-1/DIM), beta = BETA_FACTOR / dr^2.
//   otfp_bench_step_hessian precondition JITTER [SIGMA_FACTOR] [C] [SETTLE_STEPS] [AMP]
//     One implicit step of the 2-D shifted lattice (16 x 16, beta dr^2 = 2,
//     JITTER as above) by Ceres' L-BFGS to the stepper's absolute tolerance
//     (max displacement residual 1e-3 s), plain and with the unknowns changed
//     to z = z^k + M^(-1/2) w, M = I + C (dt / dt_explicit) K, K the spring
//     network of x^k with weights exp(-|x_p - x_q|^2 / (2 sigma^2)),
//     sigma = SIGMA_FACTOR x s (defaults 0.5 and 137: the best pair for the
//     unjittered lattice). With SETTLE_STEPS > 0 the jittered lattice first
//     takes that many steps at 1000 x dt_explicit (a settled arrangement, a
//     local minimum of the entropy), then every particle moves by
//     AMP dr sin(2 pi x) along x (a density mode to relax). Prints
//     evaluations and the minimum found.
#include <Eigen/Dense>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "otfp/functional.hpp"
#include "otfp/geometry.hpp"
#include "otfp/minimizer.hpp"
#include "otfp/neighbor_list.hpp"

using namespace otfp;
using Eigen::MatrixXd;
using Eigen::VectorXd;

namespace {

struct Lattice {
  int dim = 2;
  double dr = 0.0, s = 0.0, m = 0.0;
  Periodicity per;
  std::vector<Vec3> x;
  std::size_t size() const { return x.size(); }
};

// N^dim sites of a square/cubic lattice ("square"), the same with every
// other row shifted by half a spacing ("shifted"), or in 3-D N^3 cubic cells
// of 2 ("bcc") or 4 ("fcc") sites; dr = n^(-1/dim) in the unit cube.
Lattice make_lattice(int dim, int N, double beta_factor, const std::string& kind, double jitter) {
  Lattice l;
  l.dim = dim;
  l.per = Periodicity::from_domain(*make_periodic_box(dim, Vec3::Zero(), Vec3(1.0, 1.0, dim == 3 ? 1.0 : 0.0)));
  std::vector<Vec3> basis{Vec3(0.5, 0.5, 0.5)};
  if (kind == "bcc") basis = {Vec3(0.25, 0.25, 0.25), Vec3(0.75, 0.75, 0.75)};
  if (kind == "fcc")
    basis = {Vec3(0.25, 0.25, 0.25), Vec3(0.75, 0.75, 0.25), Vec3(0.75, 0.25, 0.75), Vec3(0.25, 0.75, 0.75)};
  const double a = 1.0 / N;
  for (int i = 0; i < N; ++i)
    for (int j = 0; j < N; ++j)
      for (int k = 0; k < (dim == 3 ? N : 1); ++k)
        for (const Vec3& b : basis) {
          Vec3 y = a * (Vec3(i, j, k) + b);
          if (kind == "shifted") y[0] += 0.5 * a * (j % 2);
          if (dim == 2) y[2] = 0.0;
          l.x.push_back(y);
        }
  l.dr = std::pow(1.0 / static_cast<double>(l.size()), 1.0 / dim);
  l.s = l.dr / std::sqrt(beta_factor);
  std::mt19937_64 gen(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (Vec3& y : l.x) {
    for (int c = 0; c < dim; ++c) y[c] += jitter * l.dr * u(gen);
    y = l.per.wrap(y);
  }
  l.m = 1.0 / static_cast<double>(l.size());
  return l;
}

VectorXd flat(const std::vector<Vec3>& v, int dim) {
  VectorXd out(static_cast<Eigen::Index>(v.size()) * dim);
  for (std::size_t p = 0; p < v.size(); ++p)
    for (int a = 0; a < dim; ++a) out[static_cast<Eigen::Index>(p) * dim + a] = v[p][a];
  return out;
}

// (dt/m) D^2 F at x^k by central differences of the exact gradient.
MatrixXd scaled_hessian(Functional& f, const Lattice& l, double dt) {
  const auto D = static_cast<Eigen::Index>(l.size()) * l.dim;
  const std::vector<double> s(l.size(), l.s);
  MatrixXd H(D, D);
  Gradient g;
  g.resize(l.size(), false);
  const double h = 1e-5 * l.dr;
  for (Eigen::Index c = 0; c < D; ++c) {
    std::vector<Vec3> xp = l.x, xm = l.x;
    xp[static_cast<std::size_t>(c / l.dim)][static_cast<int>(c % l.dim)] += h;
    xm[static_cast<std::size_t>(c / l.dim)][static_cast<int>(c % l.dim)] -= h;
    f.evaluate(xp, s, &g);
    const VectorXd gp = flat(g.x, l.dim);
    f.evaluate(xm, s, &g);
    H.col(c) = (gp - flat(g.x, l.dim)) * (dt / l.m / (2.0 * h));
  }
  return 0.5 * (H + H.transpose());
}

int spectrum(int argc, char** argv) {
  if (argc < 6) return 2;
  const int dim = std::atoi(argv[2]), N = std::atoi(argv[3]);
  const double bf = std::atof(argv[4]);
  const std::string kind = argv[5];
  const double jitter = argc > 6 ? std::atof(argv[6]) : 0.0;
  const double tol = argc > 7 ? std::atof(argv[7]) : 1e-8;
  const Lattice l = make_lattice(dim, N, bf, kind, jitter);
  for (double factor : {1.0, 10.0, 100.0}) {
    FunctionalOptions fo;
    fo.dt = factor * l.dr * l.dr;
    fo.neighbor.kernel_tolerance = tol;
    Functional f(dim, fo, Barrier{}, l.per);
    f.set_reference(l.x, std::vector<double>(l.size(), l.s), std::vector<double>(l.size(), l.m));
    const VectorXd ev = Eigen::SelfAdjointEigenSolver<MatrixXd>(scaled_hessian(f, l, fo.dt), Eigen::EigenvaluesOnly)
                            .eigenvalues();
    std::printf("d = %d, n = %zu, beta dr^2 = %g, %s, jitter %g: dt = %5gx: eigenvalues of H in [%.4g, %.4g]\n", dim,
                l.size(), bf, kind.c_str(), jitter, factor, ev.minCoeff(), ev.maxCoeff());
  }
  return 0;
}

// The step's objective in the unknowns w: z = z0 + T w (T = I: z = w), z = x / sqrt(dt/m).
class Step final : public Objective {
 public:
  Step(Functional& f, const Lattice& l, double dt, const MatrixXd* T, const MatrixXd* T_inv)
      : f_(f), l_(l), sc_(std::sqrt(dt / l.m)), T_(T), T_inv_(T_inv), z0_(flat(l.x, l.dim) / sc_) {}
  std::size_t num_variables() const override { return l_.size() * static_cast<std::size_t>(l_.dim); }
  VectorXd start() const { return T_ ? VectorXd::Zero(z0_.size()) : z0_; }
  bool evaluate(const double* w, double* value, double* gradient) override {
    const VectorXd z = to_z(w);
    std::vector<Vec3> x(l_.size(), Vec3::Zero());
    for (std::size_t p = 0; p < l_.size(); ++p)
      for (int a = 0; a < l_.dim; ++a) x[p][a] = sc_ * z[static_cast<Eigen::Index>(p) * l_.dim + a];
    Gradient g;
    g.resize(l_.size(), false);
    *value = f_.evaluate(x, std::vector<double>(l_.size(), l_.s), gradient ? &g : nullptr).total();
    if (gradient) {
      const VectorXd gz = sc_ * flat(g.x, l_.dim);
      Eigen::Map<VectorXd>(gradient, gz.size()) = T_ ? VectorXd(*T_ * gz) : gz;  // T symmetric
    }
    return std::isfinite(*value);
  }
  // The largest displacement residual |dt/m dF/dx_p| = sc |g_z,p|, g_z = T^-1 g_w.
  double stopping_measure(const double*, const double* gradient) const override {
    const Eigen::Map<const VectorXd> gw(gradient, static_cast<Eigen::Index>(num_variables()));
    const VectorXd gz = T_inv_ ? VectorXd(*T_inv_ * gw) : VectorXd(gw);
    double worst = 0.0;
    for (std::size_t p = 0; p < l_.size(); ++p)
      worst = std::max(worst, sc_ * gz.segment(static_cast<Eigen::Index>(p) * l_.dim, l_.dim).norm());
    return worst;
  }

 private:
  VectorXd to_z(const double* w) const {
    const Eigen::Map<const VectorXd> v(w, static_cast<Eigen::Index>(num_variables()));
    return T_ ? VectorXd(z0_ + *T_ * v) : VectorXd(v);
  }
  Functional& f_;
  const Lattice& l_;
  double sc_;
  const MatrixXd *T_, *T_inv_;
  VectorXd z0_;
};

int precondition(int argc, char** argv) {
  if (argc < 3) return 2;
  const double jitter = std::atof(argv[2]);
  const double sigma_factor = argc > 3 ? std::atof(argv[3]) : 0.5, c = argc > 4 ? std::atof(argv[4]) : 137.0;
  const int settle_steps = argc > 5 ? std::atoi(argv[5]) : 0;
  const double amp = argc > 6 ? std::atof(argv[6]) : 0.0;
  Lattice l = make_lattice(2, 16, 2.0, "shifted", jitter);
  // Settled: implicit steps at 1000 x dt_explicit (each from the last), so
  // that x^k is a local minimum of the entropy; then a cosine mode of
  // amplitude amp x dr along x gives the step something physical to do.
  for (int k = 0; k < settle_steps; ++k) {
    FunctionalOptions fo;
    fo.dt = 1000.0 * l.dr * l.dr;
    Functional f(2, fo, Barrier{}, l.per);
    f.set_reference(l.x, std::vector<double>(l.size(), l.s), std::vector<double>(l.size(), l.m));
    Step step(f, l, fo.dt, nullptr, nullptr);
    const VectorXd w0 = step.start();
    std::vector<double> w(w0.data(), w0.data() + w0.size());
    MinimizerOptions mo;
    mo.gradient_tolerance = 1e-6 * l.s;
    minimize(step, w, mo);
    const double sc = std::sqrt(fo.dt / l.m);
    for (std::size_t p = 0; p < l.size(); ++p)
      l.x[p] = l.per.wrap(Vec3(sc * w[2 * p], sc * w[2 * p + 1], 0.0));
  }
  for (Vec3& y : l.x) y = l.per.wrap(y + Vec3(amp * l.dr * std::sin(2.0 * std::numbers::pi * y[0]), 0.0, 0.0));
  const auto n = static_cast<Eigen::Index>(l.size()), D = 2 * n;
  const double sigma = sigma_factor * l.s;
  MatrixXd K = MatrixXd::Zero(D, D);  // spring network of x^k
  for (Eigen::Index p = 0; p < n; ++p)
    for (Eigen::Index q = 0; q < n; ++q) {
      if (p == q) continue;
      const Vec3 d = l.per.displacement(l.x[static_cast<std::size_t>(p)], l.x[static_cast<std::size_t>(q)]);
      const double w = std::exp(-d.squaredNorm() / (2.0 * sigma * sigma));
      const Eigen::Matrix2d e = w * d.head<2>() * d.head<2>().transpose() / d.squaredNorm();
      K.block<2, 2>(2 * p, 2 * p) += e;
      K.block<2, 2>(2 * p, 2 * q) -= e;
    }
  for (double factor : {1.0, 10.0, 100.0}) {
    FunctionalOptions fo;
    fo.dt = factor * l.dr * l.dr;
    Functional f(2, fo, Barrier{}, l.per);
    f.set_reference(l.x, std::vector<double>(l.size(), l.s), std::vector<double>(l.size(), l.m));
    const Eigen::SelfAdjointEigenSolver<MatrixXd> es(MatrixXd::Identity(D, D) + c * factor * K);
    const MatrixXd& V = es.eigenvectors();
    const MatrixXd T = V * es.eigenvalues().cwiseSqrt().cwiseInverse().asDiagonal() * V.transpose();
    const MatrixXd T_inv = V * es.eigenvalues().cwiseSqrt().asDiagonal() * V.transpose();
    for (bool pre : {false, true}) {
      Step step(f, l, fo.dt, pre ? &T : nullptr, pre ? &T_inv : nullptr);
      const VectorXd w0 = step.start();
      std::vector<double> w(w0.data(), w0.data() + w0.size());
      MinimizerOptions mo;
      mo.gradient_tolerance = 1e-3 * l.s;
      const MinimizerSummary ms = minimize(step, w, mo);
      std::printf("jitter %g, settled %d, mode %g: dt = %5gx, %-14s: %4d evaluations, F = %.10f (%s)\n", jitter,
                  settle_steps, amp, factor,
                  pre ? "spring network" : "plain", ms.evaluations, ms.final_value, to_string(ms.reason).c_str());
    }
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string mode = argc > 1 ? argv[1] : "";
  int rc = 2;
  if (mode == "spectrum") rc = spectrum(argc, argv);
  if (mode == "precondition") rc = precondition(argc, argv);
  if (rc == 2)
    std::fprintf(stderr,
                 "usage: %s spectrum DIM N BETA_FACTOR square|shifted|bcc|fcc [JITTER] [KERNEL_TOL]\n"
                 "       %s precondition JITTER [SIGMA_FACTOR] [C] [SETTLE_STEPS] [AMP]\n",
                 argv[0], argv[0]);
  return rc;
}
