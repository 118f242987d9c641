// The Domain base class: patch names, layer-cell membership, rejection
// sampling and the Monte Carlo layer-cell volume every domain falls back on.
// The shapes are in geometry_shapes.cpp, sub-patches and CSG in
// geometry_composite.cpp.
#include <cmath>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "geometry_internal.hpp"

namespace otfp {

using namespace geometry_detail;

namespace {

constexpr long kMaxRejectionTries = 10'000'000;

}  // namespace

// ---------------------------------------------------------------------------
// Domain defaults

std::shared_ptr<const MirrorWall> Domain::patch_wall(int patch) const {
  check_patch(*this, patch);
  return nullptr;
}

DomainPtr Domain::extended(const std::vector<int>& patches, double w) const {
  require(patches.empty(), "extended patch", patches.empty() ? "" : patch_name(patches.front()),
          "this domain cannot be extended over its patches");
  (void)w;
  return nullptr;
}

std::string Domain::patch_name(int patch) const {
  check_patch(*this, patch);
  return "patch" + std::to_string(patch);
}

int Domain::patch_by_name(const std::string& name) const {
  for (int p = 0; p < num_patches(); ++p)
    if (patch_name(p) == name) return p;
  return -1;
}

bool Domain::in_layer_cell(const Vec3& x, int patch, double b, LayerPart part) const {
  const BoundaryQuery q = query(x);
  if (q.patch != patch || patch < 0) return false;
  return in_layer_part(q.signed_distance, b, part);
}

bool in_layer_part(double sd, double b, LayerPart part) {
  switch (part) {
    case LayerPart::Interior: return sd >= -b && sd <= 0.0;
    case LayerPart::Exterior: return sd > 0.0 && sd <= b;
    case LayerPart::Whole: return std::abs(sd) <= b;
  }
  return false;
}

Vec3 Domain::inertia_center() const {
  const Aabb box = bounding_box();
  Vec3 c = 0.5 * (box.lo + box.hi);
  for (int k = dim(); k < 3; ++k) c[k] = 0.0;
  return c;
}

double Domain::mean_square_distance(const Vec3& c) const {
  Rng rng(0x6a696e66ULL);
  constexpr int kSamples = 200000;
  Vec3 cc = c;  // the unused axes do not count, as in the closed forms
  for (int k = dim(); k < 3; ++k) cc[k] = 0.0;
  double s2 = 0.0;
  for (int i = 0; i < kSamples; ++i) {
    Vec3 x = sample_interior(rng);
    for (int k = dim(); k < 3; ++k) x[k] = 0.0;
    s2 += (x - cc).squaredNorm();
  }
  return s2 / kSamples;
}

Vec3 Domain::sample_interior(Rng& rng) const {
  const Aabb box = bounding_box();
  const int d = dim();
  for (long i = 0; i < kMaxRejectionTries; ++i) {
    const Vec3 x = uniform_in(box, d, rng);
    if (contains(x)) return x;
  }
  throw std::runtime_error("sample_interior: no point of the domain found in " +
                           std::to_string(kMaxRejectionTries) + " tries (empty domain?)");
}

Vec3 Domain::sample_layer_cell(int patch, double b, LayerPart part, Rng& rng) const {
  check_patch(*this, patch);
  check_thickness(b);
  const Aabb box = layer_bounding_box(patch, b);
  const int d = dim();
  if (!is_empty(box, d)) {
    for (long i = 0; i < kMaxRejectionTries; ++i) {
      const Vec3 x = uniform_in(box, d, rng);
      if (in_layer_cell(x, patch, b, part)) return x;
    }
  }
  throw std::runtime_error("sample_layer_cell: no point of the layer cell of patch '" + patch_name(patch) +
                           "' (b = " + std::to_string(b) + ") found in " +
                           std::to_string(kMaxRejectionTries) + " tries (empty cell?)");
}

Aabb Domain::layer_bounding_box(int patch, double b) const {
  check_patch(*this, patch);
  require(std::isfinite(b) && b >= 0.0, "layer half-thickness b", b, "must be finite and >= 0");
  return inflate(bounding_box(), dim(), b);
}

double Domain::layer_cell_volume(int patch, double b, LayerPart part, int samples) const {
  check_patch(*this, patch);
  check_thickness(b);
  return monte_carlo_volume(layer_bounding_box(patch, b), dim(), samples,
                            [&](const Vec3& x) { return in_layer_cell(x, patch, b, part); });
}

}  // namespace otfp
