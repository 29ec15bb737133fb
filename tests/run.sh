#!/usr/bin/env bash
# Installs what the tests need (Python packages; Debian packages for the multi-host and browser
# tests once they exist) and runs the whole suite. This is the README's test command and CI's.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install --quiet --disable-pip-version-check -e '.[test]'
# pytest's exit 5 (no tests collected) must fail loudly, as must any other failure.
exec python3 -m pytest -q -p no:cacheprovider "$@"
