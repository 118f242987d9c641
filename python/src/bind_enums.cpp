// The enums (each also built from its name as a string) and the random
// number generator.
#include "common.hpp"

#include "otfp/enums.hpp"

#include "bindings.hpp"

namespace otfp::python {

namespace {

// An enum with its names as strings: Backend("nlopt") and a plain "nlopt"
// wherever a Backend is expected.
template <class E, class FromString>
void bind_enum(py::module_& m, const char* name, std::initializer_list<std::pair<const char*, E>> values,
               FromString from_string) {
  py::enum_<E> e(m, name);
  for (const auto& [n, v] : values) e.value(n, v);
  e.def(py::init([from_string](const std::string& s) { return from_string(s); }));
  // Replaces enum_'s __str__ ("PatchKind.Dirichlet"): def() would add an
  // overload behind it that is never reached.
  e.attr("__str__") = py::cpp_function([](E v) { return to_string(v); }, py::name("__str__"), py::is_method(e));
  py::implicitly_convertible<py::str, E>();
}

template <class E>
E no_from_string(const std::string& s) {
  throw InvalidArgument("\"" + s + "\" cannot be converted to this enum");
}

}  // namespace

void bind_enums(py::module_& m) {
  // ---- enums
  bind_enum<Backend>(m, "Backend", {{"Ceres", Backend::Ceres}, {"Nlopt", Backend::Nlopt}, {"Tao", Backend::Tao}}, backend_from_string);
  bind_enum<Algorithm>(m, "Algorithm",
                       {{"Lbfgs", Algorithm::Lbfgs}, {"Bfgs", Algorithm::Bfgs}, {"NonlinearCg", Algorithm::NonlinearCg},
                        {"TruncatedNewton", Algorithm::TruncatedNewton}, {"Var2", Algorithm::Var2}, {"Mma", Algorithm::Mma}},
                       algorithm_from_string);
  bind_enum<TerminationReason>(
      m, "TerminationReason",
      {{"Converged", TerminationReason::Converged}, {"FunctionTolerance", TerminationReason::FunctionTolerance},
       {"MaxIterations", TerminationReason::MaxIterations}, {"MaxEvaluations", TerminationReason::MaxEvaluations},
       {"LineSearchFailure", TerminationReason::LineSearchFailure}, {"NonFinite", TerminationReason::NonFinite},
       {"Failure", TerminationReason::Failure}},
      no_from_string<TerminationReason>);
  bind_enum<WidthMetric>(m, "WidthMetric",
                         {{"AsPrinted", WidthMetric::AsPrinted}, {"ExactGaussian", WidthMetric::ExactGaussian}},
                         width_metric_from_string);
  bind_enum<WidthMode>(m, "WidthMode", {{"Fixed", WidthMode::Fixed}, {"PerParticle", WidthMode::PerParticle}},
                       width_mode_from_string);
  bind_enum<TimeScheme>(m, "TimeScheme", {{"Euler", TimeScheme::Euler}, {"Bdf2", TimeScheme::Bdf2}},
                        time_scheme_from_string);
  bind_enum<Predictor>(m, "Predictor",
                       {{"None_", Predictor::None}, {"Extrapolate", Predictor::Extrapolate}, {"Damped", Predictor::Damped}},
                       predictor_from_string);
  bind_enum<ErrorMeasure>(m, "ErrorMeasure",
                          {{"Displacement", ErrorMeasure::Displacement}, {"Density", ErrorMeasure::Density}},
                          error_measure_from_string);
  bind_enum<StoppingNorm>(m, "StoppingNorm", {{"Max", StoppingNorm::Max}, {"Energy", StoppingNorm::Energy}},
                          stopping_norm_from_string);
  bind_enum<ExplicitScheme>(m, "ExplicitScheme",
                            {{"EulerForce27", ExplicitScheme::EulerForce27}, {"Rk4Force27", ExplicitScheme::Rk4Force27},
                             {"EulerExactGradient", ExplicitScheme::EulerExactGradient}},
                            explicit_scheme_from_string);
  bind_enum<PatchKind>(m, "PatchKind",
                       {{"NoFlux", PatchKind::NoFlux}, {"Dirichlet", PatchKind::Dirichlet}, {"Neumann", PatchKind::Neumann}},
                       patch_kind_from_string);
  bind_enum<NeumannOutflow>(m, "NeumannOutflow",
                            {{"Layer", NeumannOutflow::Layer}, {"NearestParticles", NeumannOutflow::NearestParticles}},
                            neumann_outflow_from_string);
  bind_enum<DirichletMode>(m, "DirichletMode",
                           {{"Layer", DirichletMode::Layer}, {"Reservoir", DirichletMode::Reservoir}},
                           dirichlet_mode_from_string);
  bind_enum<ReservoirProfile>(m, "ReservoirProfile",
                              {{"Uniform", ReservoirProfile::Uniform}, {"Odd", ReservoirProfile::Odd}},
                              reservoir_profile_from_string);
  bind_enum<ReservoirControl>(m, "ReservoirControl",
                              {{"Quiet", ReservoirControl::Quiet}, {"Exact", ReservoirControl::Exact}},
                              reservoir_control_from_string);
  bind_enum<DirichletTarget>(m, "DirichletTarget",
                             {{"CellIntegral", DirichletTarget::CellIntegral}, {"PaperEq34", DirichletTarget::PaperEq34}},
                             dirichlet_target_from_string);
  bind_enum<StepperKind>(m, "StepperKind", {{"Implicit", StepperKind::Implicit}, {"Explicit", StepperKind::Explicit}},
                         stepper_kind_from_string);
  bind_enum<NoFluxTreatment>(m, "NoFluxTreatment",
                             {{"Barrier", NoFluxTreatment::Barrier}, {"Images", NoFluxTreatment::Images}},
                             no_flux_treatment_from_string);
  bind_enum<SpacingRule>(m, "SpacingRule", {{"Cube", SpacingRule::Cube}, {"SphereRadius", SpacingRule::SphereRadius}},
                         spacing_rule_from_string);
  bind_enum<TreatmentPreset>(m, "TreatmentPreset",
                             {{"Converging", TreatmentPreset::Converging}, {"Papers", TreatmentPreset::Papers}},
                             treatment_preset_from_string);
  bind_enum<FillShape>(m, "FillShape",
                       {{"Uniform", FillShape::Uniform}, {"Gaussian", FillShape::Gaussian}, {"Cosine", FillShape::Cosine}},
                       fill_shape_from_string);

  // ---- random numbers
  py::class_<Rng>(m, "Rng", "xoshiro256** seeded by SplitMix64: the same seed gives the same stream everywhere.")
      .def(py::init([](const py::int_& seed) { return Rng(seed_from(seed)); }), py::arg("seed") = 0x5eed)
      .def("uniform", py::overload_cast<>(&Rng::uniform))
      .def("normal", &Rng::normal);
}

}  // namespace otfp::python
