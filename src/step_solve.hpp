#pragma once
// Internal: one solve of (28) over [t, t + dt] (implicit Euler or variational
// BDF2, with the predictor's start, the stopping rule's thresholds and the
// relative rule, the verdict and the history's shift), the same for the
// serial ImplicitStepper (src/implicit_stepper.cpp) and the distributed step
// (src/mpi/distributed_stepper.cpp). What differs between the two is handed
// in as hooks: the functional with its reductions over the ranks (identity
// serially), how the functional takes a new reference, the minimiser, the
// predictor's admissible start and the local error estimate.
#include <functional>
#include <vector>

#include "otfp/implicit_stepper.hpp"
#include "otfp/step_history.hpp"
#include "step_objective.hpp"

namespace otfp::detail {

struct StepSolveHooks {
  StepFunctional functional;                  // F; its all/sum/max span the ranks (null: one process)
  const ExternalPotential* external = nullptr;  // not null
  // set_dt(dt), set_reference(x_ref, s_ref, m, transport weights), and a
  // neighbour list valid at the start (x, s).
  std::function<void(double dt, const std::vector<Vec3>& x_ref, const std::vector<double>& s_ref,
                     const std::vector<double>& m, const std::vector<double>& weights, const std::vector<Vec3>& x,
                     const std::vector<double>& s)>
      prepare;
  // The predictor's start for a particle moving from `from` towards `to`.
  std::function<Vec3(const Vec3& from, const Vec3& to)> admissible_start;
  // The solve (options validated by the caller).
  std::function<MinimizerSummary(Objective&, std::vector<double>&, const MinimizerOptions&)> minimize;
  // The local error estimate of an accepted solve from (x, s) to (x_new,
  // s_new), into the summary's error fields (hist: before the shift).
  std::function<void(const std::vector<Vec3>& x, const std::vector<double>& s, const std::vector<Vec3>& x_new,
                     const std::vector<double>& s_new, const std::vector<double>& m,
                     const std::vector<DisplacementHistory>& hist, double dt, double dt1, double dt2,
                     StepSummary& summary)>
      estimate;
  // An exception after the objective is built, on this process only (null
  // serially): the distributed step aborts the world there.
  std::function<void(const char* what)> on_collective_error;
};

// One solve from (x, s) with masses m: on success x, s hold the minimiser,
// hist and (dt1, dt2) are shifted by the step, and the summary's figures
// are added; on failure they are left as they were (the summary says why).
bool solve_step(const ImplicitOptions& options, StepSolveHooks& hooks, std::vector<Vec3>& x, std::vector<double>& s,
                const std::vector<double>& m, std::vector<DisplacementHistory>& hist, double& dt1, double& dt2,
                double dt, StepSummary& summary);

// Factor g of the predicted displacement g d1 for a step w = dt / dt_{k-1}
// times the last (docs/stepper.md).
double predictor_factor(Predictor predictor, const DisplacementHistory& h, double omega);

// The predictor's start for one particle: the extrapolation `to`, or the
// largest of 1/2, 1/4, 1/8 of the way from `from` that is no further outside
// the barrier domain and the mirrored walls than `from` is; else `from`.
Vec3 admissible_start(const Barrier& barrier, const std::vector<MirrorWallPtr>& walls, const Vec3& from,
                      const Vec3& to);

// Milne's device per particle (docs/stepper.md): e = factor (x^{k+1} - p),
// p the explicit extrapolation of the scheme's order through the history;
// has[p] = 0 where the history is too short. factor = 0 (and the vectors
// empty) when no estimate is possible at this step.
struct MilneErrors {
  double factor = 0.0;
  std::vector<Vec3> ex;
  std::vector<double> es;
  std::vector<char> has;
};
MilneErrors milne_errors(const ImplicitOptions& options, const std::vector<Vec3>& x, const std::vector<double>& s,
                         const std::vector<Vec3>& x_new, const std::vector<double>& s_new,
                         const std::vector<DisplacementHistory>& hist, double dt, double dt1, double dt2);

// The probes of the density error estimate: particles whose id is a
// multiple of the stride (2^d / 2), about one per 1.6 spacings in 3-D, where
// the smoothed density varies over 2.2 widths; chosen by id so that the
// estimate does not depend on the particles' order or on which process
// holds them (a set with no such id anywhere probes every particle).
bool is_density_probe(ParticleId id, int dim);

// Into the summary: the error estimates from the global mass-weighted sums
// (NaN-aware maxima over substeps): smooth and raw are RMS's relative to the
// width, density the density estimate (NaN: none).
void record_error_estimates(const ImplicitOptions& options, double sum_raw, double sum_smooth, double sum_m,
                            double density_error, StepSummary& summary);

}  // namespace otfp::detail

namespace otfp::detail {

// The density error estimate (ErrorMeasure::Density) in parts: the blobs of
// the step's result and of its explicit extrapolation, both widened by the
// smoothing (a blob of width s convolved with a Gaussian of error_smoothing
// widths has width s sqrt(1 + c^2)). Particles with no estimate enter both
// at their new place.
struct SmoothedBlobs {
  std::vector<Vec3> x_pred;
  std::vector<double> w_new, w_pred;
};
SmoothedBlobs smoothed_blobs(const ImplicitOptions& options, const std::vector<Vec3>& x_new,
                             const std::vector<double>& s_new, const MilneErrors& e);

// Sums over the probes (indices into the first blobs): mass-weighted squared
// density error, mass-weighted density, mass. The sources are the blobs
// (x_new, w_new) and (x_pred, w_pred) with masses m, each list holding every
// blob within reach of the probes (a process's own and its neighbours').
struct DensityErrorSums {
  double error2 = 0.0, density = 0.0, mass = 0.0;
};
DensityErrorSums density_error_sums(int dim, const std::vector<Vec3>& x_new, const std::vector<double>& w_new,
                                    const std::vector<Vec3>& x_pred, const std::vector<double>& w_pred,
                                    const std::vector<double>& m, const std::vector<std::size_t>& probes,
                                    const Periodicity& per, double kernel_tolerance, double factor);
// The estimate from the global sums: the mass-weighted RMS error relative to
// the mass-weighted mean density (NaN without probes).
double density_error_from(const DensityErrorSums& sums);

// The kernel tolerance of the density estimate: a relative precision of
// about 1e-6 of the density, or the functional's own where that is tighter.
double density_error_tolerance(const ImplicitOptions& options);

}  // namespace otfp::detail

namespace otfp::detail {

// The displacement estimate's smoothing (ErrorMeasure::Displacement): each
// particle's error averaged over its list neighbours with Gaussian weights
// of error_smoothing widths. Blobs as rows of kErrorRow values (position,
// width, mass, error in position, error in width, has-estimate); list rows
// [0, n) are the particles summed, `own` their rows; list indices in
// [n, n + ghosts) are other blobs (another rank's: `ghost` holds their rows);
// beyond, image blobs (skipped). Adds to sums: raw, smoothed, mass (each
// mass-weighted, in squared widths).
constexpr int kErrorRow = 10;
std::vector<double> error_rows(const std::vector<Vec3>& x_new, const std::vector<double>& s_new,
                               const std::vector<double>& m, const MilneErrors& e);
void smoothed_error_sums(const ImplicitOptions& options, const NeighborList& list, const Periodicity& per,
                         std::size_t n, const std::vector<double>& own, const std::vector<double>& ghost,
                         double sums[3]);

}  // namespace otfp::detail

namespace otfp::detail {

// One step of length dt from (x, s) (positions unwrapped): a solve, retried
// as 2, 4, ... substeps (max_halvings) when one fails, the summary's F
// before and start being the first substep's. Accepted when a try succeeds
// and its error estimate is within max_error (else error_rejected); then x,
// s, hist, dt1 and dt2 hold the state after it. On any refusal they are left
// as they were.
bool step_with_halvings(const ImplicitOptions& options, StepSolveHooks& hooks, std::vector<Vec3>& x,
                        std::vector<double>& s, const std::vector<double>& m, std::vector<DisplacementHistory>& hist,
                        double& dt1, double& dt2, double dt, double max_error, StepSummary& summary);

}  // namespace otfp::detail
