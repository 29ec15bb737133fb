"""dronesim: a distributed, deterministic, turn-based multi-drone simulator over Eclipse Zenoh."""

__version__ = "0.1.0"
