#!/usr/bin/env bash
# Install what the HTML report's browser test (tests/test_browser.py) needs:
# Debian's Chromium (no browser download by a test tool) and the playwright Python package
# that drives it. Called by .ci/run before pytest. Never fails the build: where nothing can
# be installed the browser test skips and prints why.
#
#   PYTHON=/path/to/python bash .ci/browser-setup.sh
set -u
PY="${PYTHON:-python3}"

have_chromium() { command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; }

if ! have_chromium; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = "0" ]; then
    echo "browser-setup: installing chromium and chromium-driver with apt-get"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q >/tmp/browser-setup-apt.log 2>&1 \
      && apt-get install -y -q chromium chromium-driver >>/tmp/browser-setup-apt.log 2>&1 \
      || { echo "browser-setup: apt-get failed (see /tmp/browser-setup-apt.log); the browser test will skip"; tail -5 /tmp/browser-setup-apt.log; }
  else
    echo "browser-setup: no chromium and no root apt-get here; the browser test will skip"
  fi
fi
have_chromium && echo "browser-setup: $( (chromium --version || chromium-browser --version) 2>/dev/null | head -1)"

# The project's "test" extra already brings playwright into the test environment; install
# it here only when a Python is named explicitly (PYTHON=...).
if [ -n "${PYTHON:-}" ] && ! "$PY" -c "import playwright" >/dev/null 2>&1; then
  echo "browser-setup: installing playwright (the Python driver only; it drives the system chromium)"
  "$PY" -m pip install -q "playwright>=1.45" || echo "browser-setup: pip install playwright failed; the browser test will skip"
fi
"$PY" -c "import importlib.metadata as m; print('browser-setup: playwright', m.version('playwright'))" 2>/dev/null || true
exit 0
