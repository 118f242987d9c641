#include "otfp/enums.hpp"

namespace otfp {

std::string to_string(Backend b) {
  switch (b) {
    case Backend::Ceres: return "ceres";
    case Backend::Nlopt: return "nlopt";
    case Backend::Tao: return "tao";
  }
  return "unknown";
}

std::string to_string(Algorithm a) {
  switch (a) {
    case Algorithm::Lbfgs: return "lbfgs";
    case Algorithm::Bfgs: return "bfgs";
    case Algorithm::NonlinearCg: return "nonlinear_cg";
    case Algorithm::TruncatedNewton: return "tnewton";
    case Algorithm::Var2: return "var2";
    case Algorithm::Mma: return "mma";
  }
  return "unknown";
}

std::string to_string(TerminationReason r) {
  switch (r) {
    case TerminationReason::Converged: return "converged";
    case TerminationReason::FunctionTolerance: return "function_tolerance";
    case TerminationReason::MaxIterations: return "max_iterations";
    case TerminationReason::MaxEvaluations: return "max_evaluations";
    case TerminationReason::LineSearchFailure: return "line_search_failure";
    case TerminationReason::NonFinite: return "non_finite";
    case TerminationReason::Failure: return "failure";
  }
  return "unknown";
}

Backend backend_from_string(const std::string& s) {
  for (Backend b : {Backend::Ceres, Backend::Nlopt, Backend::Tao})
    if (s == to_string(b)) return b;
  require(false, "solver.backend", s, "must be one of: ceres, nlopt, tao");
  return Backend::Ceres;
}

Algorithm algorithm_from_string(const std::string& s) {
  for (Algorithm a : {Algorithm::Lbfgs, Algorithm::Bfgs, Algorithm::NonlinearCg, Algorithm::TruncatedNewton,
                      Algorithm::Var2, Algorithm::Mma})
    if (s == to_string(a)) return a;
  require(false, "solver.algorithm", s, "must be one of: lbfgs, bfgs, nonlinear_cg, tnewton, var2, mma");
  return Algorithm::Lbfgs;
}

std::string to_string(TimeScheme s) { return s == TimeScheme::Euler ? "euler" : "bdf2"; }

TimeScheme time_scheme_from_string(const std::string& s) {
  if (s == "euler") return TimeScheme::Euler;
  if (s == "bdf2") return TimeScheme::Bdf2;
  throw InvalidArgument("time_scheme = '" + s + "': must be one of euler, bdf2");
}

std::string to_string(Predictor p) {
  return p == Predictor::None ? "none" : p == Predictor::Extrapolate ? "extrapolate" : "damped";
}

Predictor predictor_from_string(const std::string& s) {
  if (s == "none") return Predictor::None;
  if (s == "extrapolate") return Predictor::Extrapolate;
  if (s == "damped") return Predictor::Damped;
  throw InvalidArgument("predictor = '" + s + "': must be one of none, extrapolate, damped");
}

std::string to_string(ErrorMeasure e) { return e == ErrorMeasure::Density ? "density" : "displacement"; }

ErrorMeasure error_measure_from_string(const std::string& s) {
  if (s == "density") return ErrorMeasure::Density;
  if (s == "displacement") return ErrorMeasure::Displacement;
  throw InvalidArgument("error_measure = '" + s + "': must be one of density, displacement");
}

std::string to_string(StoppingNorm n) { return n == StoppingNorm::Energy ? "energy" : "max"; }

StoppingNorm stopping_norm_from_string(const std::string& s) {
  if (s == "energy") return StoppingNorm::Energy;
  if (s == "max") return StoppingNorm::Max;
  throw InvalidArgument("stopping_norm = '" + s + "': must be one of energy, max");
}

std::string to_string(WidthMode m) { return m == WidthMode::Fixed ? "fixed" : "per_particle"; }

WidthMode width_mode_from_string(const std::string& s) {
  if (s == "fixed") return WidthMode::Fixed;
  if (s == "per_particle") return WidthMode::PerParticle;
  throw InvalidArgument("width_mode = '" + s + "': must be one of fixed, per_particle");
}

std::string to_string(ExplicitScheme s) {
  switch (s) {
    case ExplicitScheme::EulerForce27: return "euler27";
    case ExplicitScheme::Rk4Force27: return "rk4";
    case ExplicitScheme::EulerExactGradient: return "euler_exact";
  }
  return "?";
}

ExplicitScheme explicit_scheme_from_string(const std::string& s) {
  if (s == "euler27") return ExplicitScheme::EulerForce27;
  if (s == "rk4") return ExplicitScheme::Rk4Force27;
  if (s == "euler_exact") return ExplicitScheme::EulerExactGradient;
  throw InvalidArgument("explicit scheme = '" + s + "': must be one of euler27, rk4, euler_exact");
}

std::string to_string(PatchKind k) {
  switch (k) {
    case PatchKind::NoFlux: return "no_flux";
    case PatchKind::Dirichlet: return "dirichlet";
    case PatchKind::Neumann: return "neumann";
  }
  return "unknown";
}

PatchKind patch_kind_from_string(const std::string& s) {
  if (s == "no_flux") return PatchKind::NoFlux;
  if (s == "dirichlet") return PatchKind::Dirichlet;
  if (s == "neumann") return PatchKind::Neumann;
  require(false, "boundary.kind", s, "must be one of no_flux, dirichlet, neumann");
  return PatchKind::NoFlux;
}

std::string to_string(NeumannOutflow m) {
  switch (m) {
    case NeumannOutflow::Layer: return "layer";
    case NeumannOutflow::NearestParticles: return "nearest_particles";
  }
  return "unknown";
}

NeumannOutflow neumann_outflow_from_string(const std::string& s) {
  if (s == "layer") return NeumannOutflow::Layer;
  if (s == "nearest_particles") return NeumannOutflow::NearestParticles;
  require(false, "boundary.neumann_outflow", s, "must be one of layer, nearest_particles");
  return NeumannOutflow::Layer;
}

std::string to_string(DirichletMode m) {
  switch (m) {
    case DirichletMode::Layer: return "layer";
    case DirichletMode::Reservoir: return "reservoir";
  }
  return "unknown";
}

DirichletMode dirichlet_mode_from_string(const std::string& s) {
  if (s == "layer") return DirichletMode::Layer;
  if (s == "reservoir") return DirichletMode::Reservoir;
  require(false, "boundary.dirichlet_mode", s, "must be one of layer, reservoir");
  return DirichletMode::Layer;
}

std::string to_string(ReservoirProfile m) { return m == ReservoirProfile::Uniform ? "uniform" : "odd"; }

ReservoirProfile reservoir_profile_from_string(const std::string& s) {
  if (s == "uniform") return ReservoirProfile::Uniform;
  if (s == "odd") return ReservoirProfile::Odd;
  require(false, "boundary.reservoir_profile", s, "must be one of uniform, odd");
  return ReservoirProfile::Uniform;
}

std::string to_string(ReservoirControl m) { return m == ReservoirControl::Quiet ? "quiet" : "exact"; }

ReservoirControl reservoir_control_from_string(const std::string& s) {
  if (s == "quiet") return ReservoirControl::Quiet;
  if (s == "exact") return ReservoirControl::Exact;
  require(false, "boundary.reservoir_control", s, "must be one of quiet, exact");
  return ReservoirControl::Quiet;
}

std::string to_string(BlobMassMethod method) {
  switch (method) {
    case BlobMassMethod::ClosedForm: return "closed_form";
    case BlobMassMethod::Total: return "total";
    case BlobMassMethod::Quadrature: return "quadrature";
  }
  return "unknown";
}

std::string to_string(StepperKind k) { return k == StepperKind::Implicit ? "implicit" : "explicit"; }

StepperKind stepper_kind_from_string(const std::string& s) {
  if (s == "implicit") return StepperKind::Implicit;
  if (s == "explicit") return StepperKind::Explicit;
  throw InvalidArgument("stepper = \"" + s + "\": must be \"implicit\" or \"explicit\"");
}

std::string to_string(NoFluxTreatment t) { return t == NoFluxTreatment::Barrier ? "barrier" : "images"; }

NoFluxTreatment no_flux_treatment_from_string(const std::string& s) {
  if (s == "barrier") return NoFluxTreatment::Barrier;
  if (s == "images") return NoFluxTreatment::Images;
  throw InvalidArgument("no_flux = \"" + s + "\": must be \"barrier\" or \"images\"");
}

std::string to_string(TreatmentPreset p) { return p == TreatmentPreset::Converging ? "converging" : "papers"; }

TreatmentPreset treatment_preset_from_string(const std::string& s) {
  if (s == "converging") return TreatmentPreset::Converging;
  if (s == "papers") return TreatmentPreset::Papers;
  throw InvalidArgument("preset = \"" + s + "\": must be \"converging\" or \"papers\"");
}

std::string to_string(WidthMetric m) { return m == WidthMetric::AsPrinted ? "as_printed" : "exact"; }

WidthMetric width_metric_from_string(const std::string& s) {
  if (s == "as_printed") return WidthMetric::AsPrinted;
  if (s == "exact") return WidthMetric::ExactGaussian;
  throw InvalidArgument("width_metric = '" + s + "': must be one of as_printed, exact");
}

std::string to_string(DirichletTarget t) { return t == DirichletTarget::CellIntegral ? "cell_integral" : "paper_eq34"; }

DirichletTarget dirichlet_target_from_string(const std::string& s) {
  if (s == "cell_integral") return DirichletTarget::CellIntegral;
  if (s == "paper_eq34") return DirichletTarget::PaperEq34;
  throw InvalidArgument("dirichlet_target = '" + s + "': must be one of cell_integral, paper_eq34");
}

std::string to_string(SpacingRule r) { return r == SpacingRule::Cube ? "cube" : "sphere_radius"; }

SpacingRule spacing_rule_from_string(const std::string& s) {
  if (s == "cube") return SpacingRule::Cube;
  if (s == "sphere_radius") return SpacingRule::SphereRadius;
  throw InvalidArgument("spacing_rule = '" + s + "': must be one of cube, sphere_radius");
}

std::string to_string(FillShape f) {
  return f == FillShape::Uniform ? "uniform" : f == FillShape::Gaussian ? "gaussian" : "cosine";
}

FillShape fill_shape_from_string(const std::string& s) {
  if (s == "uniform") return FillShape::Uniform;
  if (s == "gaussian") return FillShape::Gaussian;
  if (s == "cosine") return FillShape::Cosine;
  throw InvalidArgument("fill shape = '" + s + "': must be one of uniform, gaussian, cosine");
}

}  // namespace otfp
