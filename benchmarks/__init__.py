"""Benchmarks: ``dronesim bench NAME [options]`` (or ``python -m benchmarks.NAME``); results in BENCHMARKS.md."""

from __future__ import annotations

import importlib
import sys

#: benchmark name -> module (each has ``main(argv) -> int``).
BENCHMARKS = {"autopilot": "autopilot", "perf": "perf"}


def cli(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in BENCHMARKS:
        print(f"usage: dronesim bench {{{','.join(BENCHMARKS)}}} [options]", file=sys.stderr)
        return 2
    return int(importlib.import_module(f"{__name__}.{BENCHMARKS[argv[0]]}").main(argv[1:]) or 0)
