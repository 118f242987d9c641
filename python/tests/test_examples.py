"""The Python examples say what they do."""
import math
import os
import re
import subprocess
import sys

import otfp


def test_large_steps_labels_each_run_by_the_step_it_takes(source_dir):
    script = source_dir / "examples" / "python" / "large_steps.py"
    out = subprocess.run([sys.executable, str(script), "--smoke"], capture_output=True, text=True, check=True,
                         env=dict(os.environ, OMP_NUM_THREADS="1")).stdout
    # The --smoke size: n_inf = 150 in the unit ball, kappa = 1: dt_explicit = dr^2 (39).
    ball = otfp.make_ball(3, [0, 0, 0], 1.0)
    dt_explicit = otfp.paper_parameters(ball.volume, 150, 3, length_L=1.0, kappa=1.0).dt_explicit
    blocks = out.split("--- ")[1:]
    assert len(blocks) == 2
    for block in blocks:
        label = float(re.match(r"dt = ([0-9.]+)x the explicit limit", block).group(1))
        dts = [float(d) for d in re.findall(r"step \d+: t = [0-9.e+-]+ \(dt = ([0-9.e+-]+)\)", block)]
        assert dts and max(dts) == min(dts)  # equal steps
        assert math.isclose(label, dts[0] / dt_explicit, rel_tol=5e-3), (label, dts[0] / dt_explicit)
