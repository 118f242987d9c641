// The names of the option enums (otfp/enums.hpp): every value reads back
// from its name, and an unknown name is refused with a one-line message.
#include <gtest/gtest.h>

#include <set>
#include <string>

#include "otfp/enums.hpp"

using namespace otfp;

namespace {
template <class E, class FromString>
void round_trips(std::initializer_list<E> values, FromString from_string) {
  std::set<std::string> seen;
  for (E e : values) {
    const std::string name = to_string(e);
    EXPECT_TRUE(seen.insert(name).second) << "two values named " << name;
    EXPECT_EQ(from_string(name), e) << name;
  }
  try {
    from_string("no such name");
    ADD_FAILURE() << "accepted an unknown name";
  } catch (const InvalidArgument& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("no such name"), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
  }
}
}  // namespace

TEST(Enums, EveryNameReadsBack) {
  round_trips({Backend::Ceres, Backend::Nlopt}, backend_from_string);
  round_trips({Algorithm::Lbfgs, Algorithm::Bfgs, Algorithm::NonlinearCg, Algorithm::TruncatedNewton, Algorithm::Var2,
               Algorithm::Mma},
              algorithm_from_string);
  round_trips({WidthMode::Fixed, WidthMode::PerParticle}, width_mode_from_string);
  round_trips({TimeScheme::Euler, TimeScheme::Bdf2}, time_scheme_from_string);
  round_trips({Predictor::None, Predictor::Extrapolate, Predictor::Damped}, predictor_from_string);
  round_trips({ExplicitScheme::EulerForce27, ExplicitScheme::Rk4Force27, ExplicitScheme::EulerExactGradient},
              explicit_scheme_from_string);
  round_trips({WidthMetric::AsPrinted, WidthMetric::ExactGaussian}, width_metric_from_string);
  round_trips({PatchKind::NoFlux, PatchKind::Dirichlet, PatchKind::Neumann}, patch_kind_from_string);
  round_trips({NeumannOutflow::Layer, NeumannOutflow::NearestParticles}, neumann_outflow_from_string);
  round_trips({DirichletMode::Layer, DirichletMode::Reservoir}, dirichlet_mode_from_string);
  round_trips({ReservoirProfile::Uniform, ReservoirProfile::Odd}, reservoir_profile_from_string);
  round_trips({DirichletTarget::CellIntegral, DirichletTarget::PaperEq34}, dirichlet_target_from_string);
  round_trips({SpacingRule::Cube, SpacingRule::SphereRadius}, spacing_rule_from_string);
  round_trips({StepperKind::Implicit, StepperKind::Explicit}, stepper_kind_from_string);
  round_trips({NoFluxTreatment::Barrier, NoFluxTreatment::Images}, no_flux_treatment_from_string);
  round_trips({FillShape::Uniform, FillShape::Gaussian, FillShape::Cosine}, fill_shape_from_string);
}

// Names that only go out (summaries) are distinct.
TEST(Enums, OutputNamesAreDistinct) {
  std::set<std::string> reasons;
  for (TerminationReason r : {TerminationReason::Converged, TerminationReason::FunctionTolerance,
                              TerminationReason::MaxIterations, TerminationReason::MaxEvaluations,
                              TerminationReason::LineSearchFailure, TerminationReason::NonFinite,
                              TerminationReason::Failure})
    EXPECT_TRUE(reasons.insert(to_string(r)).second) << to_string(r);
  std::set<std::string> methods;
  for (BlobMassMethod m : {BlobMassMethod::ClosedForm, BlobMassMethod::Total, BlobMassMethod::Quadrature})
    EXPECT_TRUE(methods.insert(to_string(m)).second) << to_string(m);
}
