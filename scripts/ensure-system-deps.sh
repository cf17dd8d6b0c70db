#!/usr/bin/env bash
# Installs the few system libraries the Python wheels need but do not ship.
# open3d-cpu links libusb-1.0 (for RealSense support it never uses here); without it
# `import open3d` fails with "libusb-1.0.so.0: cannot open shared object file".
# chromium: the report test opens `kogei report`'s HTML in headless Chromium (no broken images).
set -euo pipefail

python3 - <<'PY' || { echo "kogei needs Python >= 3.11 as python3 (found $(python3 --version 2>&1))." >&2; exit 1; }
import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)
PY

missing=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || missing+=(libusb-1.0-0)
command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || missing+=(chromium)
[ ${#missing[@]} -eq 0 ] && exit 0

echo "Installing system packages: ${missing[*]}" >&2
if [ "$(id -u)" -eq 0 ]; then sudo=""; elif command -v sudo >/dev/null; then sudo="sudo -n"; else
  echo "Missing system packages ${missing[*]}; install them (Debian/Ubuntu: apt-get install ${missing[*]}) and re-run." >&2
  exit 1
fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get install -y -q "${missing[@]}" >/dev/null 2>&1 \
  || { $sudo apt-get update -q >/dev/null && $sudo apt-get install -y -q "${missing[@]}" >/dev/null; } \
  || { echo "Could not install ${missing[*]} with apt-get; install them by hand and re-run." >&2; exit 1; }
