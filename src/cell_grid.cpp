#include "cell_grid.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace otfp {

void CellGrid::build(const std::vector<Vec3>& x, double cell_size, const Periodicity& periodicity, int reach) {
  per_ = periodicity;
  reach_ = std::max(1, reach);
  const int dim = per_.dim;
  const std::size_t n = x.size();
  Vec3 lo = Vec3::Zero(), hi = Vec3::Zero();
  if (n > 0) {
    lo = x[0];
    hi = x[0];
    for (std::size_t i = 0; i < n; ++i) {
      // A diverged explicit step (dt far above its limit) ends here first.
      if (!x[i].allFinite())
        throw std::runtime_error("non-finite position of particle " + std::to_string(i) +
                                 ": the step diverged (an explicit dt above its stability limit?)");
      lo = lo.cwiseMin(x[i]);
      hi = hi.cwiseMax(x[i]);
    }
  }
  // Cap the cell count near n so that sparse, spread-out clouds stay O(n) in
  // memory: counts are computed in double (a cloud blown apart by an unstable
  // step can span far more cells than an int holds), cells grown until they fit.
  const double max_cells = std::max<double>(8.0, 2.0 * static_cast<double>(n));
  double size = cell_size;
  double counts[3] = {1.0, 1.0, 1.0};
  for (int attempt = 0; attempt < 200; ++attempt) {
    double total = 1.0;
    for (int k = 0; k < dim; ++k) {
      counts[k] = per_.period[k] > 0.0 ? std::max(1.0, std::floor(per_.period[k] / size))
                                       : std::max(1.0, std::floor((hi[k] - lo[k]) / size) + 1.0);
      total *= counts[k];
    }
    if (total <= max_cells) break;
    size *= std::max(1.26, 0.5 * std::pow(total / max_cells, 1.0 / dim));
  }
  for (int k = 0; k < 3; ++k) {
    if (k >= dim) {
      n_[k] = 1;
      origin_[k] = 0.0;
      cell_width_[k] = 1.0;
    } else if (per_.period[k] > 0.0) {
      origin_[k] = per_.lo[k];
      n_[k] = static_cast<int>(counts[k]);
      cell_width_[k] = per_.period[k] / n_[k];
    } else {
      origin_[k] = lo[k];
      n_[k] = static_cast<int>(counts[k]);
      cell_width_[k] = size;
    }
  }
  const std::size_t ncell = static_cast<std::size_t>(n_[0]) * n_[1] * n_[2];
  cell_start_.assign(ncell + 1, 0);
  // Points are stored wrapped into the periodic box: the shifts passed to
  // for_each_cell assume it (an optimiser may move a particle across the box edge).
  std::vector<Vec3> xw;
  const bool wrap = per_.any();
  if (wrap) {
    xw.resize(n);
    for (std::size_t i = 0; i < n; ++i) xw[i] = canonical(x[i]);
  }
  const std::vector<Vec3>& xs = wrap ? xw : x;
  std::vector<std::uint32_t> cell_of(n);
  for (std::size_t i = 0; i < n; ++i) {
    std::size_t c = 0;
    for (int k = dim - 1; k >= 0; --k) c = c * n_[k] + cell_coord(xs[i][k], k);
    cell_of[i] = static_cast<std::uint32_t>(c);
    ++cell_start_[c + 1];
  }
  for (std::size_t c = 0; c < ncell; ++c) cell_start_[c + 1] += cell_start_[c];
  items_.resize(n);
  std::vector<std::uint32_t> fill(cell_start_.begin(), cell_start_.end() - 1);
  for (std::size_t i = 0; i < n; ++i) items_[fill[cell_of[i]]++] = static_cast<std::uint32_t>(i);
  sx_.resize(n);
  sy_.resize(n);
  sz_.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    sx_[k] = xs[items_[k]][0];
    sy_[k] = xs[items_[k]][1];
    sz_[k] = xs[items_[k]][2];
  }
  shifts_exact_ = true;
  for (int k = 0; k < dim; ++k)
    if (per_.period[k] > 0.0 && n_[k] < 2 * reach_ + 1) shifts_exact_ = false;
}

}  // namespace otfp
