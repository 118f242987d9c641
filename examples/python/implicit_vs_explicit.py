"""Implicit vs explicit on the sphere of [2025] Sec. 5.1, from Python.

Loads examples/sphere_dirichlet.toml (the CLI's configuration) three times:
the implicit stepper at dt = 1x and 10x the explicit limit (39), and the
explicit scheme of Algorithm 1 at 0.5x. Each run records M(t)/M_inf (43)
through a run_until observer; the figure compares them with Crank's uptake.

    python3 examples/python/implicit_vs_explicit.py [--smoke] [--out DIR]
"""
import argparse
import pathlib
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import otfp  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
CONFIG = HERE.parent / "sphere_dirichlet.toml"


def run(label, overrides):
    cfg = otfp.load_config(CONFIG, overrides)
    sim = cfg.make_simulation()
    t, ratio = [0.0], [sim.measure(cfg.center)[0].mass_inside / cfg.M_inf]

    def observe(s, step):
        t.append(step.t_end)
        ratio.append(s.measure(cfg.center)[0].mass_inside / cfg.M_inf)

    start = time.perf_counter()
    sim.run_until(cfg.t_end, cfg.dt, observe)
    seconds = time.perf_counter() - start
    t, ratio = np.array(t), np.array(ratio)
    crank = otfp.analytic.crank_sphere_uptake(t)  # R = 1, kappa = 1
    err = np.max(np.abs(ratio - crank))
    print(f"{label:28s} steps {sim.step_count:4d}  evaluations {sim.totals.evaluations:6d}  "
          f"max |M/M_inf - Crank| {err:.4f}  {seconds:.1f} s")
    return t, ratio, err


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="a small, short run (seconds)")
    ap.add_argument("--out", default="out/python_examples", help="where the figure goes")
    args = ap.parse_args()
    size = ["particles.n_inf=150", "run.t_end=0.1"] if args.smoke else ["particles.n_inf=400", "run.t_end=0.5"]
    runs = {
        "implicit, dt = 1x": size + ["run.dt_factor=1"],
        "implicit, dt = 10x": size + ["run.dt_factor=10"],
        "explicit (Alg. 1), dt = 0.5x": size + ["solver.stepper=explicit", "run.dt_factor=0.5"],
    }
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, overrides in runs.items():
        t, ratio, err = run(label, overrides)
        ax.plot(t, ratio, marker="o" if len(t) < 30 else None, ms=3, label=f"{label} (max err {err:.3f})")
    tt = np.linspace(0.0, t[-1], 200)
    ax.plot(tt, otfp.analytic.crank_sphere_uptake(tt), "k--", label="Crank (6.20)")
    ax.set_xlabel("t")
    ax.set_ylabel("M(t) / M_inf")
    ax.set_title("Sphere of Sec. 5.1: implicit vs explicit")
    ax.legend(fontsize=8)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out / "implicit_vs_explicit.png", dpi=120)
    print(f"figure: {out / 'implicit_vs_explicit.png'}")


if __name__ == "__main__":
    main()
