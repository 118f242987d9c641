#pragma once
// Time steppers for the diffusive fractional step: the implicit variational
// step (minimise (28) with Ceres or NLopt) and the explicit baselines of
// Algorithm 1 (sign corrected, docs/method_notes.md#explicit-sign).
//
// Umbrella header, kept so that existing code compiles; include the specific
// header instead:
//   otfp/step_summary.hpp        StepSummary (what every step reports)
//   otfp/external_potential.hpp  ExternalPotential (Psi of (15), both steppers)
//   otfp/implicit_stepper.hpp    ImplicitStepper, ImplicitOptions, WidthMode, TimeScheme, Predictor
//   otfp/explicit_stepper.hpp    ExplicitStepper, ExplicitOptions, ExplicitScheme
#include "otfp/explicit_stepper.hpp"
#include "otfp/external_potential.hpp"
#include "otfp/implicit_stepper.hpp"
#include "otfp/step_summary.hpp"
