#!/usr/bin/env python3
"""Plots of an otfp run directory (needs numpy and matplotlib, e.g. Debian's
python3-numpy and python3-matplotlib).

    python3 scripts/plot.py OUTDIR [--out PNGDIR]
        mass.png     M/M_inf against t (inside, with the external layer), with
                     Crank's curve when the run has a reference
        inertia.png  J_G/J_inf against t (or J_G and the free-space line)
        slice.png    particles of the last VTK snapshot in a slab through the
                     diagnostics centre, coloured by age

    python3 scripts/plot.py --convergence DIR1 DIR2 DIR3 ... [--out PNGDIR]
        convergence.png  relative L1-in-time error of M and J_G against m_p
                         with a fitted power law (the paper's Figs. 4, 5, 11, 12, 15)

The L1 norms are those of summary.json "l1" (46a)-(46b) as printed: rectangle
sums over all particles. As in the paper, the error of run i is
|L_i - L_inf| / L_inf with L_inf, a, q fitted to L_i = L_inf + a m_p^q.
"""
import argparse
import csv
import json
import math
import os
import re
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


# ----------------------------------------------------------------- reading

def read_series(run_dir):
    with open(os.path.join(run_dir, "series.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        sys.exit(f"plot.py: {run_dir}/series.csv has no rows")
    # Empty cells (error_estimate without an estimate) read as NaN.
    return {k: np.array([float(r[k]) if r[k] != "" else np.nan for r in rows]) for k in rows[0]}


def read_summary(run_dir):
    with open(os.path.join(run_dir, "summary.json")) as f:
        return json.load(f)


_VTK_TYPES = {"Float64": "<f8", "Float32": "<f4", "Int64": "<i8", "Int32": "<i4", "UInt8": "u1", "UInt64": "<u8"}


def read_vtp(path):
    """Arrays of a .vtp written by otfp (raw appended data, UInt64 headers)."""
    with open(path, "rb") as f:
        data = f.read()
    marker = data.index(b'<AppendedData encoding="raw">')
    start = data.index(b"_", marker) + 1
    head = data[:marker].decode()
    arrays = {}
    for tag in re.findall(r"<DataArray[^>]*>", head):
        attrs = dict(re.findall(r'(\w+)="([^"]*)"', tag))
        if attrs.get("format") != "appended":
            continue
        off = start + int(attrs["offset"])
        nbytes = int.from_bytes(data[off:off + 8], "little")
        values = np.frombuffer(data[off + 8:off + 8 + nbytes], dtype=_VTK_TYPES[attrs["type"]])
        comps = int(attrs.get("NumberOfComponents", "1"))
        arrays[attrs["Name"]] = values.reshape(-1, comps) if comps > 1 else values
    time = re.search(r'Name="TimeValue"[^>]*>([^<]*)<', head)
    arrays["_time"] = float(time.group(1)) if time else float("nan")
    return arrays


def last_snapshot(run_dir):
    pvd = os.path.join(run_dir, "particles.pvd")
    if os.path.exists(pvd):
        with open(pvd) as f:
            files = re.findall(r'file="([^"]+)"', f.read())
        if files:
            return os.path.join(run_dir, files[-1])
    files = sorted(f for f in os.listdir(run_dir) if re.fullmatch(r"particles_\d+\.vtp", f))
    return os.path.join(run_dir, files[-1]) if files else None


# ----------------------------------------------------------------- references

def crank_sphere(kappa, radius, t):
    t = np.asarray(t, dtype=float)
    out = np.zeros_like(t)
    n = np.arange(1, 20001, dtype=float)[:, None]
    pos = t > 0
    s = np.sum(np.exp(-n * n * math.pi ** 2 * kappa * t[pos][None, :] / radius ** 2) / (n * n), axis=0)
    out[pos] = 1.0 - 6.0 / math.pi ** 2 * s
    return out


def crank_slab(kappa, length, t):
    t = np.asarray(t, dtype=float)
    out = np.zeros_like(t)
    o = (2.0 * np.arange(0, 20000, dtype=float) + 1.0)[:, None]
    pos = t > 0
    s = np.sum(8.0 / (o * o * math.pi ** 2) * np.exp(-o * o * math.pi ** 2 * kappa * t[pos][None, :] / (4 * length ** 2)), axis=0)
    out[pos] = 1.0 - s
    return out


def reference_mass_ratio(series, summary):
    if "reference_mass_ratio" in series:
        return series["reference_mass_ratio"]
    ref = summary["config"]["diagnostics"]["reference"]
    kappa = summary["config"]["physics"]["kappa"]
    der = summary["derived"]
    if ref == "crank_sphere":
        return crank_sphere(kappa, der["reference_radius"], series["t"])
    if ref == "crank_slab":
        return crank_slab(kappa, der["reference_length"], series["t"])
    return None


# ----------------------------------------------------------------- run plots

def plot_run(run_dir, out_dir):
    series = read_series(run_dir)
    summary = read_summary(run_dir)
    der = summary["derived"]
    t = series["t"]
    written = []

    m_inf = der["M_inf"]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(t, series["mass_inside"] / m_inf, label="M / M_inf (inside, (43))")
    ax.plot(t, series["mass_with_layer"] / m_inf, "--", label="with external layer")
    ref = reference_mass_ratio(series, summary)
    if ref is not None:
        name = summary["config"]["diagnostics"]["reference"].replace("_", " ")
        ax.plot(t, ref, "k:", label=f"{name} (Crank)")
    ax.set_xlabel("t")
    ax.set_ylabel("M / M_inf")
    ax.set_title(os.path.basename(os.path.normpath(run_dir)))
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    written.append(os.path.join(out_dir, "mass.png"))
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    j_inf = der.get("J_inf")
    if j_inf:
        ax.plot(t, series["polar_inertia"] / j_inf, label="J_G / J_inf (inside, (44))")
        ax.plot(t, series["polar_inertia_with_layer"] / j_inf, "--", label="with external layer")
        ax.axhline(1.0, color="k", lw=0.8, ls=":")
        ax.set_ylabel("J_G / J_inf")
    else:
        ax.plot(t, series["polar_inertia_total"], label="J_G (all particles)")
        ax.set_ylabel("J_G")
    if "reference_polar_inertia" in series:
        ax.plot(t, series["reference_polar_inertia"], "k:", label="J(0) + 2 d kappa M t")
    ax.set_xlabel("t")
    ax.set_title(os.path.basename(os.path.normpath(run_dir)))
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    written.append(os.path.join(out_dir, "inertia.png"))
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)

    snap = last_snapshot(run_dir)
    if snap:
        arrays = read_vtp(snap)
        pos, age = arrays["position"], arrays["age"]
        dim = summary["config"]["run"]["dim"]
        centre = np.array(der["center"])
        fig, ax = plt.subplots(figsize=(6, 5))
        if dim == 1:
            sc = ax.scatter(pos[:, 0], age, c=age, s=8, cmap="viridis")
            ax.set_ylabel("age")
            title = "all particles"
        else:
            keep = np.ones(len(pos), dtype=bool)
            title = "all particles"
            if dim == 3:
                # A slab of thickness b (the paper's Fig. 6) through the centre, normal to z.
                half = 0.5 * max(der["layer_b"], 0.1 * der["dr"] * 10)
                keep = np.abs(pos[:, 2] - centre[2]) <= half
                title = f"|z - {centre[2]:.3g}| <= {half:.3g}"
            sc = ax.scatter(pos[keep, 0], pos[keep, 1], c=age[keep], s=10, cmap="viridis")
            ax.set_aspect("equal")
            ax.set_ylabel("y")
        ax.set_xlabel("x")
        fig.colorbar(sc, ax=ax, label="age (time since insertion)")
        ax.set_title(f"t = {arrays['_time']:.4g}, {title}")
        fig.tight_layout()
        written.append(os.path.join(out_dir, "slice.png"))
        fig.savefig(written[-1], dpi=120)
        plt.close(fig)
    return written


# ----------------------------------------------------------------- convergence

def fit_power_law(mp, values):
    """L = L_inf + a m_p^q: q by a scan, (L_inf, a) by linear least squares."""
    best = None
    for q in np.linspace(0.05, 3.0, 2951):
        A = np.column_stack([np.ones_like(mp), mp ** q])
        coef, *_ = np.linalg.lstsq(A, values, rcond=None)
        res = np.sum((A @ coef - values) ** 2)
        if best is None or res < best[0]:
            best = (res, coef[0], coef[1], q)
    _, l_inf, a, q = best
    return l_inf, a, q


def plot_convergence(dirs, out_dir):
    if len(dirs) < 3:
        sys.exit("plot.py: --convergence needs at least three run directories (L_inf, a and q are fitted)")
    mp, lm, lj = [], [], []
    for d in dirs:
        s = read_summary(d)
        if s.get("status") != "completed":
            print(f"plot.py: warning: {d} has status {s.get('status')}", file=sys.stderr)
        mp.append(s["derived"]["particle_mass"])
        lm.append(s["l1"]["mass_rectangle"])
        lj.append(s["l1"]["polar_inertia_rectangle"])
    order = np.argsort(mp)
    mp = np.array(mp)[order]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, values, name in ((axes[0], np.array(lm)[order], "M"), (axes[1], np.array(lj)[order], "J_G")):
        l_inf, a, q = fit_power_law(mp, values)
        err = np.abs(values - l_inf) / abs(l_inf)
        ax.loglog(mp, err, "o", label=f"|L1 - L1_inf| / L1_inf, L1_inf = {l_inf:.5g}")
        fine = np.geomspace(mp.min(), mp.max(), 50)
        ax.loglog(fine, np.abs(a) * fine ** q / abs(l_inf), "--", label=f"fit: e ~ m_p^{q:.2f}")
        ax.set_xlabel("m_p")
        ax.set_ylabel(f"relative L1 error of {name}")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
        print(f"{name}: L1_inf = {l_inf:.6g}, exponent q = {q:.3f}")
        if q <= 0.05 + 1e-9 or q >= 3.0 - 1e-9:
            print(f"plot.py: warning: the fitted exponent of {name} is at the end of the scanned range [0.05, 3]: "
                  "these runs show no power-law convergence (too few, too small, or not yet asymptotic)",
                  file=sys.stderr)
    fig.tight_layout()
    path = os.path.join(out_dir, "convergence.png")
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return [path]


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", nargs="?", help="an otfp output directory")
    p.add_argument("--convergence", nargs="+", metavar="DIR", help="run directories at different m_p")
    p.add_argument("--out", help="where to write the PNGs (default: the run directory, or the first one)")
    args = p.parse_args()
    if not args.run_dir and not args.convergence:
        p.error("give a run directory or --convergence DIR1 DIR2 ...")
    out_dir = args.out or args.run_dir or args.convergence[0]
    os.makedirs(out_dir, exist_ok=True)
    written = []
    if args.run_dir:
        written += plot_run(args.run_dir, out_dir)
    if args.convergence:
        written += plot_convergence(args.convergence, out_dir)
    for w in written:
        print(w)


if __name__ == "__main__":
    main()
