#pragma once
// Every option enum of otfp and its names, in one place (as Ceres' types.h):
// to_string(e) gives the name the configuration files and messages use, and
// <enum>_from_string(name) reads it back, throwing InvalidArgument with the
// list of names for anything else. The headers of the classes that take
// these options include this one.
#include <string>

#include "otfp/types.hpp"

namespace otfp {

// ---- Minimiser (minimizer.hpp)

// Tao: PETSc's TAO (LMVM), from the otfp::mpi component (OTFP_WITH_MPI); a
// program that links it calls register_tao_backend() (otfp/tao.hpp) once.
enum class Backend { Ceres, Nlopt, Tao };

enum class Algorithm {
  Lbfgs,            // Ceres LBFGS / NLopt LD_LBFGS / TAO LMVM (default for all)
  Bfgs,             // Ceres BFGS (Ceres only)
  NonlinearCg,      // Ceres NONLINEAR_CONJUGATE_GRADIENT (Ceres only)
  TruncatedNewton,  // NLopt LD_TNEWTON_PRECOND_RESTART (NLopt only)
  Var2,             // NLopt LD_VAR2 (NLopt only)
  Mma               // NLopt LD_MMA (NLopt only)
};

std::string to_string(Backend b);
std::string to_string(Algorithm a);
Backend backend_from_string(const std::string& s);      // throws InvalidArgument
Algorithm algorithm_from_string(const std::string& s);  // throws InvalidArgument

enum class TerminationReason {
  Converged,          // stopping measure reached gradient_tolerance
  FunctionTolerance,  // relative change of f below function_tolerance
  MaxIterations,      // iteration cap without convergence
  MaxEvaluations,     // evaluation cap without convergence
  LineSearchFailure,  // backend could not make progress (roundoff, failed line search)
  NonFinite,          // the objective reported a non-finite value at the start or throughout
  Failure             // any other backend failure
};
std::string to_string(TerminationReason r);

// ---- Functional (functional.hpp)

// Width metric coefficient c_w of the transport term (docs/method_notes.md#width-metric).
enum class WidthMetric {
  AsPrinted,      // c_w = 1, as printed in (28) and [2023] (15)
  ExactGaussian   // c_w = d/2, the exact 2-Wasserstein distance between isotropic Gaussians
};
std::string to_string(WidthMetric m);
WidthMetric width_metric_from_string(const std::string& s);  // "as_printed" | "exact"

// ---- Implicit stepper (implicit_stepper.hpp)

enum class WidthMode {
  Fixed,       // widths stay as given (the papers' choice)
  PerParticle  // one optimised width per particle, minimising (28) in s as well
};
std::string to_string(WidthMode m);
WidthMode width_mode_from_string(const std::string& s);  // "fixed" | "per_particle"

// Time discretisation of the implicit step (docs/stepper.md).
enum class TimeScheme {
  Euler,  // implicit Euler: minimise (28) from x^k (the papers' scheme, first order)
  Bdf2    // variational BDF2: the same functional about x_hat = x^k + c (x^k - x^{k-1}), second order
};
std::string to_string(TimeScheme s);
TimeScheme time_scheme_from_string(const std::string& s);  // "euler" | "bdf2"

// Starting point of each solve.
enum class Predictor {
  None,        // x^k (the warm start of the papers)
  Extrapolate,  // x^k + (dt_k / dt_{k-1}) (x^k - x^{k-1}), kept inside the walls
  Damped        // the same times each particle's observed ratio of successive displacements, in [0, 1]
};
std::string to_string(Predictor p);
Predictor predictor_from_string(const std::string& s);  // "none" | "extrapolate" | "damped"

// What the local time-error estimate of an implicit step measures (docs/stepper.md).
enum class ErrorMeasure {
  Density,      // the blob density smoothed over a few widths, relative to its mean (what users measure)
  Displacement  // the particles' displacement error in widths, smoothed over a neighbourhood (the former rule)
};
std::string to_string(ErrorMeasure e);
ErrorMeasure error_measure_from_string(const std::string& s);  // "density" | "displacement"

// The norm of the implicit solve's stopping rule (docs/stepper.md).
enum class StoppingNorm {
  Energy,  // mass-weighted RMS of the gradient step (the energy norm of the residual), max-norm as a safety bound
  Max      // the largest gradient step of any particle (the former rule)
};
std::string to_string(StoppingNorm n);
StoppingNorm stopping_norm_from_string(const std::string& s);  // "energy" | "max"

// ---- Explicit stepper (explicit_stepper.hpp)

enum class ExplicitScheme {
  EulerForce27,       // Algorithm 1 line 4: x <- x - dt (kappa grad rho/rho + grad Psi)
  Rk4Force27,         // classical RK4 with the same velocity ([2023] Sec. 5.1)
  EulerExactGradient  // x <- x - dt/m dF/dx with the exact gradient of (28)
};
std::string to_string(ExplicitScheme s);
ExplicitScheme explicit_scheme_from_string(const std::string& s);  // "euler27" | "rk4" | "euler_exact"

// ---- Boundary projection (boundary.hpp)

enum class PatchKind { NoFlux, Dirichlet, Neumann };
std::string to_string(PatchKind k);
PatchKind patch_kind_from_string(const std::string& s);  // "no_flux" | "dirichlet" | "neumann"

// What a Neumann outlet does when its cell B_l holds fewer particles than the
// owed outflow (ProjectionOptions::neumann_outflow).
enum class NeumannOutflow {
  Layer,            // papers: remove only from B_l; the rest is carried as debt (deficit)
  NearestParticles  // remove from B_l first, then the particles nearest A_l; debt only with no particles left
};
std::string to_string(NeumannOutflow m);
NeumannOutflow neumann_outflow_from_string(const std::string& s);  // "layer" | "nearest_particles"

// How a Dirichlet patch imposes g (ProjectionOptions::dirichlet_mode).
enum class DirichletMode {
  Layer,     // papers: fill / empty B_l^int to its target mass each step (Sec. 4.2)
  Reservoir  // persistent exterior band of thickness w, each of K sublayers held at its count
};
std::string to_string(DirichletMode m);
DirichletMode dirichlet_mode_from_string(const std::string& s);  // "layer" | "reservoir"

// The count each reservoir sublayer is held at (ProjectionOptions::reservoir_profile).
enum class ReservoirProfile {
  Uniform,  // density g in every sublayer
  Odd       // density 2 g - rho_in, rho_in the particle density of the sublayer's mirror image
            // inside Omega (clamped to [0, 2 g]): u - g odd across the face, so the blob
            // density at the face is g while the interior next to it is not yet at g
};
std::string to_string(ReservoirProfile m);
ReservoirProfile reservoir_profile_from_string(const std::string& s);  // "uniform" | "odd"

// How the reservoir holds its sublayers at their counts (ProjectionOptions::reservoir_control).
enum class ReservoirControl {
  Quiet,  // a sublayer is corrected only when its count leaves a tolerance band around its target;
          // particles go where the blob density is lowest and leave where it is highest (no random numbers)
  Exact   // every sublayer set to exactly its count every step, surplus deleted and missing
          // particles inserted uniformly at random (issue 10's rule: churns in a steady state)
};
std::string to_string(ReservoirControl m);
ReservoirControl reservoir_control_from_string(const std::string& s);  // "quiet" | "exact"

// How the Dirichlet target mass of B_l^int is computed (docs/method_notes.md#dirichlet-target).
enum class DirichletTarget {
  CellIntegral,  // integral of g over the cell B_l^int itself (default)
  PaperEq34      // (34): b times the integral of g over A_l (over-fills curved layers)
};
std::string to_string(DirichletTarget t);
DirichletTarget dirichlet_target_from_string(const std::string& s);  // "cell_integral" | "paper_eq34"

// ---- Parameters (parameters.hpp)

// How the mean spacing dr follows from |Omega| and n.
enum class SpacingRule {
  Cube,         // (37): dr = (|Omega|/n)^(1/d)
  SphereRadius  // Tables 1-3: radius of a ball of volume |Omega|/n, dr = (3|Omega|/(4 pi n))^(1/3) (d = 3)
};
std::string to_string(SpacingRule r);
SpacingRule spacing_rule_from_string(const std::string& s);  // "cube" | "sphere_radius"

// ---- Measures (mass_measure.hpp)

enum class BlobMassMethod { ClosedForm, Total, Quadrature };
std::string to_string(BlobMassMethod method);

// ---- Algorithm 1 (simulation.hpp)

enum class StepperKind { Implicit, Explicit };
std::string to_string(StepperKind k);
StepperKind stepper_kind_from_string(const std::string& s);  // "implicit" | "explicit"

// How no-flux walls hold the particles in: the barrier (27) alone, or image
// blobs across each wall as well (docs/boundaries.md).
enum class NoFluxTreatment { Barrier, Images };
std::string to_string(NoFluxTreatment t);
NoFluxTreatment no_flux_treatment_from_string(const std::string& s);  // "barrier" | "images"

// ---- Run set-up (run_setup.hpp)

// The boundary treatment as a whole (docs/boundaries.md): what study 5
// measured best (images, the odd reservoir, outlets that reach the nearest
// particles, the true spacing), or Sec. 4.2 of the 2025 paper (barrier, the
// b-thick Dirichlet layer, outlets that take only from B_l, and in 3-D the
// sphere-radius spacing of Tables 1-3).
enum class TreatmentPreset { Converging, Papers };
std::string to_string(TreatmentPreset p);
TreatmentPreset treatment_preset_from_string(const std::string& s);  // "converging" | "papers"

// ---- Initial fill (initial_fill.hpp)

enum class FillShape { Uniform, Gaussian, Cosine };
std::string to_string(FillShape f);
FillShape fill_shape_from_string(const std::string& s);  // "uniform" | "gaussian" | "cosine"

}  // namespace otfp
