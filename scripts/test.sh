#!/usr/bin/env bash
# Installs what is missing, builds otfp and runs the whole test suite.
#   bash scripts/test.sh             Release build + tests + find_package consumer check
#   bash scripts/test.sh --ci        the same with warnings as errors, then the tests
#                                    once more under AddressSanitizer + UndefinedBehaviorSanitizer
set -euo pipefail
cd "$(dirname "$0")/.."
ci=0
for arg in "$@"; do
  case "$arg" in
    --ci) ci=1 ;;
    *) echo "usage: bash scripts/test.sh [--ci]" >&2; exit 2 ;;
  esac
done
jobs=$(nproc 2>/dev/null || echo 2)
bash scripts/install_deps.sh

werror=OFF
[ "$ci" = 1 ] && werror=ON
echo "== Release build (warnings as errors: $werror)"
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DOTFP_WARNINGS_AS_ERRORS=$werror
cmake --build build -j "$jobs"
echo "== Tests"
ctest --test-dir build -j "$jobs" --output-on-failure

echo "== find_package(otfp) from an installed tree"
rm -rf build/_install build/_consumer
cmake --install build --prefix "$PWD/build/_install" >/dev/null
cmake -S examples/consumer -B build/_consumer -DCMAKE_PREFIX_PATH="$PWD/build/_install" -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build/_consumer -j "$jobs" >/dev/null
./build/_consumer/consumer
if [ -f build/python/otfp/__init__.py ]; then
  echo "== import otfp from the installed tree"
  pydir=$(dirname "$(find build/_install -path '*/otfp/__init__.py' | head -n 1)")
  PY=python3
  [ -x /usr/bin/python3 ] && PY=/usr/bin/python3
  PYTHONPATH="$PWD/$(dirname "$pydir")" "$PY" -c \
    "import otfp, sys; b = otfp.make_ball(3, [0, 0, 0], 1.0); assert abs(b.volume - 4.18879020478639) < 1e-12; print('otfp', otfp.__version__, 'from', otfp.__file__)"
fi

if [ "$ci" = 1 ]; then
  echo "== Tests under AddressSanitizer + UndefinedBehaviorSanitizer"
  # -O1 -g1 (line tables: the reports still name file and line), ASan's usual
  # level: the build takes 40% less CPU time than at RelWithDebInfo's -O2 -g.
  # The library itself builds at -O2 (src/CMakeLists.txt): the tests spend
  # most of their time in it.
  cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O1 -g1 -DNDEBUG" \
        -DOTFP_WARNINGS_AS_ERRORS=ON -DOTFP_SANITIZE=address,undefined -DOTFP_BUILD_BENCHMARKS=OFF -DOTFP_BUILD_EXAMPLES=OFF
  cmake --build build-asan -j "$jobs"
  # The script-driven smoke tests (the studies' sweeps and plots, the plot
  # and ParaView scripts) test Python scripts over the same binary the other
  # suites cover: they run in the Release pass only (the studies' sweeps took
  # 73 s under the sanitizers, the longest test of the pass). The
  # distributed suite runs here on 2 and 3 ranks only (tests/CMakeLists.txt
  # declares no 1-rank run under the sanitizers: 50 s there, on paths the
  # 2- and 3-rank runs take too; the Release pass runs all three).
  ASAN_OPTIONS=detect_leaks=0 UBSAN_OPTIONS=print_stacktrace=1 OMP_NUM_THREADS=2 \
    ctest --test-dir build-asan -j "$jobs" --output-on-failure -E '^(Studies|ParaView|Scripts)\.'
fi
echo "== all tests passed"
