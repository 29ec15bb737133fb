#!/usr/bin/env bash
# The openssl command, which `dronesim certs` (and so tests/test_security.py) runs. Idempotent: nothing to
# do where it is installed (it is on Debian by default).
set -euo pipefail
command -v openssl >/dev/null 2>&1 && exit 0
echo "security: installing openssl"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq && apt-get install -y -qq openssl >/dev/null
