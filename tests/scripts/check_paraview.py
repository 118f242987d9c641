#!/usr/bin/env python3
"""ctest ParaView.ViewScript: the files an otfp run writes for ParaView.

    python3 tests/scripts/check_paraview.py OTFP_CLI WORK_DIR

Always (no ParaView needed): a short sphere run's particles.pvd lists only
particle snapshots (a domain surface listed there is drawn opaque by
ParaView's defaults and hides every particle), domain.vtp is smaller than
every snapshot, and view.py is valid Python. A periodic 2-D run (no domain
surface) gets a view.py that names none.

Then, where `pvpython` and `xvfb-run` are installed (else exit code 77, which
ctest reports as skipped): the run directory is moved elsewhere and its
view.py is run from a third directory (it must find its files beside itself),
1. under a probe that inspects the pipeline view.py built: particles
   coloured by density at the last snapshot's time with its number of points,
   the domain translucent;
2. as `pvpython view.py --screenshot FILE`: the PNG must show density-coloured
   particles (coloured pixels; an opaque domain hides them behind grey).
"""
import os
import re
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SKIP = 77

PROBE = r'''
import os, sys
view_py = sys.argv[1]
expected_time, expected_points = float(sys.argv[2]), int(sys.argv[3])
sys.argv = [view_py]
exec(compile(open(view_py).read(), view_py, "exec"), {"__file__": view_py, "__name__": "__main__"})
from paraview.simple import FindSource, GetActiveView, GetDisplayProperties
view = GetActiveView()
particles, domain = FindSource("particles"), FindSource("domain")
problems = []
shown = GetDisplayProperties(particles, view)
if list(shown.ColorArrayName) != ["POINTS", "density"]:
    problems.append(f"particles coloured by {list(shown.ColorArrayName)}, expected density")
if shown.Representation != "Points":
    problems.append(f"particles shown as {shown.Representation}")
if abs(view.ViewTime - expected_time) > 1e-12 * max(1.0, expected_time):
    problems.append(f"view time {view.ViewTime}, expected the last snapshot's {expected_time}")
n = particles.GetDataInformation().GetNumberOfPoints()
if n != expected_points:
    problems.append(f"{n} particles shown, the last snapshot holds {expected_points}")
if domain is None:
    problems.append("no domain source")
else:
    outline = GetDisplayProperties(domain, view)
    if not 0.0 < outline.Opacity < 0.5:
        problems.append(f"domain opacity {outline.Opacity}: not translucent")
    if outline.ColorArrayName[1]:
        problems.append(f"domain coloured by {outline.ColorArrayName[1]}")
if problems:
    sys.exit("probe: " + "; ".join(problems))
print("probe: ok")
'''


def fail(msg):
    sys.exit(f"check_paraview.py: FAILED: {msg}")


def pvd_entries(run_dir):
    with open(os.path.join(run_dir, "particles.pvd")) as f:
        text = f.read()
    return [(float(t), name) for t, name in re.findall(r'timestep="([^"]*)"[^>]*file="([^"]*)"', text)]


def head(path):
    with open(path, "rb") as f:
        return f.read(4096).decode("latin-1")


def check_files(otfp, work):
    run = os.path.join(work, "sphere")
    subprocess.run([otfp, "run", os.path.join(ROOT, "examples", "sphere_dirichlet.toml"), "--out", run,
                    "--overwrite", "--quiet", "--set", "run.t_end=0.3", "--set", "run.vtk_interval=3"], check=True)
    entries = pvd_entries(run)
    if len(entries) < 2:
        fail(f"particles.pvd lists {len(entries)} entries")
    for _, name in entries:
        if 'Name="age"' not in head(os.path.join(run, name)):
            fail(f"particles.pvd lists {name}, which is not a particle snapshot")
    domain = os.path.getsize(os.path.join(run, "domain.vtp"))
    smallest = min(os.path.getsize(os.path.join(run, name)) for _, name in entries)
    if domain >= smallest:
        fail(f"domain.vtp ({domain} bytes) is not lighter than a particle snapshot ({smallest} bytes)")
    with open(os.path.join(run, "view.py")) as f:
        compile(f.read(), "view.py", "exec")
    print(f"run files: ok (domain.vtp {domain} bytes, smallest snapshot {smallest})")

    periodic = os.path.join(work, "periodic")
    subprocess.run([otfp, "run", os.path.join(ROOT, "examples", "periodic_cosine.toml"), "--out", periodic,
                    "--overwrite", "--quiet", "--set", "run.max_steps=2"], check=True)
    if os.path.exists(os.path.join(periodic, "domain.vtp")):
        fail("a periodic run wrote domain.vtp")
    with open(os.path.join(periodic, "view.py")) as f:
        text = f.read()
    compile(text, "view.py", "exec")
    if 'DOMAIN = os.fsdecode(b"")' not in text:
        fail("the periodic run's view.py names a domain file")
    return run, periodic, entries


def coloured_pixels(png):
    import matplotlib.image as mpimg
    import numpy as np
    img = mpimg.imread(png)[..., :3]
    img = img[:, : int(0.85 * img.shape[1])]  # without the colour bar at the right edge
    background = img[2, img.shape[1] // 2]
    differs = np.abs(img - background).max(axis=2) > 0.05
    saturated = (img.max(axis=2) - img.min(axis=2)) > 0.25
    # The background, the grey domain and the white axes labels are unsaturated.
    return int(np.count_nonzero(differs & saturated))


def stop_leftover_server(number):
    """xvfb-run sometimes leaves its Xvfb running after pvpython aborted: the
    server of our display number (its lock file names it) is stopped."""
    try:
        with open(f"/tmp/.X{number}-lock") as f:
            pid = int(f.read().strip())
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            argv = f.read().split(b"\0")
    except (OSError, ValueError):
        return
    if argv and os.path.basename(argv[0]) == b"Xvfb" and len(argv) > 1 and argv[1] == f":{number}".encode():
        os.kill(pid, 15)


def check_paraview(run, periodic, entries, work):
    pvpython, xvfb = shutil.which("pvpython"), shutil.which("xvfb-run")
    if not pvpython or not xvfb:
        print("ParaView (pvpython) or xvfb-run is not installed: skipped")
        sys.exit(SKIP)
    # Relocated, and run from another directory: view.py finds its files beside itself.
    moved = os.path.join(work, "moved", "sphere run")
    shutil.rmtree(os.path.dirname(moved), ignore_errors=True)
    shutil.copytree(run, moved)
    shutil.rmtree(run)
    elsewhere = tempfile.mkdtemp(dir=work)
    last_time, last_file = max(entries)
    m = re.search(r'NumberOfPoints="(\d+)"', head(os.path.join(moved, last_file)))
    probe = os.path.join(work, "probe.py")
    with open(probe, "w") as f:
        f.write(PROBE)
    shot, shot2 = os.path.join(work, "view.png"), os.path.join(work, "view_periodic.png")
    for f in (shot, shot2):
        if os.path.exists(f):
            os.remove(f)
    # Each run under its own virtual X server. On this VM (Xvfb, Mesa) pvpython
    # sometimes fails to open the display that xdpyinfo opens before and after
    # ("bad X server connection", more often under load): that is tried
    # again, and if it persists the test is skipped, as without ParaView. Any
    # other failure of view.py or of the probe fails the test.
    runs = [[pvpython, probe, os.path.join(moved, "view.py"), repr(last_time), m.group(1)],
            [pvpython, os.path.join(moved, "view.py"), "--screenshot", shot],
            [pvpython, os.path.join(periodic, "view.py"), "--screenshot", shot2]]
    number = 100 + os.getpid() % 3000
    for cmd in runs:
        for attempt in range(5):
            while os.path.exists(f"/tmp/.X{number}-lock") or os.path.exists(f"/tmp/.X11-unix/X{number}"):
                number += 1
            r = subprocess.run([xvfb, "-n", str(number), "-s", "-screen 0 1280x1024x24"] + cmd, cwd=elsewhere,
                               timeout=600, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            stop_leftover_server(number)
            number += 1
            if r.returncode == 0 or "bad X server connection" not in r.stdout:
                break
            print(f"{os.path.basename(cmd[1])}: pvpython could not open the X display (try {attempt + 1} of 5)")
        print(r.stdout)
        if r.returncode != 0 and "bad X server connection" in r.stdout:
            print("pvpython could not open a virtual X display five times: skipped")
            sys.exit(SKIP)
        if r.returncode != 0:
            fail(f"{' '.join(cmd[1:])} exited with status {r.returncode} (output above)")
    if not os.path.isfile(shot):
        fail("view.py --screenshot wrote no image")
    n = coloured_pixels(shot)
    if n < 1000:
        fail(f"the screenshot has {n} density-coloured pixels: the particles are hidden or not coloured")
    print(f"view.py screenshot: ok ({n} coloured pixels)")
    # A 2-D periodic run: no domain surface, the view in 2-D.
    n = coloured_pixels(shot2)
    if n < 1000:
        fail(f"the periodic run's screenshot has {n} density-coloured pixels")
    print(f"view.py on a 2-D periodic run: ok ({n} coloured pixels)")


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    otfp, work = sys.argv[1], sys.argv[2]
    os.makedirs(work, exist_ok=True)
    run, periodic, entries = check_files(otfp, work)
    check_paraview(run, periodic, entries, work)


if __name__ == "__main__":
    main()
