#!/usr/bin/env bash
# `dronesim bench instructions` (tests/test_bench_instructions.py) counts instructions with valgrind's callgrind.
set -euo pipefail
if ! command -v valgrind >/dev/null 2>&1; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq && apt-get install -y -qq valgrind >/dev/null
fi
