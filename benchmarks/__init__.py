"""Benchmarks run in-process (no network): ``python -m benchmarks.autopilot --help``."""
