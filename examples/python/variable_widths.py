"""A variable-width experiment from Python: a Gaussian cloud in free space
whose blobs each optimise their own width (solver.width_mode =
per_particle); histograms of the widths over time, and the growth of the
second moment against 2 d kappa M t.

    python3 examples/python/variable_widths.py [--smoke] [--out DIR]
"""
import argparse
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import otfp  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
CONFIG = HERE.parent / "free_space_heat.toml"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="a small, short run (seconds)")
    ap.add_argument("--out", default="out/python_examples", help="where the figure goes")
    args = ap.parse_args()
    n = 80 if args.smoke else 300
    t_end = 0.02 if args.smoke else 0.1
    cfg = otfp.load_config(CONFIG, [f"particles.n_inf={n}", f"run.t_end={t_end}", "run.dt_factor=0.5",
                                    "solver.width_mode=per_particle", "solver.width_metric=exact"])
    sim = cfg.make_simulation()
    dim = sim.particles.dim
    M = sim.particles.total_mass()
    S0 = otfp.blob_second_moment(sim.particles, cfg.center)
    snapshots = {0.0: np.array(sim.particles.widths)}
    growth = []
    marks = set(np.linspace(0, cfg.n_steps, 4).astype(int)[1:])

    def observe(s, step):
        ps = s.particles  # a copy
        S = otfp.blob_second_moment(ps, cfg.center)
        growth.append((step.t_end, (S - S0) / (2 * dim * 1.0 * M * step.t_end)))  # kappa = 1
        if step.step in marks:
            snapshots[step.t_end] = np.array(ps.widths)

    sim.run_until(cfg.t_end, cfg.dt, observe)
    s_rule = cfg.description["derived"]["width_s"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    bins = np.linspace(0.5 * s_rule, max(w.max() for w in snapshots.values()) * 1.05, 30)
    for t, w in snapshots.items():
        a.hist(w / s_rule, bins=bins / s_rule, histtype="step", label=f"t = {t:.3g}")
        print(f"t = {t:.4g}: widths / s0 in [{w.min() / s_rule:.3f}, {w.max() / s_rule:.3f}], "
              f"mean {w.mean() / s_rule:.3f}")
    a.set_xlabel("s_p / s_0")
    a.set_ylabel("particles")
    a.set_title(f"per-particle widths, n = {len(sim.particles)}")
    a.legend()
    g = np.array(growth)
    b.plot(g[:, 0], g[:, 1], marker="o", ms=3)
    b.axhline(1.0, color="k", ls="--", label="exact: 1")
    b.set_xlabel("t")
    b.set_ylabel("(S(t) - S(0)) / (2 d kappa M t)")
    b.set_title("effective diffusivity / kappa")
    b.legend()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out / "variable_widths.png", dpi=120)
    print(f"growth ratio at t_end: {g[-1, 1]:.4f}; figure: {out / 'variable_widths.png'}")


if __name__ == "__main__":
    main()
