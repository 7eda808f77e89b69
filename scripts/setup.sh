#!/usr/bin/env bash
# Create (or reuse) the local virtual environment and install slamlab with its test tools
# (the `dev` extra: pytest, the launchers, evo, import-linter for `make lint`).
# Installs the one system library a dependency needs (libusb-1.0 for Open3D) when missing.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}

if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  echo "[setup] installing system library libusb-1.0-0 (needed by Open3D)"
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  if command -v apt-get >/dev/null 2>&1; then
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
  else
    echo "[setup] cannot install libusb-1.0 here (no apt-get): install it with your package manager" >&2
    exit 1
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "[setup] creating virtual environment $VENV"
  "$PYTHON" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
fi

# Reinstall only when the project's metadata changed since the last install.
STAMP="$VENV/.slamlab-installed"
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ]; then
  echo "[setup] installing slamlab and its dependencies into $VENV"
  "$VENV/bin/python" -m pip install -q -e '.[dev]'
  touch "$STAMP"
fi

# pip byte-compiles a regular install but not an editable one, and where
# PYTHONDONTWRITEBYTECODE is set (many containers, and this machine) Python never
# writes the .pyc files itself: every slamlab process then compiles ~90 modules from source,
# 0.1-0.3 s CPU of a one-scan run. compileall skips files whose .pyc is up to date.
"$VENV/bin/python" -m compileall -q slamlab
