#!/usr/bin/env bash
# Time per implicit step and peak memory per particle against n (bench_scale.cpp),
# with the exponent of time ~ n^a fitted by least squares over the ladder.
#   bash bench/scaling.sh [BUILD_DIR] [THREADS] [DT_FACTOR] [N ...]
# Defaults: build, 2 threads, 1x the explicit limit, n = 1e3 1e4 1e5 1e6.
set -euo pipefail
build=${1:-build}
threads=${2:-2}
factor=${3:-1}
shift $(( $# < 3 ? $# : 3 ))
sizes=("$@")
[ ${#sizes[@]} -gt 0 ] || sizes=(1000 10000 100000 1000000)
exe="$build/bench/otfp_bench_scale"
[ -x "$exe" ] || { echo "scaling.sh: $exe not found (build the benchmarks first)" >&2; exit 2; }
out=$(mktemp)
trap 'rm -f "$out"' EXIT
for n in "${sizes[@]}"; do
  "$exe" --n "$n" --threads "$threads" --dt-factor "$factor" --steps 2 | tee -a "$out"
done
awk '$1 == "n" { for (i = 1; i < NF; ++i) if ($(i + 1) == "=") v[$i] = $(i + 2);
       x = log(v["n"]); y = log(v["seconds_per_step"]); sx += x; sy += y; sxx += x * x; sxy += x * y; k++ }
     END { if (k > 1) printf "fitted exponent: seconds per step ~ n^%.2f over %d sizes\n", (k * sxy - sx * sy) / (k * sxx - sx * sx), k }' "$out"
