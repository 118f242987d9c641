#!/usr/bin/env python3
"""Per-particle widths at long times (issue 25, item 4).

Free-space heat (examples/free_space_heat.toml: a Gaussian cloud of blobs,
fill_sigma = 0.2) run with adaptive dt to t = 2 in d = 2 and 3, where the
cloud spreads to radius ~ sqrt(2 d t) ~ 3 and the particle spacing grows
about tenfold. Fixed widths against per-particle widths (c_w = d/2,
solver.width_metric = "exact"), both with the implicit stepper, against the
heat kernel's second moment S(t) = S(0) + 2 d kappa M t.

Uses the command-line tool only:

    scripts/long_time_widths.py BUILD_DIR [--out DIR] [--only NAME ...] [--list]

BUILD_DIR is the build tree (the tool is BUILD_DIR/src/cli/otfp). Runs go
to DIR (default BUILD_DIR/long_time_widths), one at a time, one thread.
Prints one Markdown table of the runs and one of the widths against the
spacing. Columns (T = t_end = 2):

  growth       (S(T) - S(0)) / (2 d kappa M T): 1 for the heat kernel
                (= 1 + error_second_moment of the last row of series.csv)
  Euler identity  per-particle widths, Euler: the largest relative
                violation of S_k - S_{k-1} = 2 d kappa M dt - 2 dt transport_k
                (exact at the minimiser, see analyse()); the solver's residual
  growth, time  the same for a single Gaussian (variance S/(d M) per axis)
                stepped by the run's own scheme and dt sequence: the
                variational step restricted to isotropic Gaussians is that
                scheme applied to d sigma/dt = kappa/sigma, so this is the
                time-discretisation part of the error alone
  steps, evals/step, wall, rejected (error-test retries + halvings)
  dt/dt_expl    mean step over the late half (steps starting at t >= T/2)
                over dt_explicit = dr^2/kappa of the run (dr from the box)
  dt/t          median dt_k / t_{k-1} over the same steps (last step,
                cut to end on T, left out)
Widths: s_rms(t) = sqrt(2 (S - J) / (d M)) from series.csv (S - J =
d/2 sum m s^2); h(t) = (m / rho(r_med, t))^(1/d), the spacing of the exact
kernel (variance S(0)/(d M) + 2 kappa t per axis) at its mass-median radius;
median s_p/h_p over the particles of particles_final.csv with h_p the
kernel's spacing at x_p.
"""
import argparse
import csv
import json
import math
import os
import re
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
CONFIG = os.path.join(HERE, "..", "examples", "free_space_heat.toml")
T_END = 2.0
KAPPA = 1.0
# Median of the chi-square distribution with d degrees of freedom: the
# mass-median of |x|^2 / v for a d-dimensional Gaussian of variance v per axis.
CHI2_MEDIAN = {1: 0.454936423119572, 2: 2.0 * math.log(2.0), 3: 2.365973884375338}

PP = ["solver.width_mode=per_particle", "solver.width_metric=exact"]
EULER = ["solver.time_scheme=euler"]
BDF2 = ["solver.time_scheme=bdf2"]


def tol(x):
    return [f"run.time_tolerance={x}"]


# name, dim, n_inf, widths label, scheme label, --set values
CASES = []
for d in (2, 3):
    CASES += [
        (f"d{d}_fixed_euler_1e-2", d, 400, "fixed", "Euler 1e-2", EULER + tol("1e-2")),
        (f"d{d}_fixed_bdf2_1e-3", d, 400, "fixed", "BDF2 1e-3", BDF2 + tol("1e-3")),
        (f"d{d}_pp_euler_1e-2", d, 400, "per particle", "Euler 1e-2", PP + EULER + tol("1e-2")),
        (f"d{d}_pp_euler_1e-3", d, 400, "per particle", "Euler 1e-3", PP + EULER + tol("1e-3")),
        (f"d{d}_pp_bdf2_1e-2", d, 400, "per particle", "BDF2 1e-2", PP + BDF2 + tol("1e-2")),
        (f"d{d}_pp_bdf2_1e-3", d, 400, "per particle", "BDF2 1e-3", PP + BDF2 + tol("1e-3")),
        (f"d{d}_pp_bound3_bdf2_1e-3", d, 400, "per particle, bound 3 s0", "BDF2 1e-3",
         PP + BDF2 + tol("1e-3") + ["solver.max_width_factor=3"]),
    ]
    if d == 3:
        CASES.append((f"d{d}_pp_printed_bdf2_1e-3", d, 400, "per particle, c_w = 1", "BDF2 1e-3",
                      ["solver.width_mode=per_particle", "solver.width_metric=as_printed"] + BDF2 + tol("1e-3")))
    CASES += [
        (f"d{d}_fixed_bdf2_1e-3_n1600", d, 1600, "fixed", "BDF2 1e-3", BDF2 + tol("1e-3")),
        (f"d{d}_pp_bdf2_1e-2_n1600", d, 1600, "per particle", "BDF2 1e-2", PP + BDF2 + tol("1e-2")),
    ]
# Seed spread of one case (the fill is random).
for seed in (2, 3):
    for d in (2, 3):
        CASES.append((f"d{d}_pp_bdf2_1e-3_seed{seed}", d, 400, "per particle", f"BDF2 1e-3, seed {seed}",
                      PP + BDF2 + tol("1e-3") + [f"run.seed={seed}"]))

COMMON = [f"run.t_end={T_END}", "run.dt_mode=adaptive", "run.seed=1", "run.vtk_interval=0",
          "run.checkpoint_interval=0", "run.threads=1"]


def run_case(otfp, out, case):
    name, d, n_inf, _, _, sets = case
    args = [otfp, "run", CONFIG, "--out", os.path.join(out, name), "--overwrite"]
    for s in COMMON + [f"run.dim={d}", f"particles.n_inf={n_inf}"] + sets:
        args += ["--set", s]
    t0 = time.time()
    p = subprocess.run(args, capture_output=True, text=True)
    sys.stderr.write(f"{name}: exit {p.returncode}, {time.time() - t0:.1f} s  {p.stdout.strip()}{p.stderr.strip()}\n")
    return p.returncode


def gaussian_growth(rows, d, M, scheme):
    """Growth ratio of one Gaussian stepped by the run's scheme and dt's."""
    S0 = float(rows[0]["second_moment"])
    sig = math.sqrt(S0 / (d * M))
    prev, dt_prev = None, None
    for r in rows[1:]:
        dt = float(r["dt"])
        if scheme == "bdf2" and prev is not None:
            w = dt / dt_prev
            a0 = (1 + 2 * w) / (1 + w)
            xh = sig + w * w / (1 + 2 * w) * (sig - prev)
            new = 0.5 * (xh + math.sqrt(xh * xh + 4 * KAPPA * dt / a0))
        else:
            new = 0.5 * (sig + math.sqrt(sig * sig + 4 * KAPPA * dt))
        prev, sig, dt_prev = sig, new, dt
    T = float(rows[-1]["t"])
    return (d * M * sig * sig - S0) / (2 * d * KAPPA * M * T)


def kernel_spacing(d, m, M, v, r2):
    rho = M * (2 * math.pi * v) ** (-d / 2) * math.exp(-r2 / (2 * v))
    return (m / rho) ** (1.0 / d)


def analyse(out, case):
    name, d, n_inf, widths, scheme_label, _ = case
    run = os.path.join(out, name)
    summ = json.load(open(os.path.join(run, "summary.json")))
    res = {"name": name, "d": d, "n_inf": n_inf, "widths": widths, "scheme": scheme_label,
           "status": summ["status"]}
    if summ["status"] != "completed":
        res["error"] = summ.get("error", "")
        return res
    rows = list(csv.DictReader(open(os.path.join(run, "series.csv"))))
    der = summ["derived"]
    cfg = summ["config"]
    M = float(rows[0]["mass_total"])
    m = der["particle_mass"]
    s0 = der["width_s"]
    dt_expl = der["dt_explicit"]
    S0 = float(rows[0]["second_moment"])
    T = float(rows[-1]["t"])
    S = float(rows[-1]["second_moment"])
    res["growth"] = (S - S0) / (2 * d * KAPPA * M * T)
    res["growth_time"] = gaussian_growth(rows, d, M, cfg["solver"]["time_scheme"])
    res["rel_err_S"] = S / float(rows[-1]["reference_second_moment"]) - 1
    # growth over [0, T/8] (= 0.25, the earlier study's T), first row at or after it
    r8 = next(r for r in rows if float(r["t"]) >= T / 8 - 1e-12)
    res["growth_T8"] = (float(r8["second_moment"]) - S0) / (2 * d * KAPPA * M * float(r8["t"]))
    # Implicit Euler with per-particle widths and c_w = d/2 in free space:
    # S_k - S_{k-1} = 2 d kappa M dt - 2 dt transport_k exactly at the
    # minimiser (the entropy of blobs dilated by lambda, centres and widths,
    # is E - kappa M d log lambda). Largest violation over the steps (not
    # halved), relative to 2 d kappa M dt: the solver's residual.
    res["identity"] = None
    if cfg["solver"]["time_scheme"] == "euler" and cfg["solver"]["width_mode"] == "per_particle":
        worst = 0.0
        for a, b in zip(rows, rows[1:]):
            if int(b["halvings"]) != 0:
                continue
            dt = float(b["dt"])
            dS = float(b["second_moment"]) - float(a["second_moment"])
            worst = max(worst, abs(dS + 2 * dt * float(b["transport"]) - 2 * d * KAPPA * M * dt) / (2 * d * KAPPA * M * dt))
        res["identity"] = worst
    steps = len(rows) - 1
    tot = summ["solver_totals"]
    res["steps"] = steps
    res["evals_per_step"] = tot["evaluations"] / steps
    res["wall"] = summ["wall_seconds"]
    res["rejected"] = tot["error_rejected_steps"] + tot["halvings"]
    late = [(float(rows[k - 1]["t"]), float(rows[k]["dt"])) for k in range(1, len(rows))
            if float(rows[k - 1]["t"]) >= T / 2 - 1e-12]
    res["late_steps"] = len(late)
    res["dt_over_expl"] = sum(dt for _, dt in late) / len(late) / dt_expl
    ratios = [dt / t0 for t0, dt in late[:-1]] or [late[-1][1] / late[-1][0]]
    res["dt_over_t"] = statistics.median(ratios)

    def s_rms(r):
        return math.sqrt(max(0.0, 2 * (float(r["second_moment"]) - float(r["polar_inertia_total"])) / (d * M)))

    v0 = S0 / (d * M)

    def h_med(t):
        v = v0 + 2 * KAPPA * t
        return kernel_spacing(d, m, M, v, CHI2_MEDIAN[d] * v)

    res["s0"] = s0
    res["s0_over_h0"] = s_rms(rows[0]) / h_med(0.0)
    res["srms_over_s0_T"] = s_rms(rows[-1]) / s0
    res["srms_over_h_T8"] = s_rms(r8) / h_med(float(r8["t"]))
    res["srms_over_h_T"] = s_rms(rows[-1]) / h_med(T)
    vT = v0 + 2 * KAPPA * T
    ratios, widths_p = [], []
    with open(os.path.join(run, "particles_final.csv")) as f:
        for p in csv.DictReader(f):
            r2 = sum(float(p[c]) ** 2 for c in "xyz"[:d])
            ratios.append(float(p["width_s"]) / kernel_spacing(d, float(p["mass"]), M, vT, r2))
            widths_p.append(float(p["width_s"]) / s0)
    q = statistics.quantiles(ratios, n=20)
    res["s_over_h_T_q05"], res["median_s_over_h_T"], res["s_over_h_T_q95"] = q[0], statistics.median(ratios), q[-1]
    res["max_s_over_s0_T"] = max(widths_p)
    # Fourth moment Q = sum m E|Y|^4 of the blob density. The heat kernel
    # gives it exactly from the initial state: with a^2 = 2 kappa t,
    # Q(t) = Q(0) + 2 (d + 2) a^2 S(0) + d (d + 2) a^4 M. The flatness
    # K = d Q M / ((d + 2) S^2) is 1 for a Gaussian; K(T) against the kernel's
    # K_ref(T) measures the shape, not the variance.
    first = read_vtp(os.path.join(run, "particles_00000.vtp"))
    final = read_final_csv(os.path.join(run, "particles_final.csv"))
    M0, S0p, Q0 = blob_moments(first, d)
    MT, STp, QT = blob_moments(final, d)
    a2 = 2 * KAPPA * T
    Qref = Q0 + 2 * (d + 2) * a2 * S0p + d * (d + 2) * a2 * a2 * M0
    Sref = S0p + d * a2 * M0

    def flat(Q, S, M):
        return d * Q * M / ((d + 2) * S * S)

    res["K0"], res["KT"], res["Kref"] = flat(Q0, S0p, M0), flat(QT, STp, MT), flat(Qref, Sref, M0)
    res["shape0"], res["shapeT"] = shape_distance(first, d), shape_distance(final, d)
    return res


def read_vtp(path):
    """mass, width_s and position arrays of an otfp particle snapshot (raw appended VTK XML)."""
    import struct
    data = open(path, "rb").read()
    head, _, tail = data.partition(b'<AppendedData encoding="raw">')
    base = tail.index(b"_") + 1
    out = {}
    for m in re.finditer(rb'<DataArray type="(\w+)" Name="(\w+)"(?: NumberOfComponents="(\d)")? format="appended" offset="(\d+)"',
                         head):
        typ, name, _, off = m.groups()
        if name not in (b"mass", b"width_s", b"position"):
            continue
        o = base + int(off)
        (nbytes,) = struct.unpack_from("<Q", tail, o)
        vals = struct.unpack_from(f"<{nbytes // 8}d", tail, o + 8)
        out[name.decode()] = vals
    pos = out["position"]
    return [(out["mass"][i], out["width_s"][i], pos[3 * i:3 * i + 3]) for i in range(len(out["mass"]))]


def read_final_csv(path):
    with open(path) as f:
        return [(float(p["mass"]), float(p["width_s"]), (float(p["x"]), float(p["y"]), float(p["z"])))
                for p in csv.DictReader(f)]


def blob_moments(parts, d):
    """M, second and fourth moments of the blob density about 0 (blob p: N(x_p, s_p^2/2 per axis))."""
    M = S = Q = 0.0
    for m, s, x in parts:
        r2 = sum(c * c for c in x[:d])
        v = s * s / 2
        M += m
        S += m * (r2 + d * v)
        Q += m * (r2 * r2 + 2 * (d + 2) * r2 * v + d * (d + 2) * v * v)
    return M, S, Q


def gaussian_radial_cdf(d, u):
    """P(|X| <= u sqrt(v)) for X ~ N(0, v I_d)."""
    if d == 2:
        return 1 - math.exp(-u * u / 2)
    if d == 3:
        return math.erf(u / math.sqrt(2)) - math.sqrt(2 / math.pi) * u * math.exp(-u * u / 2)
    return math.erf(u / math.sqrt(2))


def shape_distance(parts, d, samples=100, seed=0):
    """Largest distance between the radial distribution of the blob density
    (Monte Carlo, `samples` draws per blob, fixed seed) and that of a Gaussian
    of the same second moment: the shape error, free of the variance's."""
    import random
    rng = random.Random(seed)
    M, S, _ = blob_moments(parts, d)
    v = S / (d * M)
    us = []
    for m, s, x in parts:
        sd = s / math.sqrt(2)
        for _ in range(samples):
            r2 = sum((x[k] + sd * rng.gauss(0, 1)) ** 2 for k in range(d))
            us.append((math.sqrt(r2 / v), m / samples))
    us.sort()
    acc, worst = 0.0, 0.0
    for u, m in us:
        f = gaussian_radial_cdf(d, u)
        worst = max(worst, abs(acc / M - f))
        acc += m
        worst = max(worst, abs(acc / M - f))
    return worst


def fmt_e(x):
    return "-" if x is None else f"{x:.0e}"


def fmt(x, p=3):
    return "-" if x is None else f"{x:.{p}f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("build_dir")
    ap.add_argument("--out", help="directory of the runs (default BUILD_DIR/long_time_widths)")
    ap.add_argument("--only", nargs="*", help="run only these case names")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    ap.add_argument("--analyse-only", action="store_true", help="do not run, only read the runs in --out")
    a = ap.parse_args()
    if a.list:
        for c in CASES:
            print(c[0])
        return 0
    otfp = os.path.join(a.build_dir, "src", "cli", "otfp")
    if not os.access(otfp, os.X_OK):
        sys.exit(f"{otfp}: not found (build the target otfp_cli)")
    out = a.out or os.path.join(a.build_dir, "long_time_widths")
    os.makedirs(out, exist_ok=True)
    cases = [c for c in CASES if not a.only or c[0] in a.only]
    if not a.analyse_only:
        for c in cases:
            run_case(otfp, out, c)
    results = [analyse(out, c) for c in cases]
    with open(os.path.join(out, "results.json"), "w") as f:
        json.dump(results, f, indent=1)

    print(f"Free-space heat, sigma_fill = 0.2, T = {T_END}, adaptive dt, implicit stepper (ceres L-BFGS)\n")
    print("| d | n_inf | widths | scheme, tol | growth(T/8) | growth(T) | growth, time only | Euler identity | steps"
          " | evals/step | rejected | dt/dt_expl late | dt/t late | wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        if r["status"] != "completed":
            print(f"| {r['d']} | {r['n_inf']} | {r['widths']} | {r['scheme']} | {r['status']}: {r.get('error', '')} |"
                  " | | | | | | | | |")
            continue
        print(f"| {r['d']} | {r['n_inf']} | {r['widths']} | {r['scheme']} | {fmt(r['growth_T8'])} | {fmt(r['growth'])}"
              f" | {fmt(r['growth_time'])} | {fmt_e(r['identity'])} | {r['steps']} | {r['evals_per_step']:.0f} | {r['rejected']}"
              f" | {r['dt_over_expl']:.1f} | {r['dt_over_t']:.3f} | {r['wall']:.1f} |")
    print("\nWidths against the spacing h of the exact kernel at its mass-median radius\n")
    print("| d | n_inf | widths | scheme, tol | s0 | s0/h(0) | s_rms/h(T/8) | s_rms/h(T) | s_p/h_p(T) 5/50/95%"
          " | s_rms/s0 (T) | max s_p/s0 (T) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        if r["status"] != "completed":
            continue
        print(f"| {r['d']} | {r['n_inf']} | {r['widths']} | {r['scheme']} | {r['s0']:.4f} | {fmt(r['s0_over_h0'], 2)}"
              f" | {fmt(r['srms_over_h_T8'], 2)} | {fmt(r['srms_over_h_T'], 2)}"
              f" | {r['s_over_h_T_q05']:.2f} / {r['median_s_over_h_T']:.2f} / {r['s_over_h_T_q95']:.2f}"
              f" | {fmt(r['srms_over_s0_T'], 2)} | {fmt(r['max_s_over_s0_T'], 2)} |")
    print("\nShape of the blob density: flatness K = d Q M / ((d + 2) S^2) (Q the fourth moment; 1 for a Gaussian)"
          " against the heat kernel's K_ref(T) from the initial state, and the largest distance between the radial"
          " distribution and a Gaussian's of the same second moment (Monte Carlo, 100 draws per blob)\n")
    print("| d | n_inf | widths | scheme, tol | K(0) | K(T) | K_ref(T) | radial distance t = 0 | radial distance T |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in results:
        if r["status"] != "completed":
            continue
        print(f"| {r['d']} | {r['n_inf']} | {r['widths']} | {r['scheme']} | {r['K0']:.3f} | {r['KT']:.3f}"
              f" | {r['Kref']:.3f} | {r['shape0']:.3f} | {r['shapeT']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
