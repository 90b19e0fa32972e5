#!/usr/bin/env bash
# The whole test suite, from a fresh clone. Fails when no test ran (pytest's exit code 5).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh test
# Tests run on every core (pytest-xdist), a module per worker: module fixtures (renders, SLAM runs) are made once.
# The browser tests drive Debian's Chromium; install it when we can (root with apt), else they skip.
if ! command -v chromium >/dev/null && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  echo "installing chromium for the browser tests" >&2
  (apt-get update -qq && apt-get install -y -qq chromium >/dev/null) || echo "warning: chromium could not be installed; browser tests will skip" >&2
fi
status=0
.venv/bin/python -m pytest -q -p no:cacheprovider -n auto --dist loadscope "$@" || status=$?
if [ "$status" = 5 ]; then
  echo "error: pytest collected no tests" >&2
  exit 1
fi
exit "$status"
