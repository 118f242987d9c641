// The parameter rules (36)-(40) and the width exponent q of WidthScaling.
#include <gtest/gtest.h>

#include <cmath>

#include "otfp/parameters.hpp"
#include "otfp/types.hpp"

using namespace otfp;

TEST(Parameters, CubeRuleIsTheTrueSpacing) {
  EXPECT_DOUBLE_EQ(spacing(2.0, 250, 3), std::cbrt(2.0 / 250.0));
  EXPECT_DOUBLE_EQ(spacing(4.0, 100, 2), 0.2);
  // The sphere-radius rule is (4 pi / 3)^(1/3) = 1.61 times smaller.
  EXPECT_NEAR(spacing(1.0, 1000, 3) / spacing(1.0, 1000, 3, SpacingRule::SphereRadius), std::cbrt(4.0 * M_PI / 3.0),
              1e-14);
}

TEST(Parameters, WidthExponentOneIsThePapersWidthBitForBit) {
  for (std::size_t n : {100u, 400u, 1600u, 25600u}) {
    const PaperParameters a = paper_parameters(4.0 / 3.0 * M_PI, n, 3, 1.0, 1.0, 2.0, SpacingRule::SphereRadius);
    const PaperParameters b =
        paper_parameters(4.0 / 3.0 * M_PI, n, 3, 1.0, 1.0, 2.0, SpacingRule::SphereRadius, WidthScaling{1.0, 37});
    const PaperParameters c = paper_parameters_from_spacing(a.dr, 1.0, 1.0, 2.0);
    EXPECT_EQ(a.width_s, c.width_s);
    EXPECT_EQ(a.beta, c.beta);
    EXPECT_EQ(b.width_s, c.width_s);
    EXPECT_EQ(b.beta, c.beta);
    EXPECT_EQ(a.beta, 2.0 / (a.dr * a.dr));
    EXPECT_EQ(scaled_width(a.dr, 2.0, 1.0, 0.0), a.width_s);
  }
}

TEST(Parameters, WidthExponentHalf) {
  // Unit cube, n = 3200 against n_ref = 400: dr / dr_ref = 1/2, so
  // s = dr / sqrt(2) * (1/2)^(-1/2) = dr.
  const PaperParameters p = paper_parameters(1.0, 3200, 3, 1.0, 1.0, 2.0, SpacingRule::Cube, WidthScaling{0.5, 400});
  EXPECT_NEAR(p.dr_ref, std::cbrt(1.0 / 400.0), 1e-16);
  EXPECT_NEAR(p.width_s, p.dr, 1e-15);
  EXPECT_NEAR(p.beta, 1.0 / (p.dr * p.dr), 1e-9);
  EXPECT_DOUBLE_EQ(p.width_exponent, 0.5);
  // The time step and barrier still follow the spacing.
  EXPECT_DOUBLE_EQ(p.dt_explicit, p.dr * p.dr);
  // At n = reference_n the width is the papers' for every q.
  for (double q : {0.3, 0.5, 1.5, 2.0}) {
    const PaperParameters r = paper_parameters(1.0, 400, 3, 1.0, 1.0, 2.0, SpacingRule::Cube, WidthScaling{q, 400});
    EXPECT_NEAR(r.width_s, r.dr / std::sqrt(2.0), 1e-15) << q;
  }
  // s ~ dr^q: the ratio of widths over a factor 8 in n (2 in dr) is 2^q.
  const PaperParameters lo = paper_parameters(1.0, 400, 3, 1.0, 1.0, 2.0, SpacingRule::Cube, WidthScaling{0.6, 100});
  const PaperParameters hi = paper_parameters(1.0, 3200, 3, 1.0, 1.0, 2.0, SpacingRule::Cube, WidthScaling{0.6, 100});
  EXPECT_NEAR(lo.width_s / hi.width_s, std::pow(2.0, 0.6), 1e-13);
}

TEST(Parameters, WidthScalingIsValidated) {
  for (double q : {0.0, -1.0, 2.5, std::nan("")})
    EXPECT_THROW(paper_parameters(1.0, 100, 3, 1.0, 1.0, 2.0, SpacingRule::Cube, WidthScaling{q, 400}), InvalidArgument)
        << q;
  EXPECT_THROW(paper_parameters(1.0, 100, 3, 1.0, 1.0, 2.0, SpacingRule::Cube, WidthScaling{0.5, 0}), InvalidArgument);
  EXPECT_NO_THROW(paper_parameters(1.0, 100, 3, 1.0, 1.0, 2.0, SpacingRule::Cube, WidthScaling{2.0, 1}));
}
