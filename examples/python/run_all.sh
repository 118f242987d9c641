#!/usr/bin/env bash
# Runs the three Python examples: bash examples/python/run_all.sh [--smoke] [OUT_DIR]
# (PYTHONPATH must reach the module: <build>/python, or an installed otfp.)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
smoke=()
if [ "${1:-}" = "--smoke" ]; then smoke=(--smoke); shift; fi
out="${1:-out/python_examples}"
PY="${PYTHON:-python3}"
[ -z "${PYTHON:-}" ] && [ -x /usr/bin/python3 ] && PY=/usr/bin/python3
export MPLBACKEND=Agg
"$PY" "$here/implicit_vs_explicit.py" "${smoke[@]}" --out "$out"
"$PY" "$here/variable_widths.py" "${smoke[@]}" --out "$out"
"$PY" "$here/large_steps.py" "${smoke[@]}"
test -s "$out/implicit_vs_explicit.png" && test -s "$out/variable_widths.png"
echo "python examples: figures in $out"
