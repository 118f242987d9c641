#!/usr/bin/env bash
# Installs the Debian 12 packages otfp needs; skips those already present (idempotent).
set -euo pipefail
pkgs=(build-essential cmake g++ pkg-config
      libeigen3-dev libceres-dev libnlopt-cxx-dev
      libgtest-dev libgmock-dev libbenchmark-dev
      libcli11-dev libtomlplusplus-dev libfmt-dev nlohmann-json3-dev
      python3 python3-matplotlib python3-numpy
      pybind11-dev python3-dev python3-pytest)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install_deps: all ${#pkgs[@]} packages present"
  exit 0
fi
echo "install_deps: installing ${missing[*]}"
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
