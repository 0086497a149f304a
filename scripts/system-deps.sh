#!/usr/bin/env bash
# Debian packages baromap's firmware build and flashing, firmware-in-the-loop tests, C port tap,
# USB adapter reset and live view client test need.
# As root: installs what is missing. Otherwise: says what is missing and how to get it;
# the tests that need them are then skipped with that reason, the rest still run.
set -euo pipefail

# gcc and libc6-dev build the daemon's port tap (daemon/tap.c); g++ pulls them in too, but the
# tap should not depend on the firmware harness's compiler staying in this list.
# avrdude: `make -C firmware flash` and its test against a stand-in bootloader; libusb-1.0-0:
# pyusb's backend, for the daemon's reset of a wedged USB adapter.
# systemd: systemd-analyze, for the unit's tests; bindfs: a FUSE mount whose server a test
# stops, for a disk that hangs under the daemon.
packages=(python3-venv gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev libelf-dev
          pkg-config gcc libc6-dev g++ make avrdude libusb-1.0-0 systemd bindfs)
# Node.js runs a third-party client of the daemon's live view in the end-to-end tests
# (tests/liveview/js); a Node installed some other way is left alone.
command -v node >/dev/null 2>&1 || packages+=(nodejs)
command -v npm >/dev/null 2>&1 || packages+=(npm)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# python3-venv only matters when the interpreter cannot make a venv by itself.
if python3 -c 'import ensurepip' 2>/dev/null; then
  missing=("${missing[@]/python3-venv}")
fi
read -r -a missing <<< "${missing[*]}"

if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "system-deps: not a Debian system; firmware tests will be skipped (missing: ${missing[*]})" >&2
  exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
  echo "system-deps: missing Debian packages: ${missing[*]}" >&2
  echo "system-deps: run 'sudo apt-get install ${missing[*]}' to build the firmware and run" >&2
  echo "system-deps: its simulator tests; without them those tests are skipped." >&2
  exit 0
fi
echo "system-deps: installing ${missing[*]}" >&2
export DEBIAN_FRONTEND=noninteractive
if ! apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null; then
  apt-get update -q >/dev/null
  apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null
fi
