#!/usr/bin/env bash
# Installs what is missing, builds otfp, runs the main example (the sphere
# Dirichlet problem of the 2025 paper, Sec. 5.1, at a small default size) and
# draws its plots into out/sphere_dirichlet/*.png.
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=$(nproc 2>/dev/null || echo 2)
bash scripts/install_deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
cmake --build build -j "$jobs" --target otfp_cli implicit_large_steps
rm -rf out/sphere_dirichlet
./build/src/cli/otfp run examples/sphere_dirichlet.toml --out out/sphere_dirichlet "$@"
# Debian's interpreter has the matplotlib that install_deps.sh installed.
PY=python3
[ -x /usr/bin/python3 ] && PY=/usr/bin/python3
"$PY" scripts/plot.py out/sphere_dirichlet
# CI runs this script: a figure that is not drawn is a failure.
for png in mass.png inertia.png slice.png; do
  [ -s "out/sphere_dirichlet/$png" ] || { echo "run_example.sh: plot.py wrote no out/sphere_dirichlet/$png" >&2; exit 1; }
done
echo "outputs and plots in out/sphere_dirichlet/"
