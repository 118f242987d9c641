#include "otfp/images.hpp"

#include "otfp/geometry.hpp"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <exception>
#include <limits>
#include <string>

namespace otfp {

namespace {

class PlaneWall final : public MirrorWall {
 public:
  PlaneWall(const Vec3& point, const Vec3& normal) : p_(point), n_(normal.normalized()) {}
  double distance(const Vec3& x) const override { return (x - p_).dot(n_); }
  // distance() spelt out per component, in Eigen's order of the dot product
  // ((0 + 1) + 2; the same bits, tested), so that the loop vectorises.
  void distances(const Vec3* x, std::size_t n, double* d) const override {
    const double p0 = p_[0], p1 = p_[1], p2 = p_[2], n0 = n_[0], n1 = n_[1], n2 = n_[2];
    const double* xs = x->data();
    for (std::size_t i = 0; i < n; ++i)
      d[i] = ((xs[3 * i] - p0) * n0 + (xs[3 * i + 1] - p1) * n1) + (xs[3 * i + 2] - p2) * n2;
  }
  bool keeps_images_farther() const override { return true; }
  // y = x - 2 ((x - p) . n) n; J = I - 2 n n^T.
  Vec3 reflect(const Vec3& x, Mat3* jac) const override {
    if (jac) *jac = Mat3::Identity() - 2.0 * n_ * n_.transpose();
    return x - 2.0 * distance(x) * n_;
  }

 private:
  Vec3 p_, n_;
};

// Sphere and cylinder side share y = x + 2 (R - r) n with r = |q|, n = q / r,
// q the offset from the centre (or from the axis, tangential part removed by P).
// J = I - 2 n n^T + 2 (R - r) / r (P - n n^T), P = I (sphere) or I - u u^T (cylinder).
// The same map serves an obstacle (domain outside): only the distance's sign differs.
class RoundWall final : public MirrorWall {
 public:
  RoundWall(int dim, const Vec3& c, double radius, const Vec3& axis, bool cylinder, WallSide side)
      : dim_(dim), c_(c), r_(radius), u_(axis.normalized()), cylinder_(cylinder),
        sign_(side == WallSide::DomainInside ? 1.0 : -1.0) {
    for (int k = dim_; k < 3; ++k) c_[k] = 0.0;
  }
  double distance(const Vec3& x) const override { return sign_ * (offset(x).norm() - r_); }
  // Inside (r_p, r_q <= R, angle a): |p - y_q|^2 - |p - q|^2 = 4 (R - r_q)(R - r_p cos a) >= 0.
  bool keeps_images_farther() const override { return sign_ > 0.0; }
  // distance() spelt out per component (Eigen's order of the sums, the same
  // bits, tested): branch-free loops for the squared distance from the
  // centre or axis, then Eigen's packet sqrt (std::sqrt keeps a scalar
  // errno path that stops the compiler from vectorising; both round exactly).
  void distances(const Vec3* x, std::size_t n, double* d) const override {
    const double c0 = c_[0], c1 = c_[1], c2 = c_[2];
    const double* xs = x->data();
    if (cylinder_) {
      const double u0 = u_[0], u1 = u_[1], u2 = u_[2];
      for (std::size_t i = 0; i < n; ++i) {
        double q0 = xs[3 * i] - c0, q1 = xs[3 * i + 1] - c1, q2 = xs[3 * i + 2] - c2;
        const double a = (q0 * u0 + q1 * u1) + q2 * u2;
        q0 -= a * u0;
        q1 -= a * u1;
        q2 -= a * u2;
        d[i] = (q0 * q0 + q1 * q1) + q2 * q2;
      }
    } else if (dim_ == 3) {
      for (std::size_t i = 0; i < n; ++i) {
        const double q0 = xs[3 * i] - c0, q1 = xs[3 * i + 1] - c1, q2 = xs[3 * i + 2] - c2;
        d[i] = (q0 * q0 + q1 * q1) + q2 * q2;
      }
    } else if (dim_ == 2) {
      for (std::size_t i = 0; i < n; ++i) {
        const double q0 = xs[3 * i] - c0, q1 = xs[3 * i + 1] - c1;
        d[i] = (q0 * q0 + q1 * q1) + 0.0;  // + 0.0: the unused axis, as in norm()
      }
    } else {
      for (std::size_t i = 0; i < n; ++i) {
        const double q0 = xs[3 * i] - c0;
        d[i] = (q0 * q0 + 0.0) + 0.0;
      }
    }
    Eigen::Map<Eigen::ArrayXd> dd(d, static_cast<Eigen::Index>(n));
    dd = sign_ * (dd.sqrt() - r_);
  }
  Vec3 reflect(const Vec3& x, Mat3* jac) const override {
    const Vec3 q = offset(x);
    const double r = q.norm();
    // At the centre (axis) the normal is undefined; such a point is a radius
    // away from the wall and never within reach of it unless the reach exceeds R.
    const Vec3 n = r > 0.0 ? Vec3(q / r) : Vec3(cylinder_ ? any_normal() : Vec3::UnitX());
    if (jac) {
      Mat3 proj = Mat3::Identity();
      if (cylinder_) proj -= u_ * u_.transpose();
      for (int k = dim_; k < 3; ++k) proj(k, k) = 0.0;  // unused axes stay zero
      const Mat3 nn = n * n.transpose();
      *jac = Mat3::Identity() - 2.0 * nn + (r > 0.0 ? 2.0 * (r_ - r) / r : 0.0) * (proj - nn);
    }
    return x + 2.0 * (r_ - r) * n;
  }

 private:
  Vec3 offset(const Vec3& x) const {
    Vec3 q = x - c_;
    for (int k = dim_; k < 3; ++k) q[k] = 0.0;
    if (cylinder_) q -= q.dot(u_) * u_;
    return q;
  }
  Vec3 any_normal() const {
    int e = 0;
    for (int k = 1; k < 3; ++k)
      if (std::abs(u_[k]) < std::abs(u_[e])) e = k;
    const Vec3 ek = Vec3::Unit(e);
    return (ek - ek.dot(u_) * u_).normalized();
  }
  int dim_;
  Vec3 c_;
  double r_;
  Vec3 u_;
  bool cylinder_;
  double sign_;  // +1: the domain is inside the round wall, -1: outside (an obstacle)
};

// Particles per block of WallImages::select, whose distances to all walls are
// computed together (6 walls: 12 KiB), and the unit the threads share out.
constexpr std::size_t kSelectBlock = 256;
// Blocks below which select() runs on one thread: 4096 particles take about
// 0.1 ms, and waking a team costs microseconds on a quiet machine but up to a
// time slice when the threads must wait for a shared core.
constexpr std::size_t kSelectParallelBlocks = 16;
// Nearby walls whose subsets are composed (2^16 subsets at most).
constexpr std::size_t kMaxNearWalls = 16;

}  // namespace

void MirrorWall::distances(const Vec3* x, std::size_t n, double* d) const {
  for (std::size_t i = 0; i < n; ++i) d[i] = distance(x[i]);
}

MirrorWallPtr make_plane_wall(const Vec3& point, const Vec3& outward_normal) {
  require(point.allFinite(), "plane wall point", point.norm(), "must be finite");
  require(outward_normal.allFinite() && outward_normal.norm() > 0.0, "plane wall normal", outward_normal.norm(),
          "must be finite and nonzero");
  return std::make_shared<PlaneWall>(point, outward_normal);
}

MirrorWallPtr make_sphere_wall(int dim, const Vec3& center, double radius, WallSide side) {
  require(dim >= 1 && dim <= 3, "dim", dim, "must be 1, 2 or 3");
  require(center.allFinite(), "sphere wall center", center.norm(), "must be finite");
  require(std::isfinite(radius) && radius > 0.0, "sphere wall radius", radius, "must be finite and > 0");
  return std::make_shared<RoundWall>(dim, center, radius, Vec3::UnitX(), false, side);
}

MirrorWallPtr make_cylinder_wall(const Vec3& axis_point, const Vec3& axis, double radius, WallSide side) {
  require(axis_point.allFinite(), "cylinder wall axis point", axis_point.norm(), "must be finite");
  require(axis.allFinite() && axis.norm() > 0.0, "cylinder wall axis", axis.norm(), "must be finite and nonzero");
  require(std::isfinite(radius) && radius > 0.0, "cylinder wall radius", radius, "must be finite and > 0");
  return std::make_shared<RoundWall>(3, axis_point, radius, axis, true, side);
}

std::vector<MirrorWallPtr> mirror_walls(const Domain& domain, const std::vector<int>& open_patches) {
  std::vector<MirrorWallPtr> all, closed;
  std::vector<MirrorWallPtr> open;
  for (int p = 0; p < domain.num_patches(); ++p) {
    MirrorWallPtr w = domain.patch_wall(p);
    require(w != nullptr, "mirror wall of patch", domain.patch_name(p),
            "this domain has no wall surface for image blobs");
    if (std::find(open_patches.begin(), open_patches.end(), p) != open_patches.end()) open.push_back(w);
    if (std::find(all.begin(), all.end(), w) == all.end()) all.push_back(w);
  }
  for (const auto& w : all)
    if (std::find(open.begin(), open.end(), w) == open.end()) closed.push_back(w);
  return closed;
}

std::size_t reflect_inside(const std::vector<MirrorWallPtr>& walls, std::vector<Vec3>& x) {
  std::size_t moved = 0;
  for (Vec3& p : x) {
    bool any = false;
    // A few passes: at an edge or a corner one reflection can cross another wall.
    for (int pass = 0; pass < 4; ++pass) {
      bool crossed = false;
      for (const auto& w : walls) {
        if (w->distance(p) > 0.0) {
          p = w->reflect(p, nullptr);
          crossed = true;
        }
      }
      if (!crossed) break;
      any = true;
    }
    if (any) ++moved;
  }
  return moved;
}

WallImages::WallImages(std::vector<MirrorWallPtr> walls, int max_order) : walls_(std::move(walls)), max_order_(max_order) {
  require(walls_.size() <= 255, "number of mirror walls", static_cast<double>(walls_.size()), "must be <= 255");
  require(max_order >= 1 && max_order <= 3, "max_order", max_order, "must be 1, 2 or 3");
  for (const auto& w : walls_) require(w != nullptr, "mirror wall", "null", "must not be null");
}

void WallImages::select_block(const std::vector<Vec3>& x, const std::vector<double>& reach, std::size_t b,
                              SelectBuffer& out) const {
  const std::size_t nw = walls_.size();
  const std::size_t i0 = b * kSelectBlock;
  const std::size_t len = std::min(kSelectBlock, x.size() - i0);
  double* d = out.distance.data();
  for (std::size_t w = 0; w < nw; ++w) walls_[w]->distances(x.data() + i0, len, d + w * kSelectBlock);
  // Which particles have a wall within reach: the largest distance over the
  // walls (one vectorised pass per wall; a NaN distance is passed over, as
  // the test below passes it over), then one comparison. The rest have no images.
  std::array<double, kSelectBlock> nearest;
  nearest.fill(-std::numeric_limits<double>::infinity());
  double* nr = nearest.data();
  for (std::size_t w = 0; w < nw; ++w) {
    const double* dw = d + w * kSelectBlock;
    for (std::size_t i = 0; i < len; ++i) {
      const double v = dw[i];
      nr[i] = nr[i] < v ? v : nr[i];
    }
  }
  std::array<std::uint8_t, kMaxNearWalls> near{};
  std::array<double, kMaxNearWalls> depth{};
  for (std::size_t i = 0; i < len; ++i) {
    const std::size_t p = i0 + i;
    if (!(nearest[i] >= -reach[p])) continue;
    // The nearby walls in wall order (the first kMaxNearWalls of them).
    std::size_t k = 0;
    for (std::size_t w = 0; w < nw && k < kMaxNearWalls; ++w) {
      const double dist = d[w * kSelectBlock + i];
      if (dist >= -reach[p]) {
        near[k] = static_cast<std::uint8_t>(w);
        depth[k] = std::max(-dist, 0.0);
        ++k;
      }
    }
    // Every nonempty subset of the nearby walls, in increasing wall order,
    // whose composed image can come within reach of the domain: across
    // orthogonal planes at depths d_i that image is sqrt(sum d_i^2) away from
    // the domain's edge or corner (for other pairs of walls it is farther,
    // so the rule keeps a superset of the images that matter).
    const double reach_sq = reach[p] * reach[p];
    for (std::uint32_t mask = 1; mask < (1u << k); ++mask) {
      std::array<std::uint8_t, 3> c{0, 0, 0};
      int order = 0;
      bool skip = false;
      double dist_sq = 0.0;
      for (std::size_t j = 0; j < k; ++j) {
        if (!(mask & (1u << j))) continue;
        if (order == max_order_) {
          skip = true;
          break;
        }
        dist_sq += depth[j] * depth[j];
        c[static_cast<std::size_t>(order++)] = near[j];
      }
      if (skip || dist_sq > reach_sq) continue;
      out.source.push_back(static_cast<std::uint32_t>(p));
      out.order.push_back(static_cast<std::uint8_t>(order));
      out.chain.push_back(c);
    }
  }
}

void WallImages::select(const std::vector<Vec3>& x, const std::vector<double>& reach) {
  require(x.size() == reach.size(), "reach size", static_cast<double>(reach.size()), "must equal the particle count");
  require(x.size() <= std::numeric_limits<std::uint32_t>::max(), "particle count", static_cast<double>(x.size()),
          "must fit the 32-bit source index of an image");
  source_.clear();
  order_.clear();
  chain_.clear();
  if (!active() || x.empty()) return;
  const std::size_t blocks = (x.size() + kSelectBlock - 1) / kSelectBlock;
  const int threads = blocks >= kSelectParallelBlocks ? std::max(1, omp_get_max_threads()) : 1;
  if (buffers_.size() < static_cast<std::size_t>(threads)) buffers_.resize(static_cast<std::size_t>(threads));
  // An exception may not leave a parallel region: the first one is kept and
  // thrown after it.
  std::exception_ptr error;
  std::size_t team = 1;
#pragma omp parallel num_threads(threads) if (threads > 1)
  {
    // Thread t takes the t-th of nt runs of whole blocks and lists their
    // images in particle order; the runs, joined in thread order, list all
    // images in particle order whatever nt is.
    const auto nt = static_cast<std::size_t>(omp_get_num_threads());
    const auto t = static_cast<std::size_t>(omp_get_thread_num());
    if (t == 0) team = nt;
    SelectBuffer& buf = buffers_[t];
    buf.source.clear();
    buf.order.clear();
    buf.chain.clear();
    try {
      buf.distance.resize(walls_.size() * kSelectBlock);
      for (std::size_t b = blocks * t / nt; b < blocks * (t + 1) / nt; ++b) select_block(x, reach, b, buf);
    } catch (...) {
#pragma omp critical(otfp_select_images_error)
      if (!error) error = std::current_exception();
    }
  }
  if (error) std::rethrow_exception(error);
  // Joining the runs copies 8 bytes per image: not worth another barrier.
  std::size_t total = 0;
  for (std::size_t k = 0; k < team; ++k) total += buffers_[k].source.size();
  source_.reserve(total);
  order_.reserve(total);
  chain_.reserve(total);
  for (std::size_t k = 0; k < team; ++k) {
    const SelectBuffer& buf = buffers_[k];
    source_.insert(source_.end(), buf.source.begin(), buf.source.end());
    order_.insert(order_.end(), buf.order.begin(), buf.order.end());
    chain_.insert(chain_.end(), buf.chain.begin(), buf.chain.end());
  }
}

Vec3 WallImages::image(std::size_t i, const Vec3& x, Mat3* jacobian) const {
  Vec3 y = x;
  if (jacobian) jacobian->setIdentity();
  for (int j = 0; j < order_[i]; ++j) {
    const MirrorWall& w = *walls_[chain_[i][static_cast<std::size_t>(j)]];
    if (jacobian) {
      Mat3 jw;
      y = w.reflect(y, &jw);
      *jacobian = jw * *jacobian;  // chain rule: J = J_k ... J_1
    } else {
      y = w.reflect(y, nullptr);
    }
  }
  return y;
}

void WallImages::positions(const std::vector<Vec3>& x, std::vector<Vec3>& y) const {
  y.resize(source_.size());
  for (std::size_t i = 0; i < source_.size(); ++i) y[i] = image(i, x[source_[i]], nullptr);
}

void WallImages::pull_back(const std::vector<Vec3>& x, const std::vector<Vec3>& g_image,
                           std::vector<Vec3>& g_source) const {
  // Serial in image order: the sum into each source is reproducible.
  for (std::size_t i = 0; i < source_.size(); ++i) {
    Mat3 jac;
    image(i, x[source_[i]], &jac);
    g_source[source_[i]] += jac.transpose() * g_image[i];
  }
}

}  // namespace otfp
