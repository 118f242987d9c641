#!/usr/bin/env bash
# Installs the Debian 12 packages otfp needs; skips those already present (idempotent).
set -euo pipefail
pkgs=(build-essential cmake g++ pkg-config
      libeigen3-dev libceres-dev libnlopt-cxx-dev
      libgtest-dev libgmock-dev libbenchmark-dev
      libcli11-dev libtomlplusplus-dev libfmt-dev nlohmann-json3-dev
      python3 python3-matplotlib python3-numpy
      pybind11-dev python3-dev python3-pytest
      libpetsc-real3.18-dev mpi-default-dev)  # otfp::mpi, the TAO backend (OTFP_WITH_MPI)
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
# Another apt (unattended-upgrades on a fresh machine, a second terminal) may
# hold dpkg's lock or the package lists' lock: wait for it, up to 10 minutes,
# instead of failing at once. dpkg's lock is waited for by apt itself
# (DPkg::Lock::Timeout); a refusal for a held lock (the lists' lock of
# `apt-get update` included) is retried every 10 s. Other errors fail at once.
lock_wait=600
apt_get() {
  local log status waited=0
  log=$(mktemp)
  while true; do
    status=0
    $SUDO apt-get -o DPkg::Lock::Timeout=$lock_wait "$@" 2> "$log" || status=$?
    if [ "$status" -ne 0 ] && [ "$waited" -lt "$lock_wait" ] &&
       grep -qE "Could not get lock|Unable to lock|Unable to acquire the dpkg frontend lock" "$log"; then
      echo "install_deps: apt's lock is held by another process; waiting (${waited} s so far)" >&2
      sleep 10
      waited=$((waited + 10))
      continue
    fi
    cat "$log" >&2
    rm -f "$log"
    return "$status"
  done
}
apt_get update -qq
apt_get install -y -qq --no-install-recommends "${missing[@]}"
