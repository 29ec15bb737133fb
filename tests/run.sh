#!/usr/bin/env bash
# Installs what the tests need, runs the static checks (ruff, mypy), then the whole suite. This is the README's
# test command and CI's.
#   - the Python package, its test extras, its rl extra (PettingZoo, gymnasium, SuperSuit: tests/test_pettingzoo.py),
#     its train extra (JAX, Flax, Optax: tests/test_ppo.py) and its mavlink extra (pymavlink, MAVProxy, MAVSDK:
#     tests/test_mavlink*.py);
#   - every tests/setup.d/*.sh (system packages: iproute2 for the multi-host tests, chromium for the
#     browser tests, zenohd, ...), each idempotent and quick when already done.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install --quiet --disable-pip-version-check -e '.[test,rl,train,ros2,mavlink]'
for step in tests/setup.d/*.sh; do
  [ -e "$step" ] || continue
  echo "setup: $step"
  bash "$step"
done
# Static checks first (configured in pyproject.toml): a lint or type error fails CI as a failing test does.
echo "static checks: ruff, mypy"
python3 -m ruff check .
python3 -m mypy
# pytest exits non-zero on any failure, and with 5 when no test ran: both fail CI.
exec python3 -m pytest -q -rs -p no:cacheprovider "$@"  # -rs: every skip says why
