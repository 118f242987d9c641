#!/usr/bin/python3
"""End-to-end timing of the example configurations (docs/performance.md).

    bench_examples.py [--large] [--out DIR] [--otfp PATH]

Runs each example with `otfp run` (one at a time, one thread) and prints a
markdown table: wall time, steps, evaluations, final particle count and the
profile of the diffusive steps (solver, neighbour list, evaluations) from
summary.json. --large runs the larger sizes listed in LARGE instead.
Run it on an otherwise idle machine.
"""
import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

DEFAULT = [
    ("sphere_dirichlet.toml", []),
    ("box_mixed.toml", []),
    ("pipe_neumann.toml", []),
    ("sphere_injection.toml", []),
    ("square_pipe_occlusion.toml", []),
    ("free_space_heat.toml", []),
    ("periodic_cosine.toml", []),
]
# The largest of the papers' sizes that run here in minutes (one thread),
# as the papers ran them (their treatment, spacing and horizons).
PAPERS = "treatment.preset=papers"
LARGE = [
    ("sphere_dirichlet.toml", ["particles.n_inf=3200", "run.t_end=15", PAPERS]),
    ("box_mixed.toml", ["particles.n_inf=1600", "run.t_end=60", PAPERS]),
    ("pipe_neumann.toml", ["particles.n_inf=4000", PAPERS]),
    ("sphere_injection.toml", ["particles.n_inf=1600", PAPERS]),
]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--large", action="store_true")
    ap.add_argument("--out", default=os.path.join(HERE, "build", "bench_examples"))
    ap.add_argument("--otfp", default=os.path.join(HERE, "build", "src", "cli", "otfp"))
    a = ap.parse_args()
    cases = LARGE if a.large else DEFAULT
    print("| example | overrides | n_inf | steps | T | wall [s] | evaluations | evaluations/step | n at T "
          "| solver | neighbour lists | pair sweeps + barrier | projection, diagnostics, output |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, sets in cases:
        out = os.path.join(a.out, name.replace(".toml", "") + ("_large" if a.large else ""))
        cmd = [a.otfp, "run", os.path.join(HERE, "examples", name), "--out", out, "--quiet",
               "--set", "run.vtk_interval=0", "--set", "run.threads=1"]
        for s in sets:
            cmd += ["--set", s]
        summary_path = os.path.join(out, "summary.json")
        if os.path.exists(summary_path):
            os.remove(summary_path)  # never report a previous run's figures
        rc = subprocess.call(cmd)
        if not os.path.exists(summary_path):
            print(f"| {name} | {' '.join(sets) or '-'} | exit {rc}: no summary.json (see {out}) |")
            continue
        with open(summary_path) as f:
            j = json.load(f)
        p = j["profile"]
        wall = j["wall_seconds"]
        steps = j["final"]["step"]
        ev = j["solver_totals"]["evaluations"]

        def share(v):
            return f"{100.0 * v / wall:.0f}%" if wall > 0 else "-"

        status = "" if rc == 0 else f" (exit {rc}: {j['error']})"
        print(f"| {name}{status} | {' '.join(sets) or '-'} | {j['config']['particles']['n_inf']} | {steps} "
              f"| {j['final']['t']:g} | {wall:.1f} | {ev} | {ev / max(steps, 1):.1f} | {j['final']['n_particles']} "
              f"| {share(p['solver_seconds'])} | {share(p['neighbor_list_seconds'])} "
              f"| {share(p['evaluation_seconds'])} | {share(p['other_seconds'])} |")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
