#!/usr/bin/env python3
"""Plots of an otfp run directory (needs numpy and matplotlib, e.g. Debian's
python3-numpy and python3-matplotlib).

    python3 scripts/plot.py OUTDIR [--out PNGDIR]
        mass.png     M/M_inf (particles inside) and M_rho/M_inf (blob density
                     over Omega) against t with Crank's curve when the run has a
                     reference, and a panel below with their errors against it
        inertia.png  J_G/J_inf against t with the analytic J_ref(t)/J_inf when
                     the run has a J_inf; otherwise J_G itself, and with
                     reference = "free_space" the blob density's second
                     moment S and its free-space line S(0) + 2 d kappa M t
        slice.png    particles of the last VTK snapshot in a slab through the
                     diagnostics centre, coloured by age, with the domain
                     boundary and the outer edge of the layer (reservoir band
                     w, or the papers' b) over the Dirichlet patches

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
from mpl_toolkits.axes_grid1 import make_axes_locatable  # noqa: E402
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


def is_particle_snapshot(path):
    """A .vtp of particles (point data "age"), not the domain surface or another file."""
    try:
        with open(path, "rb") as f:
            head = f.read(65536)
    except OSError:
        return False
    head = head.split(b"<AppendedData", 1)[0]
    return b"<PointData" in head and b'Name="age"' in head


def last_snapshot(run_dir):
    """The particle snapshot with the largest time: from particles.pvd (any
    order of entries; files that are not particle snapshots, such as a domain
    surface, are skipped), else the particles_NNNNN.vtp with the largest step."""
    pvd = os.path.join(run_dir, "particles.pvd")
    if os.path.exists(pvd):
        with open(pvd) as f:
            entries = []
            for i, tag in enumerate(re.findall(r"<DataSet\b[^>]*>", f.read())):
                attrs = dict(re.findall(r'(\w+)="([^"]*)"', tag))
                try:
                    t = float(attrs.get("timestep", "nan"))
                except ValueError:
                    t = float("nan")
                if "file" in attrs:
                    entries.append((-math.inf if math.isnan(t) else t, i, attrs["file"]))
        # Latest time first; among equal times the entry listed last.
        for _, _, name in sorted(entries, reverse=True):
            path = os.path.join(run_dir, name)
            if is_particle_snapshot(path):
                return path
    steps = sorted((int(m.group(1)), f) for f in os.listdir(run_dir)
                   for m in [re.fullmatch(r"particles_(\d+)\.vtp", f)] if m)
    for _, name in reversed(steps):
        path = os.path.join(run_dir, name)
        if is_particle_snapshot(path):
            return path
    return None


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


def plot_with_layer(ax, t, values, primary, label):
    """The with-layer line: on the main axis when it is of the same size as the
    primary lines, else on a right-hand axis of its own (a reservoir band can
    hold many times the mass inside Omega and would flatten the other lines)."""
    top = np.nanmax(np.abs(np.concatenate([np.ravel(p) for p in primary])))
    if np.nanmax(np.abs(values)) <= 2.0 * max(top, 1e-300):
        return ax.plot(t, values, "--", label=label)[0]
    right = ax.twinx()
    line = right.plot(t, values, "--", color="tab:orange", label=f"{label} (right axis)")[0]
    right.set_ylabel(f"{label} (right axis)")
    return line


# ----------------------------------------------------------------- polar inertia

# Where the analytic curves come from (include/otfp/analytic.hpp).
MASS_REFERENCE_NAMES = {"crank_sphere": "Crank 6.20 (sphere)", "crank_slab": "Crank 4.18 (slab)"}
INERTIA_REFERENCE_NAMES = {"crank_sphere": "from Crank 6.18 (sphere)", "crank_slab": "from Crank 4.17 (slab)"}


def plot_inertia(ax, series, summary):
    """J_G against t: as J_G / J_inf when the run has a J_inf, else absolute."""
    ref = summary["config"]["diagnostics"]["reference"]
    j_inf = summary["derived"].get("J_inf")
    if j_inf and "polar_inertia_ratio" in series:
        # polar_inertia_ratio = polar_inertia / J_inf (docs/outputs.md); the
        # with-layer value and the analytic reference (an absolute J_ref(t))
        # are divided by the same J_inf so that all lines share the axis.
        t = series["t"]
        lines = [ax.plot(t, series["polar_inertia_ratio"], label="J_G / J_inf (inside, (44))")[0]]
        primary = [series["polar_inertia_ratio"], [1.0]]
        lines.append(ax.axhline(1.0, color="0.5", lw=0.8, ls="-.", label="J_inf"))
        if "reference_polar_inertia" in series:
            primary.append(series["reference_polar_inertia"] / j_inf)
            lines.append(ax.plot(t, primary[-1], "k:", label=f"J_ref(t) / J_inf ({INERTIA_REFERENCE_NAMES.get(ref, ref)})")[0])
        lines.insert(1, plot_with_layer(ax, t, series["polar_inertia_with_layer"] / j_inf, primary,
                                        "with external layer"))
        ax.set_ylabel(f"J_G / J_inf  (J_inf = {j_inf:.4g})")
        return lines
    # No J_inf (free space, or a domain without one): absolute values.
    lines = [ax.plot(series["t"], series["polar_inertia_total"], label="J_G (all particles)")[0]]
    if "reference_polar_inertia" in series:
        lines += ax.plot(series["t"], series["reference_polar_inertia"], "k:",
                         label=f"J_ref(t) ({INERTIA_REFERENCE_NAMES.get(ref, ref)})")
    if ref == "free_space":
        # The free-space reference is that of the blob density's second moment
        # S = J_G + sum_p m_p d s_p^2 / 2, which includes the blob widths.
        lines += ax.plot(series["t"], series["second_moment"], "--", label="S (blob density: J_G + widths)")
        lines += ax.plot(series["t"], series["reference_second_moment"], "k:", label="free space: S(0) + 2 d kappa M t")
        ax.set_ylabel("J_G, S  (M L^2)")
    else:
        ax.set_ylabel("J_G  (M L^2)")
    return lines


# ----------------------------------------------------------------- domain outline

def _circle(ax, centre, radius, **kw):
    phi = np.linspace(0.0, 2.0 * math.pi, 361)
    return ax.plot(centre[0] + radius * np.cos(phi), centre[1] + radius * np.sin(phi), **kw)[0]


def _rect(ax, lo, hi, **kw):
    return ax.plot([lo[0], hi[0], hi[0], lo[0], lo[0]], [lo[1], lo[1], hi[1], hi[1], lo[1]], **kw)[0]


def _chord(radius, dz):
    """Half-width of a circle of this radius cut at distance dz from its centre (None: missed)."""
    return math.sqrt(radius * radius - dz * dz) if abs(dz) < radius else None


def layer_width(summary):
    """Width of the layer outside the Dirichlet patches: the reservoir band w, or
    the papers' b when there is no band; 0 without Dirichlet patches."""
    der = summary["derived"]
    if not any(p.get("kind") == "dirichlet" for p in der.get("patches", [])):
        return 0.0
    w = der.get("reservoir_width") or 0.0
    return w if w > 0.0 else (der.get("layer_b") or 0.0)


def draw_domain(ax, summary, z0):
    """Outline of Omega (solid) and of Omega plus the layer over the Dirichlet
    patches (dashed) in the plane z = z0 (3D) or the x-y plane (2D).
    Returns (handles, notes): legend handles and what could not be drawn."""
    cfg, der = summary["config"], summary["derived"]
    dom, dim = cfg["domain"], cfg["run"]["dim"]
    kind = dom["type"]
    w = layer_width(summary)
    dirichlet = {p["name"] for p in der.get("patches", []) if p.get("kind") == "dirichlet"}
    base_names = {"surface", "x-", "x+", "y-", "y+", "z-", "z+", "lateral", "cap_a", "cap_b", "obstacle"}
    notes = []
    if dirichlet - base_names:
        notes.append("layer over Dirichlet sub-patches not drawn")
    wall = dict(color="k", lw=1.2)
    lay = dict(color="tab:red", lw=1.0, ls="--")
    handles = []
    if kind == "ball":
        R = dom["radius"]
        dz = z0 - dom["center"][2] if dim == 3 else 0.0
        h = _chord(R, dz)
        if h is not None:
            handles.append(_circle(ax, dom["center"], h, label=f"boundary R = {R:.3g}", **wall))
        if w > 0 and "surface" in dirichlet:
            h = _chord(R + w, dz)
            if h is not None:
                handles.append(_circle(ax, dom["center"], h, label=f"R + {w:.3g} (layer outer edge)", **lay))
    elif kind in ("box", "periodic_box", "square_pipe_obstacle"):
        lo, hi = list(dom["lo"]), list(dom["hi"])
        if dim == 3 and not lo[2] <= z0 <= hi[2]:
            return handles, notes + ["the slab misses the box"]
        label = "periodic box" if kind == "periodic_box" else "box walls"
        handles.append(_rect(ax, lo, hi, label=label, **wall))
        if w > 0:
            lo_l, hi_l = list(lo), list(hi)
            for k, axis in enumerate("xy"):
                if f"{axis}-" in dirichlet:
                    lo_l[k] -= w
                if f"{axis}+" in dirichlet:
                    hi_l[k] += w
            if lo_l != lo or hi_l != hi:
                handles.append(_rect(ax, lo_l, hi_l, label=f"layer outer edge (width {w:.3g})", **lay))
        if kind == "square_pipe_obstacle":
            oc = dom.get("obstacle_center") or [0.5 * (a + b) for a, b in zip(lo, hi)]
            r = dom.get("obstacle_radius") or 0.2 * min(hi[k] - lo[k] for k in range(dim) if k != "xyz".index(dom["obstacle_axis"]))
            axis = dom["obstacle_axis"] if dim == 3 else "z"
            if axis == "z":
                handles.append(_circle(ax, oc, r, color="k", lw=1.2, ls="-", label="obstacle"))
            else:
                h = _chord(r, z0 - oc[2])
                if h is not None:
                    k = 1 if axis == "x" else 0  # the transverse axis in the x-y plane
                    for edge in (oc[k] - h, oc[k] + h):
                        if k == 1:
                            ax.plot([lo[0], hi[0]], [edge, edge], **wall)
                        else:
                            ax.plot([edge, edge], [lo[1], hi[1]], **wall)
    elif kind == "cylinder":
        a, b, R = np.array(dom["end_a"], float), np.array(dom["end_b"], float), dom["radius"]
        e = (b - a) / np.linalg.norm(b - a)
        if abs(e[2]) > 1 - 1e-12:
            handles.append(_circle(ax, a, R, label=f"lateral wall R = {R:.3g}", **wall))
            if w > 0 and "lateral" in dirichlet:
                handles.append(_circle(ax, a, R + w, label=f"R + {w:.3g} (layer outer edge)", **lay))
        elif abs(e[2]) < 1e-12 and (abs(e[0]) > 1 - 1e-12 or abs(e[1]) > 1 - 1e-12):
            k = 0 if abs(e[0]) > 0.5 else 1  # axis in the plane
            j = 1 - k
            def outline(radius, ext_a, ext_b, **kw):
                h = _chord(radius, z0 - a[2])
                if h is None:
                    return None
                lo, hi = [0.0, 0.0], [0.0, 0.0]
                lo[k], hi[k] = min(a[k], b[k]) - ext_a, max(a[k], b[k]) + ext_b
                lo[j], hi[j] = a[j] - h, a[j] + h
                return _rect(ax, lo, hi, **kw)
            first = "cap_a" if a[k] < b[k] else "cap_b"
            second = "cap_b" if first == "cap_a" else "cap_a"
            hnd = outline(R, 0.0, 0.0, label=f"cylinder walls R = {R:.3g}", **wall)
            if hnd is not None:
                handles.append(hnd)
            if w > 0 and dirichlet & {"lateral", "cap_a", "cap_b"}:
                hnd = outline(R + w if "lateral" in dirichlet else R, w if first in dirichlet else 0.0,
                              w if second in dirichlet else 0.0, label=f"layer outer edge (width {w:.3g})", **lay)
                if hnd is not None:
                    handles.append(hnd)
        else:
            notes.append("cylinder axis oblique to the slice: outline not drawn")
    return handles, notes


def draw_domain_1d(ax, summary):
    """Walls (solid) and the layer's outer edge (dashed) of a 1D run as vertical lines."""
    dom = summary["config"]["domain"]
    w = layer_width(summary)
    dirichlet = {p["name"] for p in summary["derived"].get("patches", []) if p.get("kind") == "dirichlet"}
    if dom["type"] == "ball":
        ends = [(dom["center"][0] - dom["radius"], -1, "surface"), (dom["center"][0] + dom["radius"], 1, "surface")]
    elif dom["type"] in ("box", "periodic_box"):
        ends = [(dom["lo"][0], -1, "x-"), (dom["hi"][0], 1, "x+")]
    else:
        return []
    handles = []
    for i, (x, side, name) in enumerate(ends):
        h = ax.axvline(x, color="k", lw=1.2, label="boundary" if i == 0 else None)
        if i == 0:
            handles.append(h)
        if w > 0 and name in dirichlet:
            h = ax.axvline(x + side * w, color="tab:red", lw=1.0, ls="--", label=f"layer outer edge (width {w:.3g})")
            if len(handles) < 2:
                handles.append(h)
    return handles


# ----------------------------------------------------------------- mass

def mass_figure(series, summary, title):
    """M/M_inf (particles inside, (43)), M_rho/M_inf (the blob density over
    Omega) and the reference on one axis; below, when there is a reference,
    their errors against it; one legend under the panels, outside the data.
    The with-layer mass (particles inside plus those in the Dirichlet buffer)
    is drawn on the same axis only when it is of the same size: a reservoir
    band can hold many times M_inf, and a second axis for it would dominate
    the comparison (the final value is then given in the legend instead)."""
    t = series["t"]
    m_inf = summary["derived"]["M_inf"]
    ref = reference_mass_ratio(series, summary)
    inside = series["mass_inside"] / m_inf
    blob = series["mass_blob_ratio"] if "mass_blob_ratio" in series else None
    if ref is not None:
        fig, (ax, axe) = plt.subplots(2, 1, figsize=(6.4, 6.2), sharex=True,
                                      gridspec_kw={"height_ratios": [2.2, 1.0]})
    else:
        fig, ax = plt.subplots(figsize=(6.4, 4.6))
        axe = None
    handles = ax.plot(t, inside, color="tab:blue", label="M / M_inf (particles inside, (43))")
    if blob is not None:
        handles += ax.plot(t, blob, color="tab:green", ls="-.", label="M_rho / M_inf (blob density over Omega)")
    if ref is not None:
        name = MASS_REFERENCE_NAMES.get(summary["config"]["diagnostics"]["reference"], "reference")
        handles += ax.plot(t, ref, "k:", lw=1.6, label=name)
    with_layer = series["mass_with_layer"] / m_inf
    drawn = [inside] + ([blob] if blob is not None else []) + ([ref] if ref is not None else [])
    top = np.nanmax(np.abs(np.concatenate([np.ravel(v) for v in drawn])))
    if np.any(with_layer != inside):
        if np.nanmax(np.abs(with_layer)) <= 1.5 * max(top, 1e-300):
            handles += ax.plot(t, with_layer, color="tab:orange", ls="--", label="with external layer")
        else:
            # An invisible handle: the legend says what is not drawn.
            handles += ax.plot([], [], " ", label=f"with external layer (off scale): {with_layer[-1]:.3g} at t = {t[-1]:.3g}")
    ax.set_ylabel("M / M_inf")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if axe is not None:
        err = series["error_mass_ratio"] if "error_mass_ratio" in series else inside - ref
        # Same colours and styles as above: the legend needs no second entry.
        axe.plot(t, err, color="tab:blue", label="error of M / M_inf")
        if blob is not None:
            err_blob = series["error_mass_blob"] if "error_mass_blob" in series else blob - ref
            axe.plot(t, err_blob, color="tab:green", ls="-.", label="error of M_rho / M_inf")
        axe.axhline(0.0, color="k", lw=0.8, ls=":")
        axe.set_ylabel("error (value - reference)")
        axe.grid(alpha=0.3)
        axe.set_xlabel("t")
    else:
        ax.set_xlabel("t")
    rows = (len(handles) + 1) // 2
    fig.legend(handles=handles, loc="lower center", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.032 * rows + 0.01, 1, 1))
    return fig


# ----------------------------------------------------------------- run plots

def plot_run(run_dir, out_dir):
    series = read_series(run_dir)
    summary = read_summary(run_dir)
    der = summary["derived"]
    t = series["t"]
    written = []

    fig = mass_figure(series, summary, os.path.basename(os.path.normpath(run_dir)))
    written.append(os.path.join(out_dir, "mass.png"))
    fig.savefig(written[-1], dpi=120, bbox_inches="tight")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    lines = plot_inertia(ax, series, summary)
    ax.set_xlabel("t")
    ax.set_title(os.path.basename(os.path.normpath(run_dir)))
    ax.grid(alpha=0.3)
    ax.legend(handles=lines)
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
        handles, notes = [], []
        if dim == 1:
            sc = ax.scatter(pos[:, 0], age, c=age, s=8, cmap="viridis")
            ax.set_ylabel("age")
            title = "all particles"
            handles = draw_domain_1d(ax, summary)
        else:
            keep = np.ones(len(pos), dtype=bool)
            title = "all particles"
            if dim == 3:
                # A slab of thickness b (the paper's Fig. 6) through the centre, normal to z.
                half = 0.5 * max(der["layer_b"], 0.1 * der["dr"] * 10)
                keep = np.abs(pos[:, 2] - centre[2]) <= half
                title = f"|z - {centre[2]:.3g}| <= {half:.3g}"
            sc = ax.scatter(pos[keep, 0], pos[keep, 1], c=age[keep], s=10, cmap="viridis")
            handles, notes = draw_domain(ax, summary, centre[2] if dim == 3 else 0.0)
            ax.set_aspect("equal")
            # Fit the figure to the domain's aspect (a long box would leave the
            # axes a thin strip in a square figure).
            (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
            fig.set_size_inches(6.5, min(7.0, max(3.4, 4.6 * (y1 - y0) / max(x1 - x0, 1e-300) + 1.9)))
            ax.set_ylabel("y")
        for note in notes:
            print(f"plot.py: slice.png: {note}", file=sys.stderr)
        if handles:
            fig.legend(handles=handles, loc="lower center", ncol=2, fontsize=9)
        ax.set_xlabel("x")
        # A colour bar as tall as the axes (with an equal aspect they can be short).
        cax = make_axes_locatable(ax).append_axes("right", size="4%", pad=0.1)
        fig.colorbar(sc, cax=cax, label="age (time since insertion)")
        ax.set_title(f"t = {arrays['_time']:.4g}, {title}")
        fig.tight_layout(rect=(0, 0.07 if handles else 0, 1, 1))
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
