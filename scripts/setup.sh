#!/usr/bin/env bash
# Create .venv (once) and install EVP into it, at the exact versions of constraints.txt, with every
# optional part (the station, MAVLink output, the PostgreSQL driver, the Dask client) and the extras given as
# arguments (e.g. "test").
# Works on a fresh Debian machine that has only Python 3.11+: installs python3-venv if it is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  if ! "$PYTHON" -m venv .venv 2>/dev/null; then
    rm -rf .venv
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
      echo "python venv support is missing: installing python3-venv" >&2
      apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null
      "$PYTHON" -m venv .venv
    else
      echo "error: '$PYTHON -m venv' failed; install your distribution's python3-venv package" >&2
      exit 1
    fi
  fi
fi
extras=$(IFS=,; echo "station,mavlink,postgres,cluster${*:+,$*}")
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -c constraints.txt -e ".[${extras}]"
