#!/usr/bin/env bash
# open3d 0.20 links against Debian's libusb-1.0. When `import open3d` fails for that reason,
# install the library (as root, with apt-get) or print the command that does.
#
# Usage: scripts/ensure_libusb.sh [PYTHON]   (default .venv/bin/python)
# APT_GET overrides the installer (tests point it at a recorder).
set -euo pipefail

python=${1:-.venv/bin/python}
apt_get=${APT_GET:-apt-get}

# Capture the error first: piping python into `grep -q` under pipefail takes python's
# exit status, so the libusb branch once never ran.
if import_error=$("$python" -c "import open3d" 2>&1); then
  exit 0
fi
if ! grep -q "libusb" <<<"$import_error"; then
  echo "[setup] open3d does not import, and not for want of libusb:" >&2
  echo "$import_error" >&2
  exit 1
fi

if [ "$(id -u)" = "0" ] && command -v "$apt_get" >/dev/null; then
  echo "[setup] installing Debian's libusb-1.0-0 for open3d"
  ("$apt_get" install -y -q libusb-1.0-0 >/dev/null 2>&1) ||
    ("$apt_get" update -q >/dev/null && "$apt_get" install -y -q libusb-1.0-0 >/dev/null)
else
  echo "[setup] open3d needs libusb-1.0: run 'sudo apt-get install libusb-1.0-0'" >&2
  exit 1
fi
# Fail loudly with the real error if the install did not help.
"$python" -c "import open3d" >/dev/null
