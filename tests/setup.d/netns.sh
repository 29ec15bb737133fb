#!/usr/bin/env bash
# The multi-host tests build network namespaces joined by veth links: they need iproute2 (and root).
set -euo pipefail
if ! command -v ip >/dev/null 2>&1; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq && apt-get install -y -qq iproute2 >/dev/null
fi
