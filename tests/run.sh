#!/usr/bin/env bash
# Installs what the tests need, then runs the whole suite. This is the README's test command and CI's.
#   - the Python package and its test extras;
#   - every tests/setup.d/*.sh (system packages: iproute2 for the multi-host tests, chromium for the
#     browser tests, zenohd, ...), each idempotent and quick when already done.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install --quiet --disable-pip-version-check -e '.[test]'
for step in tests/setup.d/*.sh; do
  [ -e "$step" ] || continue
  echo "setup: $step"
  bash "$step"
done
# pytest exits non-zero on any failure, and with 5 when no test ran: both fail CI.
exec python3 -m pytest -q -rs -p no:cacheprovider "$@"  # -rs: every skip says why
