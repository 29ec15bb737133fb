#!/usr/bin/env bash
# Installs the real Zenoh router, zenohd, at the version matching eclipse-zenoh in pyproject.toml, into
# ~/.cargo/bin (cargo's default install root), so tests/test_docker.py can run the docker/ router config
# with the real router. Idempotent: quick when the right version is already there.
#
# The first install builds zenohd from crates.io with cargo (about 8 minutes on 2 cores). It never fails
# the test run: when it cannot install (no cargo, no registry, build error), it writes why to
# $STATUS_FILE and exits 0; the zenohd tests then skip and print that reason.
# Set DRONESIM_SKIP_ZENOHD=1 to skip the install.
set -uo pipefail
cd "$(dirname "$0")/../.."

VERSION="$(sed -n 's/.*"eclipse-zenoh==\([0-9.]*\)".*/\1/p' pyproject.toml | head -n1)"
CARGO_HOME="${CARGO_HOME:-$HOME/.cargo}"
BIN="$CARGO_HOME/bin/zenohd"
STATUS_DIR="${XDG_CACHE_HOME:-$HOME/.cache}/dronesim"
STATUS_FILE="$STATUS_DIR/zenohd-install.txt"
LOG_FILE="$STATUS_DIR/zenohd-install.log"
mkdir -p "$STATUS_DIR"

status() { printf '%s\n' "$*" > "$STATUS_FILE"; echo "zenohd: $*"; }

if [ -z "$VERSION" ]; then
  status "FAILED: cannot read the eclipse-zenoh version from pyproject.toml"
  exit 0
fi
if [ -x "$BIN" ] && "$BIN" --version 2>/dev/null | grep -q "v$VERSION\b"; then
  status "OK: $BIN $VERSION already installed"
  exit 0
fi
if [ "${DRONESIM_SKIP_ZENOHD:-}" = 1 ]; then
  status "SKIPPED: DRONESIM_SKIP_ZENOHD=1"
  exit 0
fi
CARGO="$(command -v cargo || true)"
[ -z "$CARGO" ] && [ -x "$CARGO_HOME/bin/cargo" ] && CARGO="$CARGO_HOME/bin/cargo"
if [ -z "$CARGO" ]; then
  status "FAILED: cargo is not installed (install Rust with rustup, or the Debian package cargo)"
  exit 0
fi

echo "zenohd: building zenohd $VERSION with cargo (about 8 minutes once; log: $LOG_FILE)"
start=$(date +%s)
if "$CARGO" install zenohd --version "=$VERSION" --locked --root "$CARGO_HOME" >"$LOG_FILE" 2>&1 \
   && "$BIN" --version 2>/dev/null | grep -q "v$VERSION\b"; then
  status "OK: $BIN $VERSION installed in $(( $(date +%s) - start ))s"
else
  status "FAILED: cargo install zenohd --version =$VERSION --locked failed; last lines of $LOG_FILE: $(tail -n 5 "$LOG_FILE" | tr '\n' ' ')"
fi
exit 0
