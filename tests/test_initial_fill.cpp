// Initial particles: the fills sample what they say (positions, counts,
// moments against their densities), reproducibly.
#include <gtest/gtest.h>

#include <cmath>

#include "otfp/initial_fill.hpp"
#include "otfp/neighbor_list.hpp"

using namespace otfp;

TEST(InitialFill, InverseCosineCdfSolvesItsEquation) {
  const double a = 0.7, k = 2.0 * 3.141592653589793 / 3.0;
  for (double u : {0.0, 0.1, 0.75, 1.5, 2.9, 3.0}) {
    const double xi = invert_cosine_cdf(u, a, k);
    EXPECT_NEAR(xi + a / k * std::sin(k * xi) - u, 0.0, 1e-14) << u;
  }
}

TEST(InitialFill, LatticeIsTheCellCentres) {
  DomainPtr box = make_box(2, Vec3::Zero(), Vec3(2.0, 3.0, 0.0));
  FillOptions o;
  o.count = 6;
  o.width_s = 0.1;
  o.mass = 0.5;
  o.lattice = true;
  o.lattice_counts = {2, 3, 1};
  o.lo = Vec3::Zero();
  o.hi = Vec3(2.0, 3.0, 0.0);
  Rng rng(1);
  const ParticleSet ps = fill_particles(*box, o, rng);
  ASSERT_EQ(ps.size(), 6u);
  for (std::size_t i = 0; i < 6; ++i) {
    EXPECT_EQ(ps.positions()[i], Vec3(0.5 + static_cast<double>(i % 2), 0.5 + static_cast<double>(i / 2), 0.0));
    EXPECT_EQ(ps.masses()[i], 0.5);
    EXPECT_EQ(ps.widths()[i], 0.1);
  }
}

// Uniform fills stay in Omega; a Gaussian one has the requested mean and
// variance; a cosine one has the Fourier coefficient a/2 of its density
// (1 + a cos(k x)) / L; each within 5 standard errors of n = 20000 samples.
TEST(InitialFill, FillsSampleTheirDensities) {
  const int n = 20000;
  const double se = 1.0 / std::sqrt(static_cast<double>(n));
  FillOptions o;
  o.count = n;
  o.width_s = 0.05;
  o.mass = 1.0 / n;
  DomainPtr ball = make_ball(3, Vec3::Zero(), 1.0);
  Rng r1(7);
  const ParticleSet u = fill_particles(*ball, o, r1);
  ASSERT_EQ(u.size(), static_cast<std::size_t>(n));
  for (const Vec3& x : u.positions()) EXPECT_LE(x.norm(), 1.0);

  o.shape = FillShape::Gaussian;
  o.center = Vec3(0.1, -0.2, 0.3);
  o.sigma = 0.2;
  Rng r2(8);
  const ParticleSet g = fill_particles(*make_periodic_box(3, Vec3::Constant(-5), Vec3::Constant(5)), o, r2);
  Vec3 mean = Vec3::Zero();
  double var = 0.0;
  for (const Vec3& x : g.positions()) mean += x / n;
  for (const Vec3& x : g.positions()) var += (x - o.center).squaredNorm() / (3.0 * n);
  EXPECT_LT((mean - o.center).norm(), 5.0 * o.sigma * se * std::sqrt(3.0));
  EXPECT_NEAR(var / (o.sigma * o.sigma), 1.0, 5.0 * std::sqrt(2.0) * se);

  o.shape = FillShape::Cosine;
  o.lo = Vec3::Zero();
  o.hi = Vec3(2.0, 1.0, 1.0);
  o.amplitude = 0.6;
  o.wavenumber = 2.0 * 3.141592653589793 / 2.0;
  Rng r3(9);
  const ParticleSet c = fill_particles(*make_periodic_box(3, o.lo, o.hi), o, r3);
  double coefficient = 0.0;
  for (const Vec3& x : c.positions()) coefficient += std::cos(o.wavenumber * x[0]) / n;
  EXPECT_NEAR(coefficient, o.amplitude / 2.0, 5.0 * se);

  // The same stream gives the same particles.
  Rng r4(9);
  EXPECT_EQ(fill_particles(*make_periodic_box(3, o.lo, o.hi), o, r4).positions(), c.positions());
}

TEST(InitialFill, BadOptionsNameTheField) {
  FillOptions o;
  o.count = 1;
  o.width_s = 0.1;
  o.mass = 0.0;
  Rng rng(1);
  try {
    fill_particles(*make_ball(2, Vec3::Zero(), 1.0), o, rng);
    ADD_FAILURE() << "accepted mass 0";
  } catch (const InvalidArgument& e) {
    EXPECT_EQ(std::string(e.what()).rfind("fill mass = 0", 0), 0u) << e.what();
  }
}

// The staggered lattice: in 2-D the rows alternate a quarter cell left and
// right (half a cell apart), in 3-D two points per cell at 1/4 and 3/4 of its
// diagonal (bcc, whose nearest neighbours are sqrt(3)/4 of a cell width
// apart); an odd row count in 2-D is refused, naming the field.
TEST(InitialFill, StaggeredLatticeShiftsEveryOtherRowIn2DAndIsBodyCentredIn3D) {
  FillOptions o;
  o.width_s = 0.1;
  o.mass = 0.5;
  o.lattice = true;
  o.staggered = true;
  Rng rng(1);
  o.lattice_counts = {2, 4, 1};
  o.count = lattice_point_count(2, o.lattice_counts, true);
  o.hi = Vec3(2.0, 4.0, 0.0);
  const ParticleSet flat = fill_particles(*make_periodic_box(2, Vec3::Zero(), o.hi), o, rng);
  ASSERT_EQ(flat.size(), 8u);
  for (std::size_t i = 0; i < 8; ++i) {
    const double row = static_cast<double>(i / 2), shift = (i / 2) % 2 == 0 ? -0.25 : 0.25;
    EXPECT_EQ(flat.positions()[i], Vec3(0.5 + shift + static_cast<double>(i % 2), 0.5 + row, 0.0)) << i;
  }

  o.lattice_counts = {2, 2, 2};
  o.count = lattice_point_count(3, o.lattice_counts, true);
  EXPECT_EQ(o.count, 16);
  o.hi = Vec3::Ones();
  const ParticleSet bcc = fill_particles(*make_periodic_box(3, Vec3::Zero(), o.hi), o, rng);
  ASSERT_EQ(bcc.size(), 16u);
  const Periodicity per = Periodicity::from_domain(*make_periodic_box(3, Vec3::Zero(), o.hi));
  for (std::size_t p = 0; p < 16; ++p) {
    double nearest = 1e9;
    int at_nearest = 0;
    for (std::size_t q = 0; q < 16; ++q) {
      if (q == p) continue;
      const double d = per.displacement(bcc.positions()[p], bcc.positions()[q]).norm();
      if (d < nearest - 1e-12) nearest = d, at_nearest = 0;
      if (std::abs(d - nearest) <= 1e-12) ++at_nearest;
    }
    EXPECT_NEAR(nearest, std::sqrt(3.0) / 4.0, 1e-15) << p;  // cells of 1/2
    EXPECT_EQ(at_nearest, 8) << p;                            // bcc: eight nearest neighbours
  }

  o.lattice_counts = {2, 3, 1};
  o.count = 6;
  o.hi = Vec3(2.0, 3.0, 0.0);
  try {
    fill_particles(*make_periodic_box(2, Vec3::Zero(), o.hi), o, rng);
    ADD_FAILURE() << "accepted three staggered rows";
  } catch (const InvalidArgument& e) {
    EXPECT_EQ(std::string(e.what()).rfind("fill lattice count along y = 3", 0), 0u) << e.what();
  }
}
