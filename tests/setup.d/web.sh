#!/usr/bin/env bash
# What the browser tests (tests/e2e/) need: Debian's chromium and the Python `playwright` package.
# Playwright drives /usr/bin/chromium through its executable path: it never downloads a browser of its
# own (no `playwright install`). Idempotent, and quick when everything is already there.
set -euo pipefail

if ! command -v chromium >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends chromium fonts-dejavu-core >/dev/null
  else
    echo "web.sh: chromium is missing and apt-get cannot run here (not root or not Debian):" \
         "the browser tests will be skipped" >&2
  fi
fi

if ! python3 -c "import playwright.sync_api" >/dev/null 2>&1; then
  python3 -m pip install --quiet --disable-pip-version-check "playwright>=1.40"
fi

if command -v chromium >/dev/null 2>&1; then
  echo "web.sh: $(chromium --version 2>/dev/null || echo chromium), playwright $(python3 -c 'import importlib.metadata as m; print(m.version("playwright"))')"
fi
