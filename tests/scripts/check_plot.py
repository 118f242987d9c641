#!/usr/bin/env python3
"""ctest Scripts.PlotRunDirectory: scripts/plot.py on a real run directory.

    python3 tests/scripts/check_plot.py OTFP_CLI WORK_DIR

1. last_snapshot() picks the particle snapshot with the largest time from a
   particles.pvd whose entries are out of time order and that also lists a
   domain surface (and from the particles_*.vtp files when there is no .pvd).
2. A short run of examples/sphere_dirichlet.toml (the README's first command at
   a smaller t_end), then plot.py: mass.png, inertia.png and slice.png must be
   written, and mass.png has the two panels (M/M_inf with M_rho/M_inf and the
   reference; the errors against the reference).
"""
import os
import shutil
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "scripts"))

import plot  # noqa: E402

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def fail(msg):
    sys.exit(f"check_plot.py: FAILED: {msg}")


def write_vtp(path, with_age):
    """A minimal .vtp header: only the names of the point arrays matter to last_snapshot()."""
    arrays = '<DataArray type="Float64" Name="age" format="appended" offset="0"/>' if with_age else ""
    with open(path, "w") as f:
        f.write('<?xml version="1.0"?>\n<VTKFile type="PolyData"><PolyData><Piece><PointData>'
                f"{arrays}</PointData><CellData></CellData></Piece></PolyData>"
                '<AppendedData encoding="raw">\n_\n</AppendedData></VTKFile>\n')


def check_last_snapshot(work):
    d = os.path.join(work, "pvd_order")
    shutil.rmtree(d, ignore_errors=True)
    os.makedirs(d)
    for name in ("particles_00000.vtp", "particles_00010.vtp", "particles_00020.vtp", "particles_failed.vtp"):
        write_vtp(os.path.join(d, name), with_age=True)
    write_vtp(os.path.join(d, "domain.vtp"), with_age=False)
    # The domain listed last (as otfp wrote it until issue 23), and a snapshot
    # listed after a later one: the answer is the latest particle snapshot.
    with open(os.path.join(d, "particles.pvd"), "w") as f:
        f.write('<?xml version="1.0"?>\n<VTKFile type="Collection"><Collection>\n'
                '<DataSet timestep="0" group="" part="0" file="particles_00000.vtp"/>\n'
                '<DataSet timestep="0.5" group="" part="0" file="particles_00020.vtp"/>\n'
                '<DataSet timestep="0.25" group="" part="0" file="particles_00010.vtp"/>\n'
                '<DataSet timestep="0.5" group="" part="1" file="domain.vtp"/>\n'
                "</Collection></VTKFile>\n")
    got = plot.last_snapshot(d)
    if os.path.basename(got or "") != "particles_00020.vtp":
        fail(f"last_snapshot() with the domain listed last gave {got}, expected particles_00020.vtp")
    # Without a .pvd: the highest step number (never particles_failed.vtp or the domain).
    os.remove(os.path.join(d, "particles.pvd"))
    got = plot.last_snapshot(d)
    if os.path.basename(got or "") != "particles_00020.vtp":
        fail(f"last_snapshot() without a .pvd gave {got}, expected particles_00020.vtp")
    print("last_snapshot: ok")


def check_run(otfp, work):
    out = os.path.join(work, "sphere")
    cmd = [otfp, "run", os.path.join(ROOT, "examples", "sphere_dirichlet.toml"), "--out", out, "--overwrite",
           "--quiet", "--set", "run.t_end=0.2", "--set", "run.vtk_interval=2"]
    subprocess.run(cmd, check=True)
    subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "plot.py"), out], check=True)
    for name in ("mass.png", "inertia.png", "slice.png"):
        path = os.path.join(out, name)
        if not os.path.isfile(path):
            fail(f"plot.py did not write {name}")
        with open(path, "rb") as f:
            if f.read(8) != PNG_MAGIC:
                fail(f"{name} is not a PNG")
    # mass.png: two panels, no right-hand axis (the layer curve used to sit on
    # one and dominate the comparison), M_rho drawn, the legend outside the data.
    series, summary = plot.read_series(out), plot.read_summary(out)
    fig = plot.mass_figure(series, summary, "sphere")
    axes = fig.get_axes()
    if len(axes) != 2:
        fail(f"mass figure has {len(axes)} axes, expected 2 (values, errors)")
    labels = [line.get_label() for line in axes[0].get_lines()]
    for want in ("M / M_inf", "M_rho / M_inf"):
        if not any(label.startswith(want) for label in labels):
            fail(f"mass figure's upper panel has no line labelled {want!r}: {labels}")
    if not any("Crank" in label for label in labels):
        fail(f"mass figure's upper panel has no reference line: {labels}")
    err_labels = [line.get_label() for line in axes[1].get_lines()]
    if len([lab for lab in err_labels if not lab.startswith("_")]) < 2:
        fail(f"mass figure's error panel has fewer than two curves: {err_labels}")
    for ax in axes:
        if ax.get_legend() is not None:
            fail("a legend inside an axes (it covers the curves): expected one figure legend outside")
    print("plot.py on a sphere run: ok")


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    otfp, work = sys.argv[1], sys.argv[2]
    os.makedirs(work, exist_ok=True)
    check_last_snapshot(work)
    check_run(otfp, work)


if __name__ == "__main__":
    main()
