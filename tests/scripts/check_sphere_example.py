#!/usr/bin/env python3
"""examples/sphere_simulation.cpp (library calls only) reproduces the mass
column of `otfp run examples/sphere_dirichlet.toml` bit for bit, and the
series.csv it writes is the text of the command line's (issue 26).

usage: check_sphere_example.py OTFP SPHERE_SIMULATION WORK_DIR"""
import csv
import pathlib
import re
import shutil
import subprocess
import sys

otfp, example, work = sys.argv[1], sys.argv[2], pathlib.Path(sys.argv[3])
source = pathlib.Path(__file__).resolve().parents[2]
shutil.rmtree(work, ignore_errors=True)
n_inf, t_end = "400", "0.2"
subprocess.run([otfp, "run", str(source / "examples" / "sphere_dirichlet.toml"), "-o", str(work / "run"),
                "--set", "run.t_end=" + t_end, "--set", "run.vtk_interval=0"], check=True,
               stdout=subprocess.DEVNULL)
with open(work / "run" / "series.csv") as f:
    rows = [r for r in csv.DictReader(f) if int(r["step"]) > 0]
cli = [(float(r["t"]), float(r["mass_inside"])) for r in rows]
out = subprocess.run([example, n_inf, t_end, str(work / "library_series.csv")], check=True, capture_output=True,
                     text=True).stdout
lib = [(float(t), float(m)) for t, m in re.findall(r"^t = (\S+)  M = (\S+) ", out, re.M)]
if not cli or len(cli) != len(lib):
    sys.exit(f"steps: otfp run {len(cli)}, sphere_simulation {len(lib)}")
for k, ((tc, mc), (tl, ml)) in enumerate(zip(cli, lib), start=1):
    if tc != tl or mc != ml:
        sys.exit(f"step {k}: otfp run t = {tc!r}, mass_inside = {mc!r}; sphere_simulation t = {tl!r}, M = {ml!r}")
if cli[-1][1] <= 0.0:
    sys.exit("the sphere took up no mass: nothing was compared")
mine, theirs = (work / "library_series.csv").read_text(), (work / "run" / "series.csv").read_text()
if mine != theirs:
    diff = next(i for i, (a, b) in enumerate(zip(mine.splitlines() + [""], theirs.splitlines() + [""])) if a != b)
    sys.exit(f"series.csv line {diff + 1}: sphere_simulation {mine.splitlines()[diff:diff + 1]!r}, "
             f"otfp run {theirs.splitlines()[diff:diff + 1]!r}")
print(f"{len(cli)} steps, mass_inside equal to the bit (last {cli[-1][1]!r}); series.csv the same text")
