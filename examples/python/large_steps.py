"""Large steps from your own code: the sphere of Sec. 5.1 built from library
calls (no configuration file), stepped at about 1x, 5x and 10x the explicit
limit dt = dr^2 / kappa (39) with the implicit stepper (variational BDF2 from
an extrapolated start); every step's summary is printed with its distance
from Crank's uptake. The steps are equal and end on t_end, so each run is
labelled by the step it actually takes.

    python3 examples/python/large_steps.py [--smoke]
"""
import argparse
import math
import time

import otfp


def sphere(n_inf, implicit_options):
    ball = otfp.make_ball(3, [0, 0, 0], 1.0)
    g = 1.0
    pp = otfp.paper_parameters(ball.volume, n_inf, 3, length_L=1.0, kappa=1.0)  # (36)-(40)
    boundary = [otfp.BoundaryData(patch=0, kind="dirichlet", value=g)]
    # The converging boundary treatment of `otfp run` (docs/boundaries.md): a
    # reservoir band one cut-off wide. SimulationOptions() alone would be the
    # papers' layer, which does not converge to Crank.
    opts = otfp.converging_options(ball, boundary, n_inf=n_inf, length_L=1.0, particle_mass=g * ball.volume / n_inf)
    implicit = opts.implicit
    for key, value in implicit_options.items():
        setattr(implicit, key, value)
    opts.implicit = implicit
    sim = otfp.Simulation(ball, boundary, opts)
    sim.start(otfp.ParticleSet(3))
    return sim, pp, g * ball.volume


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="a small, short run (seconds)")
    args = ap.parse_args()
    n_inf, t_end, factors = (150, 0.5, (1, 5)) if args.smoke else (300, 0.6, (1, 5, 10))
    for factor in factors:
        # Large steps: BDF2 (second order) from a predicted start.
        sim, pp, M_inf = sphere(n_inf, dict(time_scheme="bdf2", predictor="extrapolate"))
        # run_until takes equal steps of at most dt that end on t_end: label
        # the run by the step it takes, not by the factor asked for.
        steps = math.ceil(t_end / (factor * pp.dt_explicit))
        dt = t_end / steps
        print(f"--- dt = {dt / pp.dt_explicit:.3g}x the explicit limit ({dt:.4g}, {steps} steps; asked {factor}x)")
        errors = []

        def observe(s, step):
            ratio = s.measure([0, 0, 0])[0].mass_inside / M_inf
            errors.append(ratio - otfp.analytic.crank_sphere_uptake(step.t_end))  # R = kappa = 1
            print(f"  {step.brief_report()}; M/M_inf - Crank = {errors[-1]:+.4f}")

        start = time.perf_counter()
        sim.run_until(t_end, dt, observe)
        seconds = time.perf_counter() - start
        print(f"  {sim.step_count} steps, {sim.totals.evaluations} evaluations, {seconds:.1f} s; "
              f"max |M/M_inf - Crank| over the steps {max(abs(e) for e in errors):.4f}")


if __name__ == "__main__":
    main()
