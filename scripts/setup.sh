#!/usr/bin/env bash
# Idempotent set-up from a fresh clone: .venv with the CPU torch pin, the package in
# editable mode with dev extras, and Debian's libusb when open3d cannot load without it.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating .venv with $($PYTHON --version)"
  "$PYTHON" -m venv .venv
fi

stamp=.venv/.semanticxr-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "[setup] installing dependencies (torch==2.13.0 CPU build first)"
  # pip.conf on this machine lists local indexes that may be absent; drop that noise.
  .venv/bin/pip install -q --disable-pip-version-check torch==2.13.0 2>&1 | grep -v "is ignored" || true
  .venv/bin/pip install -q --disable-pip-version-check -e ".[dev]" 2>&1 | grep -v "is ignored" || true
  .venv/bin/python -c "import torch, numpy, fastapi, msgpack, av, lzfse, pocketsphinx, xdist" # fail loudly if the install failed
  touch "$stamp"
fi

# open3d 0.20 links against libusb-1.0 from the system.
bash scripts/ensure_libusb.sh .venv/bin/python
# Optional Debian packages some tests need: installed as root with apt-get; elsewhere those
# tests skip, saying why.
install_optional() {  # install_optional PACKAGE WHAT-SKIPS-WITHOUT-IT
  local package=$1 tests=$2
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "[setup] installing Debian's $package for $tests (once)"
    (apt-get install -y -q "$package" >/dev/null 2>&1) || \
      (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q "$package" >/dev/null 2>&1) || \
      echo "[setup] could not install $package: $tests will be skipped"
  else
    echo "[setup] no $package: $tests will be skipped ('sudo apt-get install $package' adds it)"
  fi
}
# Page tests drive a real headless Chromium from Debian (Playwright's own download cannot
# work offline).
if [ "${SEMANTICXR_SKIP_BROWSER:-0}" != "1" ] && ! command -v chromium >/dev/null \
    && ! command -v chromium-headless-shell >/dev/null; then
  install_optional chromium "the browser tests"
fi
# The PostgreSQL store's tests start a throwaway cluster with initdb and pg_ctl: on PATH, or
# where Debian puts them (/usr/lib/postgresql/<version>/bin, not on PATH).
postgres_found() {
  if command -v initdb >/dev/null && command -v pg_ctl >/dev/null; then return 0; fi
  for bin in /usr/lib/postgresql/*/bin; do
    if [ -x "$bin/initdb" ] && [ -x "$bin/pg_ctl" ]; then return 0; fi
  done
  return 1
}
if [ "${SEMANTICXR_SKIP_POSTGRES:-0}" != "1" ] && ! postgres_found; then
  install_optional postgresql "the PostgreSQL store's tests"
fi
# Spoken-question tests and `eval --scenario speech` synthesise speech with Debian's espeak-ng.
if [ "${SEMANTICXR_SKIP_SPEECH:-0}" != "1" ] && ! command -v espeak-ng >/dev/null; then
  install_optional espeak-ng "the spoken-question tests and eval"
fi
# The server reads its labels' synonyms and definitions (the match rule) from Debian's WordNet.
if [ ! -f "${SEMANTICXR_WORDNET_DIR:-/usr/share/wordnet}/index.noun" ]; then
  install_optional wordnet-base "the WordNet label texts (labels are then matched by name alone) and their tests"
fi
echo "[setup] ok"
