#!/usr/bin/env bash
# ctest Scripts.InstallDepsWaitsForTheAptLock: scripts/install_deps.sh waits
# while another apt holds its locks instead of failing at once (issue 23).
# apt-get, dpkg-query, id, sudo and sleep are stand-ins on PATH: one package
# is "missing", `apt-get update` finds the lists' lock held twice and
# `apt-get install` dpkg's lock once; the script must then succeed, having
# asked dpkg to wait (DPkg::Lock::Timeout) and retried. A real error (not a
# lock) must still fail at once.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir "$work/bin"
cat > "$work/bin/dpkg-query" <<'SH'
#!/usr/bin/env bash
# Every package installed but cmake.
for a in "$@"; do last=$a; done
[ "$last" = cmake ] && exit 1
printf 'install ok installed'
SH
cat > "$work/bin/apt-get" <<'SH'
#!/usr/bin/env bash
echo "apt-get $*" >> "$FAKE_LOG"
n=$(grep -c "" "$FAKE_LOG")
case "$*" in
  *update*)
    if [ "$FAKE_MODE" = broken ]; then echo "E: The repository 'x' does not have a Release file." >&2; exit 100; fi
    if [ "$(grep -c update "$FAKE_LOG")" -le 2 ]; then
      echo "E: Could not get lock /var/lib/apt/lists/lock. It is held by process 4242 (apt-get)" >&2
      echo "E: Unable to lock directory /var/lib/apt/lists/" >&2
      exit 100
    fi ;;
  *install*)
    if [ "$(grep -c install "$FAKE_LOG")" -le 1 ]; then
      echo "E: Could not get lock /var/lib/dpkg/lock-frontend. It is held by process 4242 (apt-get)" >&2
      exit 100
    fi ;;
esac
exit 0
SH
printf '#!/usr/bin/env bash\necho 0\n' > "$work/bin/id"
printf '#!/usr/bin/env bash\n"$@"\n' > "$work/bin/sudo"
printf '#!/usr/bin/env bash\necho "sleep $*" >> "$FAKE_LOG.sleep"\n' > "$work/bin/sleep"
chmod +x "$work/bin/"*

export FAKE_LOG="$work/apt.log" FAKE_MODE=locked PATH="$work/bin:$PATH"
if ! bash "$root/scripts/install_deps.sh" > "$work/out" 2>&1; then
  cat "$work/out"; echo "FAILED: install_deps.sh gave up while apt held its lock"; exit 1
fi
cat "$work/out"
updates=$(grep -c update "$FAKE_LOG"); installs=$(grep -c install "$FAKE_LOG")
[ "$updates" = 3 ] || { echo "FAILED: apt-get update ran $updates times, expected 3 (two refusals)"; exit 1; }
[ "$installs" = 2 ] || { echo "FAILED: apt-get install ran $installs times, expected 2 (one refusal)"; exit 1; }
grep "install" "$FAKE_LOG" | grep -q "DPkg::Lock::Timeout=" ||
  { echo "FAILED: apt-get install without -o DPkg::Lock::Timeout"; exit 1; }
grep -q " cmake" "$FAKE_LOG" || { echo "FAILED: the missing package was not installed"; exit 1; }
[ -s "$FAKE_LOG.sleep" ] || { echo "FAILED: no wait between the tries"; exit 1; }

# A real failure is not a lock: no waiting, the error and its status come out.
: > "$FAKE_LOG"; rm -f "$FAKE_LOG.sleep"
export FAKE_MODE=broken
status=0
bash "$root/scripts/install_deps.sh" > "$work/out" 2>&1 || status=$?
[ "$status" = 100 ] || { cat "$work/out"; echo "FAILED: a broken repository gave status $status, expected 100"; exit 1; }
grep -q "does not have a Release file" "$work/out" || { echo "FAILED: apt's error was not shown"; exit 1; }
[ ! -e "$FAKE_LOG.sleep" ] || { echo "FAILED: waited on an error that is not a lock"; exit 1; }
echo "install_deps.sh waits for apt's locks: ok"
