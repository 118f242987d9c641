#!/usr/bin/python3
"""Plots and tables of the studies in docs/validation.md.

    study_plots.py STUDY --sweeps DIR --docs DOCS

STUDY is implicit_explicit, variable_width, diffusivity, convergence, boundaries or all.
Reads the sweep directories written by scripts/studies.sh (DIR/STUDY/...:
runs.csv and each run's series.csv, summary.json, particles_final.csv), writes
DOCS/<study>*.png, DOCS/<study>.md (the tables) and a small copy of the data
(runs.csv and thinned series) under DOCS/data/<study>/.

Without a run's summary.json (a sweep directory rebuilt from those copies:
DIR/STUDY/CASE/runs.csv with DIR/STUDY/CASE/run_NNN/series.csv) the plots use
fallbacks: m_p = mass_total / n_particles at T (every particle has the same
mass), kappa k^2 from the reference curve of the cosine mode; the tables then
lack their summary-only columns, the width histogram of variable_width_sphere.png
needs particles_final.csv, and the time-discretisation errors of study 1 come
from the thinned series (close to, not equal to, those of the full series).
"""
import argparse
import csv
import json
import math
import os
import shutil
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.legend_handler import HandlerTuple  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: E402

# The docs pages show each figure about 700-900 px wide: sizes of a paper
# figure, set once here. Figures have at most two panels per row.
plt.rcParams.update({
    "font.size": 12, "axes.titlesize": 13, "axes.labelsize": 12, "xtick.labelsize": 11, "ytick.labelsize": 11,
    "legend.fontsize": 10, "legend.framealpha": 0.9, "lines.markersize": 7, "lines.linewidth": 1.6,
    "savefig.dpi": 100, "savefig.bbox": "tight",
})
PANEL = (6.4, 4.8)  # inches per panel

SCHEME_KEYS = ("solver.stepper", "solver.backend", "solver.explicit_scheme")
SCHEME_ORDER = ["explicit euler27", "explicit rk4", "explicit euler_exact", "implicit ceres", "implicit nlopt"]
SCHEME_STYLE = {
    "explicit euler27": ("tab:red", "o"),
    "explicit rk4": ("tab:orange", "s"),
    "explicit euler_exact": ("tab:brown", "^"),
    "implicit ceres": ("tab:blue", "D"),
    "implicit nlopt": ("tab:green", "v"),
}


def panels(n, legend_slot=False):
    """A grid of n panels, two per row; with legend_slot one more cell that
    holds a shared legend. Returns (fig, list of axes, legend axis or None)."""
    cells = n + (1 if legend_slot else 0)
    cols = 1 if cells == 1 else 2
    rows = (cells + cols - 1) // cols
    fig, grid = plt.subplots(rows, cols, figsize=(PANEL[0] * cols, PANEL[1] * rows), squeeze=False)
    flat = list(grid.flat)
    for ax in flat[cells:]:
        ax.axis("off")
    leg = None
    if legend_slot:
        leg = flat[n]
        leg.axis("off")
    return fig, flat[:n], leg


def log_ticks(ax, axis, values):
    """Readable ticks on a log axis: at the data values themselves (plain
    numbers) when they span less than two decades, else decades only; never
    the crowded minor labels (4x10^2, 6x10^2, ...)."""
    v = np.asarray([x for x in values if x > 0 and math.isfinite(x)], float)
    a = ax.xaxis if axis == "x" else ax.yaxis
    a.set_minor_formatter(NullFormatter())
    if len(v) and v.max() / v.min() < 100.0:
        ticks = np.unique(v)
        # Thin out ticks closer than a factor 1.4 on the axis.
        kept = [ticks[0]]
        for t in ticks[1:]:
            if t / kept[-1] >= 1.4:
                kept.append(t)
        (ax.set_xticks if axis == "x" else ax.set_yticks)(kept)
        a.set_major_formatter(FuncFormatter(lambda x, _pos: f"{x:.3g}"))
    a.ticks_at_data = True


def finish(fig, path):
    """Label the log axes that span few decades at 1, 2, 5 x 10^k in plain
    numbers (instead of a single 10^k), hide crowded minor labels, save."""
    for ax in fig.axes:
        for axis, scale, lim in (("x", ax.get_xscale(), ax.get_xlim()), ("y", ax.get_yscale(), ax.get_ylim())):
            a = ax.xaxis if axis == "x" else ax.yaxis
            if scale != "log" or getattr(a, "ticks_at_data", False):
                continue
            a.set_minor_formatter(NullFormatter())
            lo, hi = min(lim), max(lim)
            if lo > 0 and hi / lo < 10 ** 2.2:
                a.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0), numticks=20))
                a.set_major_formatter(FuncFormatter(lambda x, _pos: f"{x:.3g}"))
    fig.savefig(path)
    plt.close(fig)


def key_handle(color, marker=None, ls="-"):
    """A legend entry for a colour / marker / line style drawn elsewhere."""
    return Line2D([], [], color=color, marker=marker, linestyle=ls)


# ------------------------------------------------------------------ reading
def read_rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def num(row, key, default=float("nan")):
    v = row.get(key, "")
    try:
        return float(v)
    except (TypeError, ValueError):
        return default


def series(sweep_dir, row):
    path = os.path.join(sweep_dir, row["dir"], "series.csv")
    if not os.path.exists(path):
        return None
    rows = read_rows(path)
    if not rows:
        return None
    # Empty cells (error_estimate without an estimate) read as NaN.
    return {k: np.array([float(r[k]) if r[k] != "" else np.nan for r in rows]) for k in rows[0]}


def summary(sweep_dir, row):
    path = os.path.join(sweep_dir, row["dir"], "summary.json")
    if not os.path.exists(path):
        return None
    with open(path) as f:
        return json.load(f)


def scheme(row):
    if row.get("solver.stepper") == "implicit":
        return "implicit " + row.get("solver.backend", "ceres")
    return "explicit " + row.get("solver.explicit_scheme", "euler27")


def fmt(v, digits=3):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, str):
        return v
    if v == 0:
        return "0"
    if abs(v) >= 1e4 or abs(v) < 1e-3:
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}"


def md_table(header, rows):
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        out.append("| " + " | ".join(fmt(x) if not isinstance(x, str) else x for x in r) + " |")
    return "\n".join(out) + "\n"


def copy_data(sweep_dir, dest, columns, every=None):
    """runs.csv and each run's series (selected columns, at most ~100 rows, 6 digits)."""
    os.makedirs(dest, exist_ok=True)
    shutil.copy(os.path.join(sweep_dir, "runs.csv"), os.path.join(dest, "runs.csv"))
    for row in read_rows(os.path.join(sweep_dir, "runs.csv")):
        src = os.path.join(sweep_dir, row["dir"], "series.csv")
        if not os.path.exists(src):
            continue
        rows = read_rows(src)
        if not rows:
            continue
        keep = [c for c in columns if c in rows[0]]
        stride = every or max(1, len(rows) // 100)
        picked = rows[::stride]
        if picked[-1] is not rows[-1]:
            picked.append(rows[-1])
        with open(os.path.join(dest, row["dir"] + ".csv"), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(keep)
            for r in picked:
                # Integers (counts) as they are, other numbers to 6 digits.
                w.writerow([r[c] if r[c].lstrip("-").isdigit() else f"{float(r[c]):.6g}" for c in keep])


def fit_power(x, y):
    """Least-squares fit of log y = log C + alpha log x; returns (C, alpha)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = (x > 0) & (y > 0) & np.isfinite(y)
    if ok.sum() < 2:
        return float("nan"), float("nan")
    a, b = np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)
    return math.exp(b), a


def fit_limit_power(x, y):
    """The papers' procedure: L(m) = L* + C m^alpha, alpha by a 1-D scan, L* and C by
    linear least squares for each alpha. Returns (L*, C, alpha)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) < 3:
        return float("nan"), float("nan"), float("nan")
    best = None
    for alpha in np.linspace(0.05, 3.0, 591):
        A = np.vstack([np.ones_like(x), x ** alpha]).T
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        r = float(np.sum((A @ coef - y) ** 2))
        if best is None or r < best[0]:
            best = (r, coef[0], coef[1], alpha)
    return best[1], best[2], best[3]


# ------------------------------------------------------------------ study 1
def implicit_explicit(sweeps, docs):
    md = ["# Study 1: implicit vs explicit (generated by scripts/study_plots.py)\n"]
    for case, title in (("sphere", "Sphere, Dirichlet (Crank 6.20)"), ("box", "Box, one Dirichlet face (Crank 4.18)")):
        d = os.path.join(sweeps, "implicit_explicit", case)
        if not os.path.exists(os.path.join(d, "runs.csv")):
            continue
        rows = read_rows(os.path.join(d, "runs.csv"))
        fig, axes, _ = panels(4)
        table = []
        schemes_drawn = []
        dts_drawn = []
        for sch in SCHEME_ORDER:
            rs = [r for r in rows if scheme(r) == sch]
            if not rs:
                continue
            color, marker = SCHEME_STYLE[sch]
            ok = [r for r in rs if r["status"] == "completed"]
            schemes_drawn.append(sch)
            x = [num(r, "run.dt_factor") for r in ok]
            dts_drawn += x
            e = [num(r, "ref_mean_abs_error") for r in ok]
            w = [num(r, "wall_seconds") for r in ok]
            axes[0].loglog(x, e, marker=marker, color=color, label=sch)
            axes[1].loglog(w, e, marker=marker, color=color, label=sch, linestyle="none")
            # Time-discretisation error: against the same scheme's smallest dt
            # (same particles and boundary treatment, so only dt differs).
            finest = min(ok, key=lambda r: num(r, "run.dt_factor"), default=None)
            s_fine = series(d, finest) if finest else None
            dt_err = {}
            for r in ok:
                s = series(d, r)
                if s is None or s_fine is None or r is finest:
                    continue
                ref = np.interp(s["t"], s_fine["t"], s_fine["mass_ratio"])
                dt_err[r["dir"]] = float(np.trapz(np.abs(s["mass_ratio"] - ref), s["t"]) / s["t"][-1])
            xs = sorted((num(r, "run.dt_factor"), dt_err[r["dir"]]) for r in ok if r["dir"] in dt_err)
            if xs:
                axes[3].loglog([a for a, _ in xs], [b for _, b in xs], marker=marker, color=color, label=sch)
            for r in rs:
                sm = summary(d, r)
                outside = sm["final"]["n_outside"] / max(1, sm["final"]["n_particles"]) if sm else float("nan")
                table.append([sch, num(r, "run.dt_factor"), r["status"], num(r, "steps"), num(r, "evaluations"),
                              num(r, "wall_seconds"), num(r, "ref_mean_abs_error"), num(r, "ref_max_abs_error"),
                              num(r, "ref2_mean_abs_error"), dt_err.get(r["dir"], float("nan")),
                              num(r, "mass_ratio"), outside])
            for r in ok:
                if num(r, "run.dt_factor") in (1.0, 10.0, 100.0):
                    s = series(d, r)
                    if s is not None:
                        ls = {1.0: "-", 10.0: "--", 100.0: ":"}[num(r, "run.dt_factor")]
                        axes[2].plot(s["t"], s["mass_ratio"], ls, color=color, lw=1.4)
        axes[3].set_xlabel("dt / dt_explicit")
        axes[3].set_ylabel("mean |M/M_inf - M at smallest dt|")
        axes[3].set_title("time-discretisation error (same scheme)")
        s_ref = None
        for r in rows:
            s_ref = series(d, r)
            if s_ref is not None and "reference_mass_ratio" in s_ref and len(s_ref["t"]) > 50:
                break
        ls_key = [key_handle("0.3", ls=ls) for ls in ("-", "--", ":")]
        ls_names = ["dt = 1 dt_expl", "dt = 10 dt_expl", "dt = 100 dt_expl"]
        if s_ref is not None:
            axes[2].plot(s_ref["t"], s_ref["reference_mass_ratio"], "k-", lw=3, alpha=0.35)
            ls_key.append(Line2D([], [], color="k", lw=3, alpha=0.35))
            ls_names.append("Crank")
        axes[0].set_xlabel("dt / dt_explicit  (dt_explicit = dr^2 / kappa)")
        axes[0].set_ylabel("mean |M/M_inf - Crank| over [0, T]")
        axes[0].set_title("error against Crank")
        axes[1].set_xlabel("wall time [s] (1 thread)")
        axes[1].set_ylabel("mean |M/M_inf - Crank|")
        axes[1].set_title("error vs cost")
        axes[2].set_xlabel("t")
        axes[2].set_ylabel("M / M_inf")
        axes[2].set_title("filling curves (colour: scheme)")
        axes[2].set_ylim(-0.05, 1.6)
        axes[2].legend(ls_key, ls_names, loc="upper left")
        for ax in axes:
            ax.grid(True, which="both", alpha=0.3)
        for ax in (axes[0], axes[3]):
            log_ticks(ax, "x", dts_drawn)
        axes[1].xaxis.set_minor_formatter(NullFormatter())
        fig.legend([key_handle(SCHEME_STYLE[sch][0], SCHEME_STYLE[sch][1]) for sch in schemes_drawn], schemes_drawn,
                   loc="lower center", ncol=min(3, len(schemes_drawn)), title="scheme (colour and marker)",
                   bbox_to_anchor=(0.5, -0.01))
        fig.suptitle(title, fontsize=15)
        fig.tight_layout(rect=(0, 0.08, 1, 1))
        finish(fig, os.path.join(docs, f"implicit_explicit_{case}.png"))
        md.append(f"## {title}\n")
        md.append(md_table(["scheme", "dt/dt_expl", "status", "steps", "evaluations", "wall [s]",
                            "mean abs err M", "max abs err M", "mean abs err J", "dt error M", "M/M_inf(T)",
                            "outside at T"], table))
        # Time to solution at matched accuracy: the fastest run of each scheme
        # whose mean |M/M_inf - Crank| is at most the threshold.
        done = [r for r in rows if r["status"] == "completed"]
        best = min((num(r, "ref_mean_abs_error") for r in done), default=float("nan"))
        if math.isfinite(best):
            thresholds = [float(f"{best * f:.3g}") for f in (1.1, 1.5, 2.0, 3.0)]
            tts = []
            for sch in SCHEME_ORDER:
                line = [sch]
                for th in thresholds:
                    ok = [r for r in done if scheme(r) == sch and num(r, "ref_mean_abs_error") <= th]
                    if ok:
                        r = min(ok, key=lambda r: num(r, "wall_seconds"))
                        line.append(f"{fmt(num(r, 'wall_seconds'))} s (dt = {fmt(num(r, 'run.dt_factor'))}x)")
                    else:
                        line.append("not reached")
                tts.append(line)
            md.append("\nTime to solution: fastest run with mean |M/M_inf - Crank| at most the threshold\n")
            md.append(md_table(["scheme"] + [f"<= {fmt(t)}" for t in thresholds], tts))
        copy_data(d, os.path.join(docs, "data", "implicit_explicit", case),
                  ["t", "mass_ratio", "reference_mass_ratio", "error_mass_ratio", "polar_inertia",
                   "reference_polar_inertia", "error_polar_inertia", "evaluations"])
    with open(os.path.join(docs, "implicit_explicit.md"), "w") as f:
        f.write("\n".join(md))


# ------------------------------------------------------------------ study 2
def width_label(row):
    if row.get("solver.width_mode") == "fixed":
        return "fixed beta"
    return "per-particle, c_w = " + ("1 (as printed)" if row.get("solver.width_metric") == "as_printed" else "d/2 (exact)")


WIDTH_COLORS = {"fixed beta": "tab:blue", "per-particle, c_w = 1 (as printed)": "tab:orange",
                "per-particle, c_w = d/2 (exact)": "tab:green"}


def variable_width(sweeps, docs):
    md = ["# Study 2: variable-width blobs (generated by scripts/study_plots.py)\n"]
    d = os.path.join(sweeps, "variable_width", "free_space")
    if os.path.exists(os.path.join(d, "runs.csv")):
        rows = read_rows(os.path.join(d, "runs.csv"))
        dims = sorted({int(num(r, "run.dim")) for r in rows})
        fig, axes, leg = panels(len(dims), legend_slot=True)
        table = []
        drawn = []
        for r in rows:
            dim = int(num(r, "run.dim"))
            s = series(d, r)
            table.append([dim, width_label(r), r["status"], num(r, "growth_ratio"), num(r, "ref_mean_abs_error"),
                          num(r, "evaluations"), num(r, "wall_seconds")])
            if s is None:
                continue
            ax = axes[dims.index(dim)]
            growth = s["second_moment"] - s["second_moment"][0]
            ax.plot(s["t"], growth, color=WIDTH_COLORS.get(width_label(r)))
            if width_label(r) not in drawn:
                drawn.append(width_label(r))
            if r.get("solver.width_mode") == "fixed":
                ax.plot(s["t"], s["reference_second_moment"] - s["reference_second_moment"][0], "k:", lw=2)
            ax.set_title(f"free space, d = {dim}")
            ax.set_xlabel("t")
            ax.set_ylabel("S(t) - S(0)")
        for ax in axes:
            ax.grid(alpha=0.3)
        leg.legend([key_handle(WIDTH_COLORS.get(w)) for w in drawn] + [key_handle("k", ls=":")],
                   drawn + ["2 d kappa M t (exact)"], loc="center", title="widths", fontsize=11)
        fig.tight_layout()
        finish(fig, os.path.join(docs, "variable_width_free_space.png"))
        md.append("## Free space: growth of the second moment, (S(T) - S(0)) / (2 d kappa M T)\n")
        md.append(md_table(["d", "widths", "status", "growth ratio", "mean abs err (of 2dkMT)", "evaluations",
                            "wall [s]"], table))
        copy_data(d, os.path.join(docs, "data", "variable_width", "free_space"),
                  ["t", "second_moment", "reference_second_moment", "error_second_moment"])
    d = os.path.join(sweeps, "variable_width", "sphere")
    if os.path.exists(os.path.join(d, "runs.csv")):
        rows = read_rows(os.path.join(d, "runs.csv"))
        fig, axes, _ = panels(2)
        table = []
        for r in rows:
            s = series(d, r)
            sm = summary(d, r)
            table.append([width_label(r), r["status"], num(r, "ref_mean_abs_error"), num(r, "ref_max_abs_error"),
                          num(r, "ref2_mean_abs_error"), num(r, "mass_ratio"), num(r, "evaluations"),
                          num(r, "wall_seconds")])
            if s is None:
                continue
            axes[0].plot(s["t"], s["mass_ratio"], color=WIDTH_COLORS.get(width_label(r)), label=width_label(r))
            pf = os.path.join(d, r["dir"], "particles_final.csv")
            if r.get("solver.width_mode") != "fixed" and os.path.exists(pf) and sm is not None:
                p = read_rows(pf)
                s0 = sm["derived"]["width_s"]
                ws = np.array([float(q["width_s"]) / s0 for q in p if q["region"] == "0"])
                if len(ws):
                    axes[1].hist(ws, bins=40, histtype="step", lw=1.8, color=WIDTH_COLORS.get(width_label(r)),
                                 label=width_label(r) + f" (n = {len(ws)})")
                    md.append(f"- {width_label(r)}: s/s0 of the {len(ws)} particles inside at t = T: "
                              f"median {np.median(ws):.3f}, 5% {np.percentile(ws, 5):.3f}, "
                              f"95% {np.percentile(ws, 95):.3f}, min {ws.min():.3f}, max {ws.max():.3f}\n")
        if rows:
            s = series(d, rows[0])
            if s is not None:
                axes[0].plot(s["t"], s["reference_mass_ratio"], "k:", lw=2, label="Crank")
        axes[0].set_xlabel("t")
        axes[0].set_ylabel("M / M_inf")
        axes[0].set_title("sphere filling")
        axes[0].grid(alpha=0.3)
        axes[0].legend(loc="lower right")
        axes[1].set_xlabel("s / s0 (s0: width rule (36)), inside at t = T")
        axes[1].set_ylabel("count")
        axes[1].set_title("distribution of widths at the end")
        if axes[1].get_legend_handles_labels()[0]:
            axes[1].legend()
        fig.tight_layout()
        finish(fig, os.path.join(docs, "variable_width_sphere.png"))
        md.append("\n## Sphere filling against Crank\n")
        md.append(md_table(["widths", "status", "mean abs err M", "max abs err M", "mean abs err J", "M/M_inf(T)",
                            "evaluations", "wall [s]"], table))
        copy_data(d, os.path.join(docs, "data", "variable_width", "sphere"),
                  ["t", "mass_ratio", "reference_mass_ratio", "error_mass_ratio", "polar_inertia",
                   "reference_polar_inertia"])
    with open(os.path.join(docs, "variable_width.md"), "w") as f:
        f.write("\n".join(md))


# ------------------------------------------------------------------ study 3
def diffusivity(sweeps, docs):
    closed_box(sweeps, docs)
    d = os.path.join(sweeps, "diffusivity")
    if not os.path.exists(os.path.join(d, "runs.csv")):
        return
    rows = read_rows(os.path.join(d, "runs.csv"))
    dts = sorted({num(r, "run.dt_factor") for r in rows})
    fig, axes, leg = panels(3, legend_slot=True)
    drawn = []
    dt_styles = ["-", "--", "-.", ":"]
    for k, arr in enumerate(("lattice", "random")):
        ax = axes[k]
        for sch in SCHEME_ORDER:
            color, marker = SCHEME_STYLE[sch]
            for dt in dts:
                rs = sorted([r for r in rows if scheme(r) == sch and r["particles.fill_arrangement"] == arr
                             and num(r, "run.dt_factor") == dt], key=lambda r: num(r, "particles.beta_factor"))
                if not rs:
                    continue
                if sch not in drawn:
                    drawn.append(sch)
                ax.plot([num(r, "particles.beta_factor") for r in rs], [num(r, "rate_ratio") for r in rs],
                        marker=marker, color=color, linestyle=dt_styles[dts.index(dt) % len(dt_styles)])
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xlabel("beta dr^2")
        ax.set_ylabel("decay rate / (kappa k^2)")
        ax.set_title(f"{arr} arrangement")
        ax.grid(alpha=0.3)
    leg.legend([key_handle(SCHEME_STYLE[sch][0], SCHEME_STYLE[sch][1]) for sch in drawn] +
               [key_handle("0.3", ls=dt_styles[i % len(dt_styles)]) for i in range(len(dts))] +
               [key_handle("k", ls="-")],
               drawn + [f"dt = {fmt(dt)} dt_expl" for dt in dts] + ["rate = kappa k^2"],
               loc="center", title="top row: scheme (colour), dt (line)")
    ax = axes[2]
    for r in rows:
        if (scheme(r) == "implicit ceres" and r["particles.fill_arrangement"] == "lattice"
                and num(r, "run.dt_factor") == min(dts)):
            s = series(d, r)
            if s is None:
                continue
            sm = summary(d, r)
            if sm is not None:
                lam = sm["reference"]["kappa_k2"]
            else:
                # Without summary.json (the copies in docs/validation/data):
                # kappa k^2 from the reference curve a(0) exp(-kappa k^2 t).
                ref = s["reference_mode_amplitude"]
                lam = math.log(ref[0] / ref[-1]) / s["t"][-1]
            ax.semilogy(s["t"] * lam, s["mode_amplitude"] / s["mode_amplitude"][0],
                        label=f"beta dr^2 = {r['particles.beta_factor']}")
    t = np.linspace(0, 2, 50)
    ax.semilogy(t, np.exp(-t), "k:", lw=2, label="exp(-kappa k^2 t)")
    ax.set_xlabel("kappa k^2 t")
    ax.set_ylabel("a(t) / a(0)")
    ax.set_title("mode amplitude, implicit Ceres, lattice")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left")
    fig.tight_layout()
    finish(fig, os.path.join(docs, "diffusivity.png"))
    md = ["# Study 3: effective diffusivity (generated by scripts/study_plots.py)\n",
          "Fitted decay rate of the cosine mode divided by kappa k^2 (`rate_ratio`), and divided by the rate "
          "the time scheme alone gives with an exact spatial operator (`time-discrete`).\n"]
    betas = sorted({num(r, "particles.beta_factor") for r in rows})
    for arr in ("lattice", "random"):
        table = []
        for sch in SCHEME_ORDER:
            for dt in dts:
                line = [sch, dt]
                for b in betas:
                    rr = [r for r in rows if scheme(r) == sch and r["particles.fill_arrangement"] == arr
                          and num(r, "particles.beta_factor") == b and num(r, "run.dt_factor") == dt]
                    line.append(fmt(num(rr[0], "rate_ratio")) + " / " + fmt(num(rr[0], "rate_ratio_time_discrete"))
                                if rr and rr[0]["status"] == "completed" else (rr[0]["status"] if rr else "-"))
                table.append(line)
        md.append(f"## {arr} arrangement: rate ratio / time-discrete ratio\n")
        md.append(md_table(["scheme", "dt/dt_expl"] + [f"beta dr^2 = {fmt(b)}" for b in betas], table))
    with open(os.path.join(docs, "diffusivity.md"), "w") as f:
        f.write("\n".join(md))
    copy_data(d, os.path.join(docs, "data", "diffusivity"),
              ["t", "mode_amplitude", "reference_mode_amplitude", "error_mode_amplitude"])


def wall_profile(path, dr, width, nbins):
    """Particle counts of a closed unit square in strips by distance to the nearest wall
    (width `width` dr each), and the count beyond the walls."""
    xy = np.loadtxt(path, delimiter=",", skiprows=1, usecols=(1, 2))
    inside = (xy >= 0.0).all(axis=1) & (xy <= 1.0).all(axis=1)
    dist = np.min(np.concatenate([xy[inside], 1.0 - xy[inside]], axis=1), axis=1)
    edges = np.arange(nbins + 1) * width * dr
    counts, _ = np.histogram(dist, bins=edges)
    area = (1.0 - 2.0 * edges[:-1]) ** 2 - (1.0 - 2.0 * edges[1:]) ** 2
    # The rest of the square (farther than the last strip) as a last entry.
    counts = np.append(counts, int((dist >= edges[-1]).sum()))
    area = np.append(area, (1.0 - 2.0 * edges[-1]) ** 2)
    return edges, counts, area, int((~inside).sum()), len(xy)


def closed_box(sweeps, docs):
    """Study 3 in a closed box: the cosine mode's decay rate next to no-flux walls
    (images against the barrier), and whether a uniform state stays uniform."""
    d = os.path.join(sweeps, "diffusivity", "closed_box")
    u = os.path.join(sweeps, "diffusivity", "uniform_box")
    if not os.path.exists(os.path.join(d, "runs.csv")) and not os.path.exists(os.path.join(u, "runs.csv")):
        return
    md = ["# Study 3b: the closed box (generated by scripts/study_plots.py)\n",
          "The cosine mode 1 + a cos(2 pi x) in the closed unit square (no-flux walls; the mode's slope vanishes "
          "at both walls), implicit Ceres at dt = 0.25 dt_expl. `rate_ratio` is the fitted decay rate "
          "over kappa k^2, as in the periodic box (study 3; images make the closed box the even extension of the "
          "periodic one, so its rates are the periodic ones).\n"]
    fig, axes, _ = panels(2)
    if os.path.exists(os.path.join(d, "runs.csv")):
        rows = read_rows(os.path.join(d, "runs.csv"))
        betas = sorted({num(r, "particles.beta_factor") for r in rows})
        table = []
        for arr in ("lattice", "random"):
            for nf in ("barrier", "images"):
                line = [arr, nf]
                rr = []
                for b in betas:
                    m = [r for r in rows if r["particles.fill_arrangement"] == arr and r["treatment.no_flux"] == nf
                         and num(r, "particles.beta_factor") == b]
                    v = num(m[0], "rate_ratio") if m and m[0]["status"] == "completed" else float("nan")
                    line.append(v if m and m[0]["status"] == "completed" else (status_label(m[0]) if m else "-"))
                    rr.append(v)
                table.append(line)
                axes[0].plot(betas, rr, "o-" if nf == "images" else "s--",
                             color="tab:blue" if arr == "lattice" else "tab:orange", label=f"{nf}, {arr}")
        md.append(md_table(["arrangement", "no_flux"] + [f"beta dr^2 = {fmt(b)}" for b in betas], table))
        md.append("")
        axes[0].axhline(1.0, color="k", lw=0.8)
        axes[0].set_xlabel("beta dr^2")
        axes[0].set_ylabel("decay rate / (kappa k^2)")
        axes[0].set_title("closed box: cosine mode")
        axes[0].grid(alpha=0.3)
        axes[0].legend(title="no_flux, arrangement")
    if os.path.exists(os.path.join(u, "runs.csv")):
        rows = [r for r in read_rows(os.path.join(u, "runs.csv")) if r["status"] == "completed"]
        md.append("## A uniform state next to the walls\n")
        n_u = int(num(rows[0], "n_inf")) if rows else 0
        md.append(f"Random uniform fills of the closed unit square (n = {n_u}, dr = n^-1/2), relaxed over "
                  "20 dr^2 / kappa (implicit Ceres, dt = 0.25 dt_expl), several seeds per treatment. Particle "
                  "density in strips by distance to the nearest wall, over the mean density n / |Omega|, pooled "
                  "over the seeds (+- one binomial standard error); \"beyond\" counts the particles outside the "
                  "square. Strips one spacing wide (the table) average over the layering that the strips half a "
                  "spacing wide (the plot, second table) resolve.\n")
        betas_u = sorted({num(r, "particles.beta_factor", 2.0) for r in rows})
        for width, nbins in ((1.0, 5), (0.5, 8)):
            table = []
            for nf, color, bf in [(nf, c, b) for nf, c in (("barrier", "tab:red"), ("images", "tab:blue"))
                                  for b in betas_u]:
                rs = [r for r in rows if r["treatment.no_flux"] == nf and num(r, "particles.beta_factor", 2.0) == bf]
                if not rs:
                    continue
                tot_c, tot_n, beyond, edges, area = None, 0, 0, None, None
                for r in rs:
                    dr = summary(u, r)["derived"]["dr"]
                    edges, c, area, out, n = wall_profile(os.path.join(u, r["dir"], "particles_final.csv"), dr,
                                                          width, nbins)
                    tot_c = c if tot_c is None else tot_c + c
                    tot_n += n
                    beyond += out
                expect = tot_n * area  # unit square: expected count per strip at uniform density
                ratio = tot_c / expect
                err = np.sqrt(tot_c * (1.0 - area)) / expect
                if width < 1.0:
                    mid = (np.arange(nbins) + 0.5) * width
                    axes[1].errorbar(mid, ratio[:-1], yerr=err[:-1], fmt="o-" if bf == max(betas_u) else "s--",
                                     color=color, capsize=3, label=f"{nf}, beta dr^2 = {fmt(bf)}")
                # The first strip against the interior (the rest of the square), error propagated.
                rel = ratio[0] / ratio[-1]
                rel_err = rel * math.hypot(err[0] / ratio[0], err[-1] / ratio[-1])
                table.append([nf, fmt(bf), f"{beyond} of {tot_n}"] +
                             [f"{fmt(v)} +- {fmt(e, 2)}" for v, e in zip(ratio, err)] + [f"{fmt(rel)} +- {fmt(rel_err, 2)}"])
            md.append(md_table(["no_flux", "beta dr^2", "beyond the walls"] +
                               [f"[{fmt(width * i)}, {fmt(width * (i + 1))}) dr" for i in range(nbins)] +
                               [f">= {fmt(width * nbins)} dr (interior)", "first strip / interior"], table))
            md.append("")
        axes[1].axhline(1.0, color="k", lw=0.8)
        axes[1].axhspan(0.95, 1.05, color="0.9", label="mean +- 5%")
        axes[1].set_xlabel("distance to the nearest wall / dr")
        axes[1].set_ylabel("particle density / mean")
        axes[1].set_title("uniform state next to the walls")
        axes[1].grid(alpha=0.3)
        axes[1].legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    fig.tight_layout()
    finish(fig, os.path.join(docs, "closed_box.png"))
    with open(os.path.join(docs, "closed_box.md"), "w") as f:
        f.write("\n".join(md))


# ------------------------------------------------------------------ study 4
PAPER_TABLES = {
    "sphere": {1600: (0.085498797, 273.59615, 2.58), 3200: (0.067860440, 434.30682, 2.13),
               6400: (0.053860867, 689.41911, 1.98), 12800: (0.042749399, 1094.3846, 1.97),
               25600: (0.033930220, 1737.2273, 1.69)},
    "box": {400: (0.10607847, 177.73604, 2.27), 800: (0.084194539, 282.13837, 1.99125),
            1600: (0.066825250, 447.86674, 1.799375), 3200: (0.053039236, 710.94414, 1.610625),
            6400: (0.042097269, 1128.5535, 1.5054688), 12800: (0.033412625, 1791.4670, 1.3733594)},
    "pipe": {1000: (0.0721, 192.30, 1347 / 1000), 2000: (0.0572, 305.26, 2365 / 2000),
             4000: (0.0454, 484.57, 4240 / 4000), 8000: (0.0360, 769.20, 7617 / 8000),
             16000: (0.0286, 1221.03, 14005 / 16000)},
}
PAPER_EXPONENTS = {"sphere": (0.38, 0.43), "box": (0.32, 0.42), "pipe": (0.37, None)}


def convergence(sweeps, docs):
    md = ["# Study 4: convergence with particle number (generated by scripts/study_plots.py)\n"]
    fig, axes, leg = panels(3, legend_slot=True)
    key = {}
    for k, case in enumerate(("sphere", "box", "pipe")):
        d = os.path.join(sweeps, "convergence", case)
        if not os.path.exists(os.path.join(d, "runs.csv")):
            continue
        rows = sorted([r for r in read_rows(os.path.join(d, "runs.csv")) if r["status"] == "completed"],
                      key=lambda r: num(r, "particles.n_inf"))
        if not rows:
            continue
        # m_p from summary.json; the copies in docs/validation/data have no
        # summary, and there every particle has the same mass: M / n at T.
        mp = np.array([summary(d, r)["derived"]["particle_mass"] if summary(d, r) else
                       num(r, "mass_total") / num(r, "n_particles") for r in rows])
        ax = axes[k]
        lines = []
        handles = []

        def draw(x, y, C, a, color, marker, name):
            """Data (markers) and its fitted power law (dashed): one legend entry."""
            p = ax.loglog(x, y, marker, color=color)[0]
            f = ax.loglog(x, C * np.asarray(x) ** a, "--", color=color)[0]
            handles.append(((p, f), f"m_p^{a:.2f}"))
            key[name] = (color, marker)
        table = []
        eM = np.array([abs(num(r, "ref_l1_norm_relative_error")) for r in rows])
        eJ = np.array([abs(num(r, "ref2_l1_norm_relative_error")) for r in rows])
        mM = np.array([num(r, "ref_mean_abs_error") for r in rows])
        l1 = np.array([num(r, "l1_mass") for r in rows])
        l1J = np.array([num(r, "l1_polar_inertia") for r in rows])
        if np.isfinite(eM).any():
            C, a = fit_power(mp, eM)
            draw(mp, eM, C, a, "tab:blue", "o", "|L1(M) - L1(Crank)| / L1(Crank)")
            lines.append(("L1-norm error of M against Crank (inside, trapezoid)", a))
            C, a = fit_power(mp, mM)
            draw(mp, mM, C, a, "tab:orange", "s", "mean |M/M_inf - Crank| over [0, T]")
            lines.append(("L1-in-time error mean |M/M_inf - Crank|", a))
        if np.isfinite(eJ).any():
            C, a = fit_power(mp, eJ)
            draw(mp, eJ, C, a, "tab:green", "^", "|L1(J_G) - L1(J_ref)| / L1(J_ref)")
            lines.append(("L1-norm error of J_G against the analytic J", a))
        # The papers' procedure: fit L1 = L* + C m_p^alpha to (46a) as printed (all particles).
        Ls, Cs, al = fit_limit_power(mp, l1)
        if math.isfinite(al):
            e = np.abs(l1 - Ls) / abs(Ls)
            # The fit's own error curve |C| m_p^alpha / |L*|.
            draw(mp, e, abs(Cs) / abs(Ls), al, "tab:red", "x", "|(46a) - L*| / L*, L* fitted (papers)")
            lines.append(("(46a) as printed vs its fitted limit L* (papers' procedure), L* = " + fmt(Ls), al))
        Ls, Cs, alJ = fit_limit_power(mp, l1J)
        if math.isfinite(alJ) and case != "pipe":
            lines.append(("(46b) as printed vs its fitted limit L* (papers' procedure), L* = " + fmt(Ls), alJ))
        ax.set_xlabel("m_p")
        ax.set_ylabel("relative error")
        ax.set_title(case)
        ax.grid(True, which="both", alpha=0.3)
        log_ticks(ax, "x", mp)
        ax.legend([h for h, _ in handles], [n for _, n in handles], title="fit (dashed)",
                  handler_map={tuple: HandlerTuple(ndivide=None)})
        paper = PAPER_TABLES[case]
        for r, m in zip(rows, mp):
            n = int(num(r, "particles.n_inf"))
            pr = paper.get(n)
            sm = summary(d, r)
            beyond = sm["final"]["n_outside"] / max(1, sm["final"]["n_particles"]) if sm else float("nan")
            table.append([n, m, num(r, "dr"), pr[0] if pr else "-", num(r, "beta"), pr[1] if pr else "-",
                          num(r, "n_particles") / n, pr[2] if pr else "-", num(r, "t_final"),
                          num(r, "l1_mass"), num(r, "ref_l1_norm_relative_error"), num(r, "ref_mean_abs_error"),
                          num(r, "ref2_mean_abs_error"), num(r, "mass_ratio"), beyond, num(r, "wall_seconds")])
        pe = PAPER_EXPONENTS[case]
        md.append(f"## {case}\n")
        md.append(md_table(["n_inf", "m_p", "dr", "paper dr", "beta", "paper beta", "n_t/n_inf at T",
                            "paper n_t/n_inf", "T", "(46a)", "L1(M) rel. err vs Crank", "mean abs err M",
                            "mean abs err J", "M/M_inf(T)", "beyond b at T", "wall [s]"], table))
        md.append("\nFitted exponents (error ~ m_p^alpha; alpha < 0: the error grows as m_p decreases):\n")
        for name, a in lines:
            note = ""
            if "fitted limit" in name and (a <= 0.06 or a >= 2.99):
                note = " (at the end of the scanned range 0.05-3: no power law in these data)"
            md.append(f"- {name}: alpha = {a:.2f}{note}")
        md.append(f"- papers: mass {pe[0]}" + (f", polar inertia {pe[1]}" if pe[1] else "") + "\n")
        copy_data(d, os.path.join(docs, "data", "convergence", case),
                  ["t", "mass_ratio", "reference_mass_ratio", "polar_inertia", "reference_polar_inertia",
                   "mass_total", "n_particles"])
    leg.legend([key_handle(c, m, ls="none") for c, m in key.values()] + [key_handle("0.3", ls="--")],
               list(key.keys()) + ["least-squares power law"], loc="center", title="error measure")
    fig.tight_layout()
    finish(fig, os.path.join(docs, "convergence.png"))
    with open(os.path.join(docs, "convergence.md"), "w") as f:
        f.write("\n".join(md))

# ------------------------------------------------------------------ study 5
def fit_slope(x, y):
    """log y = log C - alpha log x by least squares; returns (C, alpha, standard error of alpha)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = (x > 0) & (y > 0) & np.isfinite(y)
    if ok.sum() < 2:
        return float("nan"), float("nan"), float("nan")
    lx, ly = np.log(x[ok]), np.log(y[ok])
    b, a = np.polyfit(lx, ly, 1)
    se = float("nan")
    if ok.sum() > 2:
        res = ly - (a + b * lx)
        se = math.sqrt(float(np.sum(res ** 2)) / (ok.sum() - 2) / float(np.sum((lx - lx.mean()) ** 2)))
    return math.exp(a), -b, se


def neumann_balance(sm, t):
    """Analytic mass M(0) + integral of the inward Neumann fluxes up to t."""
    m0 = sm["ledger"]["initial_mass"]
    net = np.zeros_like(t)
    for p in sm["derived"]["patches"]:
        if p["kind"] != "neumann":
            continue
        a, b = p["t_start"], p["t_end"] if p["t_end"] is not None else float("inf")
        net += -p["value"] * p["area"] * np.clip(np.minimum(t, b) - a, 0.0, None)
    return m0 + net


def status_label(row):
    """A run stopped by hand (SIGTERM) is not a crash."""
    if row["status"] == "crashed" and "signal 15" in row.get("error", ""):
        return "stopped (SIGTERM)"
    return row["status"]


def crank_curve(case, kt):
    """Crank 6.20 (unit sphere) or 4.18 (slab of length 2) at kappa t = kt."""
    kt = np.asarray(kt, float)
    out = np.zeros_like(kt)
    if case == "sphere":
        for n in range(1, 400):
            out += np.exp(-n * n * math.pi ** 2 * kt) / (n * n)
        return 1.0 - 6.0 / math.pi ** 2 * out
    for k in range(0, 400):
        m = 2 * k + 1
        out += 8.0 / (m * m * math.pi ** 2) * np.exp(-m * m * math.pi ** 2 * kt / 16.0)
    return 1.0 - out


def effective_kappa(case, t, m):
    """The kappa_eff that brings Crank's curve closest to M/M_inf (mean abs
    error over the rows), and that residual error: what is left once the bulk
    diffusivity's bias is taken out."""
    best = (float("nan"), float("inf"))
    lo, hi = 0.5, 2.0
    for _ in range(3):  # grid, then refine twice around the best
        grid = np.linspace(lo, hi, 61)
        for k in grid:
            e = float(np.mean(np.abs(m - crank_curve(case, k * t))))
            if e < best[1]:
                best = (float(k), e)
        step = grid[1] - grid[0]
        lo, hi = best[0] - step, best[0] + step
    return best


def boundaries(sweeps, docs):
    md = ["# Study 5: boundary treatments against the analytic references (generated by scripts/study_plots.py)\n",
          "\"papers\" is `treatment.preset = \"papers\"`, \"best\" the default `treatment.preset = \"converging\"`. "
          "`pipe` runs the implicit stepper like the rest, `pipe_explicit` the same pipe with the explicit stepper "
          "(one evaluation per step, so the ladder reaches n_inf = 4000; the balance does not depend on the "
          "stepper).\n"]
    fig, axes, _ = panels(4)
    style = {"papers": ("tab:red", "o"), "best": ("tab:blue", "s")}
    fits = []
    for k, case in enumerate(("sphere", "box", "pipe", "pipe_explicit")):
        pipe = case.startswith("pipe")
        ax = axes[k]
        balance_drawn = False
        table = []
        for variant in ("papers", "best"):
            d = os.path.join(sweeps, "boundaries", f"{case}_{variant}")
            if not os.path.exists(os.path.join(d, "runs.csv")):
                continue
            rows = sorted(read_rows(os.path.join(d, "runs.csv")), key=lambda r: num(r, "particles.n_inf"))
            ns, errs, errs_blob = [], [], []
            for r in rows:
                n = int(num(r, "particles.n_inf"))
                if r["status"] != "completed":
                    table.append([str(n), variant, status_label(r), "-", "-", "-", "-", "-", num(r, "wall_seconds")])
                    continue
                sm = summary(d, r)
                se = series(d, r)
                outside = float(np.max(se["n_outside"] / np.maximum(se["n_particles"], 1)))
                if pipe:
                    bal = neumann_balance(sm, se["t"])
                    err = float(np.max(np.abs(se["mass_total"] - bal)) / sm["derived"]["M_inf"])
                    err_blob = float(np.max(np.abs(se["mass_inside"] - bal)) / sm["derived"]["M_inf"])
                else:
                    err = num(r, "ref_mean_abs_error")
                    err_blob = sm["reference"].get("mass_blob", {}).get("mean_abs_error", float("nan"))
                if pipe:  # the mass itself over time (the best treatment's error is 0: no log scale)
                    c, m = style[variant]
                    explicit = case == "pipe_explicit"
                    ax.plot(se["t"], se["mass_total"] / sm["derived"]["M_inf"], "--" if explicit else "-", color=c,
                            alpha=0.4 + 0.6 * min(1.0, n / 4000.0), label=f"{variant}, n_inf = {n}")
                    ax.plot(se["t"], bal / sm["derived"]["M_inf"], ":", color="k", lw=2,
                            label=None if balance_drawn else "analytic balance")
                    balance_drawn = True
                ns.append(n)
                errs.append(err)
                errs_blob.append(err_blob)
                table.append([str(n), variant, err, err_blob, num(r, "mass_ratio"), outside,
                              str(int(num(r, "n_particles"))),
                              sm["derived"].get("beta_true_spacing2", float("nan")), num(r, "wall_seconds")])
            if not ns:
                continue
            c, m = style[variant]
            C, a, sa = fit_slope(ns, errs)
            fits.append((case, variant, a, sa, errs[-1], ns[-1]))
            if pipe:
                continue
            ax.loglog(ns, errs, m, color=c, label=f"{variant}: n^-({a:.2f} +- {sa:.2f})")
            if math.isfinite(a):
                xx = np.array([min(ns), max(ns)], float)
                ax.loglog(xx, C * xx ** (-a), "--", color=c)
        if pipe:
            ax.set_yscale("log")
            ax.set_xlabel("t")
            ax.set_ylabel("M_total / M_inf")
        else:
            ax.set_xlabel("n_inf")
            ax.set_ylabel("mean |M/M_inf - Crank|")
            log_ticks(ax, "x", np.concatenate([np.asarray(ln.get_xdata(), float) for ln in ax.get_lines()]))
        ax.set_title({"pipe": "pipe, implicit stepper", "pipe_explicit": "pipe, explicit stepper"}.get(case, case))
        ax.grid(True, which="both", alpha=0.3)
        if pipe:
            ax.legend(ncol=2 if len(ax.get_lines()) > 8 else 1, fontsize=9, title="total mass")
        else:
            ax.legend(fontsize=9, title="treatment: fitted n^-alpha (dashed)")
        first = "mean abs err M (centres)" if not pipe else "max abs err of total mass vs balance"
        second = "mean abs err M_rho" if not pipe else "max abs err of mass inside vs balance"
        md.append(f"## {case}\n")
        md.append(md_table(["n_inf", "treatment", first, second, "M/M_inf(T)", "max fraction beyond the layers",
                            "n at T", "beta dr_true^2", "wall [s]"], table))
        md.append("")
        for variant in ("papers", "best"):
            d = os.path.join(sweeps, "boundaries", f"{case}_{variant}")
            if os.path.exists(os.path.join(d, "runs.csv")):
                copy_data(d, os.path.join(docs, "data", "boundaries", f"{case}_{variant}"),
                          ["t", "mass_ratio", "reference_mass_ratio", "mass_blob_ratio", "mass_total", "mass_inside",
                           "n_particles", "n_outside"])
    for case in ("box", "sphere"):
        d = os.path.join(sweeps, "boundaries", f"{case}_best_beta1")
        if not os.path.exists(os.path.join(d, "runs.csv")):
            continue
        base = {}
        d2 = os.path.join(sweeps, "boundaries", f"{case}_best")
        if os.path.exists(os.path.join(d2, "runs.csv")):
            base = {r["particles.n_inf"]: r for r in read_rows(os.path.join(d2, "runs.csv"))}
        table = []
        ns, e1 = [], []
        for r in sorted(read_rows(os.path.join(d, "runs.csv")), key=lambda r: num(r, "particles.n_inf")):
            b = base.get(r["particles.n_inf"], {})
            table.append([r["particles.n_inf"], num(b, "ref_mean_abs_error"), num(r, "ref_mean_abs_error"),
                          num(b, "ref_max_abs_error"), num(r, "ref_max_abs_error"), num(b, "wall_seconds"),
                          num(r, "wall_seconds")])
            ns.append(num(r, "particles.n_inf"))
            e1.append(num(r, "ref_mean_abs_error"))
        C1, a1, s1 = fit_slope(ns, e1)
        ax = axes[0 if case == "sphere" else 1]
        ax.loglog(ns, e1, "^", color="tab:green", label=f"best, beta dr^2 = 1: n^-({a1:.2f} +- {s1:.2f})")
        if math.isfinite(a1):
            xx = np.array([min(ns), max(ns)], float)
            ax.loglog(xx, C1 * xx ** (-a1), "--", color="tab:green")
        ax.legend(fontsize=9, title="treatment: fitted n^-alpha (dashed)")
        md.append(f"## {case.capitalize()}, best treatment: beta dr^2 = 2 against 1\n")
        md.append(md_table(["n_inf", "mean abs err, beta dr^2 = 2", "mean abs err, beta dr^2 = 1",
                            "max abs err, 2", "max abs err, 1", "wall [s] (2)", "wall [s] (1)"], table))
        md.append(f"\nbeta dr^2 = 1: alpha = {a1:.2f} +- {s1:.2f}\n")
    widths = []
    for name in ("sphere_widths", "sphere_widths_pp"):
        d = os.path.join(sweeps, "boundaries", name)
        if os.path.exists(os.path.join(d, "runs.csv")):
            widths += [(d, r) for r in read_rows(os.path.join(d, "runs.csv"))]
    if widths:
        table = []
        for d, r in sorted(widths, key=lambda dr: (num(dr[1], "n_inf"), dr[1].get("solver.width_mode", "fixed"),
                                                    -num(dr[1], "particles.width_exponent", 1.0))):
            done = r["status"] == "completed"
            sm = summary(d, r) if done else None
            table.append([str(int(num(r, "n_inf"))), r.get("particles.width_exponent", "1"),
                          r.get("solver.width_mode", "fixed"),
                          num(r, "ref_mean_abs_error") if done else status_label(r),
                          sm["reference"].get("mass_blob", {}).get("mean_abs_error", float("nan")) if sm else "-",
                          r["evaluations"] if done else "-", r["n_particles"] if done else "-",
                          num(r, "wall_seconds")])
        md.append("## Widths with the best treatment (sphere)\n")
        md.append(md_table(["n_inf", "width_exponent q", "width_mode", "mean abs err M", "mean abs err M_rho",
                            "evaluations", "n at T", "wall [s]"], table))
        md.append("")
    # What limits the best treatment at fixed beta dr^2: the bulk diffusivity.
    keff_rows = []
    for name, case in (("sphere_best", "sphere"), ("box_best", "box"), ("sphere_best_beta1", "sphere"),
                       ("box_best_beta1", "box")):
        d = os.path.join(sweeps, "boundaries", name)
        if not os.path.exists(os.path.join(d, "runs.csv")):
            continue
        ns, res = [], []
        for r in sorted(read_rows(os.path.join(d, "runs.csv")), key=lambda r: num(r, "particles.n_inf")):
            if r["status"] != "completed":
                continue
            se = series(d, r)
            sm = summary(d, r)
            if se is None or sm is None:
                continue
            kappa = sm["config"]["physics"]["kappa"] if "config" in sm else 1.0
            sel = se["t"] > 0
            k_eff, resid = effective_kappa(case, se["t"][sel] * kappa, se["mass_ratio"][sel])
            ns.append(num(r, "particles.n_inf"))
            res.append(resid)
            keff_rows.append([name, r["particles.n_inf"], num(r, "ref_mean_abs_error"), k_eff, resid])
        _, a_r, s_r = fit_slope(ns, res)
        if ns:
            keff_rows.append([name, "fit", "-", "-", f"alpha = {fmt(a_r)} +- {fmt(s_r, 2)}"])
    if keff_rows:
        md.append("## The bulk diffusivity's share (best treatment)\n")
        md.append("kappa_eff: the diffusivity whose Crank curve comes closest to M/M_inf (least mean abs error); "
                  "residual: that closest mean abs error, what is left once the bulk diffusivity's bias is taken "
                  "out. At fixed beta dr^2 the particle system diffuses at a fixed multiple of kappa whatever n "
                  "(study 3), which puts a floor under the error against Crank at kappa.\n")
        md.append(md_table(["sweep", "n_inf", "mean abs err vs Crank(kappa)", "kappa_eff / kappa",
                            "residual vs Crank(kappa_eff)"], keff_rows))
        md.append("")
    d = os.path.join(sweeps, "boundaries", "box_best_beta1_seeds")
    if os.path.exists(os.path.join(d, "runs.csv")):
        rows = [r for r in read_rows(os.path.join(d, "runs.csv")) if r["status"] == "completed"]
        d1 = os.path.join(sweeps, "boundaries", "box_best_beta1")
        base = [r for r in read_rows(os.path.join(d1, "runs.csv"))
                if r["status"] == "completed" and num(r, "n_inf") == num(rows[0], "n_inf")] if rows and \
            os.path.exists(os.path.join(d1, "runs.csv")) else []
        errs = [num(r, "ref_mean_abs_error") for r in base + rows]
        md.append("## Box, best treatment, beta dr^2 = 1: seed to seed\n")
        md.append(md_table(["n_inf", "run.seed", "mean abs err M"],
                           [[str(int(num(r, "n_inf"))), r.get("run.seed", "1"), num(r, "ref_mean_abs_error")]
                            for r in base + rows]))
        if len(errs) > 1:
            md.append(f"\nmean {fmt(float(np.mean(errs)))}, standard deviation {fmt(float(np.std(errs, ddof=1)))} "
                      f"over {len(errs)} seeds\n")
    md.append("## Fitted slopes (error ~ n^-alpha, least squares in log-log, +- one standard error)\n")
    md.append(md_table(["case", "treatment", "alpha", "std. error", "error at largest n", "largest n"],
                       [[c, v, a, sa, e, str(n)] for c, v, a, sa, e, n in fits]))
    fig.tight_layout()
    finish(fig, os.path.join(docs, "boundaries.png"))
    with open(os.path.join(docs, "boundaries.md"), "w") as f:
        f.write("\n".join(md))


# ------------------------------------------------------------------ study 6
def count(row, key):
    v = num(row, key)
    return str(int(v)) if math.isfinite(v) else "-"


def large_steps(sweeps, docs):
    """Time to solution at matched accuracy (issue 11): every run's wall time
    against its time-discretisation error (mean over [0, T] of |M/M_inf - the
    reference's|, the reference being explicit Euler with the exact gradient
    at dt/4, seed 1; the seed-2 reference gives the noise floor) and its error
    against the analytic curve."""
    md = ["# Study 6: large steps, time to solution (generated by scripts/study_plots.py)\n"]
    cases = [("sphere_T1", "Sphere, T = 1 (study 1's window)"), ("sphere", "Sphere, T = 15 (Table 1's horizon)"),
             ("box", "Box, T = 60 (Table 2's horizon)")]
    present = [c for c in cases if os.path.exists(os.path.join(sweeps, "large_steps", c[0], "reference", "runs.csv"))]
    if not present:
        return
    fig, axes, leg = panels(len(present), legend_slot=True)
    for ax, (case, title) in zip(axes, present):
        base = os.path.join(sweeps, "large_steps", case)
        ref_dir = os.path.join(base, "reference")
        ref_rows = [r for r in read_rows(os.path.join(ref_dir, "runs.csv")) if r["status"] == "completed"]
        ref_rows.sort(key=lambda r: num(r, "run.seed"))
        if not ref_rows:
            continue
        s_ref = series(ref_dir, ref_rows[0])

        def dt_error(s):
            m = np.interp(s["t"], s_ref["t"], s_ref["mass_ratio"])
            return float(np.trapz(np.abs(s["mass_ratio"] - m), s["t"]) / s["t"][-1])

        floor = dt_error(series(ref_dir, ref_rows[1])) if len(ref_rows) > 1 else float("nan")
        table = [["explicit euler_exact (reference, seed 1)", "0.25", count(ref_rows[0], "steps"),
                  count(ref_rows[0], "evaluations"), num(ref_rows[0], "wall_seconds"), 0.0,
                  num(ref_rows[0], "ref_mean_abs_error")]]
        if len(ref_rows) > 1:
            table.append(["explicit euler_exact (reference, seed 2)", "0.25", count(ref_rows[1], "steps"),
                          count(ref_rows[1], "evaluations"), num(ref_rows[1], "wall_seconds"), floor,
                          num(ref_rows[1], "ref_mean_abs_error")])
        styles = {"explicit": ("tab:blue", "o"), "implicit euler": ("tab:red", "s"), "implicit bdf2": ("tab:green", "^"),
                  "adaptive bdf2": ("tab:purple", "D")}
        for family in ("explicit", "implicit", "adaptive"):
            d = os.path.join(base, family)
            if not os.path.exists(os.path.join(d, "runs.csv")):
                continue
            groups = {}
            for r in read_rows(os.path.join(d, "runs.csv")):
                if family == "explicit":
                    label, setting = "explicit " + r["solver.explicit_scheme"], r["run.dt_factor"]
                    key = "explicit"
                elif family == "implicit":
                    label, setting = "implicit " + r["solver.time_scheme"], r["run.dt_factor"]
                    key = label
                else:
                    label, setting = "adaptive bdf2", "tol " + r["run.time_tolerance"]
                    key = label
                s = series(d, r) if r["status"] == "completed" else None
                e = dt_error(s) if s is not None else float("nan")
                table.append([label, setting, count(r, "steps"), count(r, "evaluations"), num(r, "wall_seconds"), e,
                              num(r, "ref_mean_abs_error") if r["status"] == "completed" else float("nan")])
                groups.setdefault((key, label), []).append((num(r, "wall_seconds"), e))
            for (key, label), pts in groups.items():
                pts = sorted(p for p in pts if math.isfinite(p[1]) and p[1] > 0)  # 0: the reference itself
                if not pts:
                    continue
                color, marker = styles[key]
                if label == "explicit euler27":
                    color = "tab:cyan"
                ax.loglog([p[0] for p in pts], [p[1] for p in pts], marker=marker, color=color, label=label, ms=7,
                          lw=1.5)
        if math.isfinite(floor) and floor > 0:
            ax.axhline(floor, color="k", ls=":", lw=1.2, label="seed-to-seed floor")
        ax.set_title(title)
        ax.set_xlabel("wall time (s, one thread)")
        ax.set_ylabel("time error of M/M_inf")
        ax.grid(True, which="both", alpha=0.3)
        md.append(f"\n## {title}\n\n")
        md.append(md_table(["scheme", "dt / dt_explicit or tolerance", "steps", "evaluations", "wall s",
                            "time error (mean over t)", "mean abs error vs analytic"], table))
    # One legend for all panels: the union of their entries, in drawing order.
    entries = {}
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(lab, h)
    leg.legend(list(entries.values()), list(entries.keys()), loc="center", title="scheme (line: dt or tolerance ladder)")
    fig.tight_layout()
    finish(fig, os.path.join(docs, "large_steps.png"))
    with open(os.path.join(docs, "large_steps.md"), "w") as f:
        f.write("".join(md))


def check(sweeps, study):
    """Every sweep of the study has its whole grid in runs.csv, every implicit
    run completed, and every completed run has finite reference errors."""
    problems = []
    found = 0
    for root, _dirs, files in os.walk(os.path.join(sweeps, study)):
        if "runs.csv" not in files:
            continue
        found += 1
        with open(os.path.join(root, "sweep.json")) as f:
            expected = json.load(f)["runs"]
        rows = read_rows(os.path.join(root, "runs.csv"))
        if len(rows) != expected:
            problems.append(f"{root}: {len(rows)} rows, grid has {expected}")
        for r in rows:
            if r["status"] not in ("completed", "failed", "invalid", "timeout", "crashed"):
                problems.append(f"{root} {r['dir']}: unknown status {r['status']}")
            if r.get("solver.stepper", "implicit") == "implicit" and r["status"] != "completed":
                problems.append(f"{root} {r['dir']}: implicit run {r['status']}: {r['error']}")
            if r["status"] == "completed" and r.get("reference") and not math.isfinite(num(r, "ref_max_abs_error")):
                problems.append(f"{root} {r['dir']}: reference error missing")
    if found == 0:
        problems.append(f"{study}: no sweep found under {sweeps}")
    return problems


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("study", choices=["implicit_explicit", "variable_width", "diffusivity", "convergence", "boundaries",
                                      "large_steps", "all"])
    ap.add_argument("--sweeps", required=True, help="directory holding the sweeps (scripts/studies.sh --out)")
    ap.add_argument("--docs", required=True, help="where the plots, tables and data copies go")
    ap.add_argument("--check", action="store_true", help="also check the sweeps' grids; exit 1 on a problem")
    a = ap.parse_args()
    os.makedirs(a.docs, exist_ok=True)
    studies = (["implicit_explicit", "variable_width", "diffusivity", "convergence", "boundaries", "large_steps"]
               if a.study == "all" else [a.study])
    problems = []
    for s in studies:
        globals()[s](a.sweeps, a.docs)
        print(f"study_plots: {s} -> {a.docs}", file=sys.stderr)
        if a.check:
            problems += check(a.sweeps, s)
    for p in problems:
        print("study_plots: check failed: " + p, file=sys.stderr)
    if problems:
        sys.exit(1)


if __name__ == "__main__":
    main()
